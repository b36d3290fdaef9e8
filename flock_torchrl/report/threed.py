"""The 3-D table in the form of Table III (docs/specification.md section 11): every policy on every
3-D scenario, from the ``summary.json`` files ``scripts/evaluate.py`` wrote (one per policy, seed
and scenario; ``make table3-3d`` lays them out as ``<folder>/<policy>/<seed>/<scenario>/``).

A cell is the mean over the policy's seeds of each seed's episode mean, with the spread over seeds
(standard deviation; a single seed shows its episodes' standard deviation instead, marked ``e``).
Success rates are those of section 5; ``t_goal`` over the episodes that reached the goal.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path
from typing import Any, Iterable

from ..io import write_text

COLUMNS = ("success_rate", "safe_success_rate", "d_min_obs", "d_min_uav", "d_c", "v_error", "phi_error", "speed",
           "t_goal")
LABELS = ("success", "safe success", "d_min^obs (m)", "d_min^uav (m)", "d_c (m)", "V_error (m/s)", "phi_error (rad)",
          "V (m/s)", "t^g (s)")


def collect(folder: str | os.PathLike) -> list[dict[str, Any]]:
    """Every evaluation summary under ``folder`` (``**/summary.json``), in path order."""
    return [json.loads(p.read_text()) for p in sorted(Path(folder).glob("**/summary.json"))]


def _number(value: Any) -> float:
    return math.nan if value is None else float(value)


def cells(summaries: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per (policy, scenario): the seeds' count and, per column, mean and spread."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for s in summaries:
        groups.setdefault((s["policy"], s["scenario"]), []).append(s)
    rows = []
    for (policy, scenario), runs in groups.items():
        row: dict[str, Any] = {"policy": policy, "scenario": scenario, "seeds": len(runs),
                               "episodes": sum(int(r["n_episodes"]) for r in runs)}
        for column in COLUMNS:
            values = [_number(r["summary"].get(column)) for r in runs]
            finite = [v for v in values if not math.isnan(v)]
            mean = sum(finite) / len(finite) if finite else math.nan
            if len(runs) > 1:
                spread = (math.sqrt(sum((v - mean) ** 2 for v in finite) / (len(finite) - 1))
                          if len(finite) > 1 else math.nan)
                row[f"{column}_spread"], row[f"{column}_over"] = spread, "seeds"
            else:
                row[f"{column}_spread"] = _number(runs[0]["summary"].get(f"{column}_std"))
                row[f"{column}_over"] = "episodes"
            row[column] = mean
        rows.append(row)
    return sorted(rows, key=lambda r: (r["scenario"], r["policy"]))


def markdown(rows: list[dict[str, Any]]) -> str:
    """The table as markdown: a block per scenario, a row per policy."""
    def fmt(row: dict[str, Any], column: str) -> str:
        mean, spread = row[column], row[f"{column}_spread"]
        if math.isnan(mean):
            return "-"
        if column.endswith("rate"):
            text = f"{100 * mean:.1f} %"
            return text + (f" ± {100 * spread:.1f}" if row[f"{column}_over"] == "seeds" and not math.isnan(spread)
                           else "")
        mark = "" if row[f"{column}_over"] == "seeds" else " e"
        return f"{mean:.3f}" + ("" if math.isnan(spread) else f" ± {spread:.3f}{mark}")

    lines = ["| scenario | policy | seeds | episodes | " + " | ".join(LABELS) + " |",
             "|" + "---|" * (4 + len(LABELS))]
    for row in rows:
        lines.append(f"| {row['scenario']} | {row['policy']} | {row['seeds']} | {row['episodes']} | "
                     + " | ".join(fmt(row, c) for c in COLUMNS) + " |")
    return "\n".join(lines) + "\n"


def write_table(folder: str | os.PathLike) -> Path:
    """``<folder>/table3_3d.md`` and ``.csv`` from the summaries under ``folder``; returns the markdown's path."""
    rows = cells(collect(folder))
    if not rows:
        raise FileNotFoundError(f"{folder}: no summary.json under it (run scripts/evaluate.py there first)")
    out = Path(folder)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    write_text(out / "table3_3d.csv", buffer.getvalue())
    text = ("# Table III in three dimensions\n\nEach cell: the mean over seeds of each seed's episode mean, ± the "
            "standard deviation over seeds (one seed: over its episodes, marked e).\n\n" + markdown(rows))
    write_text(out / "table3_3d.md", text)
    return out / "table3_3d.md"


def episode_gifs(folder: str | os.PathLike, policy: str = "policy_op",
                 scenarios: Iterable[str] = ("train3d", "forest3d", "wall3d"), reading: str = "paper_fit",
                 seed: int = 2024, size: tuple[int, int] = (300, 600), stride: int = 5) -> list[Path]:
    """One seeded episode of ``policy`` (a policy's name, or a checkpoint) on each 3-D scenario,
    drawn as a top and a side view, as ``<folder>/<scenario>_<policy>.gif`` (figures.save_animation)."""
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from ..policies.registry import resolve
    from ..run.rollout import policy_env
    from .figures import save_animation

    handle = resolve(policy, reading)[0]
    paths = []
    for scenario in scenarios:
        env = policy_env(handle, scenario, reading, 1, seed, extras=("physics", "laser"))
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            rollout = env.rollout(env.cfg.max_steps, policy=handle.build(env))
        name = Path(str(policy)).parent.parent.name if str(policy).endswith(".pt") else str(policy)
        paths.append(save_animation(rollout, env, Path(folder) / f"{scenario}_{name}.gif", size=size, stride=stride))
    return paths


__all__ = ["COLUMNS", "cells", "collect", "episode_gifs", "markdown", "write_table"]
