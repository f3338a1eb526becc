"""Bring stored ``result.json`` summaries to the verdict schema (issue #11): ``claim``,
``holds``, ``statement`` first in every ``summary``, computed by the experiment's own
``verdict(settings, summary)`` from the stored numbers (nothing is rerun).

Usage::

    python data/migrate_summaries.py [ROOT ...]     # default: data/results; rewrites in place
    python data/migrate_summaries.py --check [ROOT]  # exit 1 if a file is not migrated

What changes in each ``summary`` (see data/README.md):

* added: ``claim`` (str), ``holds`` (true / false / null), ``statement`` (str), first;
* removed after the new keys carry their information: ``claim_holds`` (now ``holds``), the
  ``verdict`` string of fig5.3–fig5.7 and ``thesis.claim`` of fig3.3 / fig3.7 (now
  ``statement`` and ``claim``); sanity3's and fig5.x's ``statement`` / ``claim`` are rewritten;
* renamed: fig3.3's per-method dict ``holds`` → ``holds_per_method``.

Issue #32 (verdicts that judge the thesis's own sentences):

* ``thesis``, where it held the thesis's numbers (a dict), is renamed ``thesis_numbers``;
  ``thesis`` is now the quoted sentence(s) the verdict judges, with their location
  (``skillkit.experiments.claims``), right after ``statement``;
* ``holds`` is recomputed by today's verdict function; for an id whose thesis reports no
  result (``claims.NO_RESULT``) it is null, with ``not_judged`` saying so and the verdict's
  own criterion kept as ``own_checks["own_criterion"]``;
* ``own_checks`` (our conditions beyond the thesis) are recomputed by the experiment's
  ``own_checks(settings, summary)`` from the stored numbers;
* the verdict keys of the old criteria, now own checks or parts of the verdict, are removed:
  fig3.3's ``holds_per_method``, fig3.5's ``checks``, fig5.6's / fig5.7's ``claim_*_holds``
  and ``trajectory_based_below_constant_holds``;
* :data:`RESUMMARIZE` ids need numbers their stored summary lacks (per-trial or placed-puck
  errors, errors near / far from the data): their summary is recomputed by the experiment's
  own ``summarize`` from the stored per-trial arrays (``trials.npz``), and every number of the
  stored summary must come back unchanged (the script refuses otherwise); nothing is rerun;
* tab4.2 (2026-12-03): its verdict's criterion changed after the paper run at 65bc574
  (medians over trials, (1) judged at the highest limit; ``ch4_balancing.verdict_42``); the
  stored run is re-summarized and re-judged, and records ``summary_migrated`` although it has
  a code fingerprint (stale by it until the regeneration);
* the top level gains ``summary_migrated`` (``{"issue": 32, "git": ..., "resummarized":
  bool}``): the numbers were made by an earlier commit's code (the result has no
  ``code_fingerprint``, so ``skillkit runs --check`` lists it as stale), only the verdict,
  and for :data:`RESUMMARIZE` ids the summary's arithmetic, are today's.

Every other key and number is kept: the script checks that each numeric leaf of the old
summary is unchanged in the new one and refuses to write otherwise. The top level gains
``overrides`` (the settings that differ from the scale's, ``{}`` for a standard run), as new
runs record it. Running it twice changes nothing.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from skillkit.experiments.claims import judged
from skillkit.experiments.provenance import git_state
from skillkit.experiments.registry import get, with_verdict
from skillkit.experiments.runner import to_jsonable
from skillkit.experiments.settings import apply_overrides

#: Keys whose information the verdict now carries (removed), and renamed keys, per id.
DROPPED = ("claim_holds",)
DROPPED_STRINGS = ("verdict",)  # fig5.x: the old one-line numbers, now in ``statement``
RENAMED = {"fig3.3": {"holds": "holds_per_method"}}
THESIS_CLAIM = ("fig3.3", "fig3.7")  # ``thesis.claim`` moved to the top-level ``claim``
#: Issue #32: verdict keys of the old criteria (now own checks or parts of the verdict).
DROPPED_32 = {
    "fig3.3": ("holds_per_method",),
    "fig3.5": ("checks",),
    **{
        i: (
            "claim_embedding_below_gp_holds",
            "claim_trajectory_below_step_holds",
            "trajectory_based_below_constant_holds",
            "claim_embedding_flat_across_noise_holds",
        )
        for i in ("fig5.6", "fig5.7")
    },
}
#: Issue #32: ids whose verdict needs numbers only ``summarize`` on the stored trials gives.
RESUMMARIZE = ("fig3.3", "fig3.5", "fig4.10", "fig4.11", "fig5.3", "fig5.4", "fig5.5", "tab4.2")


def stored_trials(folder: Path) -> list[dict]:
    """The per-trial dicts of a run folder, rebuilt from ``trials.npz`` (keys
    ``trial{i}__{key}``; 0-d arrays as scalars). Entries the runner could not store as arrays
    (ragged, objects) are absent."""
    import re

    import numpy as np

    trials: dict[int, dict] = {}
    with np.load(folder / "trials.npz", allow_pickle=False) as z:
        for key in z.files:
            m = re.fullmatch(r"trial(\d+)__(.+)", key)
            if m is None:
                raise ValueError(f"trials.npz: unexpected key {key!r} in {folder}")
            v = z[key]
            trials.setdefault(int(m[1]), {})[m[2]] = v[()] if v.ndim == 0 else v
    return [trials[i] for i in sorted(trials)]


def _renames(exp_id: str, summary: dict) -> dict[str, str]:
    """Top-level keys renamed for ``exp_id``: :data:`RENAMED` and, where ``thesis`` holds the
    thesis's numbers (a dict, before issue #32), ``thesis`` → ``thesis_numbers``."""
    out = dict(RENAMED.get(exp_id, {}))
    if isinstance(summary.get("thesis"), dict):
        out["thesis"] = "thesis_numbers"
    return out


def migrate_summary(
    exp_id: str,
    settings: dict,
    summary: dict,
    scale: str = "paper",
    folder: Path | None = None,
) -> tuple[dict, dict]:
    """The summary in the verdict schema, and a report of what changed.

    Parameters
    ----------
    exp_id : str
        Registered experiment id.
    settings : dict
        The run's stored settings (``result["settings"]``).
    summary : dict
        The stored summary (old or already migrated).
    scale : str
        The run's scale (a smoke run is not judged).
    folder : Path, optional
        The run folder; for :data:`RESUMMARIZE` ids the summary is recomputed from its
        ``trials.npz`` (required for them).

    Returns
    -------
    summary : dict
        ``claim``, ``holds``, ``statement`` first, then the other keys.
    report : dict
        ``renamed``, ``removed`` (key lists) and ``old_claim_holds`` / ``holds``.
    """
    exp = get(exp_id)
    typed = apply_overrides(exp.settings["quick"], settings)
    new = dict(summary)
    report: dict = {"renamed": [], "removed": [], "old_claim_holds": None}
    if exp_id in THESIS_CLAIM and isinstance(new.get("thesis"), dict):
        if "claim" in new["thesis"]:
            new["thesis"] = {k: v for k, v in new["thesis"].items() if k != "claim"}
            report["removed"].append("thesis.claim")
    for old, name in _renames(exp_id, new).items():
        if isinstance(new.get(old), dict):
            new[name] = new.pop(old)
            report["renamed"].append(f"{old} -> {name}")
    for key in DROPPED:
        if key in new:
            report["old_claim_holds"] = new.pop(key)
            report["removed"].append(key)
    for key in DROPPED_STRINGS:
        if isinstance(new.get(key), str):
            new.pop(key)
            report["removed"].append(key)
    for key in DROPPED_32.get(exp_id, ()):
        if key in new:
            new.pop(key)
            report["removed"].append(key)
    report["resummarized"] = False
    if exp_id in RESUMMARIZE and folder is not None:
        _, fresh = exp.summarize(typed, stored_trials(folder))
        fresh = json.loads(json.dumps(to_jsonable(fresh)))
        fresh = {k: v for k, v in fresh.items() if k not in ("claim", "holds", "statement")}
        new = _merge_new_numbers(exp_id, new, fresh)
        report["resummarized"] = True
    if exp.own_checks is not None:
        new["own_checks"] = exp.own_checks(typed, new)
    verdict = exp.verdict(typed, new)
    out = judged(with_verdict(new, verdict), exp_id, scale)
    report["holds"] = out["holds"]
    return to_jsonable(out), report


def _merge_new_numbers(exp_id: str, stored, fresh, path: str = ""):
    """``stored`` with what only ``fresh`` has added (keys at any depth). A number both hold
    must agree; where ``fresh`` lacks it (None: its input was not in ``trials.npz``) the stored
    value stays. Verdict keys and own checks are recomputed afterwards."""
    if isinstance(stored, dict) and isinstance(fresh, dict):
        out = {k: _merge_new_numbers(exp_id, v, fresh.get(k), f"{path}.{k}")
               for k, v in stored.items()}  # fmt: skip
        out.update({k: v for k, v in fresh.items() if k not in stored})
        return out
    if isinstance(stored, list) and isinstance(fresh, list) and len(stored) == len(fresh):
        return [_merge_new_numbers(exp_id, a, b, f"{path}[{i}]")
                for i, (a, b) in enumerate(zip(stored, fresh, strict=True))]  # fmt: skip
    top = path[1:].split(".")[0].split("[")[0]
    if (
        isinstance(stored, (int, float))
        and isinstance(fresh, (int, float))
        and not isinstance(stored, bool)
        and stored != fresh
        and top not in ("own_checks", "thesis", "not_judged")
    ):
        raise RuntimeError(f"{exp_id}: {path} is {stored!r} stored, {fresh!r} re-summarized")
    return stored


def _numbers(d, prefix=""):
    """Numeric leaves of a nested summary: {path: value}."""
    out = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out.update(_numbers(v, f"{prefix}.{k}"))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            out.update(_numbers(v, f"{prefix}[{i}]"))
    elif isinstance(d, (int, float)) or d is None:
        out[prefix] = d
    return out


def _check_numbers_kept(exp_id: str, old: dict, new: dict) -> None:
    """Every numeric (and boolean) leaf of ``old`` is in ``new`` unchanged, at its renamed
    path; only ``claim_holds`` and a recomputed ``holds`` may differ."""
    renames = _renames(exp_id, old)
    kept = _numbers(new)
    dropped = DROPPED_32.get(exp_id, ())
    for path, value in _numbers(old).items():
        top = path[1:].split(".")[0].split("[")[0]
        if top in renames and isinstance(old[top], dict):
            path = "." + renames[top] + path[1 + len(top) :]
        elif top in DROPPED or top in dropped or top in ("holds", "own_checks"):
            continue
        if path not in kept or kept[path] != value:
            raise RuntimeError(f"{exp_id}: {path} changed ({value!r} -> {kept.get(path)!r})")


def migrate_file(path: Path, write: bool = True) -> tuple[bool, dict]:
    """Migrate one ``result.json``; returns (whether it changed, report)."""
    text = path.read_text()
    result = json.loads(text)
    exp = get(result["id"])
    summary, report = migrate_summary(
        exp.id, result["settings"], result["summary"], result.get("scale", "paper"), path.parent
    )
    _check_numbers_kept(exp.id, result["summary"], summary)
    typed = apply_overrides(exp.settings["quick"], result["settings"])
    migrated = dict(result)
    migrated["summary"] = summary
    if "overrides" not in migrated:
        keys = list(migrated)
        at = keys.index("settings") + 1 if "settings" in keys else len(keys)
        changed = to_jsonable(exp.overrides(result["scale"], typed))
        migrated = dict(
            [(k, migrated[k]) for k in keys[:at]]
            + [("overrides", changed)]
            + [(k, migrated[k]) for k in keys[at:]]
        )
    if migrated["summary"] != result["summary"]:
        # numbers of an earlier commit's code, verdict of today's (issue #32; tab4.2's
        # criterion change of 2026-12-03 on a run that has a code fingerprint)
        done = (result.get("summary_migrated") or {}).get("resummarized", False)
        migrated["summary_migrated"] = {
            "issue": 32,
            "git": git_state(),
            "resummarized": bool(done or report["resummarized"]),
        }
    out = json.dumps(migrated, indent=1)
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
            flips = (
                ""
                if rep["old_claim_holds"] is None or rep["old_claim_holds"] == rep["holds"]
                else f"  (claim_holds was {rep['old_claim_holds']})"
            )
            print(
                f"{path.parent.name:<24} {'changed' if changed else 'up to date':<10} "
                f"holds={rep['holds']}{flips}"
                + (f"  renamed {rep['renamed']}" if rep["renamed"] else "")
                + (f"  removed {rep['removed']}" if rep["removed"] else "")
            )
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
