"""Evaluation protocol of docs/specification.md section 5: many seeded episodes in one batched rollout.

:func:`evaluate` builds one :class:`~flock_torchrl.FlockingEnv` with ``num_envs = n_episodes``
in the policy's world, resets it once and steps the policy (deterministic actions, no
gradients, no auto-reset) until every world has finished one episode; each world's metrics
are read at its first ``done``, and the worlds still running continue in a smaller env
(:meth:`FlockingEnv.subset`). Every policy sees the same starts: the env is seeded with
:data:`EVAL_SEED` and draws all ``n_episodes`` layouts in its single reset.

Example:
    >>> from flock_torchrl.run.evaluation import evaluate, goal_seeking_policy
    >>> result = evaluate(goal_seeking_policy(), scenario="s1", n_episodes=8)
    >>> result.rate("success").rate
    1.0
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.envs.utils import ExplorationType, set_exploration_type

from ..config import POLICY_SCENARIO_FIELDS, ConfigError, ScenarioConfig, scenario_config
from ..io import write_csv, write_text
from ..policies.registry import PolicyHandle, resolve
from ..world.env import FlockingEnv
from ..world.metrics import CELL_METRICS, METRIC_KEYS, RATE_METRICS

# The evaluation seed shared by every policy (section 5); conf/evaluate.yaml's ``seed`` and
# conf/train.yaml's ``eval_seed`` hold the same number (a test checks it).
EVAL_SEED = 2024
WILSON_Z = 1.959963984540054  # two-sided 95 %


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


def wilson_interval(k: int, n: int, z: float = WILSON_Z) -> tuple[float, float]:
    """Wilson score interval of ``k`` successes in ``n`` trials (``(nan, nan)`` for ``n = 0``).

    ``centre = (p + z^2/2n) / (1 + z^2/n)``, ``half = z / (1 + z^2/n) sqrt(p(1-p)/n + z^2/4n^2)``.
    """
    if n <= 0:
        return math.nan, math.nan
    p = k / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


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


# ---------------------------------------------------------------------------- scripted policy
class _GoalSeeking(torch.nn.Module):
    def __init__(self, speed_action: float) -> None:
        super().__init__()
        self.speed_action = speed_action

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        # o_g = [d_g / d_s, alpha_g / pi]: turn by alpha_g (dphi = a0 pi/2, so a0 = 2 alpha_g / pi).
        turn = (2.0 * observation[..., 1:2]).clamp(-1.0, 1.0)
        return torch.cat((turn, torch.full_like(turn, self.speed_action)), -1)


def goal_seeking_policy(speed_action: float = 0.0) -> TensorDictModule:
    """A scripted policy that steers every UAV straight at the goal at ``V = 2 + speed_action``.

    It reads only ``o_g`` of ``("agents", "observation")`` and ignores obstacles and
    neighbours, so its episodes have a known answer in S1 (tests, timing, sanity checks).
    """
    module = TensorDictModule(_GoalSeeking(speed_action), in_keys=[("agents", "observation")],
                              out_keys=[("agents", "action")])
    module.flock_meta = {"policy": "GoalSeeking"}
    return module


# ---------------------------------------------------------------------------- rollout
def policy_env(handle: PolicyHandle, scenario: str | ScenarioConfig | Mapping[str, Any] = "train",
               reading: str | None = None, num_envs: int = 1, seed: int | None = EVAL_SEED,
               device: str | torch.device = "cpu", env_overrides: Mapping[str, Any] | None = None,
               extras: Sequence[str] = ()) -> FlockingEnv:
    """An env of a scenario in the policy's world: its reading, its scenario fields and the
    env keys it reads. A complete scenario (not a name) is used as given and must agree with
    the policy's fields; the reading must match a checkpoint's."""
    overrides = dict(env_overrides or {})
    extras = tuple(sorted({*handle.extras, *extras}))
    if isinstance(scenario, str):
        reading = reading or handle.reading
        policy_id = handle.id if handle.kind in ("learned", "rule") else None
        env = FlockingEnv(scenario, num_envs=num_envs, device=device, seed=seed, reading=reading,
                          policy_id=policy_id, extras=extras, **{**handle.scenario, **overrides})
    else:
        cfg = scenario_config(scenario, **overrides)
        for key, value in handle.scenario.items():
            mine = getattr(cfg, key)
            if mine != value and not (isinstance(value, float) and math.isclose(mine, value)):
                raise ConfigError(f"scenario.{key}", f"is {mine!r} here, but {handle.origin} sets {value!r}")
        env = FlockingEnv(cfg, num_envs=num_envs, device=device, seed=seed, extras=extras)
    handle.check_reading(env.cfg.reading)
    return env


def run_episodes(env: FlockingEnv, policy: Any) -> tuple[TensorDict, int]:
    """Step ``policy`` in ``env`` from one reset until every world has been done once.

    Worlds that finish are recorded and dropped: the others continue in
    ``env.subset(running)`` (the same trajectories; S4 noise draws aside). Runs under
    ``ExplorationType.DETERMINISTIC`` and ``torch.no_grad()``.

    Returns:
        ``(episodes, steps)``: the ``"episode"`` TensorDict ``[B]`` of each world at its first
        ``done`` (on the CPU), and the number of steps the rollout took.
    """
    limit = env.cfg.max_steps
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.reset()
        records = td["episode"].clone()
        rows = torch.arange(env.num_envs, device=env.device)  # original world index of each batch row
        steps = 0
        while rows.numel():
            if steps >= limit:
                raise RuntimeError(f"{rows.numel()} episodes still running after {steps} steps; "
                                   f"the env should truncate at max_steps={limit}")
            td = env.step(policy(td))["next"]
            steps += 1
            done = td["done"].reshape(-1)
            if bool(done.any()):
                records[rows[done]] = td["episode"][done]
                keep = (~done).nonzero().squeeze(-1)
                if keep.numel():
                    env, td = env.subset(keep), td[keep]
                rows = rows[keep]
    return records.cpu(), steps


def evaluate(policy: Any, scenario: str | ScenarioConfig | Mapping[str, Any] = "train", reading: str | None = None,
             n_episodes: int = 500, seed: int = EVAL_SEED, device: str | torch.device = "cpu",
             env_overrides: Mapping[str, Any] | None = None, max_steps: int | None = None, *,
             checkpoints_dir: str | os.PathLike | None = None) -> EvaluationResult:
    """Evaluate a policy on ``n_episodes`` seeded episodes of a scenario (section 5 protocol).

    Args:
        policy: a TensorDict module, a checkpoint path, a policy id or paper name (a learned
            one pools all its shipped seeds: one run of ``n_episodes`` per seed), or a
            :class:`~flock_torchrl.policies.PolicyHandle`.
        scenario: ``train``, ``s1`` ... ``s5``, ``tau_v``, or a complete scenario.
        reading: the world's reading (default: a checkpoint's own, else the composed default).
        seed: env seed; :data:`EVAL_SEED` gives every policy the same starts and goals.
        env_overrides: scenario fields on top of the policy's (e.g. ``{"tau_v": 0.5}``).
        max_steps: episode limit T_max override.
        checkpoints_dir: root of the shipped checkpoints (for a learned policy's name).
    """
    if not isinstance(n_episodes, int) or isinstance(n_episodes, bool) or n_episodes < 1:
        raise ValueError(f"n_episodes must be an integer >= 1, got {n_episodes!r}")
    overrides = dict(env_overrides or {})
    if max_steps is not None:
        overrides["max_steps"] = int(max_steps)
    results = []
    for handle in resolve(policy, reading, checkpoints_dir, device=str(device)):
        start = time.perf_counter()
        env = policy_env(handle, scenario, reading, n_episodes, seed, device, overrides)
        records, steps = run_episodes(env, handle.build(env))
        results.append(EvaluationResult(
            policy=handle.name, scenario=env.cfg.name, reading=env.cfg.reading, seed=seed,
            episodes={k: records[k].clone() for k in METRIC_KEYS}, rollout_steps=steps,
            wall_time_s=time.perf_counter() - start, source=handle.origin))
    return EvaluationResult.pooled(results)


def rollout_episode(policy: Any, scenario: str = "train", reading: str | None = None, seed: int = EVAL_SEED,
                    device: str | torch.device = "cpu", env_overrides: Mapping[str, Any] | None = None,
                    checkpoints_dir: str | os.PathLike | None = None) -> tuple[TensorDict, FlockingEnv]:
    """One seeded episode of one world, kept step by step (for plots and animations), with the
    ``physics`` keys. The first of the policy's resolved checkpoints acts; the env has one
    world seeded with ``seed``, so every policy given that seed starts from the same layout.

    Returns:
        ``(rollout, env)``: the rollout TensorDict ``[1, T]`` up to the first ``done`` and the env.
    """
    handle = resolve(policy, reading, checkpoints_dir, device=str(device))[0]
    env = policy_env(handle, scenario, reading, 1, seed, device, env_overrides, extras=("physics",))
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(env.cfg.max_steps, handle.build(env), break_when_any_done=True)
    return rollout.cpu(), env


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


# ---------------------------------------------------------------------------- scripts/evaluate.py
def check_evaluate_config(cfg: Any) -> tuple[list[PolicyHandle], ScenarioConfig]:
    """Check ``conf/evaluate.yaml``'s composed config; the policies it names and the scenario
    they run in (exactly ``cfg.scenario``, plus ``max_steps``)."""
    from ..config import (EvaluateConfig, PolicyConfig, check_device, check_policy, check_scenario, check_seed,
                          to_object)
    from ..policies.registry import checkpoint_handle, rule_handle, shipped_checkpoints
    from ..world.spawn import check_spawn_feasible

    checked: EvaluateConfig = to_object(cfg, EvaluateConfig, "")
    scenario = check_scenario(to_object(cfg.scenario, ScenarioConfig, "scenario"))
    if checked.max_steps is not None:
        if checked.max_steps < 1:
            raise ConfigError("max_steps", f"must be an integer >= 1 or null, got {checked.max_steps}")
        scenario = check_scenario(dataclasses.replace(scenario, max_steps=checked.max_steps))
    check_spawn_feasible(scenario)
    policy = check_policy(to_object(cfg.policy, PolicyConfig, "policy"))
    if checked.episodes < 1:
        raise ConfigError("episodes", f"must be an integer >= 1, got {checked.episodes}")
    check_seed(checked.seed)
    check_device(checked.device)
    if checked.threads < 0:
        raise ConfigError("threads", f"must be an integer >= 0, got {checked.threads}")
    fields = {k: getattr(scenario, k) for k in POLICY_SCENARIO_FIELDS}
    if checked.checkpoint:
        handles = [checkpoint_handle(checked.checkpoint, checked.device)]
        if handles[0].id != policy.id:
            raise ConfigError("policy", f"{checked.checkpoint} holds {handles[0].name}; pass policy={handles[0].id} "
                                        "so that its world is composed")
    elif policy.kind == "rule":
        handles = [rule_handle(policy, fields)]
    else:
        paths = shipped_checkpoints(policy.id, scenario.reading, checked.checkpoints_dir)
        if not paths:
            raise ConfigError("policy", f"{policy.name} is a learned policy and "
                                        f"{Path(checked.checkpoints_dir) / scenario.reading / policy.id} holds no "
                                        "seed*.pt: train it, or pass checkpoint=<file>")
        handles = [checkpoint_handle(p, checked.device) for p in paths]
    for handle in handles:
        handle.check_reading(scenario.reading)
    return handles, scenario


def evaluate_app(cfg: Any, out_dir: Path) -> EvaluationResult:
    """``scripts/evaluate.py``: evaluate, print, write ``episodes.csv`` and ``summary.json``."""
    from ..config import plain

    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    handles, scenario = check_evaluate_config(cfg)
    results = []
    for handle in handles:
        start = time.perf_counter()
        env = policy_env(handle, scenario, None, int(cfg.episodes), int(cfg.seed), str(cfg.device))
        records, steps = run_episodes(env, handle.build(env))
        results.append(EvaluationResult(
            policy=handle.name, scenario=scenario.name, reading=scenario.reading, seed=int(cfg.seed),
            episodes={k: records[k].clone() for k in METRIC_KEYS}, rollout_steps=steps,
            wall_time_s=time.perf_counter() - start, source=handle.origin))
        print(results[-1], flush=True)
    result = EvaluationResult.pooled(results)
    if len(results) > 1:
        print(f"pooled over {len(results)} checkpoints: {result}", flush=True)
    paths = write_result(result, out_dir, plain(cfg))
    print("wrote " + " and ".join(str(p) for p in paths), flush=True)
    return result


__all__ = ["Cell", "EVAL_SEED", "EvaluationResult", "Rate", "evaluate", "goal_seeking_policy", "mean_std",
           "check_evaluate_config", "evaluate_app", "policy_env", "rollout_episode", "run_episodes",
           "wilson_interval", "write_result"]
