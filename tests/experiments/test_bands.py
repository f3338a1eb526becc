"""Every band of every experiment says what it is, and says it truly.

Over every registered id at the smoke scale, with its default trial count and with two trials
(so every band over trials is drawn): a series with ``lower`` / ``upper`` has a ``band`` text;
"over n trials" names the run's trial count; a "mean ± …" band is symmetric about the curve
and a geometric one symmetric in log; one trial draws no band.
"""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from skillkit.experiments.ch2_gp import GP_BAND
from skillkit.experiments.registry import get, ids
from skillkit.experiments.runner import run_trials, to_jsonable
from skillkit.viz.series import band_text, mean_band, trial_band

IDS = ids()
ROOT = Path(__file__).resolve().parents[2]
_CACHE: dict[tuple[str, int | None], dict] = {}


def _run(exp_id: str, trials: int | None = None) -> dict:
    """The smoke-scale result (strict JSON form, plus ``_trials``), computed once."""
    if (exp_id, trials) not in _CACHE:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            r = run_trials(exp_id, "smoke", trials=trials, seed=0, progress=False)
        raw = r.pop("_trials")
        r = json.loads(json.dumps(to_jsonable(r)))
        r["_trials"] = raw
        _CACHE[exp_id, trials] = r
    return _CACHE[exp_id, trials]


def _array(values) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], dtype=float)


@pytest.mark.parametrize("trials", [None, 2], ids=["default-trials", "2-trials"])
@pytest.mark.parametrize("exp_id", IDS)
def test_every_band_says_what_it_is(exp_id, trials):
    result = _run(exp_id, trials)
    n = result["trials"]
    assert n == len(result["_trials"]) == (trials or get(exp_id).trials["smoke"])
    for s in result["series"]:
        if s.get("lower") is None and s.get("upper") is None:
            assert "band" not in s, f"{s['name']}: a band text without a band"
            continue
        band = s.get("band")
        assert isinstance(band, str) and band.strip(), f"{exp_id} {s['name']!r}: band unlabelled"
        y, lo, hi = _array(s["y"]), _array(s["lower"]), _array(s["upper"])
        ok = np.isfinite(y) & np.isfinite(lo) & np.isfinite(hi)
        assert np.all(lo[ok] <= y[ok]) and np.all(y[ok] <= hi[ok])
        over = re.search(r"over (\d+) trials$", band)
        if over:
            assert int(over.group(1)) == n >= 2, f"{band!r} in a run of {n} trials"
        if band.startswith("geometric mean"):
            assert np.allclose(np.log10(y[ok]) * 2, np.log10(lo[ok]) + np.log10(hi[ok]))
        else:
            symmetric = ("mean ±", "95% interval of the mean")  # std and ci95 bands
            assert band.startswith(symmetric) or band == GP_BAND, band
            assert np.allclose(y[ok] - lo[ok], hi[ok] - y[ok])


@pytest.mark.parametrize("exp_id", IDS)
def test_one_trial_draws_no_band_over_trials(exp_id):
    result = _run(exp_id, 1) if get(exp_id).trials["smoke"] != 1 else _run(exp_id)
    assert result["trials"] == 1
    bands = [s["band"] for s in result["series"] if "band" in s]
    assert not any("trial" in b for b in bands), bands


def test_band_numbers_are_the_trials_statistics():
    """fig3.3 (mean ± std) and sanity3 (geometric) against their per-trial curves."""
    r = _run("fig3.3", 3)
    curves = np.array([t["reps_mean_reward"] for t in r["_trials"]])
    s = next(s for s in r["series"] if s["name"] == "REPS" and "band" in s)
    sd = curves.std(axis=0, ddof=1)
    assert s["band"] == "mean ± std over 3 trials"
    assert np.allclose(s["y"], curves.mean(0)) and np.allclose(s["upper"], curves.mean(0) + sd)
    r = _run("sanity3", 3)
    err = np.log10([t["REPS_error"] for t in r["_trials"]])
    s = next(s for s in r["series"] if s["name"] == "REPS" and s["log_y"])
    assert s["band"] == "geometric mean ×/÷ geometric std over 3 trials"
    assert np.allclose(np.log10(s["lower"]), err.mean(0) - err.std(0, ddof=1))


# ------------------------------------------------------------------ the band helpers


def test_trial_band_closed_form_and_text():
    curves = np.array([[1.0, 3.0], [3.0, 7.0]])
    m, band = trial_band(curves)
    assert m == [2.0, 5.0]
    assert np.allclose(band["upper"], [2 + np.sqrt(2), 5 + np.sqrt(8)])
    assert band["band"] == "mean ± std over 2 trials"
    assert (m, band["lower"], band["upper"]) == tuple(mean_band(curves))
    _, ci = trial_band(curves, over="runs", kind="ci95")
    assert np.allclose(ci["upper"], [2 + 1.96, 5 + 1.96 * 2])
    assert ci["band"] == "95% interval of the mean over 2 runs"
    m, g = trial_band([[1.0], [100.0]], kind="gstd")
    assert np.allclose(m, [10.0]) and np.allclose(g["lower"], [10 ** (1 - np.sqrt(2))])
    assert g["band"] == "geometric mean ×/÷ geometric std over 2 trials"
    m, none = trial_band([[1.0, 2.0]])
    assert m == [1.0, 2.0] and none == {}


def test_a_band_at_a_point_is_over_the_curves_with_a_number_there():
    """A trial whose evaluation rollouts all failed has no reward there (NaN): the mean and
    band at that point are those of the other trials; where none has a number, NaN."""
    curves = np.array([[1.0, np.nan, np.nan], [3.0, 2.0, np.nan], [5.0, 4.0, np.nan]])
    m, lo, hi = mean_band(curves)
    for j, column in enumerate(curves.T[:2]):
        ok = column[np.isfinite(column)]
        assert m[j] == ok.mean() and hi[j] - m[j] == pytest.approx(ok.std(ddof=1), rel=1e-15)
    assert np.isnan(m[2]) and np.isnan(lo[2]) and np.isnan(hi[2])
    m, lo, hi = mean_band([[np.nan, 7.0]])  # one value: a zero-width band
    assert np.isnan(m[0]) and (m[1], lo[1], hi[1]) == (7.0, 7.0, 7.0)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: band_text(1), "n: a band needs at least 2"),
        (lambda: band_text(3, over=""), "over: expected"),
        (lambda: band_text(3, kind="iqr"), "kind: expected one of"),
        (lambda: trial_band([1.0, 2.0]), "curves: expected shape"),
        (lambda: trial_band([[1.0]], kind="max"), "kind: expected one of"),
        # mean_band used to fall back to the 95% interval for any kind but "std" ...
        (lambda: mean_band([[1.0], [2.0]], kind="gstd"), "kind: expected 'std' or 'ci95'"),
        (lambda: mean_band([[1.0], [2.0]], kind="sd"), "kind: expected 'std' or 'ci95'"),
        # ... and to collapse a single 1-D curve to scalars, or average no curves to NaN
        (lambda: mean_band([1.0, 2.0, 3.0]), "curves: expected shape"),
        (lambda: mean_band(np.zeros((0, 3))), "curves: expected shape"),
    ],
)
def test_band_helpers_reject_bad_input(call, match):
    with pytest.raises(ValueError, match=match):
        call()
