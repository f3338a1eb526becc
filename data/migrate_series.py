"""Bring stored ``result.json`` series to the labelling of issue #12 ("figures that speak"):
every band says what it is (``Series.band``) and axis labels carry their units, exactly as a
fresh run of the current code writes them. No number is recomputed.

Usage::

    python data/migrate_series.py [ROOT ...]     # default: data/results; rewrites in place
    python data/migrate_series.py --check [ROOT]  # exit 1 if a file is not migrated

What changes in each ``series`` list (see data/README.md):

* ``band`` added to every series with ``lower`` / ``upper``: the statistic and what it is
  over, with n the run's trial count (``result["trials"]``), from
  :func:`skillkit.viz.series.band_text`, or the GP predictive band of fig2.7 / fig2.12;
* a band over a single trial (zero width: ``lower == y == upper``, checked) is removed, as a
  fresh one-trial run draws none (:func:`skillkit.viz.series.trial_band`);
* labels gain their units: fig2.10 ``f`` → ``f [rad/s²]``, fig4.5 and fig5.6 / fig5.7
  y labels (reward²), fig5.3–fig5.5 heatmap panel titles (rad², (rad/s)²);
* keys in :class:`~skillkit.viz.series.Series` field order (``Series.to_dict``).

The script checks, series by series, that every other leaf (every number, every other string)
is unchanged and refuses to write otherwise. Running it twice changes nothing. An experiment
whose bands are not described below stops the script with an error rather than guessing:
``tests/experiments/test_bands.py`` checks that these tables give what ``summarize`` gives.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from skillkit.experiments.ch2 import FORCING_LABEL
from skillkit.experiments.ch2_gp import GP_BAND
from skillkit.experiments.ch4_models import REWARD_ERROR_LABEL
from skillkit.experiments.ch4_stochastic import ERROR_PANEL
from skillkit.experiments.ch5 import E_R_LABEL, PENDULUM_ERRORS
from skillkit.viz.series import Series, band_text

#: Per id: panel -> kind of band over the trials (:data:`skillkit.viz.series.BAND_KINDS`);
#: every series with a band in these panels is one over the run's trials.
TRIAL_BANDS: dict[str, dict[str, str]] = {
    "sanity3": {"parameter error of the policy mean": "gstd", "reward of the policy mean": "std"},
    "fig3.3": {"learning curves": "std"},
    "fig3.5": {
        "reward of the policy mean": "std",
        "hit rate (held-out contexts)": "std",
        "displacement error |d_T − d*| (held-out)": "std",
    },
    "fig3.7": {"learning curve": "std"},
    "fig4.8": {ERROR_PANEL: "std"},
    "fig4.6": {"learning curves": "std"},
    "fig4.7": {"learning curves": "std"},
    "fig4.9": {"learning curves": "std"},
    "fig4.10": {"learning curves": "std", "held-out displacement error": "std"},
    "fig4.11": {"learning curve": "ci95", "held-out displacement error": "ci95"},
    "fig4.12": {"learning curves": "std", "held-out landing error": "std"},
    "tab4.2": {"cost of the current controller": "gstd"},
    "fig5.6": {"reward prediction error": "std"},
    "fig5.7": {"reward prediction error": "std"},
    # made after issue #12 (nothing stored to migrate); listed so every id is described
    "cmp.methods": {task: "std" for task in ("throwing", "hockey", "table-tennis", "balancing")},
}
#: Per id: the band text of bands that are not over trials.
FIXED_BANDS: dict[str, str] = {"fig2.12": GP_BAND, "fig2.7": GP_BAND}

#: Per id: (field, old text, new text) of the labels that gained their units.
RELABEL: dict[str, list[tuple[str, str, str]]] = {
    "fig2.10": [("ylabel", "f", FORCING_LABEL)],
    "fig4.5": [("ylabel", "mean squared reward error", REWARD_ERROR_LABEL)],
    "fig5.6": [("ylabel", "e_r", E_R_LABEL)],
    "fig5.7": [("ylabel", "e_r", E_R_LABEL)],
}
RELABEL.update(
    {
        exp_id: [
            ("panel", f"{title}: log10 {label}", f"{title}: log10 {label} ({label} in {unit})")
            for title in ("(a) kernel embedding", "(b) GP regression")
        ]
        for exp_id, _key, label, unit, *_ in PENDULUM_ERRORS
    }
)

_LABEL_FIELDS = ("name", "panel", "xlabel", "ylabel", "band")


def _same(a, b) -> bool:
    """Elementwise equality of two stored lists (None: a NaN written as null)."""
    return len(a) == len(b) and all(u == v for u, v in zip(a, b, strict=True))


def migrate_series(exp_id: str, n_trials: int, series: list[dict]) -> tuple[list[dict], dict]:
    """The series with band texts and labels as a fresh run of ``exp_id`` writes them.

    Parameters
    ----------
    exp_id : str
        Registered experiment id.
    n_trials : int
        The run's trial count (``result["trials"]``): the n of "over n trials".
    series : list of dict
        The stored series (``Series.to_dict`` form; old or already migrated).

    Returns
    -------
    series : list of dict
        Migrated copies, keys in ``Series`` field order.
    report : dict
        ``bands`` (series given a band text), ``dropped`` (indices of removed one-trial
        bands), ``relabelled`` ({index: [fields]}).

    Raises
    ------
    ValueError
        A band this script does not know, or a one-trial band that is not of zero width.
    """
    if isinstance(n_trials, bool) or not isinstance(n_trials, int) or n_trials < 1:
        raise ValueError(f"n_trials: expected a positive int, got {n_trials!r}")
    out: list[dict] = []
    report: dict = {"bands": 0, "dropped": [], "relabelled": {}}
    for i, old in enumerate(series):
        s = dict(old)
        for field, before, after in RELABEL.get(exp_id, []):
            if s.get(field) == before:
                s[field] = after
                report["relabelled"].setdefault(i, []).append(field)
        if s.get("lower") is not None and s.get("upper") is not None:
            kind = TRIAL_BANDS.get(exp_id, {}).get(s.get("panel", ""))
            if exp_id in FIXED_BANDS:
                s["band"] = FIXED_BANDS[exp_id]
                report["bands"] += 1
            elif kind is None:
                raise ValueError(
                    f"{exp_id}: series {i} ({s['name']!r}, panel {s.get('panel')!r}) has a band "
                    "this script does not describe; add it to TRIAL_BANDS or FIXED_BANDS"
                )
            elif n_trials >= 2:
                s["band"] = band_text(n_trials, "trials", kind)
                report["bands"] += 1
            else:
                if not (_same(s["lower"], s["y"]) and _same(s["upper"], s["y"])):
                    raise ValueError(
                        f"{exp_id}: series {i} ({s['name']!r}) has a band of non-zero width "
                        "over one trial"
                    )
                for key in ("lower", "upper", "band"):
                    s.pop(key, None)
                report["dropped"].append(i)
        unknown = set(s) - set(Series.__dataclass_fields__)
        if unknown:
            raise ValueError(f"{exp_id}: series {i} has keys that are no Series fields: {unknown}")
        out.append(Series(**s).to_dict())
    return out, report


def _leaves(d, prefix: str = "") -> dict:
    """Leaves (numbers, booleans, strings, None) of nested dicts and lists: {path: value}."""
    if isinstance(d, dict):
        return {p: v for k, x in d.items() for p, v in _leaves(x, f"{prefix}.{k}").items()}
    if isinstance(d, list):
        return {p: v for j, x in enumerate(d) for p, v in _leaves(x, f"{prefix}[{j}]").items()}
    return {prefix: d}


def check_series_kept(old: list[dict], new: list[dict], report: dict) -> int:
    """Every leaf of the old series is in the new unchanged, except the relabelled fields,
    ``band``, and the ``lower`` / ``upper`` of removed one-trial bands (equal to ``y``, checked
    by :func:`migrate_series`); the new series add nothing but ``band``. Returns the number
    of numeric leaves compared."""
    if len(old) != len(new):
        raise RuntimeError(f"series: {len(old)} before, {len(new)} after")
    n_numbers = 0
    for i, (a, b) in enumerate(zip(old, new, strict=True)):
        skip = set(report["relabelled"].get(i, [])) | {"band"}
        if i in report["dropped"]:
            skip |= {"lower", "upper"}
        la, lb = _leaves(a), _leaves(b)
        for path, value in la.items():
            field = path[1:].split("[")[0]
            if field in skip:
                continue
            if path not in lb or lb[path] != value or type(lb[path]) is not type(value):
                raise RuntimeError(f"series[{i}]{path} changed ({value!r} -> {lb.get(path)!r})")
            n_numbers += isinstance(value, (int, float)) and not isinstance(value, bool)
        added = {p[1:].split("[")[0] for p in lb} - {p[1:].split("[")[0] for p in la}
        if added - {"band"}:
            raise RuntimeError(f"series[{i}]: fields added: {sorted(added - {'band'})}")
    return n_numbers


def migrate_file(path: Path, write: bool = True) -> tuple[bool, dict]:
    """Migrate the series of one ``result.json``; returns (whether it changed, report)."""
    text = path.read_text()
    result = json.loads(text)
    series, report = migrate_series(result["id"], result["trials"], result["series"])
    report["numbers_kept"] = check_series_kept(result["series"], series, report)
    out = json.dumps({**result, "series": series}, indent=1)
    changed = out != text
    if changed and write:
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(out)
        tmp.replace(path)
    return changed, report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("roots", nargs="*", default=["data/results"])
    parser.add_argument("--check", action="store_true", help="only report; exit 1 if stale")
    args = parser.parse_args(argv)
    stale = 0
    for root in args.roots:
        for path in sorted(Path(root).rglob("result.json")):
            changed, rep = migrate_file(path, write=not args.check)
            stale += changed
            relabelled = sorted({f for fs in rep["relabelled"].values() for f in fs})
            print(
                f"{path.parent.name:<24} {'changed' if changed else 'up to date':<10} "
                f"bands labelled {rep['bands']:>2}, one-trial bands removed "
                f"{len(rep['dropped'])}, relabelled {relabelled or '-'}; "
                f"{rep['numbers_kept']} numbers unchanged"
            )
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
