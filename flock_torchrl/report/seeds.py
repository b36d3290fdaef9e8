"""Verdicts over seeds (docs/specification.md section 10): interval estimates over trained
runs, from ``scipy.stats.bootstrap``, and the rule that turns them into a verdict.

A seed's score is one number (its success rate, or its mean closest pair, over its own
evaluation); a policy is the list of its seeds' scores. Every interval is a percentile
bootstrap over seeds with :data:`RESAMPLES` resamples and a fixed generator, so a table is
reproducible to the last digit from the same scores.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from scipy import stats

from .claims import CLAIMS, Claim
from .reference import read_table_csv

RESAMPLES = 2000
CONFIDENCE = 0.95
MIN_SEEDS = 3          # fewer seeds on either side of a comparison: no verdict
BOOTSTRAP_SEED = 2024
PROFILE_LEVELS = np.linspace(0.0, 1.0, 201)   # success levels of a performance profile
SUMMARY_METRICS = ("success_rate", "safe_success_rate", "d_min_uav", "d_c")
# The smallest difference of means that matters, per metric (docs/specification.md section 10): a
# comparison holds or reverses only when the interval of its difference clears it.
SMALLEST_DIFFERENCE = {"success_rate": 0.01, "safe_success_rate": 0.01, "d_min_uav": 0.1, "d_c": 0.1, "t_goal": 1.0}


def iqm(scores: np.ndarray, axis: int = -1) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50 % (25 % trimmed from each end)."""
    return stats.trim_mean(scores, 0.25, axis=axis)


def mean_difference(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    """mean(X) - mean(Y) over the seeds of each side."""
    return np.mean(x, axis=axis) - np.mean(y, axis=axis)


def probability_of_improvement(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    """P(X > Y): the chance a random seed of ``x`` scores above a random seed of ``y``, ties
    counting half (the Mann-Whitney U statistic over ``n_x n_y``)."""
    x, y = np.moveaxis(np.asarray(x, float), axis, -1), np.moveaxis(np.asarray(y, float), axis, -1)
    above = (x[..., :, None] > y[..., None, :]).mean((-2, -1))
    tied = (x[..., :, None] == y[..., None, :]).mean((-2, -1))
    return above + 0.5 * tied


def score_distribution(scores: np.ndarray, levels: np.ndarray, axis: int = -1) -> np.ndarray:
    """The performance profile of Agarwal et al. (NeurIPS 2021): the fraction of runs scoring
    above each of ``levels``. Scores ``[..., n]`` (runs along ``axis``) give ``[len(levels), ...]``
    (levels first, as ``scipy.stats.bootstrap`` wants a vector statistic)."""
    s = np.moveaxis(np.asarray(scores, float), axis, -1)
    return np.moveaxis((s[..., :, None] > np.asarray(levels, float)).mean(-2), -1, 0)


def _bootstrap(statistic, samples: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """A percentile bootstrap interval of ``statistic`` over the runs of each sample (a scalar
    or a vector statistic)."""
    if any(len(s) < 2 for s in samples) or all(np.ptp(s) == 0 for s in samples):
        value = np.asarray(statistic(*samples, axis=-1), float)
        return value, value   # nothing to resample: every resample gives the same value
    result = stats.bootstrap(tuple(samples), statistic, n_resamples=RESAMPLES, confidence_level=CONFIDENCE,
                             method="percentile", vectorized=True, paired=False,
                             rng=np.random.default_rng(BOOTSTRAP_SEED))
    return np.asarray(result.confidence_interval.low), np.asarray(result.confidence_interval.high)


def _interval(statistic, samples: Sequence[np.ndarray]) -> tuple[float, float]:
    low, high = _bootstrap(statistic, samples)
    return float(low), float(high)


@dataclass(frozen=True)
class Profile:
    """One policy's performance profile: the fraction of its runs above each level, with a
    95 % band over runs."""

    levels: np.ndarray
    fraction: np.ndarray
    low: np.ndarray
    high: np.ndarray


def performance_profile(scores: Sequence[float], levels: np.ndarray = PROFILE_LEVELS) -> Profile:
    x = np.asarray(scores, float)
    statistic = lambda s, axis: score_distribution(s, levels, axis=axis)  # noqa: E731
    return Profile(np.asarray(levels, float), score_distribution(x, levels), *_bootstrap(statistic, [x]))


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
    """``better`` above ``worse`` on a metric: P(better > worse) with its interval, the difference
    of means with its interval, and the verdict."""

    better: str
    worse: str
    probability: float
    low: float
    high: float
    verdict: str
    difference: float = math.nan
    difference_low: float = math.nan
    difference_high: float = math.nan


def smallest_difference(metric: str) -> float:
    """The metric's smallest difference that matters (:data:`SMALLEST_DIFFERENCE`)."""
    if metric not in SMALLEST_DIFFERENCE:
        raise ValueError(f"no smallest difference is set for metric {metric!r}; known: {sorted(SMALLEST_DIFFERENCE)}")
    return SMALLEST_DIFFERENCE[metric]


def verdict(low: float, high: float, n: int, difference_low: float, difference_high: float, smallest: float) -> str:
    """The rule of docs/specification.md section 10: P(X > Y)'s interval ``[low, high]`` must
    clear 0.5 and the difference of means' interval must clear ``smallest`` on the same side."""
    if n < MIN_SEEDS:
        return "too few seeds"
    if low > 0.5 and difference_low > smallest:
        return "holds"
    if high < 0.5 and difference_high < -smallest:
        return "reversed"
    return "not distinguishable"


def compare(better: str, worse: str, scores: Mapping[str, Sequence[float]], metric: str) -> Comparison:
    x, y = np.asarray(scores[better], float), np.asarray(scores[worse], float)
    low, high = _interval(probability_of_improvement, [x, y])
    d_low, d_high = _interval(mean_difference, [x, y])
    return Comparison(better, worse, float(probability_of_improvement(x, y)), low, high,
                      verdict(low, high, min(len(x), len(y)), d_low, d_high, smallest_difference(metric)),
                      float(mean_difference(x, y)), d_low, d_high)


def compare_fixed(better: str, worse: str, scores: Sequence[float], value: float, metric: str) -> Comparison:
    """``better``'s seeds above a fixed score ``value`` (a deterministic baseline flown on the same
    episodes, docs/specification.md section 11): P(X > y) is the fraction of X's seeds above it (ties
    half), and both intervals resample X's seeds alone; the verdict is :func:`verdict`'s, over X's seeds."""
    x, y = np.asarray(scores, float), np.asarray([value], float)
    probability = lambda s, axis: probability_of_improvement(s, y, axis=axis)  # noqa: E731
    difference = lambda s, axis: np.mean(s, axis=axis) - value  # noqa: E731
    low, high = _interval(probability, [x])
    d_low, d_high = _interval(difference, [x])
    return Comparison(better, worse, float(probability(x, -1)), low, high,
                      verdict(low, high, len(x), d_low, d_high, smallest_difference(metric)),
                      float(difference(x, -1)), d_low, d_high)


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
    return [compare(x, y, scores, claim.metric) for x, y in pairs if x in scores and y in scores]


def read_seed_scores(path: str | Path, metric: str) -> dict[str, list[float]]:
    """``{policy: [score per seed]}`` from a ``*_seeds.csv`` table (one row per checkpoint)."""
    scores: dict[str, list[float]] = {}
    for row in read_table_csv(path):
        if row.get("extra"):
            continue
        value = float(row[metric])
        if not math.isnan(value):
            scores.setdefault(row["policy"], []).append(value)
    return scores


def claims_table(seeds_csv: str | Path) -> str:
    """Markdown: every claim of :data:`~.claims.CLAIMS` over the seeds of ``seeds_csv``."""
    lines = ["| claim | comparison | seeds | P(better > worse) [95 %] | difference of means [95 %] | verdict |",
             "|---|---|---|---|---|---|"]
    for claim in CLAIMS:
        scores = read_seed_scores(seeds_csv, claim.metric)
        found = comparisons_of(claim, scores)
        for c in found:
            n = f"{len(scores[c.better])} / {len(scores[c.worse])}"
            lines.append(f"| {claim.text} | {c.better} above {c.worse} | {n} | {c.probability:.2f} "
                         f"[{c.low:.2f}, {c.high:.2f}] | {_difference(c)} | {c.verdict} |")
        if found:
            lines.append(f"| {claim.text} | **the claim** | | | smallest that matters: "
                         f"{smallest_difference(claim.metric):g} | **{claim_verdict(found)}** |")
    return "\n".join(lines) + "\n"


def _difference(c: Comparison) -> str:
    return f"{c.difference:+.3f} [{c.difference_low:+.3f}, {c.difference_high:+.3f}]"


def summary_table(seeds_csv: str | Path, metrics: Sequence[str] = SUMMARY_METRICS) -> str:
    """Markdown: per policy and metric, the mean and the interquartile mean over seeds with
    their 95 % bootstrap intervals, and the seeds' spread (lowest and highest)."""
    lines = ["| policy | metric | seeds | mean [95 %] | IQM [95 %] | seeds' spread |", "|---|---|---|---|---|---|"]
    tables = {metric: read_seed_scores(seeds_csv, metric) for metric in metrics}
    for policy in tables[metrics[0]]:
        for metric in metrics:
            if policy not in tables[metric]:
                continue
            m = summarise(tables[metric][policy])
            lines.append(f"| {policy} | {metric} | {m.n} | {m.mean:.3f} [{m.mean_low:.3f}, {m.mean_high:.3f}] | "
                         f"{m.iqm:.3f} [{m.iqm_low:.3f}, {m.iqm_high:.3f}] | {m.minimum:.3f}-{m.maximum:.3f} |")
    return "\n".join(lines) + "\n"


def plot_profiles(seeds_csv: str | Path, destination: str | Path) -> Path:
    """A performance profile per policy with at least two seeds: the fraction of its runs whose
    success rate lies above each level, with its 95 % band over runs, saved (atomically) as a PNG."""
    from matplotlib.figure import Figure

    from .figures import save_figure

    fig = Figure(figsize=(7.0, 4.5), dpi=120)
    ax = fig.add_subplot()
    scores = {p: s for p, s in read_seed_scores(seeds_csv, "success_rate").items() if len(s) >= 2}
    for policy, runs in scores.items():
        profile = performance_profile(runs)
        line, = ax.step(profile.levels, profile.fraction, where="post", label=f"{policy} ({len(runs)})")
        ax.fill_between(profile.levels, profile.low, profile.high, step="post", alpha=0.12, color=line.get_color())
    lowest = min((min(runs) for runs in scores.values()), default=0.0)
    ax.set_xlim(max(0.0, math.floor(lowest * 50 - 1) / 50), 1.0 + 0.005)   # from just below the lowest run
    ax.set_xlabel("success_rate level")
    ax.set_ylabel("fraction of runs above the level")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(f"Performance profiles over seeds: {Path(seeds_csv).name}")
    ax.legend(fontsize=7, ncol=2, loc="lower left")
    ax.grid(alpha=0.3)
    return save_figure(fig, destination)


def _seed_cell(claim: Claim, seeds_csv: str | Path) -> str:
    """One claim over one recipe's seeds: its verdict, then P(X > Y) with its interval (one
    comparison) or the range of P over its comparisons, and the seeds per policy."""
    scores = read_seed_scores(seeds_csv, claim.metric)
    found = comparisons_of(claim, scores)
    if not found:
        return "no comparison (policies not trained)"
    counts = sorted({len(scores[n]) for c in found for n in (c.better, c.worse)})
    seeds = (f"{counts[0]} seed" + "s" * (counts[0] != 1)) if len(counts) == 1 else f"{counts[0]}-{counts[-1]} seeds"
    if len(found) == 1:
        c = found[0]
        return (f"{c.verdict}: P = {c.probability:.2f} [{c.low:.2f}, {c.high:.2f}], difference "
                f"{_difference(c)} ({seeds})")
    ps, ds = [c.probability for c in found], [c.difference for c in found]
    return (f"{claim_verdict(found)}: P {min(ps):.2f}-{max(ps):.2f}, difference {min(ds):+.3f} to {max(ds):+.3f} "
            f"over {len(found)} pairs ({seeds} each)")


def _paper_cell(claim: Claim) -> str:
    """The claim in the paper's own Table III (point values: how many comparisons hold)."""
    from .reference import load_reference

    values = {row["policy"]: float(row[claim.metric]) for row in load_reference(3)[1]}
    held, total = claim.compare(claim.groups, values.__getitem__)
    return f"holds ({held} of {total})" if held == total else f"{held} of {total} hold"


def claims_overview(recipes: Mapping[str, str | Path]) -> str:
    """Markdown: each claim of :data:`~.claims.CLAIMS` that compares policies, in the paper's
    Table III and over the seeds of each recipe (``{column title: seeds csv}``; a missing file
    gives an empty column)."""
    claims = [c for c in CLAIMS if c.compare.__name__ in ("_pairs_below", "_all_above", "_lowest")]
    titles = list(recipes)
    lines = ["| claim | paper (Table III) | " + " | ".join(titles) + " |", "|---|---|" + "---|" * len(titles)]
    for claim in claims:
        cells = [_seed_cell(claim, path) if Path(path).is_file() else "not published" for path in recipes.values()]
        lines.append(f"| {claim.text} | {_paper_cell(claim)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_overview(recipes: Mapping[str, str | Path], destination: str | Path) -> Path:
    """Write :func:`claims_overview` to ``destination`` (atomically), with how it was made."""
    from ..io import write_text

    text = ("# The paper's claims: paper, fast recipe, paper recipe\n\n"
            + claims_overview(recipes)
            + "\nPaper: the comparisons that hold in the paper's own Table III (one value per policy). "
            "Ours: the verdict of docs/specification.md section 10 over trained seeds (holds when the 95 % "
            "interval of P(X > Y) lies above 0.5 and that of the difference of means above the smallest "
            "difference that matters, "
            + ", ".join(f"{m} {v:g}" for m, v in SMALLEST_DIFFERENCE.items() if m in ("success_rate", "d_min_uav", "d_c"))
            + "; reversed when P's interval lies below 0.5 and the difference's below minus that difference; else "
            "not distinguishable; fewer than "
            f"{MIN_SEEDS} seeds: too few), with P(X > Y), the difference of means and their percentile bootstrap "
            f"intervals ({RESAMPLES} resamples, scipy.stats.bootstrap). Each comparison in full: "
            "`results/<reading>/table3*_claims.md`. Written by `make publish-claims`.\n")
    return write_text(destination, text)


def write_claims(seeds_csv: str | Path, destination: str | Path) -> Path:
    """Write :func:`claims_table` and :func:`summary_table` of ``seeds_csv`` to ``destination``
    (atomically), with how they were made."""
    from ..io import write_text

    text = (f"# The paper's claims over seeds: `{Path(seeds_csv).name}`\n\n"
            "Each comparison is P(X > Y) over the seeds' scores (ties half) and the difference of their means, "
            f"each with a 95 % percentile bootstrap interval ({RESAMPLES} resamples, scipy.stats.bootstrap); the "
            "verdict follows docs/specification.md section 10 (both intervals clear their thresholds: 0.5, and "
            "the metric's smallest difference that matters). Written by `make publish-claims`.\n\n"
            + claims_table(seeds_csv)
            + "\n## Per policy, over seeds\n\nIntervals: percentile bootstrap over seeds, as above; a single "
            "seed has no interval (its value twice).\n\n" + summary_table(seeds_csv))
    return write_text(destination, text)


__all__ = ["SMALLEST_DIFFERENCE", "Comparison", "Profile", "SeedSummary", "claim_verdict", "claims_overview",
           "claims_table", "compare", "compare_fixed", "comparisons_of", "iqm", "mean_difference", "performance_profile",
           "plot_profiles", "probability_of_improvement", "read_seed_scores", "score_distribution",
           "smallest_difference", "summarise", "summary_table", "verdict", "write_claims", "write_overview"]
