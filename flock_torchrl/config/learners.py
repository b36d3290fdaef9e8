"""The learners' configurations (``conf/algo/*.yaml``): one typed schema per learner, chosen by
its ``name``; an experiment's own settings for a learner: ``conf/tuning/<algo>_<experiment>.yaml``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from omegaconf import MISSING

from .checks import Schema, choice, count, dotted, fraction, is_number, non_negative, positive, reject


@dataclass
class LearnerConfig(Schema):
    """What every learner's schema checks: the shared network and optimisation fields. The apps'
    ``algo`` is typed with it; its value is one of :data:`ALGO_SCHEMAS`, chosen by ``name``."""

    prefix: ClassVar[str] = "algo"
    # Network sizes and batches a machine can hold: far above every recipe.
    _counts: ClassVar[tuple[tuple[str, int], ...]] = (("hidden", 65536), ("depth", 64))

    def checked_fields(self, prefix: str) -> dict[str, Any]:
        p = prefix
        for name, maximum in self._counts:
            count(dotted(p, name), getattr(self, name), 1, maximum)
        fraction(dotted(p, "gamma"), self.gamma)
        non_negative(dotted(p, "max_grad_norm"), self.max_grad_norm)
        self._check_own(p)
        return {}

    def _check_own(self, p: str) -> None:
        pass


def sac_target_entropy(dims: Any) -> float:
    """SAC's default target entropy, -|A| (Table I's H-bar = -2 for the plane's two action numbers, the
    usual heuristic): the action has one number per dimension of the world, so -2 in the plane and -3 in
    space (docs/specification.md section 11). ``conf/algo/sac.yaml`` reads it as
    ``${flock.target_entropy:${scenario.dims}}``, resolved when the config is composed."""
    return -float(dims)   # scenario.dims is checked (2 or 3) by the scenario's schema


# Replay buffers are counted in UAV transitions; 1e9 is about 0.5 TB of swarm transitions.
MAX_BUFFER = 10**9


@dataclass
class SACConfig(LearnerConfig):
    name: str = MISSING
    gamma: float = MISSING
    lr_actor: float = MISSING
    lr_critic: float = MISSING
    lr_alpha: float = MISSING
    alpha_init: float = MISSING
    target_entropy: float = MISSING
    tau: float = MISSING
    batch_size: int = MISSING                # UAV transitions
    buffer_size: int = MISSING               # UAV transitions
    num_qvalue_nets: int = MISSING
    loss_function: str = MISSING
    hidden: int = MISSING
    depth: int = MISSING
    max_grad_norm: float = MISSING

    _counts: ClassVar = (("hidden", 65536), ("depth", 64), ("batch_size", 10**7), ("buffer_size", MAX_BUFFER),
                         ("num_qvalue_nets", 16))

    def _check_own(self, p: str) -> None:
        for name in ("lr_actor", "lr_critic", "lr_alpha", "alpha_init"):
            positive(dotted(p, name), getattr(self, name))
        fraction(dotted(p, "tau"), self.tau)
        if not is_number(self.target_entropy):
            reject(dotted(p, "target_entropy"), f"must be a finite number, got {self.target_entropy!r}")
        choice(dotted(p, "loss_function"), self.loss_function, ("l1", "l2", "smooth_l1"))


@dataclass
class DDPGConfig(LearnerConfig):
    name: str = MISSING
    gamma: float = MISSING
    lr_actor: float = MISSING
    lr_critic: float = MISSING
    tau: float = MISSING
    batch_size: int = MISSING
    buffer_size: int = MISSING
    loss_function: str = MISSING
    hidden: int = MISSING
    depth: int = MISSING
    noise_sigma: float = MISSING
    noise_sigma_end: float = MISSING
    noise_anneal_frames: int = MISSING
    max_grad_norm: float = MISSING

    _counts: ClassVar = (("hidden", 65536), ("depth", 64), ("batch_size", 10**7), ("buffer_size", MAX_BUFFER),
                         ("noise_anneal_frames", 10**12))

    def _check_own(self, p: str) -> None:
        for name in ("lr_actor", "lr_critic"):
            positive(dotted(p, name), getattr(self, name))
        fraction(dotted(p, "tau"), self.tau)
        for name in ("noise_sigma", "noise_sigma_end"):
            non_negative(dotted(p, name), getattr(self, name))
        choice(dotted(p, "loss_function"), self.loss_function, ("l1", "l2", "smooth_l1"))


@dataclass
class PPOConfig(LearnerConfig):
    name: str = MISSING
    rollout_steps: int = MISSING             # env steps per env per on-policy batch
    gamma: float = MISSING
    lmbda: float = MISSING
    clip_epsilon: float = MISSING
    lr: float = MISSING
    epochs: int = MISSING
    minibatch_size: int = MISSING            # swarm transitions per gradient step
    entropy_coeff: float = MISSING
    critic_coeff: float = MISSING
    loss_critic_type: str = MISSING
    normalize_advantage: bool = MISSING
    hidden: int = MISSING
    depth: int = MISSING
    max_grad_norm: float = MISSING

    _counts: ClassVar = (("hidden", 65536), ("depth", 64), ("rollout_steps", 10**6), ("epochs", 10**4),
                         ("minibatch_size", 10**7))

    def _check_own(self, p: str) -> None:
        for name in ("lr", "clip_epsilon"):
            positive(dotted(p, name), getattr(self, name))
        fraction(dotted(p, "lmbda"), self.lmbda, low_open=False)
        for name in ("entropy_coeff", "critic_coeff"):
            non_negative(dotted(p, name), getattr(self, name))
        choice(dotted(p, "loss_critic_type"), self.loss_critic_type, ("l1", "l2", "smooth_l1"))


ALGO_SCHEMAS: dict[str, type[LearnerConfig]] = {"sac": SACConfig, "ddpg": DDPGConfig, "ppo": PPOConfig}


def algo_config(node: Any, prefix: str = "algo") -> LearnerConfig:
    """A learner's node as its schema, chosen by ``name`` (``sac``, ``ddpg``, ``ppo``), checked."""
    if isinstance(node, LearnerConfig):
        return node if node.is_checked else node.check(prefix)
    name = node.get("name") if hasattr(node, "get") else None
    if name not in ALGO_SCHEMAS:
        reject(dotted(prefix, "name"), f"must be one of {', '.join(ALGO_SCHEMAS)}; got {name!r}")
    return ALGO_SCHEMAS[name].from_config(node, prefix)


__all__ = ["ALGO_SCHEMAS", "DDPGConfig", "LearnerConfig", "MAX_BUFFER", "PPOConfig", "SACConfig", "algo_config",
           "sac_target_entropy"]
