"""The paper's two rule-based baselines, acting in :class:`~flock_torchrl.FlockingEnv` like a learned policy.

* **Policy-MA** — Olfati-Saber 2006, Algorithm 3 (:mod:`.olfati_saber`), ``conf/policy/policy_ma.yaml``.
* **Policy-OP** — Vasarhelyi et al. 2018 (:mod:`.vasarhelyi`), ``conf/policy/policy_op.yaml``.

Both are TensorDict modules that read the env's raw sensing (position, velocity, heading,
laser ``scan`` / ``scan_obstacle``, ``goal``), keep to what the UAV's own sensors give it
(SPEC 7), and write ``("agents", "action")`` as a velocity command (``action_mode="velocity"``).

Example:
    >>> from flock_torchrl.baselines import baseline_env, make_baseline, evaluate_policy, summarize
    >>> env = baseline_env("policy_op", "s1", num_envs=8, seed=0)
    >>> policy = make_baseline("policy_op", env.cfg)
    >>> summarize(evaluate_policy(env, policy))["success"][0]
    1.0
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase

from ..config import ConfigError, ScenarioConfig, load_scenario
from ..env import FlockingEnv
from ..schema import PolicyConfig, load_group, validate_policy
from .olfati_saber import OlfatiSaberParams, OlfatiSaberPolicy
from .params import params_from_mapping
from .sensing import RuleBasedPolicy
from .vasarhelyi import VasarhelyiParams, VasarhelyiPolicy

CONTROLLERS: dict[str, tuple[type, type]] = {
    "olfati_saber": (OlfatiSaberParams, OlfatiSaberPolicy),
    "vasarhelyi": (VasarhelyiParams, VasarhelyiPolicy),
}
BASELINES = ("policy_ma", "policy_op")


def load_baseline_config(name_or_cfg: str | PolicyConfig | DictConfig | Mapping[str, Any]) -> PolicyConfig:
    """A rule-based policy's config: a name under ``conf/policy/`` or a config node, validated.

    Raises :class:`~flock_torchrl.config.ConfigError` for a learned policy, an unknown
    controller or bad parameters (naming the field).
    """
    if isinstance(name_or_cfg, str):
        node: Any = load_group("policy", name_or_cfg)
    elif isinstance(name_or_cfg, PolicyConfig):
        node = OmegaConf.structured(name_or_cfg)
    else:
        node = name_or_cfg
    cfg = validate_policy(node)
    if cfg.kind != "rule":
        raise ConfigError(f"policy field 'kind': {cfg.name} is a {cfg.kind!r} policy, not a rule-based baseline")
    if cfg.controller not in CONTROLLERS:
        raise ConfigError(f"policy field 'controller': unknown controller {cfg.controller!r}; "
                          f"known: {sorted(CONTROLLERS)}")
    controller_params(cfg)  # fail now on a bad parameter
    return cfg


def controller_params(cfg: PolicyConfig) -> OlfatiSaberParams | VasarhelyiParams:
    """The controller's params dataclass built from ``cfg.params`` (unknown keys fail by name)."""
    params_cls, _ = CONTROLLERS[cfg.controller]  # type: ignore[index]
    return params_from_mapping(params_cls, cfg.params)


def _scenario(env_cfg: Any, policy: PolicyConfig, **overrides: Any) -> ScenarioConfig:
    if isinstance(env_cfg, FlockingEnv):
        return env_cfg.cfg
    if isinstance(env_cfg, ScenarioConfig):
        return env_cfg if not overrides else load_scenario(env_cfg, **overrides)
    return load_scenario(env_cfg, **{**policy.env, **overrides})


def make_baseline(name_or_cfg: str | PolicyConfig | DictConfig | Mapping[str, Any],
                  env_cfg: ScenarioConfig | FlockingEnv | str | Mapping[str, Any] = "train",
                  seed: int = 0) -> TensorDictModuleBase:
    """The TensorDict module of a rule-based baseline.

    Args:
        name_or_cfg: ``"policy_ma"`` / ``"policy_op"`` (``conf/policy/<name>.yaml``) or a policy
            config with ``kind: rule``, ``controller`` and ``params``.
        env_cfg: the scenario the policy acts in: a :class:`ScenarioConfig` or a
            :class:`FlockingEnv` (used as is: the controller's sensors are the env's), or a
            scenario name / mapping (the policy's ``env`` overrides are applied).
        seed: seed of the controller's S4 camera noise.

    Returns:
        A module reading the env's tensordict and writing ``("agents", "action")``, the velocity
        command; ``env.rollout(T, policy=module)`` works.
    """
    cfg = load_baseline_config(name_or_cfg)
    scenario = _scenario(env_cfg, cfg)
    if scenario.action_mode != "velocity":
        raise ConfigError(f"scenario field 'action_mode': {cfg.name} writes velocity commands and needs "
                          f"action_mode='velocity', got {scenario.action_mode!r} (build the env with the "
                          "policy's env overrides, e.g. baseline_env())")
    _, policy_cls = CONTROLLERS[cfg.controller]  # type: ignore[index]
    return policy_cls(controller_params(cfg), scenario, seed=seed)


def baseline_env(name_or_cfg: str | PolicyConfig | DictConfig | Mapping[str, Any], scenario: str = "train",
                 num_envs: int = 1, seed: int | None = 0, device: str | torch.device = "cpu",
                 **overrides: Any) -> FlockingEnv:
    """A :class:`FlockingEnv` with the policy's ``env`` overrides (fov, no instinct, velocity actions)."""
    cfg = load_baseline_config(name_or_cfg)
    return FlockingEnv(scenario, num_envs=num_envs, device=device, seed=seed, **{**cfg.env, **overrides})


@torch.no_grad()
def evaluate_policy(env: FlockingEnv, policy: TensorDictModuleBase, max_steps: int | None = None) -> TensorDict:
    """Run one batched episode per env without auto-reset; each env's metrics at its FIRST done.

    Calls ``env.reset()`` once, then ``policy`` / ``env.step`` / ``env.step_mdp`` until every env
    has been done once (or ``max_steps``, default the scenario's ``max_steps``; envs still running
    then report their episode so far, not a success). Envs that finish early keep stepping,
    unrecorded.

    Returns:
        The ``("next", "episode")`` entries (``success``, ``safe_success``, ``d_min_obs``,
        ``d_min_uav``, ``d_c``, ``v_error``, ``phi_error``, ``speed``, ``t_goal`` (NaN if the goal
        was not reached), ...) of each env at its first done, batch ``[B]``.
    """
    steps = env.cfg.max_steps if max_steps is None else max_steps
    if steps < 1:
        raise ValueError(f"max_steps must be >= 1, got {steps}")
    td = env.reset()
    finished = torch.zeros(env.batch_size, dtype=torch.bool, device=env.device)
    record: TensorDictBase | None = None
    for _ in range(steps):
        td = env.step(policy(td))
        episode = td["next", "episode"]
        done = td["next", "done"].reshape(env.batch_size)
        # Keep the recorded entries of envs done before; take this step's for all others, so
        # envs still running when ``max_steps`` stops the loop report their episode so far.
        record = episode.clone() if record is None else record.apply(
            lambda old, new: torch.where(finished.view(-1, *[1] * (new.dim() - 1)), old, new), episode)
        finished |= done
        if bool(finished.all()):
            break
        td = env.step_mdp(td)
    return record


def summarize(metrics: TensorDictBase) -> dict[str, tuple[float, float]]:
    """Table cells ``{metric: (mean, std)}`` over episodes (SPEC 5).

    ``success`` / ``safe_success`` are rates (std of the 0/1 outcomes); ``t_goal`` is over the
    episodes that reached the goal (NaN if none did); the rest over all episodes.
    """
    out: dict[str, tuple[float, float]] = {}
    for key in ("success", "safe_success", "d_min_obs", "d_min_uav", "d_c", "v_error", "phi_error", "speed",
                "t_goal"):
        value = metrics[key].to(torch.float64)
        if key == "t_goal":
            value = value[~torch.isnan(value)]
        if value.numel() == 0:
            out[key] = (math.nan, math.nan)
        else:
            out[key] = (value.mean().item(), value.std(correction=0).item())
    return out


__all__ = [
    "BASELINES", "CONTROLLERS", "OlfatiSaberParams", "OlfatiSaberPolicy", "RuleBasedPolicy", "VasarhelyiParams",
    "VasarhelyiPolicy",
    "baseline_env", "controller_params", "evaluate_policy", "load_baseline_config", "make_baseline", "summarize",
]
