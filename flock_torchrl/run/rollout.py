"""The evaluation protocol of docs/specification.md section 5: many seeded episodes in one batched rollout.

:func:`evaluate_handle` builds one :class:`~flock_torchrl.FlockingEnv` with ``num_envs =
n_episodes`` in the policy's world, resets it once and steps the policy (deterministic
actions, no gradients, no auto-reset) until every world has finished one episode; each
world's metrics are read at its first ``done``, and the worlds still running continue in a
smaller env (:meth:`FlockingEnv.subset`). Every policy sees the same starts: the env is
seeded with the evaluation seed (``eval_seed`` of conf/world.yaml) and draws all ``n_episodes`` layouts in its single reset.
:func:`evaluate` resolves what a policy argument stands for (a learned policy pools its
shipped seeds) and evaluates each.

Example:
    >>> from flock_torchrl.policies.scripted import goal_seeking_policy
    >>> from flock_torchrl.run.rollout import evaluate
    >>> result = evaluate(goal_seeking_policy(), scenario="s1", n_episodes=8)
    >>> result.rate("success").rate
    1.0
"""

from __future__ import annotations

import math
import os
import time
from typing import Any, Callable, Mapping, Sequence, Union

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from ..config import ConfigError, ScenarioConfig, eval_seed, scenario_config
from ..policies.registry import PolicyHandle, describe, module_device, resolve
from ..world.env import FlockingEnv
from ..world.metrics import METRIC_KEYS
from .results import EvaluationResult

Scenario = Union[str, ScenarioConfig, Mapping[str, Any]]  # a scenario's name, or a complete scenario


def policy_env(handle: PolicyHandle, scenario: Scenario = "train", reading: str | None = None, num_envs: int = 1,
               seed: int | None = None, device: str | torch.device = "cpu",
               env_overrides: Mapping[str, Any] | None = None, extras: Sequence[str] = ()) -> FlockingEnv:
    """An env of a scenario in the policy's world: its reading, its scenario fields and the
    env keys it reads. A complete scenario (not a name) is used as given and must agree with
    the policy's fields (a contender's declared world replaces them: it flies in the same world
    through every door); the reading must match a checkpoint's."""
    overrides = dict(env_overrides or {})
    extras = tuple(sorted({*handle.extras, *extras}))
    if isinstance(scenario, str):
        reading = reading or handle.reading
        policy_id = handle.id if handle.kind in ("learned", "rule") else None
        env = FlockingEnv(scenario, num_envs=num_envs, device=device, seed=seed, reading=reading,
                          policy_id=policy_id, extras=extras, **{**handle.scenario, **overrides})
    elif handle.kind == "contender":  # it flies in its declared world, whatever policy the config composed
        cfg = scenario_config(scenario, **{**overrides, **handle.scenario})
        env = FlockingEnv(cfg, num_envs=num_envs, device=device, seed=seed, extras=extras)
    else:
        cfg = scenario_config(scenario, **overrides)
        for key, value in handle.scenario.items():
            mine = getattr(cfg, key)
            if mine != value and not (isinstance(value, float) and math.isclose(mine, value)):
                raise ConfigError(f"scenario.{key}", f"is {mine!r} here, but {handle.origin} sets {value!r}")
        env = FlockingEnv(cfg, num_envs=num_envs, device=device, seed=seed, extras=extras)
    handle.check_reading(env.cfg.reading)
    return env


ACTION = ("agents", "action")


class CheckedContender:
    """A contender's module, its every output checked before the env reads it: a TensorDict
    holding a finite float ``("agents", "action")`` of shape ``[*batch, N, 2]`` (3-D: ``N, 3``). Anything else
    is a :class:`ConfigError` under ``key`` naming the contender, what it returned and at
    which step (the env's own checks would not name it)."""

    def __init__(self, module: Any, name: str, key: str = "contenders", dims: int = 2) -> None:
        self.module, self.name, self.key, self.steps = module, name, key, 0
        self.dims = dims  # the action's numbers: 3 in a 3-D world (docs/specification.md section 11)

    def fail(self, what: str) -> None:
        raise ConfigError(self.key, f"{self.name} {what} (at step {self.steps} of its episodes)")

    def __call__(self, td: TensorDict) -> TensorDict:
        self.steps += 1
        try:
            out = self.module(td)
        except ConfigError:
            raise
        except Exception as exc:
            self.fail(f"raised {type(exc).__name__}: {' '.join(str(exc).split())[:200]}")
        if not isinstance(out, TensorDictBase):
            self.fail(f"returned {describe(out)}, not a TensorDict with {ACTION}")
        action = out.get(ACTION, None)
        if action is None:
            keys = sorted(str(k) for k in out.keys(include_nested=True, leaves_only=True))
            self.fail(f"wrote no {ACTION}; its output holds {', '.join(keys[:8])}")
        if not isinstance(action, torch.Tensor):
            self.fail(f"wrote {describe(action)} as {ACTION}, not a tensor")
        if not action.is_floating_point():
            self.fail(f"wrote a {action.dtype} action; actions are float in [-1, 1]")
        n_uavs = td.get(("agents", "observation")).shape[-2]
        expected = (*td.batch_size, n_uavs, self.dims)
        if tuple(action.shape) != expected:
            self.fail(f"wrote an action of shape {list(action.shape)}; this env needs {list(expected)}")
        finite = torch.isfinite(action)
        if not bool(finite.all()):
            bad = "NaN" if bool(torch.isnan(action).any()) else "inf"
            self.fail(f"wrote {bad} actions ({int((~finite).sum())} of {action.numel()} values)")
        return out


def try_contender(handle: PolicyHandle, scenario: Scenario = "train", reading: str | None = None,
                  device: str | torch.device = "cpu", env_overrides: Mapping[str, Any] | None = None,
                  key: str = "contenders", num_envs: int = 2, steps: int = 3) -> None:
    """Build a contender for a small batch of its first scenario and step it a few times,
    before any row is evaluated: a factory that raises or returns no module, an output the env
    cannot take, the reading of a checkpoint — each is one :class:`ConfigError` naming it."""
    env = policy_env(handle, scenario, reading, num_envs, eval_seed(), device, env_overrides)
    module = CheckedContender(handle.build(env), handle.name, key, env.cfg.dims)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.reset()
        for _ in range(steps):
            td = env.step(module(td))["next"]
            if bool(td["done"].any()):
                break


def _within_limit(running: int, steps: int, limit: int) -> None:
    """An evaluation's guard: ``running`` episodes left after ``steps`` steps means the env did
    not truncate at ``max_steps``."""
    if steps >= limit:
        raise RuntimeError(f"{running} episodes still running after {steps} steps; "
                           f"the env should truncate at max_steps={limit}")


def run_episodes(env: FlockingEnv, policy: Any, progress: bool | None = None,
                 label: str = "episodes", log: Callable[[str], None] | None = None,
                 every: float = 5.0) -> tuple[TensorDict, int]:
    """Step ``policy`` in ``env`` from one reset until every world has been done once.

    Worlds that finish are recorded and dropped: the others continue in
    ``env.subset(running)`` (the same trajectories; S4 noise draws aside). Runs under
    ``ExplorationType.DETERMINISTIC`` and ``torch.no_grad()``. ``progress``: a bar of finished
    episodes on stderr (``None``: only when stderr is a terminal). ``log``: where there is no
    bar, a line every ``every`` seconds (episodes done, steps, seconds) goes to it, so a long
    evaluation shows progress in a log file too.

    Returns:
        ``(episodes, steps)``: the ``"episode"`` TensorDict ``[B]`` of each world at its first
        ``done`` (on the CPU), and the number of steps the rollout took.
    """
    from tqdm.auto import tqdm

    limit = env.cfg.max_steps
    bar = tqdm(total=env.num_envs, desc=label, unit="episode", leave=False, dynamic_ncols=True,
               disable=None if progress is None else not progress)
    start = last = time.perf_counter()
    total = env.num_envs
    with bar, torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.reset()
        records = td["episode"].clone()
        rows = torch.arange(env.num_envs, device=env.device)  # original world index of each batch row
        steps = 0
        while rows.numel():
            _within_limit(rows.numel(), steps, limit)
            td = env.step(policy(td))["next"]
            steps += 1
            done = td["done"].reshape(-1)
            if bool(done.any()):
                bar.update(int(done.sum()))
                records[rows[done]] = td["episode"][done]
                keep = (~done).nonzero().squeeze(-1)
                if keep.numel():
                    env, td = env.subset(keep), td[keep]
                rows = rows[keep]
            if log is not None and bar.disable and time.perf_counter() - last >= every:
                last = time.perf_counter()
                log(f"[{label}] {total - rows.numel()}/{total} episodes done, step {steps} of at most {limit}, "
                    f"{last - start:.0f} s")
    return records.cpu(), steps


def evaluate(policy: Any, scenario: Scenario = "train", reading: str | None = None, n_episodes: int = 500,
             seed: int | None = None, device: str | torch.device | None = None,
             env_overrides: Mapping[str, Any] | None = None, max_steps: int | None = None, *,
             checkpoints_dir: str | os.PathLike | None = None) -> EvaluationResult:
    """Evaluate a policy on ``n_episodes`` seeded episodes of a scenario (section 5 protocol).

    Args:
        policy: a TensorDict module, a checkpoint path, a policy id or paper name (a learned
            one pools all its shipped seeds: one run of ``n_episodes`` per seed), or a
            :class:`~flock_torchrl.policies.PolicyHandle`.
        scenario: ``train``, ``s1`` ... ``s5``, ``tau_v``, or a complete scenario.
        reading: the world's reading (default: a checkpoint's own, else the composed default).
        seed: env seed; the default, the evaluation seed (``eval_seed`` of conf/world.yaml), gives every
            policy the same starts and goals.
        env_overrides: scenario fields on top of the policy's (e.g. ``{"tau_v": 0.5}``).
        max_steps: episode limit T_max override.
        checkpoints_dir: root of the shipped checkpoints (for a learned policy's name).
        device: where the worlds run; by default a module's own device, else the CPU.
    """
    if not isinstance(n_episodes, int) or isinstance(n_episodes, bool) or n_episodes < 1:
        raise ValueError(f"n_episodes must be an integer >= 1, got {n_episodes!r}")
    overrides = dict(env_overrides or {})
    if max_steps is not None:
        overrides["max_steps"] = int(max_steps)
    if device is None:
        device = module_device(policy) if isinstance(policy, torch.nn.Module) else "cpu"
    results = [evaluate_handle(handle, scenario, reading, n_episodes, seed, device, overrides)
               for handle in resolve(policy, reading, checkpoints_dir, device=str(device))]
    return EvaluationResult.pooled(results)


def evaluate_handle(handle: PolicyHandle, scenario: Scenario = "train", reading: str | None = None,
                    n_episodes: int = 500, seed: int | None = None, device: str | torch.device = "cpu",
                    env_overrides: Mapping[str, Any] | None = None, contender_key: str = "contenders",
                    log: Callable[[str], None] | None = None) -> EvaluationResult:
    """One policy (one checkpoint, controller or module) on ``n_episodes`` seeded episodes: the
    protocol's unit that :func:`evaluate`, the apps, the tables and the tuning all run. A
    contender's every output is checked (:class:`CheckedContender`, errors under
    ``contender_key``); ``log``: progress lines where no bar shows (:func:`run_episodes`)."""
    start = time.perf_counter()
    seed = eval_seed() if seed is None else seed
    env = policy_env(handle, scenario, reading, n_episodes, seed, device, env_overrides)
    module = handle.build(env)
    if handle.kind == "contender":
        module = CheckedContender(module, handle.name, contender_key, env.cfg.dims)
    records, steps = run_episodes(env, module, label=f"{handle.name} on {env.cfg.name}", log=log)
    return EvaluationResult(
        policy=handle.name, scenario=env.cfg.name, reading=env.cfg.reading, seed=seed,
        episodes={k: records[k].clone() for k in METRIC_KEYS}, rollout_steps=steps,
        wall_time_s=time.perf_counter() - start, source=handle.source)


def evaluate_members(actor: torch.nn.Module, params: TensorDictBase, scenario: Scenario, n_episodes: int,
                     seed: int | None = None, device: str | torch.device = "cpu") -> list[EvaluationResult]:
    """K actors of one architecture (``actor``'s, with member k's weights ``params[k]``, the
    layout of ``TensorDict.from_module(actor)`` stacked ``[K]``) on the same ``n_episodes``
    seeded episodes, in one batched rollout of ``K * n_episodes`` worlds: what a population's
    evaluation runs, instead of K rollouts one after another.

    The env is :func:`evaluate_handle`'s, reset once; its worlds are copied K times
    (:meth:`FlockingEnv.subset`), so every member starts from the layouts :func:`evaluate` gives
    it. The batch keeps one block per member: a world that finishes keeps stepping (its metrics
    are read at its first ``done``; the env's per-step action checks, which refuse that, are off)
    until that layout has finished for every member, and then leaves the batch. The trajectories
    are :func:`evaluate`'s up to the float round-off of the batched actor (vmapped over members)
    and, where a scenario draws per step (S4's noise), other draws."""
    from ..policies.members import MemberPolicy

    start = time.perf_counter()
    k = int(params.batch_size[0])
    seed = eval_seed() if seed is None else seed
    handle = resolve(actor, device=str(device))[0]
    one = policy_env(handle, scenario, None, n_episodes, seed, device)
    limit = one.cfg.max_steps
    policy = MemberPolicy(actor, params, k)
    members = torch.arange(k, device=one.device).unsqueeze(-1)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = one.reset()
        records = td["episode"].clone().unsqueeze(0).expand(k, n_episodes).clone()      # [K, E]
        layouts = torch.arange(n_episodes, device=one.device)                           # still in the batch
        rows = layouts.repeat(k)                                                        # world m * E + e: layout e
        env, td = one.subset(rows), td[rows]
        env.check_actions = False
        finished = torch.zeros(k, n_episodes, dtype=torch.bool, device=one.device)      # [K, layouts]
        steps = 0
        while layouts.numel():
            _within_limit(int((~finished).sum()), steps, limit)
            td = env.step(policy(td))["next"]
            steps += 1
            done = td["done"].reshape(k, -1) & ~finished
            if bool(done.any()):
                where = torch.zeros(k, n_episodes, dtype=torch.bool, device=one.device)
                where[:, layouts] = done
                records[where] = td["episode"].reshape(k, -1)[done]
                finished |= done
                gone = finished.all(0)
                if bool(gone.any()):
                    keep = (~gone).nonzero().squeeze(-1)
                    if not keep.numel():
                        break
                    rows = (members * layouts.numel() + keep).reshape(-1)
                    env, td, finished, layouts = env.subset(rows), td[rows], finished[:, keep], layouts[keep]
    records = records.cpu()
    wall = time.perf_counter() - start
    return [EvaluationResult(policy=f"{handle.name} member {m}", scenario=env.cfg.name, reading=env.cfg.reading,
                             seed=seed, episodes={key: records[m][key].clone() for key in METRIC_KEYS},
                             rollout_steps=steps, wall_time_s=wall / k, source=handle.source)
            for m in range(k)]


def rollout_episode(policy: Any, scenario: str = "train", reading: str | None = None, seed: int | None = None,
                    device: str | torch.device = "cpu", env_overrides: Mapping[str, Any] | None = None,
                    checkpoints_dir: str | os.PathLike | None = None) -> tuple[TensorDict, FlockingEnv]:
    """One seeded episode of one world, kept step by step (for plots and animations), with the
    ``physics`` keys. The first of the policy's resolved checkpoints acts; the env has one
    world seeded with ``seed``, so every policy given that seed starts from the same layout.

    Returns:
        ``(rollout, env)``: the rollout TensorDict ``[1, T]`` up to the first ``done`` and the env.
    """
    handle = resolve(policy, reading, checkpoints_dir, device=str(device))[0]
    env = policy_env(handle, scenario, reading, 1, eval_seed() if seed is None else seed, device, env_overrides,
                     extras=("physics",))
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(env.cfg.max_steps, handle.build(env), break_when_any_done=True)
    return rollout.cpu(), env


__all__ = ["CheckedContender", "evaluate", "try_contender", "evaluate_handle", "evaluate_members", "policy_env",
           "rollout_episode", "run_episodes"]
