"""Running things: training (collector, buffer, learner, checkpoints) and the evaluation protocol."""

from .evaluation import EVAL_SEED, EvaluationResult, evaluate, rollout_episode
from .trainer import TrainingInterrupted, TrainResult, make_train_config, train

__all__ = ["EVAL_SEED", "EvaluationResult", "TrainResult", "TrainingInterrupted", "evaluate", "make_train_config",
           "rollout_episode", "train"]
