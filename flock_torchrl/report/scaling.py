"""Beyond the paper: a policy trained with five UAVs, flown by larger swarms.

The paper stops at nine UAVs (S2). :func:`scaling` evaluates one shipped policy on the
training scenario at N = 5, 9, 20, 50, 100 (500 episodes each, the evaluation seed), the
spawn disc growing with the swarm by the reading's rule (docs/specification.md section 9),
and writes a table and a plot of success, safe_success, d_c, d_min_uav and t_goal against N.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Callable, Sequence

from matplotlib.figure import Figure

from ..config import scenario_config
from ..io import write_csv, write_text
from ..policies.registry import resolve
from ..config import EVAL_SEED
from ..run.rollout import evaluate_handle
from .figures import save_figure

COLUMNS = ("n_uavs", "spawn_radius", "crashed_rate", "success_rate", "success_rate_low", "success_rate_high", "safe_success_rate",
           "safe_success_rate_low", "safe_success_rate_high", "d_c", "d_c_std", "d_min_uav", "d_min_uav_std",
           "t_goal", "t_goal_std", "n_episodes", "seconds")


def scaling(policy: str, reading: str, sizes: Sequence[int] = (5, 9, 20, 50, 100), episodes: int = 500,
            seed: int = EVAL_SEED, checkpoints_dir: str | Path = "checkpoints", device: str = "cpu",
            out_dir: str | Path = ".", log: Callable[[str], None] = print) -> list[dict]:
    """Evaluate ``policy`` (its lowest shipped seed) at each swarm size; write ``scaling.csv``,
    ``scaling.md`` and ``scaling.png`` into ``out_dir``."""
    handle = resolve(policy, reading, checkpoints_dir, device)[0]
    rows = []
    for n in sizes:
        start = time.perf_counter()
        result = evaluate_handle(handle, "train", reading, episodes, seed, device, {"n_uavs": n})
        s = result.summary()
        radius = scenario_config("train", reading=reading, n_uavs=n).swarm_spawn_radius
        rows.append({"n_uavs": n, "spawn_radius": radius, "crashed_rate": result.rate("crashed").rate,
                     **{k: s[k] for k in COLUMNS if k in s},
                     "seconds": round(time.perf_counter() - start, 1)})
        log(f"[{len(rows)}/{len(sizes)}] N={n}: {result}")
    out = Path(out_dir)
    write_csv(out / "scaling.csv", COLUMNS, rows)
    lines = [f"# {handle.name} trained with 5 UAVs, flown by N UAVs (reading `{reading}`)", "",
             f"Training scenario, {episodes} episodes per size, evaluation seed {seed}, deterministic actions; "
             f"checkpoint `{handle.origin}`. Spawn radius by the reading's swarm-size rule "
             "(docs/specification.md section 9). Rates with 95 % Wilson intervals; cells mean ± std.", "",
             "An episode ends when any UAV comes within 0.5 m of an obstacle: `crashed` counts those episodes.", "",
             "| N | spawn radius (m) | success % | safe_success % | crashed % | d_c (m) | d_min_uav (m) | t_goal (s) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['n_uavs']} | {r['spawn_radius']:.2f} | {100 * r['success_rate']:.1f} "
                     f"[{100 * r['success_rate_low']:.1f}, {100 * r['success_rate_high']:.1f}] | "
                     f"{100 * r['safe_success_rate']:.1f} [{100 * r['safe_success_rate_low']:.1f}, "
                     f"{100 * r['safe_success_rate_high']:.1f}] | {100 * r['crashed_rate']:.1f} | "
                     f"{r['d_c']:.2f} ± {r['d_c_std']:.2f} | "
                     f"{r['d_min_uav']:.2f} ± {r['d_min_uav_std']:.2f} | "
                     + ("—" if math.isnan(r["t_goal"]) else f"{r['t_goal']:.1f} ± {r['t_goal_std']:.1f}") + " |")
    write_text(out / "scaling.md", "\n".join(lines) + "\n")
    plot(rows, f"{handle.name} ({reading}) by swarm size", out / "scaling.png")
    return rows


def plot(rows: Sequence[dict], title: str, path: Path) -> None:
    n = [r["n_uavs"] for r in rows]
    fig = Figure(figsize=(10, 3.2), dpi=100, layout="constrained")
    panels = [("rate", [("success_rate", "success"), ("safe_success_rate", "safe_success")], (0, 1.02)),
              ("m", [("d_c", "d_c"), ("d_min_uav", "d_min_uav")], None), ("s", [("t_goal", "t_goal")], None)]
    for i, (unit, series, ylim) in enumerate(panels):
        ax = fig.add_subplot(1, 3, i + 1)
        for key, label in series:
            y = [r[key] for r in rows]
            std = [r.get(f"{key}_std", 0.0) for r in rows]
            ax.errorbar(n, y, yerr=None if key.endswith("rate") else std, marker="o", ms=3, capsize=2, label=label)
        ax.set_xscale("log")
        ax.set_xticks(n, [str(x) for x in n])
        ax.set_xlabel("UAVs (N)")
        ax.set_ylabel(unit)
        if ylim:
            ax.set_ylim(*ylim)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    save_figure(fig, path)


__all__ = ["scaling"]
