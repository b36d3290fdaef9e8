"""Running policies: training (:mod:`.trainer`), the evaluation protocol (:mod:`.rollout`) and its
results (:mod:`.results`), shipping checkpoints (:mod:`.shipping`)."""

import contextlib
import functools
import logging
import os
from typing import Any, Iterator

from ..config import eval_seed
from . import launch
from .results import EvaluationResult
from .rollout import evaluate, evaluate_handle, rollout_episode
from .setup import make_train_config
from .signals import TrainingInterrupted
from .parts import TrainResult


@contextlib.contextmanager
def quiet_torchrl() -> Iterator[None]:
    """TorchRL's own INFO lines (ANSI-coloured, e.g. its storages' "Initialized ...") held back
    while ours run, as the apps do; a user's ``RL_LOGGING_LEVEL`` is left as they set it."""
    log = logging.getLogger("torchrl")
    level = log.level
    if "RL_LOGGING_LEVEL" not in os.environ:
        log.setLevel(max(level, logging.WARNING))
    try:
        yield
    finally:
        log.setLevel(level)


@functools.wraps(launch.train)
def train(*args: Any, **kwargs: Any) -> TrainResult:
    with quiet_torchrl():
        return launch.train(*args, **kwargs)


def __getattr__(name: str) -> Any:
    """``EVAL_SEED``: the evaluation seed of conf/world.yaml, read when first asked for."""
    if name == "EVAL_SEED":
        return eval_seed()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["EVAL_SEED", "EvaluationResult", "TrainResult", "TrainingInterrupted", "evaluate", "evaluate_handle",
           "make_train_config", "quiet_torchrl", "rollout_episode", "train"]
