"""Configuration: the schema of every Hydra group and app, and the one composer.

Every value lives once, in the YAML files under ``conf/``; the dataclasses give each group and
each app its fields and types (fields are ``MISSING``: a YAML that forgets one fails when it is
composed) and checks for what a type cannot say (ranges, choices, consistency), raising
:class:`ConfigError` naming the dotted key, e.g. ``scenario.n_uavs: must be an integer >= 1, got 0``.

* :mod:`.checks`: :class:`ConfigError`, the range helpers and :class:`Schema`, whose
  :meth:`~Schema.check` returns a checked copy and :meth:`~Schema.from_config` converts Hydra's
  composed ``DictConfig`` into a checked object once;
* :mod:`.scenario`: the world's :class:`ScenarioConfig` (plain dataclass, no Hydra; the only
  configuration ``flock_torchrl.world`` imports);
* :mod:`.learners`: the typed SAC, DDPG and PPO configs; :mod:`.groups`: policy, experiment, logger;
* :mod:`.apps`: every app's schema, the run options they share checked once (:class:`RunOptions`);
* :mod:`.names`, :mod:`.paths`: folder names made from values, where ``conf/`` is;
* :mod:`.compose`: the only module that touches Hydra (the composer, the schemas' registration,
  the resolvers), called explicitly: importing this package composes, registers and reads nothing.
"""

from typing import Any

from .apps import (APP_SCHEMAS, COMPARED, COMPILE_MODES, MAX_POPULATION, OBJECTIVES, RESUME_MODES, EpisodeOptions,
                   EvaluateConfig, FiguresConfig, ReproduceConfig, RunOptions, ScalingConfig, ShipConfig, TrainConfig,
                   TuneConfig, WorldApp, check_contender, check_tolerance, training_scenario)
from .checks import (MAX_SEED, MAX_UAVS, ConfigError, Schema, check_device, check_seed, check_threads, config_error,
                     safe_name)
from .compose import (app_config, compose, compose_world, default_checkpoints_dir, eval_seed, flatten, plain, register,
                      saved_scenario, scenario_config, scenario_overrides)
from .groups import ExperimentConfig, LoggerConfig, PolicyConfig
from .learners import ALGO_SCHEMAS, DDPGConfig, LearnerConfig, PPOConfig, SACConfig, algo_config
from .names import config_folder, contender_name, evaluated_name, is_file_target, run_name, selection_dir
from .paths import CONF_DIR, available, config_dir, shipped_checkpoints_dir
from .scenario import POLICY_SCENARIO_FIELDS, READINGS, SCENARIO_FIELDS, ScenarioConfig


def __getattr__(name: str) -> Any:
    """``EVAL_SEED``: conf/world.yaml's evaluation seed, read when first asked for (:func:`eval_seed`)."""
    if name == "EVAL_SEED":
        return eval_seed()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "ALGO_SCHEMAS", "APP_SCHEMAS", "COMPARED", "COMPILE_MODES", "CONF_DIR", "ConfigError", "DDPGConfig", "EVAL_SEED",
    "EpisodeOptions", "EvaluateConfig", "ExperimentConfig", "FiguresConfig", "LearnerConfig", "LoggerConfig",
    "MAX_POPULATION", "MAX_SEED", "MAX_UAVS", "OBJECTIVES", "POLICY_SCENARIO_FIELDS", "PPOConfig", "PolicyConfig",
    "READINGS", "RESUME_MODES", "ReproduceConfig", "RunOptions", "SACConfig", "SCENARIO_FIELDS", "ScalingConfig",
    "ScenarioConfig", "Schema", "ShipConfig", "TrainConfig", "TuneConfig", "WorldApp", "algo_config", "app_config",
    "available", "check_contender", "check_device", "check_seed", "check_threads", "check_tolerance", "compose",
    "compose_world", "config_dir", "config_error", "config_folder", "contender_name", "default_checkpoints_dir",
    "eval_seed", "evaluated_name", "flatten", "is_file_target", "plain", "register", "run_name", "safe_name",
    "saved_scenario", "scenario_config", "scenario_overrides", "selection_dir", "shipped_checkpoints_dir",
    "training_scenario",
]
