"""Kernel contract: every kernel class in skillkit.models.kernels passes the same checks."""

from __future__ import annotations

import gpytorch
import numpy as np
import pytest
import torch
from _tolerances import fp_tol

from skillkit.models import kernels
from skillkit.models.kernels import (
    Linear,
    SquaredExponential,
    gram,
    linear_kernel,
    se_kernel,
    se_kernel_from_operands,
    se_operands,
)


def _se():
    return SquaredExponential(3, lengthscale=[0.5, 1.0, 2.0], outputscale=1.7)


def _se_batch():
    k = SquaredExponential(3, batch_shape=torch.Size([2]))
    k.lengthscale = torch.tensor([[[0.5, 1.0, 2.0]], [[1.5, 0.7, 0.9]]], dtype=torch.float64)
    k.outputscale = torch.tensor([1.7, 0.4], dtype=torch.float64)
    return k


def _linear():
    return Linear(variance=0.8, bias=0.3)


def _linear_batch():
    k = Linear(variance=1.0, bias=0.1, batch_shape=torch.Size([2]))
    k.variance = torch.tensor([0.8, 2.5], dtype=torch.float64)
    return k


FACTORIES = {"se": _se, "se_batch": _se_batch, "linear": _linear, "linear_batch": _linear_batch}
CLASSES = {SquaredExponential, Linear}


def test_contract_covers_every_kernel_in_the_module():
    defined = {
        obj
        for obj in vars(kernels).values()
        if isinstance(obj, type)
        and issubclass(obj, gpytorch.kernels.Kernel)
        and obj.__module__ == kernels.__name__
    }
    assert defined == CLASSES
    assert {type(f()) for f in FACTORIES.values()} == CLASSES


def _x(n=7, seed=0):
    return np.random.default_rng(seed).normal(size=(n, 3))


def _a2(k, x):
    """max ‖x / w‖² over the rows of ``x`` and the SE kernel ``k``'s batch entries (w its
    length-scales)."""
    return float(((torch.as_tensor(x) / k.lengthscale.detach()) ** 2).sum(-1).max())


def _gram_tol(k, x, z):
    """Absolute round-off of one Gram entry, two evaluation paths compared.

    SE: the exponent −½‖a − b‖² + log σ_f² (a = x/w) comes out of one (D + 2)-term product
    ``[a, −½‖a‖², 1]·[b, 1, −½‖b‖² + log σ_f²]``, off by ε (D + 2)(1 + ‖a‖² + ‖b‖²); k ≤ σ_f²
    times that. Linear: σ² x·z + c (D products, the scaling, the bias), off by
    ε (D + 2)(σ² ‖x‖ ‖z‖ + c).
    """
    d = x.shape[-1]
    if isinstance(k, SquaredExponential):
        os = float(k.outputscale.detach().max())
        return fp_tol(d + 2, scale=os * (1 + _a2(k, x) + _a2(k, z)))
    var, c = float(k.variance.detach().max()), float(torch.as_tensor(k.bias).max())
    nx = float(torch.as_tensor(x).norm(dim=-1).max())
    nz = float(torch.as_tensor(z).norm(dim=-1).max())
    return fp_tol(d + 2, scale=var * nx * nz + c)


@pytest.mark.parametrize("name", ["se", "linear"])
def test_gram_symmetric_psd(name):
    k = FACTORIES[name]()
    G = gram(k, _x(12))
    assert G.shape == (12, 12)
    # G_ij and G_ji come from different operand products (SE) or summation orders (linear).
    np.testing.assert_allclose(G, G.T, rtol=0, atol=_gram_tol(k, _x(12), _x(12)))
    assert np.linalg.eigvalsh(G).min() > -1e-10 * np.abs(G).max()


@pytest.mark.parametrize("name", list(FACTORIES))
def test_diag_matches_full(name):
    k = FACTORIES[name]()
    x = torch.as_tensor(_x(6))
    full = k.forward(x, x)
    diag = k.forward(x, x, diag=True)
    # diag: SE gives σ_f² exp(0) exactly, linear a D-term sum; full: the operand product.
    tol = _gram_tol(k, x, x)
    torch.testing.assert_close(diag, full.diagonal(dim1=-2, dim2=-1), rtol=0, atol=tol)


@pytest.mark.parametrize("name", ["se", "linear"])
def test_gram_equals_forward_and_gpytorch_call(name):
    k = FACTORIES[name]()
    X, Z = _x(5, 1), _x(4, 2)
    G = gram(k, X, Z)
    fwd = k.forward(torch.as_tensor(X), torch.as_tensor(Z)).detach().numpy()
    called = k(torch.as_tensor(X), torch.as_tensor(Z)).to_dense().detach().numpy()
    np.testing.assert_array_equal(G, fwd)  # gram() calls forward() on the same float64 inputs
    # gpytorch's lazy tensor evaluates the same forward(): equal up to an ulp at most.
    np.testing.assert_allclose(G, called, rtol=fp_tol(1))


@pytest.mark.parametrize("batch,single", [("se_batch", "se"), ("linear_batch", "linear")])
def test_batch_shapes_and_entries(batch, single):
    kb = FACTORIES[batch]()
    x1 = torch.as_tensor(np.random.default_rng(3).normal(size=(2, 5, 3)))
    x2 = torch.as_tensor(np.random.default_rng(4).normal(size=(2, 4, 3)))
    out = kb.forward(x1, x2)
    assert out.shape == (2, 5, 4)
    assert kb.forward(x1, x1, diag=True).shape == (2, 5)
    # Each batch entry equals an unbatched kernel with that entry's parameters.
    for i in range(2):
        if batch == "se_batch":
            ki = SquaredExponential(
                3,
                lengthscale=kb.lengthscale[i, 0].detach().numpy(),
                outputscale=float(kb.outputscale[i].detach()),
            )
        else:
            ki = Linear(variance=float(kb.variance[i].detach()), bias=kb.bias)
        # Batched vs unbatched products (different BLAS paths), and the parameters' round
        # trip through the positivity constraint (a few ulps, inside the safety factor).
        tol = _gram_tol(kb, x1[i], x2[i])
        torch.testing.assert_close(out[i], ki.forward(x1[i], x2[i]), rtol=fp_tol(4), atol=tol)


def test_se_closed_form_eq_2_25():
    X, Z = _x(4, 5), _x(3, 6)
    w = np.array([0.5, 1.0, 2.0])
    ref = 1.7 * np.exp(-0.5 * (((X[:, None, :] - Z[None, :, :]) / w) ** 2).sum(-1))
    # Round-off: the squared distance through ‖a‖² − 2a·b + ‖b‖² (a = x/w) is off by about
    # ε (D + 2)(‖a‖² + ‖b‖²), and k by k times that (exp adds an ulp). The diagonal is 1.7 up
    # to the same (k(x, x) ≤ σ_f²; rtol=1e-15 passed at 8.9e-16, half of it, on one CPU).
    a2 = lambda v: ((v / w) ** 2).sum(-1).max()  # noqa: E731
    rel = fp_tol(w.size + 2, scale=1.0 + a2(X) + a2(Z))  # ~2e-13
    np.testing.assert_allclose(gram(_se(), X, Z), ref, rtol=rel)
    np.testing.assert_allclose(gram(_se(), X, X).diagonal(), 1.7, rtol=fp_tol(5, 1 + 2 * a2(X)))


def test_linear_closed_form():
    X, Z = _x(4, 5), _x(3, 6)
    tol = _gram_tol(_linear(), X, Z)  # torch vs numpy 3-term products
    np.testing.assert_allclose(gram(_linear(), X, Z), 0.8 * X @ Z.T + 0.3, rtol=0, atol=tol)
    x = torch.as_tensor(X)
    torch.testing.assert_close(linear_kernel(x, x, 2.0, diag=True), 2.0 * (x * x).sum(-1))


def test_cached_operands_equal_closed_form_with_and_without_grad():
    rng = np.random.default_rng(7)
    x1, x2 = rng.normal(size=(2, 5, 3)), rng.normal(size=(2, 6, 3))
    ls = np.array([[[0.5, 1.0, 2.0]], [[1.5, 0.7, 0.9]]])
    os = np.array([1.7, 0.4])
    ref = os[:, None, None] * np.exp(
        -0.5 * (((x1[:, :, None, :] - x2[:, None, :, :]) / ls[:, :, None, :]) ** 2).sum(-1)
    )
    t = {k: torch.as_tensor(v) for k, v in dict(x1=x1, x2=x2, ls=ls, os=os).items()}
    support = se_operands(t["x2"], t["ls"], t["os"])
    with torch.no_grad():  # in-place path
        k = se_kernel_from_operands(se_operands(t["x1"], t["ls"]), support, torch.log(t["os"]))
    # Exponent off by ε (D + 2)(1 + ‖a‖² + ‖b‖²) (a = x/w), k relatively by that.
    a2 = lambda v: float(((v / ls) ** 2).sum(-1).max())  # noqa: E731
    rel = fp_tol(ls.shape[-1] + 2, scale=1 + a2(x1) + a2(x2))  # ~2e-13
    np.testing.assert_allclose(k.numpy(), ref, rtol=rel)
    q = se_operands(t["x1"].requires_grad_(), t["ls"])  # autograd path
    k = se_kernel_from_operands(q, support, torch.log(t["os"]))
    np.testing.assert_allclose(k.detach().numpy(), ref, rtol=rel)
    # k(x, x) = σ_f² (the round-off guard clamps the exponent at log σ_f², never above), up
    # to the exponent's round-off below the clamp, ε (D + 2)(1 + 2‖a‖²) as above, and
    # exp(log σ_f²)'s round trip (an ulp or two, inside the safety factor).
    with torch.no_grad():
        kxx = se_kernel(t["x1"], t["x1"], t["ls"], t["os"])
    assert torch.all(kxx <= t["os"][:, None, None])
    torch.testing.assert_close(
        kxx.diagonal(dim1=-2, dim2=-1),
        t["os"][:, None].expand(2, 5),
        rtol=fp_tol(ls.shape[-1] + 2, scale=1 + 2 * a2(x1)),
        atol=0,
    )


def test_se_kernel_gradcheck():
    rng = np.random.default_rng(9)
    x1 = torch.as_tensor(rng.normal(size=(4, 2)), dtype=torch.float64).requires_grad_()
    x2 = torch.as_tensor(rng.normal(size=(3, 2)), dtype=torch.float64)
    ls = torch.tensor([[0.8, 1.3]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, w: se_kernel(a, x2, w, 1.3), (x1, ls))


def test_bad_input():
    with pytest.raises(ValueError, match="Z"):
        gram(_se(), _x(3), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="X"):
        gram(_se(), np.array([[np.nan, 0.0, 0.0]]))
    with pytest.raises(ValueError, match="X"):
        gram(_se(), np.zeros(3))
    with pytest.raises(ValueError, match="lengthscale"):
        SquaredExponential(2, lengthscale=[-1.0, 1.0])
    with pytest.raises(ValueError, match="input_dim"):
        SquaredExponential(0)
    with pytest.raises(ValueError, match="outputscale"):
        SquaredExponential(2, outputscale=0.0)
    with pytest.raises(ValueError, match="variance"):
        Linear(variance=-1.0)
    with pytest.raises(ValueError, match="bias"):
        Linear(bias=-0.5)


@pytest.mark.parametrize("input_dim", [1, 2, 4])
def test_gram_rejects_inputs_whose_width_is_not_the_kernels(input_dim):
    """An ARD kernel of d inputs on data with 3 columns: a ValueError naming X, not one
    length-scale silently broadcast over every column (d = 1) or a torch size error."""
    with pytest.raises(ValueError, match=rf"X: expected {input_dim} columns"):
        gram(SquaredExponential(input_dim), _x(4))
    assert gram(Linear(), _x(4)).shape == (4, 4)  # no input dimension: any width


def test_kernel_parameters_name_the_argument():
    with pytest.raises(ValueError, match=r"lengthscale: expected a scalar or shape \(3,\)"):
        SquaredExponential(3, lengthscale=[1.0, 2.0])
    with pytest.raises(ValueError, match="outputscale"):
        SquaredExponential(2, outputscale="large")
    with pytest.raises(ValueError, match="variance"):
        Linear(variance=None)
    with pytest.raises(ValueError, match="bias"):
        Linear(bias=float("nan"))
