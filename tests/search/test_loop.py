"""The model-free learning loop (Table 3.1): collection, evaluation, bookkeeping, extra
contexts, checkpoint and resume, progress, determinism, bad input."""

import warnings

import numpy as np
import pytest

from skillkit.models.kernels import Linear
from skillkit.policies.gaussian import GaussianPolicy
from skillkit.search.base import Batch
from skillkit.search.crkr import CrKR
from skillkit.search.loop import N_EVAL_CONTEXTS, Evaluator, LoopState, collect, learn
from skillkit.search.reps import ContextualREPS
from skillkit.search.rwr import RWR
from skillkit.tasks.base import Task
from skillkit.tasks.functional import FunctionTask
from skillkit.tasks.toy import LinearTarget
from skillkit.trajectory import Trajectory
from skillkit.trial import NullBar, TrialContext
from tests._snapshots import Snapshots
from tests._tolerances import fp_tol

Target = LinearTarget  # R(s, ω) = −‖ω − 2s‖²; the trajectory is ω itself


class TargetInScene(Target):
    name = "target-in-scene"
    trajectory_depends_on_context = True


class Bowl(Task):
    """Context-free: R(ω) = −‖ω − 1‖²."""

    name = "bowl"
    parameter_dim = 2

    def _simulate(self, omega, context, rng):
        return Trajectory(np.zeros(1), omega[None, :], np.zeros((1, 0)))

    def _reward(self, trajectory, context):
        return float(-np.sum((trajectory.states[0] - 1.0) ** 2))

    def initial_policy(self):
        return GaussianPolicy(np.zeros(2), np.eye(2))


class NoisyBowl(Bowl):
    """Bowl with a noisy outcome: the trajectory is ω plus noise from the rollout's stream."""

    name = "noisy-bowl"

    def _simulate(self, omega, context, rng):
        return Trajectory(np.zeros(1), (omega + rng.standard_normal(2))[None, :], np.zeros((1, 0)))


class Recorder:
    """A fake algorithm: fixed policy, records what update receives."""

    def __init__(self, policy):
        self.policy = policy
        self.batches = []

    def update(self, batch):
        self.batches.append(batch)
        return len(batch)


class Progress(NullBar):
    def __init__(self):
        self.total, self.count, self.postfix = None, 0, None

    def reset(self, total=None):
        self.total, self.count = total, 0

    def update(self, n=1):
        self.count += n

    def set_postfix(self, *args, **kwargs):
        self.postfix = kwargs


def test_bookkeeping_curves_and_callbacks():
    task = Target()
    alg = Recorder(task.initial_policy())
    bar, calls = Progress(), []
    eval_s = np.array([[0.5, -0.5], [0.0, 1.0]])
    trial = TrialContext(bar)
    trial.reset(total=4)  # the trial's owner sets the total; learn advances it
    res = learn(
        task,
        alg,
        4,
        6,
        0,
        trial=trial,
        eval_contexts=eval_s,
        callback=lambda k, a: calls.append(k),
    )
    assert bar.total == 4 and bar.count == 4 and calls == [0, 1, 2, 3, 4]
    assert float(bar.postfix["mean_reward"]) == pytest.approx(res["mean_reward"][-1], rel=1e-3)
    np.testing.assert_array_equal(res["rollouts"], [0, 6, 12, 18, 24])
    np.testing.assert_array_equal(res["explore_rollouts"], [6, 12, 18, 24])
    assert res["diagnostics"] == [6, 6, 6, 6] and np.all(res["n_failed"] == 0)
    # the policy never changes: the mean reward is the initial mean's reward, computed directly
    expected = np.mean([-np.sum((np.zeros(2) - 2 * s) ** 2) for s in eval_s])
    np.testing.assert_allclose(res["mean_reward"], expected)
    for batch, er in zip(alg.batches, res["explore_reward"], strict=True):
        s, w, r = batch.contexts, batch.omegas, batch.rewards
        assert len(batch.trajectories) == 6
        np.testing.assert_allclose(r, -np.sum((w - 2 * s) ** 2, axis=1))
        assert er == pytest.approx(r.mean())
        assert np.all(np.abs(s) <= 1)
    assert res["policy"] is alg.policy


def test_extra_contexts_rescore_each_trajectory():
    task = Target()
    alg = Recorder(task.initial_policy())
    res = learn(task, alg, 2, 5, 1, extra_contexts=3)
    for batch in alg.batches:
        s, w, r = batch.contexts, batch.omegas, batch.rewards
        assert s.shape == (20, 2) and w.shape == (20, 2) and r.shape == (20,)
        # each ω appears once with its own context and then 3 times with fresh ones
        np.testing.assert_array_equal(w[5:], np.repeat(w[:5], 3, axis=0))
        # ... and so does its trajectory, the very object that was re-scored
        assert all(t is batch.trajectories[i // 3] for i, t in enumerate(batch.trajectories[5:]))
        np.testing.assert_allclose(r, -np.sum((w - 2 * s) ** 2, axis=1))
        assert len({tuple(c) for c in s}) == 20
    # the exploratory curve only counts the real rollouts
    assert res["explore_reward"][0] == alg.batches[0].rewards[:5].mean()


def test_extra_contexts_refused_when_trajectory_depends_on_context():
    with pytest.raises(ValueError, match="extra_contexts"):
        learn(TargetInScene(), Recorder(Target().initial_policy()), 1, 5, 0, extra_contexts=2)
    with pytest.raises(ValueError, match="extra_contexts"):
        learn(Bowl(), Recorder(Bowl().initial_policy()), 1, 5, 0, extra_contexts=2)


def test_same_seed_same_curves_and_reps_learns():
    task = Target()

    def run(seed):
        alg = ContextualREPS(task.initial_policy(), 0.5, n_reuse_batches=4)
        return learn(task, alg, 15, 20, seed)

    a, b, c = run(3), run(3), run(4)
    for key in ("mean_reward", "explore_reward"):
        np.testing.assert_array_equal(a[key], b[key])
    assert not np.array_equal(a["explore_reward"], c["explore_reward"])
    np.testing.assert_array_equal(a["policy"].coefficients, b["policy"].coefficients)
    assert a["eval_contexts"].shape == (N_EVAL_CONTEXTS, 2)
    assert a["mean_reward"][-1] > 0.2 * a["mean_reward"][0]  # rewards are ≤ 0: closer to 0


def test_context_free_task():
    task = Bowl()
    res = learn(task, ContextualREPS(task.initial_policy(), 1.0), 5, 20, 0)
    assert res["eval_contexts"].shape == (N_EVAL_CONTEXTS, 0)
    assert res["mean_reward"][-1] > res["mean_reward"][0]


def test_bad_input_names_the_argument():
    task = Target()
    alg = Recorder(task.initial_policy())
    with pytest.raises(ValueError, match="n_updates"):
        learn(task, alg, 0, 5, 0)
    with pytest.raises(ValueError, match="rollouts_per_update"):
        learn(task, alg, 1, 0, 0)
    with pytest.raises(ValueError, match="extra_contexts"):
        learn(task, alg, 1, 5, 0, extra_contexts=-1)
    with pytest.raises(ValueError, match="eval_contexts"):
        learn(task, alg, 1, 5, 0, eval_contexts=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="eval_contexts"):
        learn(task, alg, 1, 5, 0, eval_contexts=np.full((3, 2), 5.0))  # outside μ(s)'s range
    with pytest.raises(ValueError, match="algorithm"):
        learn(task, Recorder(GaussianPolicy(np.zeros(2), np.eye(2))), 1, 5, 0)
    with pytest.raises(ValueError, match="task"):
        learn("target", alg, 1, 5, 0)
    with pytest.raises(ValueError, match="rng"):
        learn(task, alg, 1, 5, -3)
    with pytest.raises(ValueError, match="trial"):
        learn(task, alg, 1, 5, 0, trial=Progress())  # a bar is not a trial context
    with pytest.raises(ValueError, match="extra_contexts"):
        collect(TargetInScene(), alg.policy, 5, 0, extra_contexts=1)
    with pytest.raises(ValueError, match="n"):
        collect(task, alg.policy, 0, 0)


# --------------------------------------------------------------------------- the pieces
def test_collect_draws_a_validated_batch_in_a_fixed_order():
    task, pol = Target(), Target().initial_policy()
    batch = collect(task, pol, 4, np.random.default_rng(5), extra_contexts=2)
    assert isinstance(batch, Batch) and len(batch) == 12 and len(batch.trajectories) == 12
    # the documented draw order: contexts, parameters, rollouts, extra contexts
    rng = np.random.default_rng(5)
    s = task.sample_context(rng, n=4)
    w = pol.sample(s, rng)
    extra = task.sample_context(rng, n=8)
    np.testing.assert_array_equal(batch.contexts, np.concatenate([s, extra]))
    np.testing.assert_array_equal(batch.omegas[:4], w)
    np.testing.assert_allclose(batch.rewards, -np.sum((batch.omegas - 2 * batch.contexts) ** 2, 1))
    again = collect(task, pol, 4, np.random.default_rng(5), extra_contexts=2)
    np.testing.assert_array_equal(again.rewards, batch.rewards)


def test_evaluator_uses_common_random_numbers():
    task = Target()
    rng = np.random.default_rng(2)
    ev = Evaluator.draw(task, rng)
    check = np.random.default_rng(2)
    np.testing.assert_array_equal(ev.contexts, task.sample_context(check, n=N_EVAL_CONTEXTS))
    assert ev.seed == int(check.integers(2**63))  # the seed is drawn after the contexts
    pol = task.initial_policy()
    assert ev(pol) == ev(pol)  # same noise every call
    expected = np.mean([-np.sum((0 - 2 * s) ** 2) for s in ev.contexts])
    assert ev(pol) == (pytest.approx(expected), 0.0)  # (mean, failure rate)
    with pytest.raises(ValueError, match="eval_contexts"):
        Evaluator.draw(task, rng, np.zeros((0, 2)))
    # A given seed replaces the drawn one, and the stream advances as without it.
    a, b = np.random.default_rng(5), np.random.default_rng(5)
    fixed = Evaluator.draw(task, a, seed=123)
    drawn = Evaluator.draw(task, b)
    assert fixed.seed == 123 and drawn.seed != 123
    np.testing.assert_array_equal(fixed.contexts, drawn.contexts)
    assert a.integers(2**63) == b.integers(2**63)
    with pytest.raises(ValueError, match="eval_seed"):
        Evaluator.draw(task, rng, seed=-1)


def test_runs_with_one_eval_seed_are_evaluated_on_the_same_noise():
    """Two context-free runs with different learning streams and one ``eval_seed`` score the
    same initial policy identically; without it, they draw different evaluation noise."""
    task = NoisyBowl()
    same = [
        learn(
            task, _reps(task), 1, 20, s, progress=False, eval_contexts=np.zeros((4, 0)), eval_seed=7
        )["mean_reward"][0]
        for s in (1, 2)
    ]
    assert same[0] == same[1]
    own = [
        learn(task, _reps(task), 1, 20, s, progress=False, eval_contexts=np.zeros((4, 0)))[
            "mean_reward"
        ][0]
        for s in (1, 2)
    ]
    assert own[0] != own[1]


def _reps(task):
    return ContextualREPS(task.initial_policy(), 0.5, n_reuse_batches=3)


def _assert_same_run(a, b):
    for key in ("rollouts", "mean_reward", "explore_reward", "n_failed", "eval_contexts"):
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert [d.eta for d in a["diagnostics"]] == [d.eta for d in b["diagnostics"]]
    assert a["callback"] == b["callback"]
    for p, q in zip(a["policies"], b["policies"], strict=True):
        np.testing.assert_array_equal(p.coefficients, q.coefficients)
        np.testing.assert_array_equal(p.cov, q.cov)


def test_checkpointed_learning_resumes_to_identical_numbers():
    task = Target()

    def record(k, a):
        return float(a.policy.mean[0])

    plain = learn(task, _reps(task), 6, 10, 4, progress=False, callback=record)
    full = Snapshots()
    reference = learn(task, _reps(task), 6, 10, 4, trial=full, callback=record)
    _assert_same_run(plain, reference)  # checkpointing does not change the numbers
    assert len(full.history) == 6
    state = full.resume("learn", np.random.default_rng())
    assert isinstance(state, LoopState) and state.k == 6
    for k in (0, 2, 5):  # resume after update k + 1, with a fresh algorithm object
        alg = _reps(task)
        resumed = learn(
            task, alg, 6, 10, 4, trial=Snapshots(states=full.history[k]), callback=record
        )
        _assert_same_run(reference, resumed)
        assert resumed["policy"] is alg.policy and alg.n_updates == 6
    with pytest.raises(ValueError, match="n_updates"):  # a longer run's state does not fit
        learn(task, _reps(task), 5, 10, 4, trial=Snapshots(states=full.snapshots))


def test_interrupted_learning_resumes_in_memory():
    """A run stopped mid-update (here by its callback) continues from its last save."""
    task = Target()
    reference = learn(task, _reps(task), 5, 10, 8, progress=False)

    class Stop(Exception):
        pass

    def stop_at_3(k, a):
        if k == 3:
            raise Stop

    trial, alg = TrialContext(), _reps(task)
    with pytest.raises(Stop):
        learn(task, alg, 5, 10, 8, trial=trial, callback=stop_at_3)
    # the algorithm has done update 3, the checkpoint holds the state after update 2
    assert alg.n_updates == 3 and trial.resume("learn", np.random.default_rng()).k == 2
    _assert_same_run(reference, learn(task, alg, 5, 10, 8, trial=trial))


def test_resuming_with_other_batch_sizes_is_refused():
    # The saved state's rollout counts are N₀ + (k − 1) N: resuming with another N would
    # relabel the finished updates (rollouts 0, 20, 40, 60, 80 after three batches of 10).
    task = Target()
    trial = TrialContext()
    learn(task, _reps(task), 3, 10, 0, trial=trial)
    with pytest.raises(ValueError, match="rollouts_per_update: .* 10 rollouts per update, got 20"):
        learn(task, _reps(task), 4, 20, 0, trial=trial)
    with pytest.raises(ValueError, match="initial_rollouts: .* 10 rollouts, got 15"):
        learn(task, _reps(task), 4, 10, 0, trial=trial, initial_rollouts=15)
    first = TrialContext()
    learn(task, _reps(task), 2, 10, 0, trial=first, initial_rollouts=15)
    with pytest.raises(ValueError, match="initial_rollouts: .* 15 rollouts, got 10"):
        learn(task, _reps(task), 3, 10, 0, trial=first)
    resumed = learn(task, _reps(task), 3, 10, 0, trial=first, initial_rollouts=15)
    np.testing.assert_array_equal(resumed["rollouts"], [0, 15, 25, 35])
    # a state saved before N was recorded (no attribute) resumes as before
    state = first.resume("learn", np.random.default_rng())
    del state.__dict__["rollouts_per_update"]
    first.save("learn", state, np.random.default_rng(0))
    old = learn(task, _reps(task), 4, 10, 0, trial=first, initial_rollouts=15)
    np.testing.assert_array_equal(old["rollouts"], [0, 15, 25, 35, 45])


def test_evaluator_draw_normalises_rng_and_refuses_a_bool_seed():
    task = Target()
    by_int = Evaluator.draw(task, 3)
    by_gen = Evaluator.draw(task, np.random.default_rng(3))
    np.testing.assert_array_equal(by_int.contexts, by_gen.contexts)
    assert by_int.seed == by_gen.seed
    with pytest.raises(ValueError, match="eval_seed"):
        Evaluator.draw(task, 0, seed=True)
    with pytest.raises(ValueError, match="rng"):
        Evaluator.draw(task, "seed")


def test_default_progress_bar_shows_and_warns_nothing(capsys):
    task = Target()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning (e.g. from tqdm.auto) fails the test
        shown = learn(task, _reps(task), 3, 5, 0)
    err = capsys.readouterr().err
    assert "3/3" in err and "mean_reward" in err and "arning" not in err
    quiet = learn(task, _reps(task), 3, 5, 0, progress=False)
    assert capsys.readouterr().err == ""
    _assert_same_run(shown, quiet)


# --------------------------------------------------------------------------- reprs
def _short(obj, *needles):
    text = repr(obj)
    assert len(text) < 300 and "\n" not in text and "array" not in text, text
    for needle in needles:
        assert needle in text, (needle, text)
    return text


def test_reprs_are_short_and_informative():
    task = Target()
    rng = np.random.default_rng(0)
    batch = collect(task, task.initial_policy(), 30, rng)
    reps = ContextualREPS(task.initial_policy(), 0.5, n_reuse_batches=4)
    _short(reps, "ContextualREPS", "epsilon=0.5", "dim=2", "context_dim=2", "0 updates")
    d = reps.update(batch)
    _short(reps, "reuse=4 batches", "1 updates", "30 samples kept")
    _short(d, f"eta={d.eta:.4g}", f"kl={d.kl:.4g}", "epsilon=0.5", f"ess={d.ess:.4g}")
    _short(d, "n_samples=30", "success=True")
    rwr = RWR(task.initial_policy(), beta_scale=2.0, n_reuse_batches=None)
    d = rwr.update(batch)
    _short(rwr, "RWR", "beta_scale=2", "reuse=all batches", "1 updates")
    _short(d, f"beta={d.beta:.4g}", f"ess={d.ess:.4g}", "n_samples=30")
    crkr = CrKR(task.initial_policy(), Linear(1.0), lam=0.5)
    d = crkr.update(batch)
    _short(crkr, "CrKR", "lam=0.5", "kernel=Linear", "1 updates", "30 samples kept")
    _short(d, f"beta={d.beta:.4g}", "n_samples=30")
    _short(
        batch, "N=30", "dim=2", "context_dim=2", f"{batch.rewards.mean():.4g}", "trajectories: 30"
    )
    res_trial = TrialContext()
    learn(task, _reps(task), 2, 5, 0, trial=res_trial)
    state = res_trial.resume("learn", np.random.default_rng())
    _short(state, "k=2", f"{state.mean_reward[-1]:.4g}", "ContextualREPS")
    _short(Evaluator.draw(task, rng), "20 contexts", "target")
    _short(res_trial, "learn")


# --------------------------------------------------------------------------- failed evaluations
FAIL_P = 0.3


def _target_failing_30pc(omega, context, rng):
    """R = −‖ω − 2s‖², the rollout failing (NaN) with probability 0.3 from its own stream."""
    if rng.random() < FAIL_P:
        return np.nan
    return -float(np.sum((omega - 2 * context) ** 2))


def test_evaluation_leaves_failed_rollouts_out_of_the_mean_and_reports_their_rate():
    task = FunctionTask(_target_failing_30pc, 2, context_low=[-1, -1], context_high=[1, 1])
    m, seed = 50, 11
    eval_s = task.sample_context(np.random.default_rng(1), n=m)
    with pytest.warns(RuntimeWarning, match="rollout failed"):
        res = learn(task, _reps(task), 12, 30, 0, eval_contexts=eval_s, eval_seed=seed)

    def independent(policy):  # the raw function on the evaluator's re-seeded stream
        rng = np.random.default_rng(seed)
        pairs = zip(policy.mean_of(eval_s), eval_s, strict=True)
        r = np.array([_target_failing_30pc(w, s, rng) for w, s in pairs])
        ok = r[np.isfinite(r)]
        return ok.mean(), 1 - ok.size / m

    expected = np.array([independent(p) for p in res["policies"]])
    # same-sign sums of at most m terms
    np.testing.assert_allclose(res["mean_reward"], expected[:, 0], rtol=fp_tol(m))
    np.testing.assert_allclose(res["eval_failure_rate"], expected[:, 1], rtol=fp_tol(2))
    # one Binomial(m, 0.3) draw (common random numbers): within 4 standard errors of 0.3
    assert abs(res["eval_failure_rate"][0] - FAIL_P) < 4 * np.sqrt(FAIL_P * (1 - FAIL_P) / m)
    assert np.all(res["eval_failure_rate"] > 0)
    # the mean over successes shows the learning that −1e6 per failure would hide
    assert res["mean_reward"][-1] > 0.5 * res["mean_reward"][0]
    assert np.all(res["mean_reward"] > task.worst_reward / 1e3)
    assert res["n_failed"].sum() > 0


def _always_fails(omega, context, rng):
    raise RuntimeError("diverged")


def test_evaluation_of_a_policy_whose_rollouts_all_fail_has_a_nan_mean():
    task = FunctionTask(_always_fails, 2)
    ev = Evaluator.draw(task, 0, np.zeros((3, 0)))
    with pytest.warns(RuntimeWarning, match="rollout failed"):
        mean, rate = ev(task.initial_policy())
    assert np.isnan(mean) and rate == 1.0
    mean, rate = Evaluator.draw(Bowl(), 0)(Bowl().initial_policy())
    assert mean == pytest.approx(-2.0) and rate == 0.0
