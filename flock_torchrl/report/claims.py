"""How close our tables are to the paper's: the fidelity score, and the paper's qualitative claims.

The **fidelity score** of a reading (docs/specification.md section 9), fixed before any result
was seen: the mean over Table III's twelve policies and Table IV's 25 cells of
``|ours - paper| / max(paper std, 0.1 |paper|, 0.05)`` over d_min_obs, d_min_uav, d_c,
v_error, phi_error, speed and t_goal (success excluded). Lower is closer to the paper.

The **claims** are the paper's comparisons on Table III (the instinct keeps UAVs apart, the
centralised critic helps, ...): for each, how many of its comparisons hold in the paper's
numbers and in ours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

from ..world.metrics import CELL_METRICS
from .reference import ROMAN, as_float, load_reference

# The fidelity score's terms (docs/specification.md section 9): every table cell metric.
FIDELITY_METRICS = CELL_METRICS
FIDELITY_TABLES = (3, 4)


# ---------------------------------------------------------------------------- fidelity
def fidelity_terms(rows: Sequence[Mapping[str, Any]], metrics: Sequence[str] = FIDELITY_METRICS) -> list[float]:
    """``|ours - paper| / max(paper std, 0.1 |paper|, 0.05)`` for every metric of every row
    that has both values (rows without a paper value, e.g. the paper-recipe row, count nothing)."""
    terms = []
    for row in rows:
        for m in metrics:
            ours, paper, std = as_float(row.get(m)), as_float(row.get(f"{m}_paper")), as_float(row.get(f"{m}_std_paper"))
            if math.isnan(ours) or math.isnan(paper):
                continue
            terms.append(abs(ours - paper) / max(std if not math.isnan(std) else 0.0, 0.1 * abs(paper), 0.05))
    return terms


@dataclass
class Fidelity:
    """A reading's fidelity score, from the Table III and IV rows evaluated so far."""

    score: float
    terms: int
    expected: int
    parts: dict[int, float]
    per_metric: dict[str, float] = field(default_factory=dict)  # the mean term of each metric, same rows

    @property
    def complete(self) -> bool:
        return self.terms == self.expected

    def __str__(self) -> str:
        if not self.terms:
            return "fidelity score: not available (Tables III and IV not evaluated)"
        parts = ", ".join(f"Table {ROMAN[t]} alone {v:.3f}" for t, v in self.parts.items())
        if not self.complete:  # coverage first: a partial mean must never read like the reading's score
            return (f"INCOMPLETE, {self.terms} of {self.expected} terms: partial fidelity {self.score:.3f} over "
                    f"these rows only ({parts}), not the reading's fidelity score, which needs all of Tables III "
                    "and IV")
        return f"fidelity score {self.score:.3f} (lower is closer to the paper; {parts})"

    def metric_line(self) -> str:
        """The mean term per metric, largest first: where the distance to the paper lies."""
        ranked = sorted(self.per_metric.items(), key=lambda kv: -kv[1])
        return "mean term per metric: " + ", ".join(f"{m} {v:.2f}" for m, v in ranked)


def fidelity(tables: Mapping[int, Sequence[Mapping[str, Any]]]) -> Fidelity:
    """The score over the rows of Tables III and IV given (docs/specification.md section 9)."""
    terms, parts, counted = [], {}, []
    for t in FIDELITY_TABLES:
        rows = [r for r in tables.get(t, []) if not is_extra_row(r)]
        part = fidelity_terms(rows)
        if part:
            parts[t] = sum(part) / len(part)
        terms += part
        counted += rows
    per_metric = {m: sum(v) / len(v) for m in FIDELITY_METRICS if (v := fidelity_terms(counted, (m,)))}
    expected = sum(len(load_reference(t)[1]) for t in FIDELITY_TABLES) * len(FIDELITY_METRICS)
    return Fidelity(sum(terms) / len(terms) if terms else math.nan, len(terms), expected, parts, per_metric)


# ---------------------------------------------------------------------------- the paper's claims
@dataclass(frozen=True)
class Claim:
    """One of the paper's qualitative claims, tested on Table III's rows. ``groups`` are lists
    of paper policy names; ``compare(groups, value)`` says whether the claim holds for the
    values of ``metric`` (``value(name)`` reads one row: ours or the paper's)."""

    text: str
    metric: str
    groups: tuple[tuple[str, ...], ...]
    compare: Callable[[tuple[tuple[str, ...], ...], Callable[[str], float]], tuple[int, int]]


def _pairs_below(groups, value):
    """The pairs ``(a, b)`` of ``groups[0]`` and ``groups[1]``, position by position: how many
    have ``value(a) < value(b)``."""
    pairs = list(zip(*groups))
    return sum(value(a) < value(b) for a, b in pairs), len(pairs)


def _all_above(groups, value):
    """Every policy of ``groups[0]`` above every policy of ``groups[1]``: 1 of 1, else 0 of 1."""
    return int(min(value(n) for n in groups[0]) > max(value(n) for n in groups[1])), 1


def _all_above_1m(groups, value):
    """Every policy of ``groups[0]`` keeps its mean closest pair above 1 m (half of d_safe)."""
    return sum(value(n) > 1.0 for n in groups[0]), len(groups[0])


def _lowest(groups, value):
    """``groups[0][0]`` has the lowest value of all of ``groups[1]``."""
    target = value(groups[0][0])
    return int(all(target < value(n) for n in groups[1] if n != groups[0][0])), 1


LEARNED = ("Policy1", "Policy1-G", "Policy2", "Policy2-G", "Policy3", "Policy3-G", "Policy4-G", "Policy5-G",
           "PolicyD-G", "PolicyP-G")
CLAIMS = (
    Claim("the instinct keeps UAVs apart (closest pair of every instinct policy above every SAC policy without it)",
          "d_min_uav", (("Policy3", "Policy3-G", "Policy5-G"), ("Policy1", "Policy1-G", "Policy2", "Policy2-G")),
          _all_above),
    Claim("... and by a safe margin: every instinct policy's mean closest pair above 1 m (half of d_safe)",
          "d_min_uav", (("Policy3", "Policy3-G", "Policy5-G"),), _all_above_1m),
    Claim("the centralised critic (-G) beats its plain twin (success)", "success_rate",
          (("Policy1", "Policy2", "Policy3"), ("Policy1-G", "Policy2-G", "Policy3-G")), _pairs_below),
    Claim("Policy4-G (instinct as a reward term) has the lowest success of the learned policies", "success_rate",
          (("Policy4-G",), LEARNED), _lowest),
    Claim("the tangential term helps (Policy3-G above Policy5-G, success)", "success_rate",
          (("Policy5-G",), ("Policy3-G",)), _pairs_below),
    Claim("a wider field of view gives more compact flocks (d_c, 2 pi below 0.5 pi, without instinct)", "d_c",
          (("Policy1", "Policy1-G"), ("Policy2", "Policy2-G")), _pairs_below),
)


def _restricted(claim: Claim, evaluated: set[str]) -> tuple[tuple[str, ...], ...] | None:
    """The claim's groups cut down to the policies a table evaluated (a table of only some
    policies, e.g. the paper recipe's): the pairs whose both sides are there, or each group's
    policies that are there; ``None`` when no comparison is left."""
    groups = claim.groups
    if claim.compare is _pairs_below:
        pairs = [(a, b) for a, b in zip(*groups) if a in evaluated and b in evaluated]
        return tuple(zip(*pairs)) if pairs else None
    if claim.compare is _lowest:
        return (groups[0], tuple(n for n in groups[1] if n in evaluated)) if groups[0][0] in evaluated else None
    kept = tuple(tuple(n for n in g if n in evaluated) for g in groups)
    return kept if all(kept) else None


def claim_verdicts(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """For each of :data:`CLAIMS`: how many of its comparisons hold in the paper's Table III and
    in ours, with the values compared. Where our table lacks some policies, ours counts the
    comparisons among those it has (``ours_partial``); none left gives ``None``."""
    by_name = {r["policy"]: r for r in rows if not is_extra_row(r)}
    evaluated = {n for n, r in by_name.items() if not math.isnan(as_float(r.get("success_rate")))}
    out = []
    for claim in CLAIMS:
        names = list(dict.fromkeys(n for g in claim.groups for n in g))
        verdict: dict[str, Any] = {"claim": claim.text, "metric": claim.metric}
        paper = {n: as_float(by_name[n].get(f"{claim.metric}_paper")) if n in by_name else math.nan for n in names}
        ours = {n: as_float(by_name[n].get(claim.metric)) if n in evaluated else math.nan for n in names}
        verdict["paper_values"], verdict["ours_values"] = paper, ours
        # The paper's side over the claim as stated (its "lowest" over all learned policies).
        verdict["paper"] = None if any(math.isnan(v) for v in paper.values()) else claim.compare(
            claim.groups, paper.__getitem__)
        groups = _restricted(claim, evaluated)
        verdict["ours"] = None if groups is None else claim.compare(groups, ours.__getitem__)
        # "lowest of the learned policies" means of those the table holds: never partial
        verdict["ours_partial"] = claim.compare is not _lowest and groups is not None and groups != claim.groups
        out.append(verdict)
    return out


def is_extra_row(row: Mapping[str, Any]) -> bool:
    """A row that is not one of the paper's (the paper recipe's, a contender's): it never enters
    the fidelity score or the claims."""
    return bool(str(row.get("extra", "") or "").strip()) or str(row.get("policy", "")).endswith("(paper recipe)")


__all__ = ["CLAIMS", "Claim", "FIDELITY_METRICS", "FIDELITY_TABLES", "Fidelity", "LEARNED", "claim_verdicts",
           "fidelity", "fidelity_terms", "is_extra_row"]
