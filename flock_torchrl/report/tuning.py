"""Tuning the two rule-based baselines' key parameters on the TRAINING scenario only.

A small grid per controller around the rescaled literature values (every other parameter as
composed). Each candidate flies the same seeded batch of training episodes (one batched
rollout, the evaluation protocol's :func:`~flock_torchrl.run.evaluation.run_episodes`) and is
scored by ``(success + safe_success) / 2``; ties go to the higher success rate, then to the
larger obstacle clearance. The chosen values are copied by hand, with their reasoning, into
the policy's YAML (``conf/policy/<id>.yaml``, or ``conf/baseline_tuning/<id>_<reading>.yaml``
for another reading). :func:`evaluate_all` measures the composed values on train and S1-S5
beside the paper; it never tunes there.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from pathlib import Path
from typing import Callable, Iterator, Sequence

from ..config import TuneConfig
from ..io import write_csv
from ..policies.baselines import controller_params
from ..policies.registry import policy_config_of, rule_handle
from ..run.results import EvaluationResult
from ..run.rollout import evaluate_handle
from ..world.metrics import CELL_METRICS
from .reference import load_reference

# The few parameters that decide how the flock meets obstacles and itself. Ranges follow the
# rescaling notes (docs/baselines.md): spacing 2-4 m with r = 1.2 d inside the 5 m camera
# range; obstacle ranges from just above the ~1.3 m stopping distance to 4 m.
GRIDS: dict[str, dict[str, list[float]]] = {
    "policy_ma": {"d": [3.0, 3.5, 4.0], "d_beta": [2.0, 2.5, 3.0]},
    "policy_op": {"r0_rep": [2.5, 3.5], "r0_shill": [0.5, 1.5, 2.5], "v_shill": [5.0, 7.5]},
}
TIED = {"d": ("r", 1.2), "d_beta": ("r_beta", 1.2)}   # parameters kept in ratio to a tuned one


def candidates(name: str) -> Iterator[dict[str, float]]:
    """Every grid point as a dict of parameter values (tied parameters included)."""
    grid = GRIDS[name]
    for values in itertools.product(*grid.values()):
        point = dict(zip(grid, values))
        for key, (tied, ratio) in TIED.items():
            if key in point:
                point[tied] = round(ratio * point[key], 3)
        yield point


def score(result: EvaluationResult) -> tuple[float, float, float]:
    """``(success + safe_success) / 2``, then success, then obstacle clearance ``d_min_obs``."""
    success, safe = result.rate("success").rate, result.rate("safe_success").rate
    return round((success + safe) / 2, 6), round(success, 6), result.cell("d_min_obs").mean


def _run(policy, scenario: str, reading: str, episodes: int, seed: int, max_steps: int | None,
         device: str = "cpu") -> EvaluationResult:
    handle = rule_handle(policy, policy_config_of(policy.id, reading)[1])
    return evaluate_handle(handle, scenario, reading, episodes, seed, device,
                           env_overrides={"max_steps": max_steps} if max_steps else None)


def tune(name: str, reading: str, episodes: int, seed: int, max_steps: int,
         log: Callable[[str], None] = print, device: str = "cpu") -> tuple[dict[str, float], list[dict]]:
    """Grid-tune one controller on the training scenario; ``(best point, one row per candidate)``."""
    policy, _ = policy_config_of(name, reading)
    base = controller_params(policy)
    log(f"\n== {policy.name} ({policy.controller}) on 'train' ({reading}): {episodes} episodes, env seed {seed}, "
        f"{max_steps} steps")
    rows = []
    for point in candidates(name):
        params = dataclasses.asdict(dataclasses.replace(base, **point))
        candidate = dataclasses.replace(policy, params=params)
        result = _run(candidate, "train", reading, episodes, seed, max_steps, device)
        s = result.summary()
        rows.append({**point, "score": score(result)[0], "success": s["success_rate"],
                     "safe_success": s["safe_success_rate"], **{m: s[m] for m in CELL_METRICS},
                     "seconds": round(result.wall_time_s, 1)})
        log(" ".join(f"{k}={v:g}" for k, v in point.items()) + f": score {rows[-1]['score']:.3f}, success "
            f"{s['success_rate']:.3f}, safe_success {s['safe_success_rate']:.3f}, d_min_uav {s['d_min_uav']:.3f}, "
            f"d_min_obs {s['d_min_obs']:.3f} ({result.wall_time_s:.1f} s)")
    best = max(rows, key=lambda r: (r["score"], r["success"], r["d_min_obs"]))
    chosen = {k: best[k] for k in next(candidates(name))}
    log(f"chosen for {policy.name} ({reading}): {chosen} (score {best['score']:.3f})")
    return chosen, rows


def evaluate_all(names: Sequence[str], reading: str, episodes: int, scenarios: Sequence[str], seed: int,
                 log: Callable[[str], None] = print, device: str = "cpu") -> list[dict]:
    """The composed parameters on each scenario (evaluation seed), beside the paper's numbers."""
    paper = {("train", r["policy"]): r for r in load_reference(3)[1]}
    paper.update({(r["scenario"].lower(), r["policy"]): r for r in load_reference(4)[1]})
    rows = []
    for scenario in scenarios:
        for name in names:
            policy, _ = policy_config_of(name, reading)
            result = _run(policy, scenario, reading, episodes, seed, None, device)
            s = result.summary()
            crashed = result.rate("crashed").rate
            rows.append({"scenario": scenario, "policy": policy.name, **s, "crashed": crashed})
            ref = paper.get((scenario, policy.name), {})
            log(f"{scenario:<6} {policy.name:<10} success {s['success_rate']:.3f} (paper {ref.get('success_rate', '-')}),"
                f" safe_success {s['safe_success_rate']:.3f}, crashed {crashed:.3f}; "
                + ", ".join(f"{m} {s[m]:.3f} ({ref.get(m, '-')})" for m in CELL_METRICS))
    return rows


def tune_app(cfg: TuneConfig, out_dir: Path, log: Callable[[str], None] = print) -> None:
    """``scripts/tune_baselines.py``: tune (or, ``evaluate=true``, measure) and write CSVs; ``cfg``:
    ``conf/tune_baselines.yaml``'s checked config (:func:`flock_torchrl.config.app_config`)."""
    reading = cfg.scenario.reading
    start = time.perf_counter()
    if cfg.evaluate:
        rows = evaluate_all(list(cfg.controllers), reading, cfg.episodes, list(cfg.scenarios), cfg.eval_seed, log,
                            cfg.device)
        write_csv(out_dir / "evaluation.csv", list(rows[0]), rows)
    else:
        for name in cfg.controllers:
            chosen, rows = tune(name, reading, cfg.episodes, cfg.seed, cfg.max_steps, log, cfg.device)
            write_csv(out_dir / f"{name}.csv", list(rows[0]), rows)
            log(f"# {name} ({reading}): " + ", ".join(f"{k}: {v}" for k, v in chosen.items()))
    log(f"wrote {out_dir} ({time.perf_counter() - start:.0f} s)")


__all__ = ["GRIDS", "candidates", "evaluate_all", "score", "tune", "tune_app"]
