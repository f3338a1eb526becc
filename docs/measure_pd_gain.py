"""The balancing PD controller's design grid: stability at 20 Hz, gain size, and rollouts.

:meth:`~skillkit.tasks.balancing.Balancing.pd_gain` places the continuous closed-loop poles
of the linearised robot at −ζω ± ω√(ζ² − 1). Holding each torque for 50 ms moves the
discrete poles; this script prints, per (ω, ζ), the spectral radius of the 20 Hz closed loop
A + B G, the largest gain, and from 30 rollouts each in Sec. 5.4's setting (initial std 0.3,
torque noise 4 N m) and Sec. 4.2.3's (0.1, 0.5) the failures and the RMS joint-angle deviation
over the second half. For comparison it prints the LQR gains' largest entries. Run from the
repository root::

    OMP_NUM_THREADS=1 python docs/measure_pd_gain.py

Measured for issue #16 (seed 1): the default ω = 3, ζ = 1.5 is the lowest stiffness on the
grid with spectral radius ≤ 0.95 (0.944, largest gain 1.9e3 N m/rad; RMS 0.256 and 0.040 rad,
no failures); ω = 3, ζ = 1 is unstable (1.02). The LQR gains are 1.4e3 (R = 1e-4) and 1.3e3
(R = 1, minimum effort): no lower-gain controller balances this robot at 20 Hz.
"""

import numpy as np

from skillkit.tasks import make
from skillkit.tasks.planar_model import UPRIGHT


def main(seed: int = 1) -> None:
    rng = np.random.default_rng(seed)
    task = make("balancing")
    A, B = task.linearization()
    print(f"LQR largest gain: R = 1e-4 {np.abs(task.lqr_gain()).max():.0f}, "
          f"R = 1 {np.abs(task.lqr_gain(control_weight=1.0)).max():.0f}")  # fmt: skip
    print(f"{'ω':>4} {'ζ':>4} {'ρ(A+BG)':>8} {'max|G|':>7}  RMS q̃ (fails): σ0 0.3/4 N m, 0.1/0.5")
    for w in (2.5, 3.0, 4.0, 5.0, 6.0):
        for z in (0.7, 1.0, 1.5, 2.0):
            G = task.pd_gain(w, z)
            rho = np.abs(np.linalg.eigvals(A + B @ G)).max()
            cells = []
            for s0, noise in ((0.3, 4.0), (0.1, 0.5)):
                t = make("balancing", initial_std=s0, torque_noise_std=noise, n_steps=40)
                trajs = [t.rollout(G.ravel(), rng=rng) for _ in range(30)] if rho < 1 else []
                ok = [x for x in trajs if not x.failed]
                q = np.array([x.states[20:, :4] - UPRIGHT for x in ok])
                rms = np.sqrt((q**2).mean()) if ok else np.nan
                cells.append(f"{rms:.3f} ({len(trajs) - len(ok)})" if trajs else "unstable")
            print(f"{w:>4} {z:>4} {rho:>8.3f} {np.abs(G).max():>7.0f}  " + ", ".join(cells))


if __name__ == "__main__":
    main()
