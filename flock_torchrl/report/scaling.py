"""Beyond the paper: policies flown by larger swarms than they were trained with.

The paper stops at nine UAVs (S2). :func:`scaling` evaluates shipped policies (Policy3-G
trained with five UAVs; the mixed-size one trained with 5, 20 and 50 at once) and the
rule-based baselines beside them (``others=["policy_ma", "policy_op"]``) on the training
scenario or ``forest`` at N = 5, 9, 20, 50, 100 (500 episodes each, the evaluation seed), the
spawn disc growing with the swarm by the reading's rule (docs/specification.md section 9),
and writes a table and a plot of success, safe_success, d_c, d_min_uav and t_goal against N
(``scaling.*`` for the training scenario, ``scaling_<scenario>.*`` for another).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Callable, Sequence

from matplotlib.figure import Figure

from ..config import ScalingConfig, scenario_config
from ..io import shown, write_csv, write_text
from ..policies.checkpoint import CheckpointError, load_checkpoint
from ..policies.registry import resolve
from ..run.rollout import evaluate_handle
from .figures import save_figure

COLUMNS = ("policy", "trained_sizes", "n_uavs", "spawn_radius", "crashed_rate", "success_rate", "success_rate_low",
           "success_rate_high", "safe_success_rate", "safe_success_rate_low", "safe_success_rate_high", "d_c", "d_c_std",
           "d_min_uav", "d_min_uav_std", "t_goal", "t_goal_std", "n_episodes", "seconds")


def training_of(handle) -> tuple[str, str]:
    """The experiment a learned policy was trained with and its swarm sizes (``5``, ``5+9+20``),
    from its checkpoint; dashes for a rule-based one."""
    try:
        payload = load_checkpoint(handle.origin)
    except (CheckpointError, OSError):
        return "—", "—"
    meta, experiment = payload["meta"], (payload.get("config") or {}).get("experiment", {})
    sizes = meta.get("trained_sizes") or experiment.get("swarm_sizes") or [meta["n_agents"]]
    # One entry per training world kind and size (train_mix repeats each size): the sizes, once each.
    return str(meta.get("experiment", "—")), "+".join(str(n) for n in dict.fromkeys(sizes))


def scaling(cfg: ScalingConfig, out_dir: str | Path = ".", log: Callable[[str], None] = print) -> list[dict]:
    """``conf/scaling.yaml``'s app: evaluate ``cfg.policy_name`` (its lowest shipped seed) and each
    of ``cfg.others`` (policy ids or checkpoint files, e.g. the mixed-size policy or the baselines
    ``policy_ma``, ``policy_op``) at each of ``cfg.sizes`` on ``cfg.scenario`` (by its name:
    ``train``, ``forest``); write ``scaling.csv``, ``scaling.md`` and ``scaling.png`` into
    ``out_dir`` (for another scenario than ``train``: ``scaling_<scenario>.*``). Build ``cfg``
    with :func:`flock_torchrl.config.app_config`, e.g.
    ``app_config("scaling", reading="literal", policy_name="policy_ma", sizes=[3], episodes=1)``."""
    reading, sizes, episodes, seed = cfg.scenario.reading, list(cfg.sizes), cfg.episodes, cfg.seed
    scenario = cfg.scenario.name
    handles = [resolve(p, reading, cfg.checkpoints_dir, cfg.device)[0] for p in (cfg.policy_name, *cfg.others)]
    rows = []
    for k, handle in enumerate(handles):
        experiment, trained = training_of(handle)
        member = "" if handle.member is None else f", member={handle.member} of a population"  # its lowest seed
        label = f"{handle.name} [{experiment}, seed {handle.seed}{member}]" if k and handle.kind != "rule" else handle.name
        for n in sizes:
            start = time.perf_counter()
            result = evaluate_handle(handle, scenario, reading, episodes, seed, cfg.device, {"n_uavs": n})
            s = result.summary()
            radius = scenario_config(scenario, reading=reading, n_uavs=n).swarm_spawn_radius
            rows.append({"policy": label, "trained_sizes": trained, "n_uavs": n, "spawn_radius": radius,
                         "crashed_rate": result.rate("crashed").rate, **{c: s[c] for c in COLUMNS if c in s},
                         "seconds": round(time.perf_counter() - start, 1)})
            log(f"[{len(rows)}/{len(sizes) * len(handles)}] {label} N={n}: {result}")
    out = Path(out_dir)
    stem = "scaling" if scenario == "train" else f"scaling_{scenario}"
    where = "Training scenario" if scenario == "train" else f"Scenario `{scenario}`"
    write_csv(out / f"{stem}.csv", COLUMNS, rows)
    lines = [f"# Policies flown by N UAVs (reading `{reading}`{'' if scenario == 'train' else f', {scenario}'})", "",
             f"{where}, {episodes} episodes per size, evaluation seed {seed}, deterministic actions; "
             "checkpoints " + ", ".join(f"`{shown(h.origin)}`" for h in handles) + ". Spawn radius by the reading's "
             "swarm-size rule (docs/specification.md section 9). Rates with 95 % Wilson intervals; cells mean ± std.",
             "", "An episode ends when any UAV comes within 0.5 m of an obstacle: `crashed` counts those episodes.", "",
             "| policy | trained at N | N | spawn radius (m) | success % | safe_success % | crashed % | d_c (m) | "
             "d_min_uav (m) | t_goal (s) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    rate = lambda r, m: f"{100 * r[m]:.1f} [{100 * r[m + '_low']:.1f}, {100 * r[m + '_high']:.1f}]"  # noqa: E731
    for r in rows:
        lines.append(f"| {r['policy']} | {r['trained_sizes']} | {r['n_uavs']} | {r['spawn_radius']:.2f} | "
                     f"{rate(r, 'success_rate')} | {rate(r, 'safe_success_rate')} | {100 * r['crashed_rate']:.1f} | "
                     f"{r['d_c']:.2f} ± {r['d_c_std']:.2f} | {r['d_min_uav']:.2f} ± {r['d_min_uav_std']:.2f} | "
                     + ("—" if math.isnan(r["t_goal"]) else f"{r['t_goal']:.1f} ± {r['t_goal_std']:.1f}") + " |")
    write_text(out / f"{stem}.md", "\n".join(lines) + "\n")
    plot(rows, f"By swarm size ({reading}, {scenario})", out / f"{stem}.png")
    return rows


def plot(rows: Sequence[dict], title: str, path: Path) -> None:
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    fig = Figure(figsize=(10, 3.4), dpi=100, layout="constrained")
    panels = [("rate", [("success_rate", "success"), ("safe_success_rate", "safe")], (0, 1.02)),
              ("m", [("d_c", "d_c"), ("d_min_uav", "d_min_uav")], None), ("s", [("t_goal", "t_goal")], None)]
    for i, (unit, series, ylim) in enumerate(panels):
        ax = fig.add_subplot(1, 3, i + 1)
        for p, policy in enumerate(policies):
            mine = [r for r in rows if r["policy"] == policy]
            n = [r["n_uavs"] for r in mine]
            for key, label in series:
                y = [r[key] for r in mine]
                std = [r.get(f"{key}_std", 0.0) for r in mine]
                name = label if len(policies) == 1 else f"{label}: {policy} (N={mine[0]['trained_sizes']})"
                ax.errorbar(n, y, yerr=None if key.endswith("rate") else std, marker="os^v"[p % 4], ms=3, capsize=2,
                            linestyle="-" if p == 0 else "--", label=name)
            ax.set_xscale("log")
            ax.set_xticks(n, [str(x) for x in n])
        ax.set_xlabel("UAVs (N)")
        ax.set_ylabel(unit)
        if ylim:
            ax.set_ylim(*ylim)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6)
    fig.suptitle(title, fontsize=10)
    save_figure(fig, path)


__all__ = ["scaling"]
