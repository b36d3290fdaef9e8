"""The other groups' schemas: a policy (``conf/policy``), an experiment (``conf/experiment``:
how long and how fast to train) and a logger (``conf/logger``)."""

from __future__ import annotations

import importlib.util
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Dict, List, Optional

from omegaconf import MISSING

from .checks import MAX_UAVS, Schema, choice, count, dotted, folder_name, non_negative, reject
from .scenario import SCENARIO_FIELDS


@dataclass
class PolicyConfig(Schema):
    """One of the twelve policies (section 7); its scenario fields sit in the YAML's ``scenario:``."""

    prefix: ClassVar[str] = "policy"

    id: str = MISSING                        # the YAML's stem, e.g. policy3_g
    name: str = MISSING                      # the paper's name, e.g. Policy3-G
    kind: str = MISSING                      # learned | rule
    critic_input: Optional[str] = None       # observation | state (learned policies)
    controller: Optional[str] = None         # olfati_saber | vasarhelyi (rule-based policies)
    params: Dict[str, Any] = field(default_factory=dict)  # the controller's parameters

    def checked_fields(self, p: str) -> dict[str, Any]:
        folder_name(dotted(p, "id"), self.id)
        choice(dotted(p, "kind"), self.kind, ("learned", "rule"))
        if self.kind == "learned":
            choice(dotted(p, "critic_input"), self.critic_input, ("observation", "state"))
        else:
            choice(dotted(p, "controller"), self.controller, ("olfati_saber", "vasarhelyi"))
        return {}


@dataclass
class ExperimentConfig(Schema):
    """How long and how fast to train; its learner settings over the paper's Table I (``conf/algo``):
    ``conf/tuning/<algo>_<experiment>.yaml``, where it has one."""

    prefix: ClassVar[str] = "experiment"

    name: str = MISSING
    num_envs: int = MISSING                  # envs stepped together in one batched FlockingEnv
    workers: int = MISSING                   # >1: MultiSyncCollector over that many processes
    steps_per_batch: int = MISSING           # env steps per env between updates (off-policy)
    updates_per_batch: int = MISSING         # gradient steps per collected batch (off-policy)
    init_random_frames: int = MISSING        # env frames of uniform random actions first
    max_episodes: int = MISSING              # budgets: 0 = no limit; at least one is set
    max_frames: int = MISSING
    max_minutes: float = MISSING
    log_every_frames: int = MISSING          # scalar logs at most this often (0: every collector batch)
    eval_every_frames: int = MISSING
    eval_episodes: int = MISSING
    checkpoint_every_frames: int = MISSING
    keep_buffer_in_checkpoint: bool = MISSING
    # Scenario fields changed for the *training* env only (a training recipe such as ending
    # an episode at UAV contact); evaluation runs the scenario as composed.
    train_env: Dict[str, Any] = field(default_factory=dict)
    # Several swarm sizes trained at once, one shared policy (docs/specification.md section 7,
    # a decision beyond the paper): the training worlds are split evenly between the sizes and
    # the replay buffer holds single UAV transitions. Empty: the scenario's n_uavs only.
    swarm_sizes: List[int] = field(default_factory=list)
    # Several kinds of training world at once (beyond the paper): each entry the scenario fields of one
    # kind over train_env (e.g. wall3d's wall among train3d's worlds); the worlds are split evenly
    # between every swarm size and every kind. Empty: the training scenario alone.
    train_mix: List[Dict[str, Any]] = field(default_factory=list)

    def checked_fields(self, p: str) -> dict[str, Any]:
        folder_name(dotted(p, "name"), self.name)
        count(dotted(p, "num_envs"), self.num_envs, 1, 10**7)
        count(dotted(p, "workers"), self.workers, 1, 1024)
        count(dotted(p, "steps_per_batch"), self.steps_per_batch, 1, 10**6)
        count(dotted(p, "eval_episodes"), self.eval_episodes, 1, 10**6)
        for name in ("updates_per_batch", "init_random_frames", "max_episodes", "max_frames", "log_every_frames",
                     "eval_every_frames", "checkpoint_every_frames"):
            count(dotted(p, name), getattr(self, name), 0, 10**13)
        non_negative(dotted(p, "max_minutes"), self.max_minutes)
        if not (self.max_episodes or self.max_frames or self.max_minutes):
            reject(p, "set at least one budget: max_episodes, max_frames or max_minutes")
        unknown = sorted(set(self.train_env) - SCENARIO_FIELDS)
        if unknown:
            reject(dotted(p, "train_env"), f"unknown scenario field(s) {unknown}")
        if self.workers > 1 and self.num_envs % self.workers:
            reject(dotted(p, "workers"), f"{self.workers} must divide num_envs={self.num_envs}")
        if self.swarm_sizes:
            key = dotted(p, "swarm_sizes")
            for i, n in enumerate(self.swarm_sizes):
                count(f"{key}[{i}]", n, 1, MAX_UAVS)  # the bound of scenario.n_uavs
            if len(set(self.swarm_sizes)) != len(self.swarm_sizes):
                reject(key, f"sizes repeat: {list(self.swarm_sizes)}")
            if self.num_envs % len(self.swarm_sizes):
                reject(key, f"{len(self.swarm_sizes)} sizes must divide num_envs={self.num_envs} (worlds per size)")
            if self.workers > 1:
                reject(key, "trains in one process: set workers=1")
            if "n_uavs" in self.train_env:
                reject(key, "and train_env.n_uavs both set the training swarm size; keep one")
        if self.train_mix:
            key = dotted(p, "train_mix")
            for i, kind in enumerate(self.train_mix):
                if not isinstance(kind, Mapping):
                    reject(f"{key}[{i}]", f"must be a mapping of scenario fields, got {kind!r}")
                unknown = sorted(set(kind) - SCENARIO_FIELDS)
                if unknown:
                    reject(f"{key}[{i}]", f"unknown scenario field(s) {unknown}")
                if "n_uavs" in kind:
                    reject(f"{key}[{i}]", "sets n_uavs: the swarm sizes are experiment.swarm_sizes")
            envs = len(self.swarm_sizes or [0]) * len(self.train_mix)
            if self.num_envs % envs:
                reject(key, f"{envs} kinds of world (swarm sizes x kinds) must divide num_envs={self.num_envs}")
            if self.workers > 1:
                reject(key, "trains in one process: set workers=1")
        return {}


@dataclass
class LoggerConfig(Schema):
    prefix: ClassVar[str] = "logger"

    backend: str = MISSING                   # csv | wandb | tensorboard | none
    project: str = MISSING
    mode: str = MISSING                      # wandb: offline | online

    def checked_fields(self, p: str) -> dict[str, Any]:
        choice(dotted(p, "backend"), self.backend, ("csv", "wandb", "tensorboard", "none"))
        choice(dotted(p, "mode"), self.mode, ("offline", "online"))
        extra = {"tensorboard": "tensorboard", "wandb": "wandb"}.get(self.backend)
        if extra and importlib.util.find_spec(extra) is None:
            reject(dotted(p, "backend"), f"{self.backend} is not installed: pip install 'flock_torchrl[{extra}]'")
        return {}


__all__ = ["ExperimentConfig", "LoggerConfig", "PolicyConfig"]
