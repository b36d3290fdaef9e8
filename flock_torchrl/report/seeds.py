"""Verdicts over seeds (docs/specification.md section 10): interval estimates over trained
runs, from ``scipy.stats.bootstrap``, and the rule that turns them into a verdict.

A seed's score is one number (its success rate, or its mean closest pair, over its own
evaluation); a policy is the list of its seeds' scores. Every interval is a percentile
bootstrap over seeds with :data:`RESAMPLES` resamples and a fixed generator, so a table is
reproducible to the last digit from the same scores.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from scipy import stats

from .claims import CLAIMS, Claim

RESAMPLES = 2000
CONFIDENCE = 0.95
MIN_SEEDS = 3          # fewer seeds on either side of a comparison: no verdict
BOOTSTRAP_SEED = 2024


def iqm(scores: np.ndarray, axis: int = -1) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50 % (25 % trimmed from each end)."""
    return stats.trim_mean(scores, 0.25, axis=axis)


def probability_of_improvement(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    """P(X > Y): the chance a random seed of ``x`` scores above a random seed of ``y``, ties
    counting half (the Mann-Whitney U statistic over ``n_x n_y``)."""
    x, y = np.moveaxis(np.asarray(x, float), axis, -1), np.moveaxis(np.asarray(y, float), axis, -1)
    above = (x[..., :, None] > y[..., None, :]).mean((-2, -1))
    tied = (x[..., :, None] == y[..., None, :]).mean((-2, -1))
    return above + 0.5 * tied


def _interval(statistic, samples: Sequence[np.ndarray]) -> tuple[float, float]:
    if any(len(s) < 2 for s in samples) or all(np.ptp(s) == 0 for s in samples):
        value = float(statistic(*samples, axis=-1))
        return value, value   # nothing to resample: every resample gives the same value
    result = stats.bootstrap(tuple(samples), statistic, n_resamples=RESAMPLES, confidence_level=CONFIDENCE,
                             method="percentile", vectorized=True, paired=False,
                             rng=np.random.default_rng(BOOTSTRAP_SEED))
    return float(result.confidence_interval.low), float(result.confidence_interval.high)


@dataclass(frozen=True)
class SeedSummary:
    """One policy's seeds on one metric."""

    n: int
    mean: float
    mean_low: float
    mean_high: float
    iqm: float
    iqm_low: float
    iqm_high: float
    minimum: float
    maximum: float


def summarise(scores: Sequence[float]) -> SeedSummary:
    x = np.asarray(scores, float)
    mean_ci = _interval(lambda s, axis: np.mean(s, axis=axis), [x])
    iqm_ci = _interval(iqm, [x])
    return SeedSummary(len(x), float(x.mean()), *mean_ci, float(iqm(x)), *iqm_ci, float(x.min()), float(x.max()))


@dataclass(frozen=True)
class Comparison:
    """``better`` above ``worse`` on a metric: P(better > worse) with its interval and verdict."""

    better: str
    worse: str
    probability: float
    low: float
    high: float
    verdict: str


def verdict(low: float, high: float, n: int) -> str:
    """The rule of docs/specification.md section 10."""
    if n < MIN_SEEDS:
        return "too few seeds"
    if low > 0.5:
        return "holds"
    if high < 0.5:
        return "reversed"
    return "not distinguishable"


def compare(better: str, worse: str, scores: Mapping[str, Sequence[float]]) -> Comparison:
    x, y = np.asarray(scores[better], float), np.asarray(scores[worse], float)
    low, high = _interval(probability_of_improvement, [x, y])
    return Comparison(better, worse, float(probability_of_improvement(x, y)), low, high,
                      verdict(low, high, min(len(x), len(y))))


def claim_verdict(comparisons: Sequence[Comparison]) -> str:
    """A claim of several comparisons: ``holds`` / ``reversed`` if all are, else the counts."""
    kinds = [c.verdict for c in comparisons]
    if not kinds:
        return "no comparison"
    if len(set(kinds)) == 1:
        return kinds[0]
    return ", ".join(f"{kinds.count(k)} {k}" for k in ("holds", "reversed", "not distinguishable", "too few seeds")
                     if kinds.count(k))


def comparisons_of(claim: Claim, scores: Mapping[str, Sequence[float]]) -> list[Comparison]:
    """The comparisons a claim of :data:`~.claims.CLAIMS` makes, each as ``X above Y`` on the
    claim's metric as it is ("a wider view gives more compact flocks" is Policy2 above Policy1
    in ``d_c``); pairs whose policies have no scores are left out."""
    groups, kind = claim.groups, claim.compare.__name__
    if kind == "_pairs_below":       # groups[0][i] below groups[1][i]
        pairs = [(b, a) for a, b in zip(*groups)]
    elif kind == "_all_above":       # every one of groups[0] above every one of groups[1]
        pairs = [(a, b) for a in groups[0] for b in groups[1]]
    elif kind == "_lowest":          # groups[0][0] below every other policy of groups[1]
        pairs = [(b, groups[0][0]) for b in groups[1] if b != groups[0][0]]
    else:                            # a threshold claim (above 1 m): no comparison of policies
        return []
    return [compare(x, y, scores) for x, y in pairs if x in scores and y in scores]


def read_seed_scores(path: str | Path, metric: str) -> dict[str, list[float]]:
    """``{policy: [score per seed]}`` from a ``*_seeds.csv`` table (one row per checkpoint)."""
    scores: dict[str, list[float]] = {}
    with Path(path).open(newline="") as handle:
        for row in csv.DictReader(handle):
            if row.get("extra"):
                continue
            value = float(row[metric])
            if not math.isnan(value):
                scores.setdefault(row["policy"], []).append(value)
    return scores


def claims_table(seeds_csv: str | Path) -> str:
    """Markdown: every claim of :data:`~.claims.CLAIMS` over the seeds of ``seeds_csv``."""
    lines = ["| claim | comparison | seeds | P(better > worse) [95 %] | verdict |", "|---|---|---|---|---|"]
    for claim in CLAIMS:
        scores = read_seed_scores(seeds_csv, claim.metric)
        found = comparisons_of(claim, scores)
        for c in found:
            n = f"{len(scores[c.better])} / {len(scores[c.worse])}"
            lines.append(f"| {claim.text} | {c.better} above {c.worse} | {n} | {c.probability:.2f} "
                         f"[{c.low:.2f}, {c.high:.2f}] | {c.verdict} |")
        if found:
            lines.append(f"| {claim.text} | **the claim** | | | **{claim_verdict(found)}** |")
    return "\n".join(lines) + "\n"


def write_claims(seeds_csv: str | Path, destination: str | Path) -> Path:
    """Write :func:`claims_table` of ``seeds_csv`` to ``destination`` (atomically), with how it was made."""
    from ..io import write_text

    text = (f"# The paper's claims over seeds: `{Path(seeds_csv).name}`\n\n"
            "Each comparison is P(X > Y) over the seeds' scores (ties half) with a 95 % percentile bootstrap "
            f"interval ({RESAMPLES} resamples, scipy.stats.bootstrap); the verdict follows "
            "docs/specification.md section 10. Written by `python -m flock_torchrl.report.seeds`.\n\n"
            + claims_table(seeds_csv))
    return write_text(destination, text)


def main(argv: Sequence[str] | None = None) -> None:
    """``python -m flock_torchrl.report.seeds <table_seeds.csv> <claims.md>``."""
    import sys

    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 2:
        raise SystemExit("usage: python -m flock_torchrl.report.seeds <table3_seeds.csv> <claims_over_seeds.md>")
    if not Path(args[0]).is_file():
        raise SystemExit(f"error: no seeds table at {args[0]}")
    print(f"wrote {write_claims(*args)}")


if __name__ == "__main__":
    main()


__all__ = ["Comparison", "SeedSummary", "claim_verdict", "claims_table", "compare", "comparisons_of", "iqm",
           "probability_of_improvement", "read_seed_scores", "summarise", "verdict", "write_claims"]
