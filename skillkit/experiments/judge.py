"""Claims as data, judged by one engine with a 95% interval across trials.

A run stores what was measured (its ``summary``); the claims spec, one TOML file per chapter
in ``skillkit/data/claims/``, says how it is judged: per experiment id the thesis's sentences
(quote and location), the claim in plain words, a setup table and the **parts**. A part names
the quantity (a path into the summary, or ``settings.<name>``), the statistic that makes it an
estimate with a 95% interval (:data:`STATISTICS`), the reading (``op``, ``threshold``, the
thesis's number, a ``reason``, whether it was ``fixed`` before or after the numbers were seen),
and ``own = true`` for a check of ours that never decides the verdict.

A part **holds** when its interval lies wholly on the claim's side of the threshold, **does not
hold** when wholly on the other, and is **undecided** when it straddles it. The verdict is
"does not hold" if a thesis part does not hold, else "undecided" if one is, else "holds";
smoke runs and ids whose passage reports no result are "not judged".

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

SPEC_DIR = Path(__file__).resolve().parent.parent / "data" / "claims"
"""The folder of the claims spec (one ``*.toml`` per chapter)."""

STATISTICS = ("mean", "paired", "ratio", "rate", "fraction", "value")
"""How a part turns its quantity into an estimate and a 95% interval: ``mean`` (Student-t over
trials), ``paired`` (mean of ``quantity − minus``, Student-t), ``ratio`` (``mean(quantity) /
mean(over)``, paired percentile bootstrap), ``rate`` (over ``count`` items per trial, Wilson),
``fraction`` (of trials meeting ``each_op each_threshold``, Wilson) and ``value`` (one number
without sampling noise; the interval is the point)."""

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
    choices = {"statistic": STATISTICS, "op": tuple(OPS), "fixed": ("before", "after")}
    for name, allowed in choices.items():
        if raw[name] not in allowed:
            expected = "'before' or 'after'" if name == "fixed" else f"one of {allowed}"
            raise ValueError(f"{where}.{name}: expected {expected}, got {raw[name]!r}")
    for name, most in (("label", 32), ("thesis", 24)):
        if len(raw[name]) > most:
            raise ValueError(f"{where}.{name}: at most {most} characters, got {raw[name]!r}")
    kw = dict(raw)
    for key in ("quantity", "threshold", "minus", "over", "count"):
        value = raw.get(key)
        if key == "threshold" and isinstance(value, (int, float)):
            kw[key] = float(value)
        elif key in raw and not (key == "count" and isinstance(value, int)):
            kw[key] = _path(value, f"{where}.{key}")
    stat = raw["statistic"]
    need = {"paired": "minus", "ratio": "over", "rate": "count", "fraction": "each_op"}.get(stat)
    if need and need not in raw:
        raise ValueError(f"{where}: statistic {stat!r} needs {need!r}")
    if stat == "fraction" and ("each_threshold" not in raw or raw["each_op"] not in OPS):
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
        most = CARD_WIDTH - len(exp_id) - 3
        raise ValueError(
            f"{where}.plain: expected the claim in ≤ {PLAIN_WORDS} words and ≤ {most} "
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
    """Every claim of the spec ``folder`` (default :data:`SPEC_DIR`), by experiment id.

    Raises
    ------
    ValueError
        A malformed entry (naming the file, the id and the field) or an id given twice.
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
    """The first number in the ``thesis`` text of part ``label`` of ``exp_id`` (``"≈ 50 in the
    top 95%"`` → 50.0); ValueError without such a part or number."""
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
    """One part judged on one run: the estimate and its 95% interval (None: not measured), the
    trials (``rate``: items) it rests on, the outcome ("holds", "does not hold", "undecided"
    or "not measured") and, when undecided, what would decide it."""

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
        fields = ("estimate", "lower", "upper", "n", "outcome", "needed")
        return {
            "label": p.label,
            "own": p.own,
            **{k: getattr(self, k) for k in fields},
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


def markdown_row(cells: list[str]) -> str:
    """A Markdown table row of ``cells`` (``|`` escaped, line breaks as spaces)."""
    return "| " + " | ".join(c.replace("|", "\\|").replace("\n", " ") for c in cells) + " |"


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


def _estimate(p: Part, summary: Mapping, settings: Mapping) -> tuple | None:
    """(estimate, lower, upper, n, needed-text, threshold), or None when the run lacks a number."""
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
    if p.statistic in ("paired", "ratio"):
        y = _array(_lookup(tree, p.minus if p.statistic == "paired" else p.over))
        if y is None or y.size != x.size or not np.all(np.isfinite(y)):
            return None
    n, what = x.size, "trials"
    if p.statistic in ("mean", "paired"):
        est, lo, hi, spread = _t_interval(x - y if p.statistic == "paired" else x)
    elif p.statistic == "ratio":
        with np.errstate(divide="ignore", invalid="ignore"):
            est = float(np.mean(x) / np.mean(y))
        if not np.isfinite(est):
            return None
        lo = hi = spread = math.nan
        if n >= 2:
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
            spread = res.standard_error * math.sqrt(x.size)
    else:  # rate over items, or the fraction of trials meeting a per-trial condition
        if p.statistic == "rate":
            count = p.count if isinstance(p.count, int) else _lookup(tree, p.count)
            if count is None:
                return None
            counts = np.broadcast_to(np.asarray(count, dtype=float), x.shape)
            k, total = float(np.sum(x * counts)), float(np.sum(counts))
            n, what = int(total), "items"
        else:
            k, total = float(np.sum(OPS[p.each_op](x, p.each_threshold))), float(x.size)
        est, lo, hi = _wilson(k, total)
        spread = math.sqrt(est * (1 - est))
    if x.size < 2 and p.statistic in ("mean", "paired", "ratio"):
        return est, lo, hi, n, "one trial: an interval needs ≥ 2", thr
    needed = _trials_needed(spread, abs(est - thr), n, what) if lo <= thr <= hi else ""
    return est, lo, hi, n, needed, thr


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
    """The verdict on one run: the outcome ("holds", "does not hold", "undecided" or "not
    judged", ``why_not_judged`` saying why), the readings, the card and the details."""

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
        order = (FAILS, UNDECIDED, "not measured")
        found = [r for w in order for r in self.thesis_readings if r.outcome == w]
        found += self.thesis_readings or self.readings
        return found[0] if found else None

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
        why = f" ({self.why_not_judged})" if self.why_not_judged else ""
        out.append(f"**Verdict:** {self.outcome}{why}")
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
                fixed = f"{p.fixed} the numbers"
                out.append(
                    markdown_row([name, r.number(), p.thesis, reading, outcome, p.reason, fixed])
                )
        if c.setup:
            out += ["", "| setting | thesis | ours | why |", "|---|---|---|---|"]
            out += [markdown_row([s.what, s.thesis, s.ours, s.why]) for s in c.setup]
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
    outcome = (
        FAILS if FAILS in outcomes else HOLDS if all(o == HOLDS for o in outcomes) else UNDECIDED
    )
    return Judgement(claim, scale, outcome, readings, "", n_trials, thesis)


def quotes_of(exp_id: str) -> list[dict[str, str]]:
    """The thesis's sentences of ``exp_id`` as ``[{"quote", "location"}]`` ([] without a spec)."""
    claim = specs().get(exp_id)
    return (
        [] if claim is None else [{"quote": q.text, "location": q.location} for q in claim.quotes]
    )


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
