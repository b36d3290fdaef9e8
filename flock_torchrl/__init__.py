"""flock_torchrl: multi-UAV flocking (Bai et al. 2024) as a TorchRL multi-agent pipeline.

    from flock_torchrl import FlockingEnv, make_policy, make_train_config, train, evaluate, load_policy

The package reads from the bottom up: ``config`` (the schemas and the one composer),
``world/`` (the simulator and its TorchRL env), ``policies/`` (networks, learners,
baselines, checkpoints, the registry), ``run/`` (training, evaluation), ``report/``
(tables, figures); each layer imports only those below it.
"""

from typing import Any

from .config import ConfigError, ScenarioConfig, TrainConfig, app_config, compose, eval_seed, scenario_config
from .policies import CheckpointError, PolicyHandle, load_policy, make_policy, resolve
from .run import EvaluationResult, TrainingInterrupted, evaluate, make_train_config, rollout_episode, train
from .world import FlockingEnv, SpawnError


def __getattr__(name: str) -> Any:
    """``EVAL_SEED``: the evaluation seed of conf/world.yaml, read when first asked for."""
    if name == "EVAL_SEED":
        return eval_seed()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "CheckpointError", "ConfigError", "EVAL_SEED", "EvaluationResult", "FlockingEnv", "PolicyHandle", "ScenarioConfig",
    "SpawnError", "TrainConfig", "TrainingInterrupted", "app_config", "compose", "evaluate", "load_policy", "make_policy",
    "make_train_config", "resolve", "rollout_episode", "scenario_config", "train",
]
__version__ = "0.2.0"
