"""Every YAML composes against its dataclass; bad names and values fail at config time."""

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from flock_torchrl.config import CONF_DIR, ConfigError, load_scenario
from flock_torchrl.schema import (ALGO_SCHEMAS, available, load_group, validate_algo, validate_experiment,
                                  validate_logger, validate_policy)
from flock_torchrl.trainer import make_train_config, resolve_config

ALL_POLICIES = ["policy1", "policy1_g", "policy2", "policy2_g", "policy3", "policy3_g", "policy4_g", "policy5_g",
                "policyd_g", "policyp_g", "policy_ma", "policy_op"]
LEARNED = ALL_POLICIES[:10]


def compose_train(*overrides):
    """Compose conf/train.yaml as scripts/train.py would, minus Hydra's runtime resolvers."""
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        cfg = compose(config_name="train", overrides=list(overrides), return_hydra_config=True)
    OmegaConf.set_struct(cfg, False)
    cfg.cli_overrides = list(cfg.hydra.overrides.task)
    cfg.policy_id = cfg.hydra.runtime.choices.policy
    del cfg["hydra"]
    return cfg


@pytest.mark.parametrize("policy", ALL_POLICIES)
def test_every_policy_composes(policy):
    if policy not in available("policy"):
        pytest.fail(f"conf/policy/{policy}.yaml is missing")
    cfg = compose_train(f"policy={policy}", "run_dir=/tmp/unused")
    validated = validate_policy(cfg.policy)
    load_scenario(OmegaConf.to_container(cfg.scenario, resolve=True), **validated.env)
    if validated.kind == "learned":
        assert validate_algo(cfg.algo).name in ALGO_SCHEMAS
        resolve_config(cfg)


def test_policy_table_matches_spec():
    """SPEC section 7, column by column."""
    expected = {  # fov/pi, instinct, tangential, critic, algo, reward source
        "policy1": (2.0, False, True, "observation", "sac", "scan"),
        "policy1_g": (2.0, False, True, "state", "sac", "scan"),
        "policy2": (0.5, False, True, "observation", "sac", "scan"),
        "policy2_g": (0.5, False, True, "state", "sac", "scan"),
        "policy3": (0.5, True, True, "observation", "sac", "scan"),
        "policy3_g": (0.5, True, True, "state", "sac", "scan"),
        "policy4_g": (0.5, False, True, "state", "sac", "min_uav_scan"),
        "policy5_g": (0.5, True, False, "state", "sac", "scan"),
        "policyd_g": (0.5, True, True, "state", "ddpg", "scan"),
        "policyp_g": (0.5, True, True, "state", "ppo", "scan"),
    }
    import math

    for policy, (fov, instinct, tangential, critic, algo, source) in expected.items():
        cfg = compose_train(f"policy={policy}", "run_dir=/tmp/unused")
        env = cfg.policy.env
        assert math.isclose(env.fov, fov * math.pi), policy
        assert env.instinct is instinct and env.tangential is tangential, policy
        assert env.collision_reward_source == source, policy
        assert cfg.policy.critic_input == critic and cfg.algo.name == algo, policy


@pytest.mark.parametrize("group", ["algo", "experiment", "logger", "scenario"])
def test_every_group_yaml_matches_its_dataclass(group):
    validators = {"algo": validate_algo, "experiment": validate_experiment, "logger": validate_logger,
                  "scenario": lambda node: load_scenario(OmegaConf.to_container(node, resolve=True))}
    names = available(group)
    assert names
    for name in names:
        node = load_group(group, name) if group != "scenario" else OmegaConf.create(
            OmegaConf.to_container(OmegaConf.structured(load_scenario(name)), resolve=True))
        validators[group](node)


def test_experiment_algo_overrides_are_valid():
    for name in available("experiment"):
        exp = validate_experiment(load_group("experiment", name))
        for algo, patch in exp.algo_overrides.items():
            validate_algo(OmegaConf.merge(load_group("algo", algo), patch))


@pytest.mark.parametrize("override, field", [
    ("policy=nope", "policy"),
    ("logger=nope", "logger"),
    ("experiment=nope", "experiment"),
])
def test_unknown_group_choice_is_refused_by_hydra(override, field):
    with pytest.raises(Exception, match=field):
        compose_train(override)


@pytest.mark.parametrize("key, value, field", [
    ("algo.gamma", 1.5, "gamma"),
    ("algo.batch_size", 0, "batch_size"),
    ("experiment.num_envs", 0, "num_envs"),
    ("logger.backend", "nope", "backend"),
    ("policy.critic_input", "nope", "critic_input"),
    ("scenario.fov", 7.0, "fov"),
    ("scenario.n_uavs", 0, "n_uavs"),
])
def test_bad_values_name_the_field(key, value, field):
    cfg = make_train_config("policy3_g", "tiny", run_dir="/tmp/unused", overrides={key: value})
    with pytest.raises(ConfigError, match=field):
        resolve_config(cfg)


def test_user_algo_override_beats_the_experiment():
    cfg = make_train_config("policy3_g", "tiny", run_dir="/tmp/unused", overrides={"algo.batch_size": 77})
    assert resolve_config(cfg).algo.batch_size == 77  # tiny's algo_overrides say 40
    composed = compose_train("experiment=fast", "algo.lr_actor=0.123", "run_dir=/tmp/unused")
    assert resolve_config(composed).algo.lr_actor == 0.123  # fast's algo_overrides say 3e-4


def test_unknown_key_is_refused():
    cfg = make_train_config("policy3_g", "tiny", run_dir="/tmp/unused")
    OmegaConf.update(cfg, "algo.lr_critc", 1e-3, force_add=True)
    with pytest.raises(ConfigError, match="lr_critc"):
        resolve_config(cfg)


def test_rule_based_policy_is_not_trainable():
    cfg = compose_train("policy=policy_ma", "run_dir=/tmp/unused")
    with pytest.raises(ConfigError, match="rule-based"):
        resolve_config(cfg)
