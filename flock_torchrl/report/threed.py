"""The 3-D table in the form of Table III (docs/specification.md section 11): every policy on every
3-D scenario, each seed evaluated (:func:`seed_rows`), pooled over seeds with bootstrap intervals
(:func:`pooled_rows`) and section 11's verdicts (:func:`comparisons`); :func:`publish` writes it with
its figures (``make publish-threed``, ``make table3-3d``). Success rates are those of section 5;
``t_goal`` over the episodes that reached the goal.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from ..io import write_text

COLUMNS = ("success_rate", "safe_success_rate", "d_min_obs", "d_min_uav", "d_c", "v_error", "phi_error", "speed",
           "t_goal")
SCENARIOS = ("train3d", "forest3d", "wall3d")
LABELS = ("success", "safe success", "d_min^obs (m)", "d_min^uav (m)", "d_c (m)", "V_error (m/s)", "phi_error (rad)",
          "V (m/s)", "t^g (s)")


def _episode(handle: Any, scenario: str, reading: str, seed: int) -> tuple[Any, Any]:
    """One seeded episode of a policy's handle (deterministic actions), kept step by step, and its env."""
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from ..run.rollout import policy_env

    env = policy_env(handle, scenario, reading, 1, seed, extras=("physics", "laser"))
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(env.cfg.max_steps, policy=handle.build(env))
    return rollout, env


def episode_gifs(folder: str | os.PathLike, policy: str = "policy_op",
                 scenarios: Iterable[str] = SCENARIOS, reading: str = "paper_fit",
                 seed: int = 2024, size: tuple[int, int] = (300, 600), stride: int = 5, prefix: str = "") -> list[Path]:
    """One seeded episode of ``policy`` (a policy's name, or a checkpoint) on each 3-D scenario,
    drawn as a top and a side view, as ``<folder>/<prefix><scenario>_<policy id>.gif`` (figures.save_animation)."""
    from ..policies.registry import resolve
    from .figures import save_animation

    handle = resolve(policy, reading)[0]
    paths = []
    for scenario in scenarios:
        rollout, env = _episode(handle, scenario, reading, seed)
        path = Path(folder) / f"{prefix}{scenario}_{handle.id}.gif"
        paths.append(save_animation(rollout, env, path, size=size, stride=stride))
    return paths


def episode_frame(path: str | os.PathLike, policy: str, scenario: str = "wall3d", reading: str = "paper_fit",
                  seed: int = 2024, size: tuple[int, int] = (360, 720), at: Sequence[float] = (0.0, 0.5, 1.0)) -> Path:
    """Frames (top and side view) of a seeded episode of ``policy`` on ``scenario``, at each fraction
    ``at`` of the episode's steps, one above the other, as a PNG."""
    import numpy as np

    import imageio.v2 as imageio

    from ..io import atomic_write
    from ..policies.registry import resolve
    from ..world.frame import frame_image, image_size, rollout_states, world_extent

    handle = resolve(policy, reading)[0]
    rollout, env = _episode(handle, scenario, reading, seed)
    states = rollout_states(rollout, env.cfg, 0)
    height, width = image_size(size)
    extent = world_extent(env.cfg, states)
    steps = [min(len(states) - 1, int(round(a * (len(states) - 1)))) for a in at]
    name = handle.name if handle.seed is None else f"{handle.name} (seed {handle.seed})"
    image = np.concatenate([frame_image(env.cfg, states[t], extent, height, width, True,
                                        f"{name} on {scenario}, t = {t * env.cfg.dt:.1f} s") for t in steps])
    return atomic_write(path, lambda tmp: imageio.imwrite(tmp, image, format="PNG"))


# ---------------------------------------------------------------------------- the published table (section 11)
SEED_COLUMNS = ("scenario", "policy", "checkpoint",
                *(c for m in COLUMNS[:2] for c in (m, f"{m}_low", f"{m}_high")),   # rates, 95 % Wilson bounds
                *(c for m in COLUMNS[2:] for c in (m, f"{m}_std")), "n_episodes", "n_reached", "wall_time_s")
COMPARED = ("success_rate", "safe_success_rate", "d_min_uav")   # section 11's comparisons, each metric
FIRST = "Policy3-G"
AGAINST = ("Policy2-G", "Policy-MA", "Policy-OP")


def seed_rows(policies: Sequence[str], reading: str, scenarios: Sequence[str] = SCENARIOS, episodes: int = 500,
              seed: int = 2024, device: str = "cpu", log: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """One row per policy (each checkpoint file, each rule-based id) and scenario: its evaluation's
    Table III columns over ``episodes`` seeded episodes (``EvaluationResult.summary``)."""
    from ..io import shown
    from ..policies.registry import resolve
    from ..run.rollout import evaluate_handle

    handles = [h for p in policies for h in resolve(p, reading, device=device)]
    rows = []
    for scenario in scenarios:
        for handle in handles:
            result = evaluate_handle(handle, scenario, reading, episodes, seed, device)
            rows.append({"scenario": scenario, "policy": handle.name, "checkpoint": shown(handle.origin),
                         **result.summary(),
                         "wall_time_s": round(result.wall_time_s, 2), "seed": handle.seed})
            log(f"[{len(rows)}/{len(handles) * len(scenarios)}] {result}")
    return rows


def _scores(rows: Sequence[dict[str, Any]], scenario: str, policy: str, column: str) -> list[float]:
    values = [float(r[column]) for r in rows if r["scenario"] == scenario and r["policy"] == policy]
    return [v for v in values if not math.isnan(v)]


def _is_rule(rows: Sequence[dict[str, Any]], policy: str) -> bool:
    return any(r["policy"] == policy and str(r["checkpoint"]).startswith("baseline:") for r in rows)


def pooled_rows(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per scenario and policy: the seeds' count and, per column, the mean of the seeds' scores with
    its 95 % percentile bootstrap interval over seeds (:func:`.seeds.summarise`; one score: no interval)."""
    from .seeds import summarise

    out = []
    for scenario, policy in dict.fromkeys((r["scenario"], r["policy"]) for r in rows):
        mine = [r for r in rows if r["scenario"] == scenario and r["policy"] == policy]
        row: dict[str, Any] = {"scenario": scenario, "policy": policy, "seeds": len(mine),
                               "episodes": sum(int(r["n_episodes"]) for r in mine)}
        for column in COLUMNS:
            scores = _scores(rows, scenario, policy, column)
            if not scores:
                row[column] = row[f"{column}_low"] = row[f"{column}_high"] = math.nan
                continue
            m = summarise(scores)
            row[column], row[f"{column}_low"], row[f"{column}_high"] = ((m.mean, m.mean_low, m.mean_high)
                                                                         if len(scores) > 1 else (m.mean, math.nan, math.nan))
        out.append(row)
    return out


def comparisons(rows: Sequence[dict[str, Any]]) -> list[tuple[str, str, Any]]:
    """Section 11's verdicts: on each scenario, Policy3-G above Policy2-G, Policy-MA and Policy-OP in each
    of :data:`COMPARED` (a rule-based policy as a fixed score, :func:`.seeds.compare_fixed`)."""
    from .seeds import compare, compare_fixed

    found = []
    for scenario in dict.fromkeys(r["scenario"] for r in rows):
        for other in AGAINST:
            for metric in COMPARED:
                x, y = _scores(rows, scenario, FIRST, metric), _scores(rows, scenario, other, metric)
                if not x or not y:
                    continue
                if _is_rule(rows, other) and len(y) == 1:
                    c = compare_fixed(FIRST, other, x, y[0], metric)
                else:
                    c = compare(FIRST, other, {FIRST: x, other: y}, metric)
                found.append((scenario, metric, c))
    return found


def _interval_cell(row: dict[str, Any], column: str) -> str:
    mean, low, high = row[column], row[f"{column}_low"], row[f"{column}_high"]
    if math.isnan(mean):
        return "-"
    k, digits = (100.0, 1) if column.endswith("rate") else (1.0, 3)
    text = f"{k * mean:.{digits}f}"
    return text if math.isnan(low) else f"{text} [{k * low:.{digits}f}, {k * high:.{digits}f}]"


def published_markdown(rows: Sequence[dict[str, Any]], command: str) -> str:
    """``table3_3d.md``: the pooled table and the verdicts, with how they were made."""
    from .seeds import CONFIDENCE, RESAMPLES, SMALLEST_DIFFERENCE

    pooled = pooled_rows(rows)
    episodes = sorted({int(r["n_episodes"]) for r in rows})
    lines = ["# Table III in three dimensions", "",
             f"The shipped 3-D seeds and the two baselines on the 3-D scenarios, {'/'.join(map(str, episodes))} episodes "
             "per seed and scenario (evaluation seed 2024, deterministic actions), written by `" + command + "`. "
             f"Learned policies: the mean over seeds of each seed's score with its {100 * CONFIDENCE:.0f} % percentile "
             f"bootstrap interval over seeds (scipy.stats.bootstrap, {RESAMPLES} resamples); a baseline has one "
             "score per scenario. Rates in %, distances in m, speeds in m/s, angles in rad, t^g in s over the "
             "episodes that reached the goal. Each seed: `table3_3d_seeds.csv`. The rule: "
             "docs/specification.md section 11.", "",
             "| scenario | policy | seeds | episodes | " + " | ".join(LABELS) + " |", "|" + "---|" * (4 + len(LABELS)),
             *(f"| {r['scenario']} | {r['policy']} | {r['seeds']} | {r['episodes']} | "
               + " | ".join(_interval_cell(r, c) for c in COLUMNS) + " |" for r in pooled),
             "", "## Verdicts", "",
             "Policy3-G above each other policy, per scenario and metric: P(X > Y) over seeds (ties half; against "
             "a baseline, the fraction of Policy3-G's seeds above its one score) and the difference of means, each "
             f"with its {100 * CONFIDENCE:.0f} % interval; the verdict by docs/specification.md section 10's rule "
             "(smallest differences that matter: " + ", ".join(f"{m} {SMALLEST_DIFFERENCE[m]:g}" for m in COMPARED) + ").", "",
             "| scenario | comparison | metric | seeds | P(X > Y) [95 %] | difference of means [95 %] | verdict |",
             "|---|---|---|---|---|---|---|"]
    for scenario, metric, c in comparisons(rows):
        n = f"{len(_scores(rows, scenario, c.better, metric))} / {len(_scores(rows, scenario, c.worse, metric))}"
        lines.append(f"| {scenario} | {c.better} above {c.worse} | {metric} | {n} | {c.probability:.2f} "
                     f"[{c.low:.2f}, {c.high:.2f}] | {c.difference:+.3f} [{c.difference_low:+.3f}, "
                     f"{c.difference_high:+.3f}] | {c.verdict} |")
    return "\n".join(lines) + "\n"


def brief_markdown(rows: Sequence[dict[str, Any]]) -> str:
    """``table3_3d_brief.md`` (README quotes it): per scenario, each policy's safe success rate in %
    (mean [95 % interval over seeds]; each policy's seeds in its title) and Policy3-G's verdicts on it
    against the others (section 10's rule)."""
    pooled = {(r["scenario"], r["policy"]): r for r in pooled_rows(rows)}
    found = {(scenario, c.worse): c.verdict for scenario, metric, c in comparisons(rows) if metric == "safe_success_rate"}
    policies = [FIRST, *AGAINST]
    seeds = "/".join(map(str, sorted({pooled[k]["seeds"] for k in pooled if k[1] in (FIRST, AGAINST[0])})))
    lines = ["# Safe success in three dimensions (written by `make publish-threed`)", "",
             "| scenario | " + " | ".join(f"{p} ({seeds if p in (FIRST, AGAINST[0]) else 1})" for p in policies)
             + " | Policy3-G above " + " / ".join(AGAINST) + " |",
             "|" + "---|" * (len(policies) + 2)]
    for scenario in dict.fromkeys(r["scenario"] for r in rows):
        cells = [_interval_cell(pooled[(scenario, p)], "safe_success_rate") if (scenario, p) in pooled else "-"
                 for p in policies]
        verdicts = " / ".join(found.get((scenario, other), "-") for other in AGAINST)
        lines.append(f"| {scenario} | " + " | ".join(cells) + f" | {verdicts} |")
    return "\n".join(lines) + "\n"


def publish_table(rows: Sequence[dict[str, Any]], out_dir: str | os.PathLike, command: str) -> list[Path]:
    """``table3_3d_seeds.csv`` (one row per seed and scenario), ``table3_3d.csv`` (pooled, with intervals),
    ``table3_3d.md`` (pooled and the verdicts) and ``table3_3d_brief.md`` into ``out_dir``, each written
    atomically."""
    from ..io import write_csv

    out = Path(out_dir)
    pooled = pooled_rows(rows)
    pooled_columns = ["scenario", "policy", "seeds", "episodes", *(c for m in COLUMNS for c in (m, f"{m}_low", f"{m}_high"))]
    return [write_csv(out / "table3_3d_seeds.csv", SEED_COLUMNS, rows),
            write_csv(out / "table3_3d.csv", pooled_columns, pooled),
            write_text(out / "table3_3d.md", published_markdown(rows, command)),
            write_text(out / "table3_3d_brief.md", brief_markdown(rows))]


def representative(rows: Sequence[dict[str, Any]], policy: str, scenario: str) -> dict[str, Any] | None:
    """The row of ``policy``'s seed whose success rate on ``scenario`` is the median of its seeds' (for an even
    count, the lower of the two middle ones; equal scores in the order of the seeds): the seed a figure
    shows, typical rather than the best or the worst. ``None`` when ``policy`` has no row there."""
    mine = [r for r in rows if r["policy"] == policy and r["scenario"] == scenario]
    if not mine:
        return None
    mine.sort(key=lambda r: (float(r["success_rate"]), -1 if r.get("seed") is None else int(r["seed"]),
                             str(r["checkpoint"])))
    return mine[(len(mine) - 1) // 2]


def figures_markdown(rows: Sequence[dict[str, Any]], shown: dict[str, dict[str, Any]], baseline: str,
                     frames: str | None) -> str:
    """``threed_figures.md``: which seed each figure shows, and why."""
    policy = next(iter(shown.values()))["policy"] if shown else FIRST
    lines = ["# The 3-D figures", "",
             f"`threed_<scenario>_<policy>.gif`: one seeded episode (evaluation seed 2024, deterministic actions) of "
             f"{baseline} and of one seed of {policy} on each 3-D scenario, a top view (left) and a side view in the "
             "vertical plane through the area's centre and the goal (right)"
             + (f"; `threed_{frames}_frames.png`: that seed's episode on {frames} at its start, half-way and its end"
                if frames in shown else "")
             + ". The seed shown on a scenario is the one whose success rate there is the median of "
             "the seeds' (the lower middle one for an even count; `flock_torchrl.report.threed.representative`): a "
             "typical seed, neither the best nor the worst.", "",
             f"| scenario | {policy}'s seed shown | its success rate | every seed's |", "|---|---|---|---|"]
    for scenario, row in shown.items():
        seeds = sorted((r for r in rows if r["policy"] == row["policy"] and r["scenario"] == scenario),
                       key=lambda r: -1 if r.get("seed") is None else int(r["seed"]))
        every = ", ".join(f"{r.get('seed')}: {100 * float(r['success_rate']):.1f} %" for r in seeds)
        lines.append(f"| {scenario} | {row.get('seed')} | {100 * float(row['success_rate']):.1f} % | {every} |")
    return "\n".join(lines) + "\n"


def publish(checkpoints: Sequence[str], results: str | os.PathLike, figures: str | os.PathLike, reading: str,
            episodes: int, command: str, baselines: Sequence[str] = ("policy_ma", "policy_op"),
            scenarios: Sequence[str] = SCENARIOS, gif_size: tuple[int, int] = (300, 600), gif_stride: int = 5,
            shown: str = FIRST, frames: str | None = "wall3d", log: Callable[[str], None] = print) -> list[Path]:
    """``make publish-threed``'s table, GIFs and frames: every checkpoint of ``checkpoints`` and each of
    ``baselines`` on ``scenarios`` (:func:`publish_table` into ``results``); on each scenario, one seeded episode
    of the last baseline and of ``shown``'s :func:`representative` seed there as a GIF
    (``threed_<scenario>_<policy>.gif``), and on ``frames`` that seed's episode at its start, half-way and its
    end as ``threed_<frames>_frames.png``, into ``figures``; which seed each shows, ``threed_figures.md`` in
    ``results``. A table without ``shown`` shows the first checkpoint."""
    if not checkpoints:
        raise FileNotFoundError("no 3-D checkpoint to publish (make ship-threed ships them)")
    rows = seed_rows([*checkpoints, *baselines], reading, scenarios, episodes, log=log)
    paths = publish_table(rows, results, command)
    chosen = {scenario: representative(rows, shown, scenario) or representative(rows, rows[0]["policy"], scenario)
              for scenario in scenarios}
    for scenario in scenarios:
        for policy in (baselines[-1], chosen[scenario]["checkpoint"]):
            paths += episode_gifs(figures, policy, [scenario], reading, size=gif_size, stride=gif_stride, prefix="threed_")
        log(f"{scenario}: the GIF shows {chosen[scenario]['policy']} seed {chosen[scenario].get('seed')} "
            f"({chosen[scenario]['checkpoint']}), the seed of median success there")
    if frames in scenarios:
        paths.append(episode_frame(Path(figures) / f"threed_{frames}_frames.png", chosen[frames]["checkpoint"], frames,
                                   reading))
    baseline = next((r["policy"] for r in rows if r["checkpoint"] == f"baseline:{baselines[-1]}"), baselines[-1])
    paths.append(write_text(Path(results) / "threed_figures.md", figures_markdown(rows, chosen, baseline, frames)))
    for path in paths:
        log(f"wrote {path}")
    return paths


__all__ = ["COLUMNS", "SCENARIOS", "comparisons", "episode_frame", "episode_gifs", "figures_markdown", "pooled_rows",
           "publish", "publish_table", "representative", "seed_rows"]
