"""Running policies: training (:mod:`.trainer`), the evaluation protocol (:mod:`.rollout`) and its
results (:mod:`.results`), shipping checkpoints (:mod:`.shipping`)."""

from .results import EvaluationResult
from .rollout import EVAL_SEED, evaluate, evaluate_handle, rollout_episode
from .launch import train
from .trainer import TrainResult, TrainingInterrupted, make_train_config

__all__ = ["EVAL_SEED", "EvaluationResult", "TrainResult", "TrainingInterrupted", "evaluate", "evaluate_handle",
           "make_train_config", "rollout_episode", "train"]
