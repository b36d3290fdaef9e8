"""flock_torchrl: multi-UAV flocking (Bai et al. 2024) as a TorchRL multi-agent pipeline."""

from .config import ConfigError, ScenarioConfig, available_scenarios, load_scenario
from .env import FlockingEnv

__all__ = ["ConfigError", "FlockingEnv", "ScenarioConfig", "available_scenarios", "load_scenario"]
__version__ = "0.1.0"
