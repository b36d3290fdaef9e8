"""The paper's two rule-based baselines, acting in :class:`~flock_torchrl.FlockingEnv` like a learned policy.

* **Policy-MA** — Olfati-Saber 2006, Algorithm 3 (:mod:`.olfati_saber`), ``conf/policy/policy_ma.yaml``.
* **Policy-OP** — Vasarhelyi et al. 2018 (:mod:`.vasarhelyi`), ``conf/policy/policy_op.yaml``.

Both are TensorDict modules that read the env's raw sensing (the ``physics`` and ``laser``
extras: position, velocity, heading, laser ``scan`` / ``scan_obstacle``, ``goal``), keep to
what the UAV's own sensors give it (docs/specification.md section 7), and write
``("agents", "action")`` as a velocity command (the policy YAML sets ``action_mode: velocity``).
Names resolve through :mod:`flock_torchrl.policies.registry` (``make_policy("policy_ma", env)``).
"""

from __future__ import annotations

from typing import Any

from tensordict.nn import TensorDictModuleBase

from ...config import ConfigError, PolicyConfig, ScenarioConfig
from .olfati_saber import OlfatiSaberParams, OlfatiSaberPolicy
from .params import params_from_mapping
from .sensing import RuleBasedPolicy
from .vasarhelyi import VasarhelyiParams, VasarhelyiPolicy

CONTROLLERS: dict[str, tuple[type, type]] = {
    "olfati_saber": (OlfatiSaberParams, OlfatiSaberPolicy),
    "vasarhelyi": (VasarhelyiParams, VasarhelyiPolicy),
}
# What a baseline reads from the env (FlockingEnv(extras=...)).
REQUIRED_EXTRAS = ("physics", "laser")


def controller_params(policy: PolicyConfig) -> Any:
    """The controller's parameter dataclass from ``policy.params`` (a missing, unknown or bad
    field fails naming it)."""
    if policy.controller not in CONTROLLERS:
        raise ConfigError("policy.controller", f"must be one of {', '.join(CONTROLLERS)}; got {policy.controller!r}")
    params_cls, _ = CONTROLLERS[policy.controller]
    return params_from_mapping(params_cls, policy.params)


def make_baseline(policy: PolicyConfig, scenario: ScenarioConfig, seed: int = 0) -> TensorDictModuleBase:
    """The TensorDict module of a rule-based policy acting in ``scenario``.

    Args:
        policy: a composed rule-based policy (``kind: rule``, ``controller``, ``params``).
        scenario: the scenario of the env it acts in (camera, ``tau_v``, obstacles, S4 noise).
        seed: seed of the controller's S4 camera noise.
    """
    if policy.kind != "rule":
        raise ConfigError("policy.kind", f"{policy.name} is a {policy.kind!r} policy, not a rule-based baseline")
    if scenario.action_mode != "velocity":
        raise ConfigError("scenario.action_mode", f"{policy.name} writes velocity commands and needs 'velocity', "
                          f"got {scenario.action_mode!r} (build the env with policy_id={policy.id!r})")
    _, policy_cls = CONTROLLERS[policy.controller]  # type: ignore[index]
    return policy_cls(controller_params(policy), scenario, seed=seed)


__all__ = ["CONTROLLERS", "OlfatiSaberParams", "OlfatiSaberPolicy", "REQUIRED_EXTRAS", "RuleBasedPolicy",
           "VasarhelyiParams", "VasarhelyiPolicy", "controller_params", "make_baseline"]
