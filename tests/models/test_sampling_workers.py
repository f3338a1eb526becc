"""The sampler's chunks of rows on several threads, and its float32 / float64 choice.

Rows are independent and their noise is drawn before any chunk runs, so concurrent chunks
write the same numbers as one thread; ``sampling_dtype`` picks float32 exactly when its
one-step moments are within ``PRECISION_TOL`` of float64's.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from _tolerances import EPS32

from skillkit.models.gp import ExactGP, ForwardModel, GPNumericalWarning
from skillkit.models.linear import LinearGaussianModel
from skillkit.models.sampling import PRECISION_TOL, sample_trajectories, sampling_dtype
from skillkit.models.sparse import FITC


def _data(n: int, seed: int, noise: float):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, size=(n, 2))
    u = rng.uniform(-1, 1, size=(n, 1))
    step = 0.3 * np.stack([np.sin(3 * x[:, 1]), -np.sin(3 * x[:, 0]) + u[:, 0]], axis=1)
    return x, u, x + step + noise * rng.standard_normal((n, 2))


@pytest.fixture(scope="module")
def model():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GPNumericalWarning)
        return ForwardModel(FITC(30, n_steps=25), target="delta").fit(*_data(300, 1, 0.05), rng=0)


def _policy(t, x, pair):
    return -0.8 * x[:, :1] + 0.1 * pair[:, None].to(x.dtype)


def _fell(k, x):
    return x[:, 0] > 0.8


@pytest.mark.parametrize("method", ["per-step", "pathwise"])
def test_threads_over_chunks_give_the_serial_result_bit_for_bit(model, method):
    """Eight chunks (a 3·E·M·8 = 1440-byte row, a 20 kB budget: 13 rows each) on one and on
    three threads: every output equal, with saturation, stopping and clamp counts exercised."""
    x0 = np.array([[0.1, -0.2], [0.4, 0.3], [-0.5, 0.0]])
    kw = dict(rng=4, control_limit=0.3, max_chunk_bytes=20_000, method=method, n_features=16)
    if method == "per-step":
        kw["stop"] = _fell
    serial = sample_trajectories(model, x0, _policy, 12, 33, workers=1, **kw)
    threaded = sample_trajectories(model, x0, _policy, 12, 33, workers=3, **kw)
    assert serial.n_saturated > 0
    for name in ("states", "controls", "stopped_at"):
        a, b = getattr(serial, name), getattr(threaded, name)
        assert (a is None and b is None) or torch.equal(a, b), name
    for name in ("n_saturated", "n_variance_clamped", "worst_variance", "precision_error"):
        assert getattr(serial, name) == getattr(threaded, name), name
    if method == "per-step":
        assert 0 < (serial.stopped_at < 12).sum() < serial.stopped_at.numel()


def test_an_error_in_one_chunk_is_raised_from_the_threads(model):
    def policy(t, x, pair):
        u = _policy(t, x, pair)
        return u if t < 3 else u * float("nan")

    with pytest.raises(ValueError, match="policy: returned non-finite controls"):
        sample_trajectories(model, [[0.0, 0.0]], policy, 5, 40, max_chunk_bytes=5000, workers=2)

    def broken(t, x, pair):
        raise RuntimeError("policy failed")

    with pytest.raises(RuntimeError, match="policy failed"):
        sample_trajectories(model, [[0.0, 0.0]], broken, 5, 40, max_chunk_bytes=5000, workers=2)


@pytest.mark.parametrize("bad", [0, -1, 1.5, "2"])
def test_bad_workers(model, bad):
    with pytest.raises(ValueError, match="workers"):
        sample_trajectories(model, [[0.0, 0.0]], _policy, 2, 2, workers=bad)


def _error(model, x, u) -> float:
    """The float32 moments' largest error against float64 (in sds, or relative variance)."""
    x, u = torch.as_tensor(x), torch.as_tensor(u)
    a = model.to(dtype=torch.float64).next_state_moments(x, u)
    b = model.to(dtype=torch.float32).next_state_moments(x.float(), u.float())
    return max(
        float(((b.mean.double() - a.mean).abs() / a.var.sqrt()).max()),
        float(((b.var.double() - a.var).abs() / a.var).max()),
    )


def test_sampling_dtype_is_float32_exactly_when_its_moments_are_close(model):
    """A linear-Gaussian model (moments off by float32 round-off, ~1e-7) and the noisy FITC
    model pass; an exact GP of 200 nearly noise-free x′ targets (σ_f²/σ_ε² ~ 1e4, large β)
    does not. The error reported is that of the ≤ 64 evenly spaced rows checked."""
    x, u, xn = _data(200, 0, 0.02)
    rows = np.unique(np.linspace(0, 199, 64).astype(int))
    linear = LinearGaussianModel().fit(x, u, xn)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GPNumericalWarning)
        stiff = ForwardModel(ExactGP(n_steps=25)).fit(x, u, xn, rng=0)
    for m, expected in ((linear, torch.float32), (model, torch.float32), (stiff, torch.float64)):
        dtype, error = sampling_dtype(m, x, u)
        assert dtype == expected
        assert error == pytest.approx(_error(m, x[rows], u[rows]), rel=1e-12)
    assert sampling_dtype(linear, x, u)[1] < 100 * EPS32
    assert sampling_dtype(stiff, x, u)[1] > PRECISION_TOL
    assert sampling_dtype(model, x[:5], u[:5])[1] == pytest.approx(_error(model, x[:5], u[:5]))
