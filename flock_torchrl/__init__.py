"""flock_torchrl: multi-UAV flocking (Bai et al. 2024) as a TorchRL multi-agent pipeline.

    from flock_torchrl import FlockingEnv, make_policy, train, evaluate, load_policy
"""

from .checkpoint import CheckpointError, load_policy
from .config import ConfigError, ScenarioConfig, available_scenarios, load_scenario
from .env import FlockingEnv
from .evaluation import EVAL_SEED, EvaluationResult, evaluate
from .policies import make_env_overrides, make_policy
from .trainer import make_train_config, train

__all__ = [
    "CheckpointError", "ConfigError", "EVAL_SEED", "EvaluationResult", "FlockingEnv", "ScenarioConfig", "available_scenarios", "evaluate",
    "load_policy", "load_scenario", "make_env_overrides", "make_policy", "make_train_config", "train",
]
__version__ = "0.1.0"
