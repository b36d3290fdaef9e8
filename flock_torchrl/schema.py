"""Structured configs: one dataclass per Hydra group, mirrored field by field by the YAMLs.

``conf/<group>/*.yaml`` compose against these (``tests/test_configs.py`` checks every file),
so a misspelt or mistyped key fails when the config is built, with the key's name, instead
of deep inside a run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Dict, Optional

from omegaconf import DictConfig, OmegaConf

from .config import CONF_DIR, SCENARIO_FIELDS, ConfigError, ScenarioConfig


@dataclass
class PolicyConfig:
    """One of the twelve policies (SPEC section 7): a learner or controller plus env overrides."""

    name: str = "Policy3-G"
    kind: str = "learned"               # learned | rule
    critic_input: str = "state"         # observation | state (learned policies)
    controller: Optional[str] = None    # olfati_saber | vasarhelyi (rule-based policies)
    env: Dict[str, Any] = field(default_factory=dict)
    params: Dict[str, Any] = field(default_factory=dict)


@dataclass
class SACConfig:
    name: str = "sac"
    gamma: float = 0.99
    lr_actor: float = 5e-5
    lr_critic: float = 1e-3
    lr_alpha: float = 1e-3
    alpha_init: float = 0.2
    target_entropy: float = -2.0
    tau: float = 0.01
    batch_size: int = 128
    buffer_size: int = 100_000
    num_qvalue_nets: int = 2
    loss_function: str = "l2"
    hidden: int = 128
    depth: int = 2
    max_grad_norm: float = 0.0


@dataclass
class DDPGConfig:
    name: str = "ddpg"
    gamma: float = 0.99
    lr_actor: float = 5e-5
    lr_critic: float = 1e-3
    tau: float = 0.01
    batch_size: int = 128
    buffer_size: int = 100_000
    loss_function: str = "l2"
    hidden: int = 128
    depth: int = 2
    noise_sigma: float = 0.3
    noise_sigma_end: float = 0.05
    noise_anneal_frames: int = 200_000
    max_grad_norm: float = 0.0


@dataclass
class PPOConfig:
    name: str = "ppo"
    rollout_steps: int = 64             # env steps per env per on-policy batch (replaces steps_per_batch)
    gamma: float = 0.99
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    lr: float = 3e-4
    epochs: int = 10
    minibatch_size: int = 1024
    entropy_coeff: float = 1e-3
    critic_coeff: float = 1.0
    loss_critic_type: str = "l2"
    normalize_advantage: bool = True
    hidden: int = 128
    depth: int = 2
    max_grad_norm: float = 1.0


ALGO_SCHEMAS = {"sac": SACConfig, "ddpg": DDPGConfig, "ppo": PPOConfig}


@dataclass
class LoggerConfig:
    backend: str = "csv"                # csv | wandb | tensorboard | none
    project: str = "flock_torchrl"
    mode: str = "offline"               # wandb only: offline | online


LOGGER_BACKENDS = ("csv", "wandb", "tensorboard", "none")


@dataclass
class ExperimentConfig:
    """How long and how fast to train; ``algo_overrides.<algo>`` patches the algo group."""

    name: str = "fast"
    num_envs: int = 32                  # envs stepped together in one batched FlockingEnv
    workers: int = 1                    # >1: MultiSyncCollector over that many processes
    steps_per_batch: int = 8            # env steps per env between updates
    updates_per_batch: int = 8          # gradient steps per collected batch (off-policy)
    init_random_frames: int = 0         # env frames of uniform random actions first
    max_episodes: int = 0               # stop after this many finished episodes (0: no limit)
    max_frames: int = 0                 # stop after this many env frames (swarm steps; 0: no limit)
    max_minutes: float = 0.0            # wall-clock budget (0: no limit)
    eval_every_frames: int = 50_000
    eval_episodes: int = 100
    checkpoint_every_frames: int = 50_000
    keep_buffer_in_checkpoint: bool = True
    algo_overrides: Dict[str, Dict[str, Any]] = field(default_factory=dict)
    # Scenario fields changed for the *training* env only (a training recipe, e.g. ending an
    # episode at UAV-UAV contact); evaluation always runs the scenario as the policy defines it.
    train_env: Dict[str, Any] = field(default_factory=dict)


@dataclass
class TrainConfig:
    """The primary config of ``scripts/train.py`` (``conf/train.yaml``)."""

    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    algo: Any = None
    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    seed: int = 0
    device: str = "cpu"
    run_dir: str = "runs/default"
    resume: Any = False                 # true | false | auto (resume if a checkpoint exists)
    progress: bool = True
    eval_seed: int = 2024
    policy_id: Optional[str] = None
    cli_overrides: Any = None


def _structured(schema: type, node: Any, what: str):
    try:
        merged = OmegaConf.merge(OmegaConf.structured(schema), node)
        return OmegaConf.to_object(merged)
    except Exception as exc:  # omegaconf errors name the offending key
        raise ConfigError(f"invalid {what} config: {exc}") from exc


def validate_policy(node: Any) -> PolicyConfig:
    cfg: PolicyConfig = _structured(PolicyConfig, node, "policy")
    if cfg.kind not in ("learned", "rule"):
        raise ConfigError(f"policy field 'kind': must be 'learned' or 'rule', got {cfg.kind!r}")
    if cfg.kind == "learned" and cfg.critic_input not in ("observation", "state"):
        raise ConfigError(f"policy field 'critic_input': must be 'observation' or 'state', got {cfg.critic_input!r}")
    unknown = sorted(set(cfg.env) - SCENARIO_FIELDS)
    if unknown:
        raise ConfigError(f"policy field 'env': unknown scenario field(s) {unknown}")
    return cfg


def validate_algo(node: Any) -> SACConfig | DDPGConfig | PPOConfig:
    if node is None:
        raise ConfigError("no 'algo' config: a learned policy's YAML must select one (defaults: - /algo: sac)")
    name = node.get("name") if hasattr(node, "get") else None
    if name not in ALGO_SCHEMAS:
        raise ConfigError(f"algo field 'name': unknown algorithm {name!r}; known: {sorted(ALGO_SCHEMAS)}")
    cfg = _structured(ALGO_SCHEMAS[name], node, f"algo '{name}'")
    for key in ("gamma",):
        if not 0 < getattr(cfg, key) <= 1:
            raise ConfigError(f"algo field '{key}': must lie in (0, 1], got {getattr(cfg, key)}")
    for key, value in vars(cfg).items():
        if isinstance(value, (int, float)) and not isinstance(value, bool) and not math.isfinite(value):
            raise ConfigError(f"algo field '{key}': must be finite, got {value}")
    for key in ("batch_size", "buffer_size", "minibatch_size", "epochs", "hidden", "depth", "rollout_steps"):
        if hasattr(cfg, key) and getattr(cfg, key) < 1:
            raise ConfigError(f"algo field '{key}': must be >= 1, got {getattr(cfg, key)}")
    return cfg


def validate_logger(node: Any) -> LoggerConfig:
    cfg: LoggerConfig = _structured(LoggerConfig, node, "logger")
    if cfg.backend not in LOGGER_BACKENDS:
        raise ConfigError(f"logger field 'backend': unknown logger {cfg.backend!r}; known: {LOGGER_BACKENDS}")
    if cfg.mode not in ("offline", "online"):
        raise ConfigError(f"logger field 'mode': must be 'offline' or 'online', got {cfg.mode!r}")
    return cfg


def validate_experiment(node: Any) -> ExperimentConfig:
    cfg: ExperimentConfig = _structured(ExperimentConfig, node, "experiment")
    for key in ("num_envs", "workers", "steps_per_batch", "eval_episodes"):
        if getattr(cfg, key) < 1:
            raise ConfigError(f"experiment field '{key}': must be >= 1, got {getattr(cfg, key)}")
    for key in ("updates_per_batch", "init_random_frames", "max_episodes", "max_frames", "eval_every_frames",
                "checkpoint_every_frames"):
        if getattr(cfg, key) < 0:
            raise ConfigError(f"experiment field '{key}': must be >= 0, got {getattr(cfg, key)}")
    if cfg.max_minutes < 0:
        raise ConfigError(f"experiment field 'max_minutes': must be >= 0, got {cfg.max_minutes}")
    if not (cfg.max_episodes or cfg.max_frames or cfg.max_minutes):
        raise ConfigError("experiment: set at least one of max_episodes, max_frames, max_minutes")
    unknown = sorted(set(cfg.train_env) - SCENARIO_FIELDS)
    if unknown:
        raise ConfigError(f"experiment field 'train_env': unknown scenario field(s) {unknown}")
    unknown = sorted(set(cfg.algo_overrides) - set(ALGO_SCHEMAS))
    if unknown:
        raise ConfigError(f"experiment field 'algo_overrides': unknown algorithm(s) {unknown}")
    if cfg.workers > 1 and cfg.num_envs % cfg.workers:
        raise ConfigError(f"experiment field 'workers': {cfg.workers} must divide num_envs={cfg.num_envs}")
    return cfg


def load_group(group: str, name: str) -> DictConfig:
    """Load ``conf/<group>/<name>.yaml`` without Hydra (its ``defaults`` list is dropped)."""
    path = CONF_DIR / group / f"{name}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))
        raise ConfigError(f"unknown {group} {name!r}; available: {known}")
    node = OmegaConf.load(path)
    node.pop("defaults", None)
    return node


def policy_algo_name(policy_name: str) -> Optional[str]:
    """The algo a policy YAML selects in its defaults list (``/algo@_global_.algo: sac``), if any."""
    node = OmegaConf.load(CONF_DIR / "policy" / f"{policy_name}.yaml")
    for entry in node.get("defaults", []) or []:
        if isinstance(entry, (dict, DictConfig)):
            for key, value in entry.items():
                if str(key).startswith("/algo"):
                    return str(value)
    return None


def available(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))
