"""Evaluation results: per-episode metrics, their cells and rates, and the files they are written to.

An :class:`EvaluationResult` holds the section 5 metrics of every episode of one policy in one
scenario (docs/specification.md); its table cells are ``mean +- std`` (:class:`Cell`), its
rates come with 95 % Wilson score intervals (:class:`Rate`). :func:`write_result` writes
``episodes.csv`` and ``summary.json`` as ``scripts/evaluate.py`` does.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import torch

from ..io import write_csv, write_text
from ..world.metrics import CELL_METRICS, METRIC_KEYS, RATE_METRICS

WILSON_CONFIDENCE = 0.95  # two-sided


# ---------------------------------------------------------------------------- statistics
@dataclass(frozen=True)
class Cell:
    """``mean +- std`` of one metric over ``n`` episodes (population std, like ``numpy.std``)."""

    mean: float
    std: float
    n: int


@dataclass(frozen=True)
class Rate:
    """A proportion ``k / n`` with its 95 % Wilson score interval ``[low, high]``."""

    rate: float
    low: float
    high: float
    k: int
    n: int


def wilson_interval(k: int, n: int, confidence: float = WILSON_CONFIDENCE) -> tuple[float, float]:
    """Wilson score interval of ``k`` successes in ``n`` trials (``(nan, nan)`` for ``n = 0``):
    scipy's ``binomtest(k, n).proportion_ci(method="wilson")``, two-sided at ``confidence``."""
    from scipy.stats import binomtest  # scipy.stats takes a second to import: only where an interval is asked for

    if n <= 0:
        return math.nan, math.nan
    interval = binomtest(int(k), int(n)).proportion_ci(confidence_level=confidence, method="wilson")
    return float(interval.low), float(interval.high)


def mean_std(values: torch.Tensor) -> Cell:
    """Mean and population std of the finite entries of a 1-D tensor (NaN cell if none)."""
    v = values.double()
    v = v[torch.isfinite(v)]
    if v.numel() == 0:
        return Cell(math.nan, math.nan, 0)
    return Cell(float(v.mean()), float(v.std(correction=0)), int(v.numel()))


# ---------------------------------------------------------------------------- results
@dataclass
class EvaluationResult:
    """Per-episode section 5 metrics of one policy in one scenario, and their summary.

    Attributes:
        policy: the policy's name (``"Policy3-G"``, ``"Policy-MA"``, ...).
        scenario: the scenario name (``"train"``, ``"s1"``, ...).
        reading: the world's reading.
        seed: the env seed the episodes were drawn with.
        episodes: metric name -> ``[n]`` CPU tensor, one entry per episode (METRIC_KEYS).
        rollout_steps: env steps the batched rollout took (the slowest episode's length).
        wall_time_s: seconds from env construction to the last step.
        source: where the policy came from (checkpoint paths, ``baseline:<id>``, ``module``).
        parts: the per-checkpoint results a pooled result was made of.
    """

    policy: str
    scenario: str
    reading: str
    seed: int
    episodes: dict[str, torch.Tensor]
    rollout_steps: int = 0
    wall_time_s: float = 0.0
    source: str = "module"
    parts: list["EvaluationResult"] = field(default_factory=list)

    @property
    def n_episodes(self) -> int:
        return int(self.episodes["success"].numel())

    def cell(self, metric: str) -> Cell:
        """``mean +- std`` of a metric; ``t_goal`` only over the episodes that reached the goal."""
        values = self.episodes[metric]
        if metric == "t_goal":
            values = values[self.episodes["reached"]]
        return mean_std(values)

    def rate(self, metric: str = "success") -> Rate:
        """Rate of a boolean metric (``success``, ``safe_success``, ``reached``, ``crashed``)."""
        flags = self.episodes[metric].bool()
        k, n = int(flags.sum()), int(flags.numel())
        low, high = wilson_interval(k, n)
        return Rate(k / n if n else math.nan, low, high, k, n)

    def summary(self) -> dict[str, float | int]:
        """One flat row: ``<metric>``, ``<metric>_std`` for the table cells (the paper's column
        names), ``success_rate`` / ``safe_success_rate`` with ``_low`` / ``_high`` Wilson
        bounds, ``n_episodes`` and ``n_reached``."""
        row: dict[str, float | int] = {}
        for m in CELL_METRICS:
            c = self.cell(m)
            row[m], row[f"{m}_std"] = c.mean, c.std
        for m in RATE_METRICS:
            r = self.rate(m)
            row[f"{m}_rate"], row[f"{m}_rate_low"], row[f"{m}_rate_high"] = r.rate, r.low, r.high
        row["n_episodes"] = self.n_episodes
        row["n_reached"] = int(self.episodes["reached"].sum())
        return row

    def records(self) -> list[dict[str, Any]]:
        """One dict per episode: ``episode`` index, ``policy``, ``scenario`` and every metric."""
        cols = {k: v.tolist() for k, v in self.episodes.items()}
        return [{"episode": i, "policy": self.policy, "scenario": self.scenario,
                 **{k: cols[k][i] for k in self.episodes}} for i in range(self.n_episodes)]

    def write_csv(self, path: str | os.PathLike) -> Path:
        """Per-episode records as CSV, written atomically; returns the path."""
        return write_csv(path, ["episode", "policy", "scenario", *METRIC_KEYS], self.records())

    def __str__(self) -> str:
        s = self.summary()
        cells = ", ".join(f"{m} {s[m]:.3f}±{s[f'{m}_std']:.3f}" for m in CELL_METRICS)
        return (f"{self.policy} on {self.scenario} ({self.reading}, {self.n_episodes} episodes, seed {self.seed}): "
                f"success {s['success_rate']:.3f} [{s['success_rate_low']:.3f}, {s['success_rate_high']:.3f}], "
                f"safe_success {s['safe_success_rate']:.3f}; {cells}; "
                f"{self.rollout_steps} steps in {self.wall_time_s:.1f} s")

    @classmethod
    def pooled(cls, results: Sequence["EvaluationResult"]) -> "EvaluationResult":
        """All episodes of several results (e.g. one per training seed) as one result."""
        if not results:
            raise ValueError("pooled() needs at least one result")
        if len(results) == 1:
            return results[0]
        first = results[0]
        episodes = {k: torch.cat([r.episodes[k] for r in results]) for k in first.episodes}
        return cls(policy=first.policy, scenario=first.scenario, reading=first.reading, seed=first.seed,
                   episodes=episodes, rollout_steps=max(r.rollout_steps for r in results),
                   wall_time_s=sum(r.wall_time_s for r in results),
                   source="; ".join(r.source for r in results), parts=list(results))


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


def write_result(result: EvaluationResult, out_dir: str | os.PathLike, config: Mapping[str, Any] | None = None
                 ) -> list[Path]:
    """``episodes.csv`` (one row per episode) and ``summary.json`` (cells, rates, provenance)."""
    out = Path(out_dir)
    summary = {"policy": result.policy, "scenario": result.scenario, "reading": result.reading,
               "source": result.source, "seed": result.seed, "n_episodes": result.n_episodes,
               "summary": result.summary(), "rollout_steps": result.rollout_steps,
               "wall_time_s": round(result.wall_time_s, 3), "config": dict(config or {})}
    return [result.write_csv(out / "episodes.csv"),
            write_text(out / "summary.json", json.dumps(_jsonable(summary), indent=2) + "\n")]


__all__ = ["Cell", "EvaluationResult", "Rate", "WILSON_CONFIDENCE", "mean_std", "wilson_interval", "write_result"]
