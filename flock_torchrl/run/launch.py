"""``train(cfg)``: the one entry point of training, a solo run or a population."""

from __future__ import annotations

import os
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from ..config import TrainConfig
from .run_folder import RunLock, clean_stale_temporaries
from .setup import hydra_output_dir, prepare
from .trainer import Training
from .parts import TrainResult


def train(cfg: TrainConfig | DictConfig | dict, run_dir: str | os.PathLike | None = None) -> TrainResult:
    """Train one learned policy (``population=1``) or a population of seeds (``population=K``).

    Args:
        cfg: a checked :class:`TrainConfig`, or the composed ``conf/train.yaml`` (Hydra's, or
            :func:`~flock_torchrl.run.setup.make_train_config`'s), converted and checked here.
        run_dir: the run folder; default: Hydra's output folder (``scripts/train.py``).

    Raises:
        ConfigError: a bad config value (nothing is written).
        CheckpointError: a refused resume or a busy / mismatched run folder (nothing changes).
        TrainingInterrupted: a signal stopped the run after it wrote its checkpoint.
    """
    if not isinstance(cfg, TrainConfig):
        cfg = TrainConfig.from_config(OmegaConf.create(cfg) if isinstance(cfg, dict) else cfg)
    run_dir = Path(run_dir) if run_dir is not None else hydra_output_dir()
    prepare(cfg, run_dir)
    with RunLock(run_dir):
        clean_stale_temporaries(run_dir)
        return Training(cfg, run_dir).run()


__all__ = ["train"]
