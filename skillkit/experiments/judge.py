"""Claims as data, judged by one engine with a 95% interval across trials.

A run stores what was measured (its ``summary``). How it is *judged* lives in the claims
spec, one TOML file per chapter in ``skillkit/data/claims/``: per experiment id the thesis's
sentences (quote and location), the claim in plain words, a setup table and the **parts**. A
part names the quantity (a path into the summary, or ``settings.<name>``), the statistic that
makes it an estimate with a 95% interval (:data:`STATISTICS`), the reading (``op``,
``threshold``, the thesis's number, a ``reason``, whether it was ``fixed`` before or after the
numbers were seen), and ``own = true`` for a check of ours that never decides the verdict.

A part **holds** when its interval lies wholly on the claim's side of the threshold, **does not
hold** when wholly on the other, and is **undecided** when it straddles it (saying how many
trials would decide it). The verdict is "does not hold" if a thesis part does not hold, else
"undecided" if one is, else "holds"; smoke runs and ids whose passage reports no result are
"not judged". A changed reading re-judges every run at its next load.

Examples
--------
>>> from skillkit.experiments.judge import spec
>>> spec("fig4.10").quotes[0].location
'Fig. 4.10 caption'
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

__all__ = [
    "CARD_WIDTH",
    "JUDGEMENT_KEYS",
    "Claim",
    "Judgement",
    "Part",
    "Quote",
    "Reading",
    "STATISTICS",
    "apply",
    "judge",
    "normalise_text",
    "quoted_numbers",
    "spec",
    "specs",
    "thesis_value",
]

SPEC_DIR = Path(__file__).resolve().parent.parent / "data" / "claims"
"""The folder of the claims spec (one ``*.toml`` per chapter)."""

STATISTICS = ("mean", "paired", "ratio", "rate", "fraction", "value")
"""How a part turns its quantity into an estimate and a 95% interval:

* ``mean``: the mean of a per-trial array, Student-t interval over trials;
* ``paired``: the mean per-trial difference ``quantity − minus`` (two arms run with the same
  seeds in each trial), Student-t interval;
* ``ratio``: ``mean(quantity) / mean(over)`` of two per-trial arrays, percentile bootstrap over
  trials (resampled in pairs);
* ``rate``: a success rate over ``count`` items per trial (per-trial rates or one rate),
  Wilson interval on the pooled counts;
* ``fraction``: the fraction of trials whose value satisfies ``each_op each_threshold``, Wilson
  interval over trials;
* ``value``: one number without sampling noise (a deterministic computation, or a quantity
  measured once); its interval is the point. The part's ``reason`` says why that is fair.
"""

OPS = {"<": np.less, "<=": np.less_equal, ">": np.greater, ">=": np.greater_equal}
CARD_WIDTH = 100
"""Characters per card line."""
PLAIN_WORDS = 12
"""Words of a claim in plain words (the card's first line, the scoreboard's claim)."""
LEVEL = 0.95
_Z = float(stats.norm.ppf(0.5 + LEVEL / 2))
_BOOTSTRAP_RESAMPLES = 9999

JUDGEMENT_KEYS = frozenset(
    "claim holds statement thesis not_judged own_checks claim_parts setup variants verdict "
    "judgement".split()
)
"""Summary keys that hold a judgement or its words, never a measurement."""

HOLDS, FAILS, UNDECIDED, NOT_JUDGED = "holds", "does not hold", "undecided", "not judged"


# ------------------------------------------------------------------------------ the spec
def normalise_text(text: str) -> str:
    """``text`` with end-of-line hyphenation undone ("rep-\\nresents" → "represents") and
    every run of whitespace one space: a spec quote appears verbatim in the normalised thesis."""
    text = re.sub(r"(\w)-[ \t]*\n\s*(?=[a-z])", r"\1", text)
    return " ".join(text.split())


@dataclass(frozen=True)
class Quote:
    """A sentence of the thesis, verbatim (whitespace normalised), and where it stands."""

    text: str
    location: str


@dataclass(frozen=True)
class Part:
    """One judged quantity of a claim (see the module docstring for the fields)."""

    label: str
    quantity: tuple[str, ...]
    statistic: str
    op: str
    threshold: float | tuple[str, ...]
    thesis: str
    reason: str
    fixed: str
    own: bool = False
    minus: tuple[str, ...] | None = None
    over: tuple[str, ...] | None = None
    count: int | tuple[str, ...] | None = None
    each_op: str | None = None
    each_threshold: float | None = None
    unit: str = ""
    factor: float = 1.0
    digits: int = 3


@dataclass(frozen=True)
class SetupRow:
    """One row of a setup table: what, the thesis's setting, ours, and why they differ."""

    what: str
    thesis: str
    ours: str
    why: str


@dataclass(frozen=True)
class Claim:
    """The spec of one experiment id: quotes, the claim in plain words, parts, setup table."""

    id: str
    plain: str
    quotes: tuple[Quote, ...]
    parts: tuple[Part, ...] = ()
    no_result: str = ""
    setup: tuple[SetupRow, ...] = ()
    notes: tuple[str, ...] = ()


def _path(value: Any, where: str) -> tuple[str, ...]:
    if isinstance(value, str) and value:
        return tuple(value.split("."))
    if isinstance(value, list) and value and all(isinstance(v, str) for v in value):
        return tuple(value)
    raise ValueError(f"{where}: expected a dotted path or a list of keys, got {value!r}")


def _part(raw: Mapping[str, Any], where: str) -> Part:
    known = set(Part.__dataclass_fields__)
    unknown = set(raw) - known
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {sorted(unknown)}; known: {sorted(known)}")
    for name in ("label", "quantity", "statistic", "op", "threshold", "thesis", "reason", "fixed"):
        if name not in raw:
            raise ValueError(f"{where}: missing field {name!r}")
    if raw["statistic"] not in STATISTICS:
        raise ValueError(
            f"{where}.statistic: expected one of {STATISTICS}, got {raw['statistic']!r}"
        )
    if raw["op"] not in OPS:
        raise ValueError(f"{where}.op: expected one of {tuple(OPS)}, got {raw['op']!r}")
    if raw["fixed"] not in ("before", "after"):
        raise ValueError(f"{where}.fixed: expected 'before' or 'after', got {raw['fixed']!r}")
    if len(raw["label"]) > 32:
        raise ValueError(f"{where}.label: at most 32 characters, got {raw['label']!r}")
    if len(raw["thesis"]) > 24:
        raise ValueError(f"{where}.thesis: at most 24 characters, got {raw['thesis']!r}")
    kw = dict(raw)
    kw["quantity"] = _path(raw["quantity"], f"{where}.quantity")
    thr = raw["threshold"]
    kw["threshold"] = (
        float(thr) if isinstance(thr, (int, float)) else _path(thr, f"{where}.threshold")
    )
    for key in ("minus", "over"):
        if key in raw:
            kw[key] = _path(raw[key], f"{where}.{key}")
    if "count" in raw and not isinstance(raw["count"], int):
        kw["count"] = _path(raw["count"], f"{where}.count")
    need = {"paired": "minus", "ratio": "over", "rate": "count", "fraction": "each_op"}
    if raw["statistic"] in need and need[raw["statistic"]] not in raw:
        raise ValueError(
            f"{where}: statistic {raw['statistic']!r} needs {need[raw['statistic']]!r}"
        )
    if raw["statistic"] == "fraction" and (
        "each_threshold" not in raw or raw["each_op"] not in OPS
    ):
        raise ValueError(
            f"{where}: statistic 'fraction' needs each_op in {tuple(OPS)} and each_threshold"
        )
    return Part(**kw)


def _claim(raw: Mapping[str, Any], source: str) -> Claim:
    exp_id = raw.get("id")
    if not isinstance(exp_id, str) or not exp_id:
        raise ValueError(f"{source}: a [[claim]] lacks its id")
    where = f"{source} [{exp_id}]"
    plain = raw.get("plain", "")
    if (
        not isinstance(plain, str)
        or not plain
        or len(plain) > CARD_WIDTH - len(exp_id) - 3
        or len(plain.split()) > PLAIN_WORDS
    ):
        raise ValueError(
            f"{where}.plain: expected the claim in ≤ {PLAIN_WORDS} words and "
            f"≤ {CARD_WIDTH - len(exp_id) - 3} "
            f"characters, got {plain!r}"
        )
    quotes = tuple(Quote(q["text"], q["location"]) for q in raw.get("quote", []))
    parts = tuple(_part(p, f"{where}.part[{i}]") for i, p in enumerate(raw.get("part", [])))
    setup = tuple(SetupRow(**row) for row in raw.get("setup", []))
    no_result = raw.get("no_result", "")
    if not quotes and not no_result:
        raise ValueError(f"{where}: no [[claim.quote]]")
    return Claim(exp_id, plain, quotes, parts, no_result, setup, tuple(raw.get("notes", [])))


@cache
def specs(folder: str | None = None) -> dict[str, Claim]:
    """Every claim of the spec folder, by experiment id.

    Parameters
    ----------
    folder : str, optional
        A folder of ``*.toml`` files (default: :data:`SPEC_DIR`).

    Raises
    ------
    ValueError
        A malformed entry (the message names the file, the id and the field) or an id that
        appears twice.
    """
    out: dict[str, Claim] = {}
    for path in sorted(Path(folder or SPEC_DIR).glob("*.toml")):
        with path.open("rb") as fh:
            data = tomllib.load(fh)
        for raw in data.get("claim", []):
            claim = _claim(raw, path.name)
            if claim.id in out:
                raise ValueError(f"{path.name}: id {claim.id!r} is specified twice")
            out[claim.id] = claim
    return out


def spec(exp_id: str) -> Claim:
    """The claim of ``exp_id`` (ValueError naming the known ids when there is none)."""
    table = specs()
    if exp_id not in table:
        raise ValueError(f"exp_id: no claim for {exp_id!r}; known: {', '.join(table)}")
    return table[exp_id]


_NUMBER = re.compile(r"[-−]?\d+(?:\.\d+)?")


def _numbers(text: str) -> list[float]:
    return [float(m.replace("−", "-")) for m in _NUMBER.findall(text)]


def thesis_value(exp_id: str, label: str) -> float:
    """The thesis's number of the part ``label`` of ``exp_id``: the first number in the
    part's ``thesis`` text (``"≈ 50 in the top 95%"`` → 50.0).

    Raises
    ------
    ValueError
        ``exp_id`` has no part ``label``, or its ``thesis`` text holds no number.
    """
    for p in spec(exp_id).parts:
        if p.label == label:
            found = _numbers(p.thesis)
            if not found:
                raise ValueError(f"label: the thesis text of {exp_id} {label!r} has no number")
            return found[0]
    raise ValueError(f"label: {exp_id} has no part {label!r}")


def quoted_numbers(exp_id: str) -> list[float]:
    """The numbers the spec of ``exp_id`` records in parentheses after its quotes' locations,
    in order (``"Table 4.2 caption (PILCO 10.18 / 11.46 s, …)"`` → [10.18, 11.46, …]; ``−``
    is a minus sign)."""
    return [
        x
        for q in spec(exp_id).quotes
        if "(" in q.location
        for x in _numbers(q.location.split("(", 1)[1])
    ]


# ----------------------------------------------------------------------------- statistics
@dataclass(frozen=True)
class Reading:
    """One part judged on one run.

    Attributes
    ----------
    part : Part
    estimate, lower, upper : float or None
        The estimate and its 95% interval (None: the run lacks the number).
    n : int
        Trials (or, for ``rate``, items) the estimate rests on.
    outcome : str
        "holds", "does not hold", "undecided" or "not measured".
    needed : str
        For an undecided part, what would decide it ("" otherwise).
    """

    part: Part
    estimate: float | None
    lower: float | None
    upper: float | None
    n: int
    outcome: str
    needed: str = ""

    def number(self, interval: bool = True) -> str:
        """``"6.2 cm [5.1, 7.4]"`` in the part's unit."""
        p = self.part
        if self.estimate is None:
            return "not measured"
        text, fmt = _g(self.estimate * p.factor, p.digits)
        if interval and self.lower is not None and self.lower != self.upper:
            text += f" [{format(self.lower * p.factor, fmt)}, {format(self.upper * p.factor, fmt)}]"
        return f"{text} {p.unit}".rstrip()

    def as_dict(self) -> dict[str, Any]:
        p = self.part
        return {
            "label": p.label,
            "own": p.own,
            "estimate": self.estimate,
            "lower": self.lower,
            "upper": self.upper,
            "n": self.n,
            "outcome": self.outcome,
            "needed": self.needed,
            "reading": f"{p.statistic} {p.op} {_threshold_text(p)}",
            "thesis": p.thesis,
            "reason": p.reason,
            "fixed": p.fixed,
        }


def _g(x: float, digits: int) -> tuple[str, str]:
    """``x`` to ``digits`` significant digits, and the format spec that wrote it (so an
    interval's bounds share the estimate's decimals)."""
    if not np.isfinite(x):
        return str(x), "g"
    if x != 0 and (abs(x) >= 10 ** (digits + 2) or abs(x) < 1e-3):
        spec = f".{max(digits - 1, 1)}e"
    else:
        exponent = math.floor(math.log10(abs(x))) if x != 0 else 0
        spec = f".{max(digits - 1 - exponent, 0)}f"
    return format(x, spec), spec


def _threshold_text(p: Part) -> str:
    """The threshold in the part's display unit (``"5 cm"``), or the path it is read from."""
    if not isinstance(p.threshold, float):
        return ".".join(p.threshold)
    return f"{_g(p.threshold * p.factor, 4)[0]} {p.unit}".rstrip()


def _cell(text: str) -> str:
    """Text for a Markdown table cell (a ``|`` would end the cell)."""
    return text.replace("|", "\\|").replace("\n", " ")


def _lookup(tree: Mapping[str, Any], path: tuple[str, ...]) -> Any:
    node: Any = tree
    for key in path:
        if isinstance(node, Mapping) and key in node:
            node = node[key]
        elif isinstance(node, list) and key.lstrip("-").isdigit():
            node = node[int(key)]
        else:
            return None
    return node


def _array(value: Any) -> np.ndarray | None:
    if value is None:
        return None
    arr = np.asarray([np.nan if v is None else v for v in np.ravel(value)], dtype=float)
    return arr if arr.size else None


def _t_interval(x: np.ndarray) -> tuple[float, float, float, float]:
    """Mean, 95% Student-t interval and the t quantile × std (NaN half-width below 2 trials)."""
    mean = float(np.mean(x))
    if x.size < 2:
        return mean, math.nan, math.nan, math.nan
    spread = float(np.std(x, ddof=1))
    half = float(stats.t.ppf(0.5 + LEVEL / 2, x.size - 1)) * spread / math.sqrt(x.size)
    return mean, mean - half, mean + half, spread


def _wilson(k: float, n: float) -> tuple[float, float, float]:
    p = k / n
    centre = (p + _Z**2 / (2 * n)) / (1 + _Z**2 / n)
    half = _Z * math.sqrt(p * (1 - p) / n + _Z**2 / (4 * n * n)) / (1 + _Z**2 / n)
    return p, max(centre - half, 0.0), min(centre + half, 1.0)


def _trials_needed(spread: float, gap: float, n: int, what: str) -> str:
    """How many trials (or items) a t- or z-interval needs to exclude a threshold ``gap`` away."""
    if not np.isfinite(spread) or spread == 0 or gap <= 1e-6 * spread:
        return f"no number of {what} decides it at this estimate"
    need = max(n + 1, math.ceil((_Z * spread / gap) ** 2))
    for _ in range(50):  # the t quantile shrinks towards z as n grows
        t = float(stats.t.ppf(0.5 + LEVEL / 2, max(need - 1, 1)))
        nxt = max(n + 1, math.ceil((t * spread / gap) ** 2))
        if nxt == need:
            break
        need = nxt
    return f"≈ {need} {what} would decide it"


def _estimate(p: Part, summary: Mapping, settings: Mapping) -> tuple:
    """(estimate, lower, upper, n, needed-text) or None when the run lacks a number."""
    tree = {**summary, "settings": settings}
    x = _array(_lookup(tree, p.quantity))
    if x is None or not np.all(np.isfinite(x)):
        return None
    thr = p.threshold if isinstance(p.threshold, float) else _lookup(tree, p.threshold)
    if thr is None:
        return None
    thr = float(thr)
    if p.statistic == "value":
        if x.size != 1:
            raise ValueError(f"{p.label}: statistic 'value' needs one number, got {x.size}")
        v = float(x[0])
        return v, v, v, 1, "", thr
    if p.statistic in ("mean", "paired"):
        if p.statistic == "paired":
            y = _array(_lookup(tree, p.minus))
            if y is None or y.size != x.size or not np.all(np.isfinite(y)):
                return None
            x = x - y
        mean, lo, hi, spread = _t_interval(x)
        needed = "" if x.size >= 2 else "one trial: an interval needs ≥ 2"
        if x.size >= 2 and lo <= thr <= hi:
            needed = _trials_needed(spread, abs(mean - thr), x.size, "trials")
        return mean, lo, hi, x.size, needed, thr
    if p.statistic == "ratio":
        y = _array(_lookup(tree, p.over))
        if y is None or y.size != x.size or not np.all(np.isfinite(y)):
            return None
        with np.errstate(divide="ignore", invalid="ignore"):
            est = float(np.mean(x) / np.mean(y))
        if not np.isfinite(est):
            return None
        if x.size < 2:
            return est, math.nan, math.nan, 1, "one trial: an interval needs ≥ 2", thr
        res = stats.bootstrap(
            (x, y),
            lambda a, b, axis=-1: np.mean(a, axis=axis) / np.mean(b, axis=axis),
            paired=True,
            vectorized=True,
            n_resamples=_BOOTSTRAP_RESAMPLES,
            confidence_level=LEVEL,
            method="percentile",
            rng=np.random.default_rng(0),
        )
        lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
        needed = ""
        if lo <= thr <= hi:
            needed = _trials_needed(
                res.standard_error * math.sqrt(x.size), abs(est - thr), x.size, "trials"
            )
        return est, lo, hi, x.size, needed, thr
    if p.statistic == "rate":
        count = p.count if isinstance(p.count, int) else _lookup(tree, p.count)
        if count is None:
            return None
        counts = np.broadcast_to(np.asarray(count, dtype=float), x.shape)
        k, n = float(np.sum(x * counts)), float(np.sum(counts))
        rate, lo, hi = _wilson(k, n)
        needed = ""
        if lo <= thr <= hi:
            needed = _trials_needed(math.sqrt(rate * (1 - rate)), abs(rate - thr), int(n), "items")
        return rate, lo, hi, int(n), needed, thr
    # fraction of trials meeting a per-trial condition
    hits = OPS[p.each_op](x, p.each_threshold)
    rate, lo, hi = _wilson(float(np.sum(hits)), float(x.size))
    needed = ""
    if lo <= thr <= hi:
        needed = _trials_needed(math.sqrt(rate * (1 - rate)), abs(rate - thr), x.size, "trials")
    return rate, lo, hi, x.size, needed, thr


def read(p: Part, summary: Mapping, settings: Mapping | None = None) -> Reading:
    """Judge one part on a run's summary (and settings, for ``settings.`` paths)."""
    got = _estimate(p, summary, settings or {})
    if got is None:
        return Reading(p, None, None, None, 0, "not measured", "not recorded in this run")
    est, lo, hi, n, needed, thr = got
    if not np.isfinite(lo):
        return Reading(p, est, None, None, n, UNDECIDED, needed)
    op = OPS[p.op]
    if op(lo, thr) and op(hi, thr):
        outcome = HOLDS
    elif not op(lo, thr) and not op(hi, thr):
        outcome = FAILS
    else:
        outcome = UNDECIDED
    return Reading(p, est, lo, hi, n, outcome, needed if outcome == UNDECIDED else "")


# ------------------------------------------------------------------------------- verdicts
@dataclass(frozen=True)
class Judgement:
    """The verdict on one run: its readings, the outcome, the card and the details.

    Attributes
    ----------
    claim : Claim
    scale : str
    outcome : str
        "holds", "does not hold", "undecided" or "not judged".
    readings : tuple of Reading
        Thesis parts first, then our own checks.
    why_not_judged : str
        "smoke scale" or the spec's ``no_result`` ("" when judged).
    n_trials : int or None
    """

    claim: Claim
    scale: str
    outcome: str
    readings: tuple[Reading, ...]
    why_not_judged: str = ""
    n_trials: int | None = None
    thesis_readings: tuple[Reading, ...] = field(default=(), repr=False)

    @property
    def holds(self) -> bool | None:
        """True / False for holds / does not hold; None otherwise."""
        return {HOLDS: True, FAILS: False}.get(self.outcome)

    def key(self) -> Reading | None:
        """The reading the card shows: the first failing, undecided or unmeasured thesis part,
        else the first."""
        rs = self.thesis_readings
        for wanted in (FAILS, UNDECIDED, "not measured"):
            for r in rs:
                if r.outcome == wanted:
                    return r
        return rs[0] if rs else (self.readings[0] if self.readings else None)

    def verdict_line(self) -> str:
        """The card's second line: key number, interval, the thesis's number, outcome."""
        r = self.key()
        if self.outcome == NOT_JUDGED:
            head = f"{self.why_not_judged}: not judged"
            if r is not None and r.estimate is not None:
                head += f"; {r.part.label} {r.number(interval=False)} (thesis {r.part.thesis})"
            return _fit(head)
        assert r is not None
        return _fit(f"{r.part.label} {r.number()}, thesis {r.part.thesis}: {self.outcome}")

    def card(self) -> str:
        """At most three lines of :data:`CARD_WIDTH` characters: the claim, the verdict line,
        the tally and where the details are."""
        lines = [f"{self.claim.id}: {self.claim.plain}", self.verdict_line()]
        rs = self.thesis_readings
        words = {HOLDS: "hold", FAILS: "fail", UNDECIDED: "undecided", "not measured": "unmeasured"}
        counts = {w: sum(r.outcome == o for r in rs) for o, w in words.items()}
        third = (
            [f"{self.n_trials} trial{'s' if self.n_trials != 1 else ''}"] if self.n_trials else []
        )
        if len(rs) > 1 and self.outcome != NOT_JUDGED:
            tally = ", ".join(f"{v} {k}" for k, v in counts.items() if v)
            third.append(f"{len(rs)} parts: {tally}")
        third.append("details: run.details()")
        lines.append(_fit(" · ".join(third)))
        return "\n".join(lines)

    def details(self) -> str:
        """Markdown: the quotes, every reading, the setup table and the notes."""
        c = self.claim
        out = [f"### {c.id}: {c.plain}", ""]
        out += [f"> {q.text}\n>\n> — {q.location}\n" for q in c.quotes]
        out.append(
            f"**Verdict:** {self.outcome}"
            + (f" ({self.why_not_judged})" if self.why_not_judged else "")
        )
        if self.readings:
            out += [
                "",
                "| part | ours [95% interval] | thesis | reading | outcome | reason | fixed |",
                "|---|---|---|---|---|---|---|",
            ]
            for r in self.readings:
                p = r.part
                name = f"{p.label} (own)" if p.own else p.label
                outcome = r.outcome + (f"; {r.needed}" if r.needed else "")
                what = "items" if p.statistic == "rate" else "trials"
                reading = f"{p.statistic} over {r.n} {what} {p.op} {_threshold_text(p)}"
                cells = [
                    name,
                    r.number(),
                    p.thesis,
                    reading,
                    outcome,
                    p.reason,
                    f"{p.fixed} the numbers",
                ]
                out.append("| " + " | ".join(_cell(c) for c in cells) + " |")
        if c.setup:
            out += ["", "| setting | thesis | ours | why |", "|---|---|---|---|"]
            out += [
                "| " + " | ".join(_cell(x) for x in (s.what, s.thesis, s.ours, s.why)) + " |"
                for s in c.setup
            ]
        if c.notes:
            out += [""] + [f"- {n}" for n in c.notes]
        return "\n".join(out)

    def as_dict(self) -> dict[str, Any]:
        """What ``result.json`` stores under ``summary["judgement"]``."""
        return {
            "outcome": self.outcome,
            "card": self.card(),
            "readings": [r.as_dict() for r in self.readings],
            **({"not_judged": self.why_not_judged} if self.why_not_judged else {}),
        }


def _fit(line: str) -> str:
    return line if len(line) <= CARD_WIDTH else line[: CARD_WIDTH - 1] + "…"


def judge(
    exp_id: str, summary: Mapping[str, Any], scale: str, settings: Mapping | None = None
) -> Judgement:
    """Judge a run's summary (and settings) against the spec of ``exp_id`` ("smoke" runs are
    not judged)."""
    claim = spec(exp_id)
    readings = tuple(read(p, summary, settings) for p in claim.parts)
    thesis = tuple(r for r, p in zip(readings, claim.parts, strict=True) if not p.own)
    n_trials = summary.get("n_trials") if isinstance(summary.get("n_trials"), int) else None
    if scale == "smoke" or claim.no_result:
        why = "smoke scale" if scale == "smoke" else claim.no_result
        return Judgement(claim, scale, NOT_JUDGED, readings, why, n_trials, thesis)
    outcomes = [r.outcome for r in thesis]
    if FAILS in outcomes:
        outcome = FAILS
    elif all(o == HOLDS for o in outcomes):
        outcome = HOLDS
    else:
        outcome = UNDECIDED
    return Judgement(claim, scale, outcome, readings, "", n_trials, thesis)


def quotes_of(exp_id: str) -> list[dict[str, str]]:
    """The thesis's sentences of ``exp_id`` as ``[{"quote", "location"}]`` ([] without a spec)."""
    table = specs()
    if exp_id not in table:
        return []
    return [{"quote": q.text, "location": q.location} for q in table[exp_id].quotes]


def is_judged(exp_id: str) -> bool:
    """Whether the spec judges ``exp_id``: it has parts, or says it reports no result."""
    claim = specs().get(exp_id)
    return claim is not None and bool(claim.parts or claim.no_result)


def apply(
    summary: Mapping[str, Any], exp_id: str, scale: str, settings: Mapping | None = None
) -> dict[str, Any]:
    """``summary`` with the judgement in front (``claim``, ``holds``, ``verdict``,
    ``statement``, ``thesis``, ``own_checks``, ``judgement``), replacing any earlier one; an
    id the spec does not judge keeps its summary."""
    if not is_judged(exp_id):
        return dict(summary)
    j = judge(exp_id, summary, scale, settings)
    rest = {k: v for k, v in summary.items() if k not in JUDGEMENT_KEYS}
    judged = j.outcome != NOT_JUDGED or bool(j.claim.no_result and scale != "smoke")
    own = {
        r.part.label: {
            "holds": {HOLDS: True, FAILS: False}.get(r.outcome) if judged else None,
            "criterion": f"{r.part.label} {r.part.op} {_threshold_text(r.part)}",
        }
        for r in j.readings
        if r.part.own
    }
    head = {
        "claim": j.claim.plain,
        "holds": j.holds,
        "verdict": j.outcome,
        "statement": j.verdict_line(),
        "thesis": quotes_of(exp_id),
        **({"not_judged": j.why_not_judged} if j.why_not_judged else {}),
        **({"own_checks": own} if own else {}),
        "judgement": j.as_dict(),
    }
    return {**head, **rest}


def card_lines_ok(card: str) -> bool:
    """A card has at most three lines of at most :data:`CARD_WIDTH` characters."""
    lines = card.split("\n")
    return len(lines) <= 3 and all(len(line) <= CARD_WIDTH for line in lines)
