"""Sparse GPs (FITC, VFE): reduce to the exact GP, bound it, train, survive bad data."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from skillkit.models.gp import ExactGP
from skillkit.models.sparse import FITC, VFE, kmeans_pp


def _data(n=50, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-3, 3, size=(n, 2))
    Y = np.stack(
        [np.sin(X[:, 0]) + 0.1 * rng.standard_normal(n), X[:, 0] * np.cos(X[:, 1])], axis=1
    )
    return X, Y


HYPERS = dict(
    lengthscale=[[1.0, 1.5], [0.8, 1.2]], outputscale=1.2, noise=0.05, n_steps=0, additive_noise=0.0
)


@pytest.mark.parametrize("cls", [FITC, VFE])
def test_pseudo_inputs_at_training_inputs_equal_exact_gp(cls):
    X, Y = _data()
    exact = ExactGP(**HYPERS).fit(X, Y)
    sparse = cls(inducing=X, optimize_inducing=False, jitter=1e-10, **HYPERS).fit(X, Y)
    Xs = np.random.default_rng(1).uniform(-4, 4, size=(30, 2))
    me, ve = exact.predict(Xs)
    ms, vs = sparse.predict(Xs)
    np.testing.assert_allclose(ms, me, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(vs, ve, rtol=1e-5, atol=1e-7)
    assert sparse.diagnostics["log_marginal_likelihood"] == pytest.approx(
        exact.diagnostics["log_marginal_likelihood"].sum(), rel=1e-6
    )


def test_vfe_bound_below_exact_and_fitc_differs():
    X, Y = _data()
    exact = ExactGP(**HYPERS).fit(X, Y)
    lml = exact.diagnostics["log_marginal_likelihood"].sum()
    for seed in range(3):
        Z = np.random.default_rng(seed).uniform(-3, 3, size=(8, 2))
        vfe = VFE(inducing=Z, optimize_inducing=False, **HYPERS).fit(X, Y)
        assert vfe.diagnostics["log_marginal_likelihood"] < lml
    fitc = FITC(inducing=Z, optimize_inducing=False, **HYPERS).fit(X, Y)
    assert fitc.diagnostics["log_marginal_likelihood"] != pytest.approx(lml, rel=1e-3)


@pytest.mark.parametrize("cls", [FITC, VFE])
def test_training_improves_objective_and_moves_pseudo_inputs(cls):
    X, Y = _data(120, seed=2)
    gp = cls(n_inducing=12, n_steps=40, additive_noise=0.0).fit(X, Y, rng=0)
    trace = gp.diagnostics["objective_trace"]
    assert min(trace) < trace[0]
    assert gp.diagnostics["n_inducing"] == 12
    start = X[kmeans_pp(X / X.std(axis=0), 12, np.random.default_rng(0))]
    assert not np.allclose(gp.predictor.support[0].numpy(), start)
    fixed = cls(n_inducing=12, n_steps=10, optimize_inducing=False, additive_noise=0.0).fit(
        X, Y, rng=0
    )
    np.testing.assert_array_equal(fixed.predictor.support[0].numpy(), start)
    Xs = np.random.default_rng(3).uniform(-2.5, 2.5, size=(100, 2))
    mean, var = gp.predict(Xs)
    truth = np.stack([np.sin(Xs[:, 0]), Xs[:, 0] * np.cos(Xs[:, 1])], axis=1)
    assert np.sqrt(np.mean((mean - truth) ** 2)) < 0.25 and np.all(var > 0)


def test_variance_factor_matches_ik():
    X, Y = _data(80)
    gp = FITC(n_inducing=15, n_steps=10).fit(X, Y, rng=0)
    p = gp.predictor
    RtR = p.var_factor.transpose(-1, -2) @ p.var_factor
    torch.testing.assert_close(RtR, p.iK, rtol=1e-6, atol=1e-6 * float(p.iK.abs().max()))
    assert np.linalg.eigvalsh(p.iK.numpy()).min() > -1e-8 * float(p.iK.abs().max())


def test_many_points_with_duplicates_and_constant_targets():
    rng = np.random.default_rng(4)
    X = np.repeat(rng.uniform(-2, 2, size=(1000, 3)), 10, axis=0)  # 10,000 points
    Y = np.stack([np.sin(X).sum(1), np.full(len(X), -1.0)], axis=1)
    gp = FITC(n_inducing=30, n_steps=4).fit(X, Y, rng=0)
    mean, var = gp.predict(rng.uniform(-3, 3, size=(200, 3)))
    _, fvar = gp.predict(rng.uniform(-3, 3, size=(200, 3)), include_noise=False)
    assert np.all(np.isfinite(mean)) and np.all(var > 0) and np.all(fvar >= 0)
    np.testing.assert_allclose(mean[:, 1], -1.0, atol=1e-6)
    assert gp.diagnostics["constant_outputs"] == [1]


def test_kmeans_pp_spreads_over_clusters_and_is_seeded():
    rng = np.random.default_rng(5)
    centres = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0]])
    X = np.vstack([c + 0.01 * rng.standard_normal((30, 2)) for c in centres])
    idx = kmeans_pp(X, 3, np.random.default_rng(0))
    assert sorted(i // 30 for i in idx) == [0, 1, 2]
    np.testing.assert_array_equal(idx, kmeans_pp(X, 3, np.random.default_rng(0)))
    dup = np.repeat(X[:4], 5, axis=0)
    idx = kmeans_pp(dup, 4, np.random.default_rng(1))
    assert len({tuple(dup[i]) for i in idx}) == 4  # never the same point twice while others remain
    assert len(set(kmeans_pp(dup, 20, np.random.default_rng(1)))) == 20


def test_more_pseudo_inputs_than_data_uses_all_data():
    X, Y = _data(20)
    gp = FITC(n_inducing=50, n_steps=0).fit(X, Y)
    assert gp.diagnostics["n_inducing"] == 20


def test_bad_input():
    X, Y = _data(20)
    with pytest.raises(ValueError, match="n_inducing"):
        FITC(n_inducing=0)
    with pytest.raises(ValueError, match="inducing"):
        FITC(inducing=np.zeros((5, 3)), n_steps=0).fit(X, Y)
    with pytest.raises(ValueError, match="inducing"):
        VFE(inducing=np.full((5, 2), np.nan))
    with pytest.raises(ValueError, match="jitter"):
        FITC(jitter=-1.0)
    with pytest.raises(ValueError, match=r"n: expected 1 <= n <= 20, got 0"):
        kmeans_pp(X, 0, np.random.default_rng(0))


# ---------------------------------------------------------------------------- device
def _fit_outputs(gp, X_test):
    """Everything a fit returns, as numpy arrays: predictor tensors, θ, log ML, predictions."""
    fields = ("support", "lengthscale", "outputscale", "noise", "beta", "iK", "var_factor")
    out = {f: getattr(gp.predictor, f).cpu().numpy() for f in fields}
    out.update({f"h_{k}": v for k, v in gp.hyperparameters.items()})
    out["lml"] = np.asarray(gp.diagnostics["log_marginal_likelihood"])
    out["mean"], out["var"] = gp.predict(X_test)
    return out


@pytest.mark.parametrize("cls", [FITC, VFE])
def test_explicit_cpu_device_is_bit_identical_to_default(cls):
    X, Y = _data(40)
    default = _fit_outputs(cls(n_inducing=8, n_steps=15).fit(X, Y, rng=3), X[:6] + 0.1)
    gp = cls(n_inducing=8, n_steps=15, device="cpu").fit(X, Y, rng=3)
    explicit = _fit_outputs(gp, X[:6] + 0.1)
    for key, value in default.items():
        np.testing.assert_array_equal(explicit[key], value, err_msg=key)
    tensors = [gp.X, gp.Y, gp.inducing, *gp.kernel.parameters(), *gp.likelihood.parameters()]
    tensors += [gp.predictor.support, gp.predictor.beta, gp.predictor.iK, gp.predictor.y_scale]
    assert all(t.device == torch.device("cpu") and t.dtype == torch.float64 for t in tensors)


@pytest.mark.parametrize("cls", [FITC, VFE])
def test_bad_device_raises(cls):
    with pytest.raises(ValueError, match="device"):
        cls(n_inducing=5, device="nonsense")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="device: .*CUDA is not available"):
            cls(n_inducing=5, device="cuda")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("cls", [FITC, VFE])
def test_cuda_fit_matches_cpu(cls):
    X, Y = _data(40)
    outs = {}
    for device in ("cpu", "cuda"):
        gp = cls(n_inducing=8, n_steps=10, device=device).fit(X, Y, rng=3)
        assert gp.predictor.device.type == device and gp.inducing.device.type == device
        outs[device] = _fit_outputs(gp, X[:6] + 0.1)
        # R = diag(√(1 − 1/a)) Uᵀ Lm⁻¹ is unique only up to the sign of each row (eigh's
        # eigenvectors: LAPACK and cuSOLVER choose differently): compare the invariant RᵀR = iK.
        r = outs[device].pop("var_factor")
        outs[device]["RtR"] = np.swapaxes(r, -1, -2) @ r
    for key, value in outs["cpu"].items():
        np.testing.assert_allclose(
            outs["cuda"][key], value, rtol=1e-8, atol=1e-8 * np.abs(value).max(), err_msg=key
        )
    np.testing.assert_allclose(
        outs["cuda"]["RtR"],
        outs["cuda"]["iK"],
        rtol=1e-8,
        atol=1e-8 * np.abs(outs["cuda"]["iK"]).max(),
    )
