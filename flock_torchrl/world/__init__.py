"""The world: geometry, kinematics, sensors, the instinct, reward, spawn, metrics and the
batched TorchRL env that owns their state (docs/specification.md sections 1-6, 9)."""

from .env import EXTRAS, FlockingEnv
from .metrics import CELL_METRICS, METRIC_KEYS, METRICS, RATE_METRICS
from .forest import SpawnError

__all__ = ["CELL_METRICS", "EXTRAS", "FlockingEnv", "METRICS", "METRIC_KEYS", "RATE_METRICS", "SpawnError"]
