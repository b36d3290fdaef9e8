"""``make_policy``: any of the twelve policies as a TensorDict module for ``env.rollout``."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .checkpoint import load_policy
from .config import ConfigError
from .env import FlockingEnv
from .models import make_actor
from .schema import available, load_group, policy_algo_name, validate_policy


def make_policy(policy: str | os.PathLike, env: FlockingEnv | None = None, *, device: str = "cpu") -> Any:
    """Build a policy module that reads ``("agents", "observation")`` (or, for the rule-based
    controllers, the raw sensor keys) and writes ``("agents", "action")``.

    Args:
        policy: a checkpoint file or run folder (a trained policy, see :func:`load_policy`);
            a rule-based policy name (``"policy_ma"``, ``"policy_op"``), built for ``env``'s
            scenario; or a learned policy name (``"policy3_g"`` ...), giving a freshly
            initialised shared actor sized from ``env``'s specs, for scripting your own training.
        env: required for policy names; it must be built with the policy's overrides
            (``make_env_overrides(name)``).
    """
    path = Path(policy)
    if path.suffix == ".pt" or path.is_dir():
        return load_policy(path, device=device)
    name = str(policy)
    if name not in available("policy"):
        raise ConfigError(f"unknown policy {name!r}; available: {available('policy')} or a checkpoint path")
    if env is None:
        raise ConfigError(f"make_policy({name!r}) needs the env it will act in")
    cfg = validate_policy(load_group("policy", name))
    if cfg.kind == "rule":
        from .baselines import make_baseline

        return make_baseline(name, env.cfg)
    algo = load_group("algo", policy_algo_name(name))
    return make_actor(env, stochastic=algo.name != "ddpg", hidden=algo.hidden, depth=algo.depth)


def make_env_overrides(name: str) -> dict[str, Any]:
    """The scenario fields a policy implies (its YAML's ``env:`` block), e.g. ``fov``, ``instinct``."""
    return dict(validate_policy(load_group("policy", name)).env)
