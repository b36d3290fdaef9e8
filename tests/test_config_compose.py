"""One composition: every app's, policy's, experiment's and learner's YAML against its schema,
what --cfg job prints is what runs, bad names and values fail at config time naming the key
(the scenario schema and the readings: tests/test_config_scenario.py)."""

import dataclasses
import math

import pytest
from omegaconf import OmegaConf

from flock_torchrl import FlockingEnv
from flock_torchrl.config import (ALGO_SCHEMAS, EVAL_SEED, POLICY_SCENARIO_FIELDS, ConfigError, ExperimentConfig,
                                  TrainConfig, algo_config, available, compose, scenario_config)
from flock_torchrl.run.setup import make_train_config


def check_train_config(cfg):
    return TrainConfig.from_config(cfg)

ALL_POLICIES = ["policy1", "policy1_g", "policy2", "policy2_g", "policy3", "policy3_g", "policy4_g", "policy5_g",
                "policyd_g", "policyp_g", "policy_ma", "policy_op"]
LEARNED = ALL_POLICIES[:10]


def test_every_policy_has_a_yaml_whose_id_is_its_name_and_that_sets_only_policy_fields():
    # A checkpoint records POLICY_SCENARIO_FIELDS: a policy YAML may set nothing else of the world.
    assert set(ALL_POLICIES) <= set(available("policy"))
    base = compose("world", []).scenario
    for policy in ALL_POLICIES:
        cfg = compose("world", [f"policy={policy}"])
        assert cfg.policy.id == policy
        changed = {k for k in base if base[k] != cfg.scenario[k]}
        assert changed <= set(POLICY_SCENARIO_FIELDS), (policy, changed)


EXPERIMENTS = ["paper", "fast", "mixed", "demo", "tiny"]
# Every pair in make test-all; make test composes each policy once and each experiment twice.
PAIRS = [pytest.param(policy, experiment, id=f"{experiment}-{policy}",
                      marks=() if i % len(EXPERIMENTS) == EXPERIMENTS.index(experiment) else pytest.mark.slow)
         for experiment in EXPERIMENTS for i, policy in enumerate(LEARNED)]


@pytest.mark.parametrize("policy, experiment", PAIRS)
def test_every_learned_policy_and_experiment_compose_and_check(policy, experiment):
    if experiment == "mixed" and policy == "policyp_g":  # several swarm sizes: off-policy learners only
        with pytest.raises(ConfigError, match="experiment.swarm_sizes: needs an off-policy learner"):
            check_train_config(make_train_config(policy, experiment))
        return
    rc = check_train_config(make_train_config(policy, experiment))
    assert rc.policy.id == policy and rc.experiment.name == experiment


def test_policy_table_matches_the_specification():
    """docs/specification.md section 7, column by column."""
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
    for policy, (fov, instinct, tangential, critic, algo, source) in expected.items():
        rc = check_train_config(make_train_config(policy, "fast"))
        s = rc.scenario
        assert math.isclose(s.fov, fov * math.pi), policy
        assert s.instinct is instinct and s.tangential is tangential, policy
        assert s.collision_reward_source == source, policy
        assert rc.policy.critic_input == critic and rc.algo.name == algo, policy
    for policy in ("policy_ma", "policy_op"):
        cfg = compose("world", [f"policy={policy}"])
        assert cfg.policy.kind == "rule" and cfg.scenario.action_mode == "velocity" and not cfg.scenario.instinct
        assert math.isclose(cfg.scenario.fov, 0.5 * math.pi)


# Each experiment (so each tuning file) composes with every learner in the fast tier's
# test_each_experiment_file_lists_the_learner_settings_it_changes, each scenario's env is built in
# test_env.py, test_threed.py and test_forest.py: here those groups in the full tier.
@pytest.mark.parametrize("group", ["algo", "logger", "reading", *(pytest.param(g, marks=pytest.mark.slow)
                                                                  for g in ("experiment", "scenario", "tuning"))])
def test_every_group_yaml_composes(group):
    names = available(group)
    assert names
    for name in names:
        if group == "tuning":
            algo, _, experiment = name.partition("_")
            policy = {"sac": "policy3_g", "ddpg": "policyd_g", "ppo": "policyp_g"}[algo]
            algo_config(make_train_config(policy, experiment).algo)
        elif group in ("scenario", "reading"):
            scenario_config(name if group == "scenario" else "train", reading=name if group == "reading" else None)
        else:
            cfg = compose("train", [f"{group}={name}"])
            if group == "algo":
                algo_config(cfg.algo)
            elif group == "experiment":
                ExperimentConfig.from_config(cfg.experiment)


def test_experiments_tune_the_learner_through_composition():
    fast = check_train_config(make_train_config("policy3_g", "fast"))
    paper = check_train_config(make_train_config("policy3_g", "paper"))
    assert (paper.algo.batch_size, paper.algo.lr_actor) == (128, 5e-5)  # Table I
    assert (fast.algo.batch_size, fast.algo.lr_actor) == (1280, 3e-4)
    # demo, mixed and mixed_cluttered are deltas of fast, and learn like it.
    for name in ("demo", "mixed", "mixed_cluttered"):
        delta = check_train_config(make_train_config("policy3_g", name))
        assert dataclasses.asdict(delta.algo) == dataclasses.asdict(fast.algo), name
    cluttered = check_train_config(make_train_config("policy3_g", "mixed_cluttered"))
    assert cluttered.train_scenario.random_circles == 9 and cluttered.scenario.random_circles == 0
    # The user's override wins over the experiment's tuning.
    assert check_train_config(make_train_config("policy3_g", "fast", ["algo.lr_actor=0.123"])).algo.lr_actor == 0.123


def test_what_is_shown_is_what_runs():
    """The composed config (what --cfg job prints and config.yaml saves) holds the values the run
    uses: the experiment's batch size, the policy's instinct, the tiny network."""
    cfg = make_train_config("policy3_g", "fast")
    assert cfg.algo.batch_size == 1280 and cfg.scenario.instinct is True
    tiny = make_train_config("policy3_g", "tiny")
    assert tiny.algo.hidden == 32
    env = FlockingEnv.from_config(tiny.scenario)
    assert env.cfg.instinct is True and env.cfg.fov == pytest.approx(0.5 * math.pi)


def test_evaluation_seed_is_one_number():
    # One YAML place (conf/world.yaml); every app reads it from there.
    assert compose("train").eval_seed == EVAL_SEED
    for app in ("evaluate", "reproduce", "figures", "scaling"):
        assert compose(app).seed == EVAL_SEED, app
    hits = [p.name for p in __import__("flock_torchrl.config", fromlist=["CONF_DIR"]).CONF_DIR.rglob("*.yaml")
            if str(EVAL_SEED) in p.read_text()]
    assert hits == ["world.yaml"]


@pytest.mark.parametrize("override, key", [
    ("policy=nope", "policy"),
    ("logger=nope", "logger"),
    ("experiment=nope", "experiment"),
    ("reading=nope", "reading"),
    ("scenario.n_uavs=abc", "scenario.n_uavs"),
    ("algo.lr_critc=1", "algo.lr_critc"),
])
def test_unknown_names_and_wrong_types_fail_at_composition(override, key):
    with pytest.raises(ConfigError) as info:
        compose("train", [override])
    assert info.value.key == key


@pytest.mark.parametrize("override, key", [
    ("algo.gamma=1.5", "algo.gamma"),
    ("algo.batch_size=0", "algo.batch_size"),
    ("algo.lr_actor=-1", "algo.lr_actor"),
    ("experiment.num_envs=0", "experiment.num_envs"),
    ("logger.backend=nope", "logger.backend"),
    ("policy.critic_input=nope", "policy.critic_input"),
    ("scenario.fov=7.0", "scenario.fov"),
    ("scenario.n_uavs=0", "scenario.n_uavs"),
    ("seed=-1", "seed"),
    ("device=gpu0", "device"),
    ("compile=steps", "compile"),
    ("+algo.lr_critc=1", "algo.lr_critc"),
])
def test_bad_values_name_the_key(override, key):
    with pytest.raises(ConfigError) as info:
        check_train_config(make_train_config("policy3_g", "tiny", [override]))
    assert info.value.key == key


@pytest.mark.parametrize("value, step, loss", [("false", False, False), ("true", True, True), ("step", True, False),
                                               ("loss", False, True)])
def test_compile_picks_the_step_the_loss_both_or_neither(value, step, loss):
    cfg = check_train_config(make_train_config("policy3_g", "tiny", [f"compile={value}"]))
    assert (cfg.compile_step, cfg.compile_loss) == (step, loss)


def test_cuda_on_a_machine_without_it_is_a_config_error():
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(ConfigError, match="no CUDA device"):
        check_train_config(make_train_config("policy3_g", "tiny", ["device=cuda"]))


def test_rule_based_policy_is_not_trainable():
    with pytest.raises(ConfigError, match="rule-based") as info:
        check_train_config(make_train_config("policy_ma", "tiny"))
    assert info.value.key == "policy"
    cfg = OmegaConf.create(OmegaConf.to_container(make_train_config("policy3_g", "tiny")))
    cfg.policy = OmegaConf.to_container(compose("world", ["policy=policy_ma"]).policy)
    with pytest.raises(ConfigError, match="rule-based"):
        check_train_config(cfg)


def test_reading_is_one_choice_in_every_app():
    for app in ("train", "evaluate", "reproduce", "figures", "scaling", "tune_baselines", "ship"):
        assert compose(app, ["reading=paper_fit"]).scenario.reading == "paper_fit", app
    assert compose("world").scenario.reading in ("literal", "paper_fit")


def test_algo_schemas_cover_every_algo_yaml():
    assert set(available("algo")) == set(ALGO_SCHEMAS)


@pytest.mark.parametrize("every", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_every_train_composition_keeps_the_values_main_composed(every):
    """conf/train.yaml for every policy x experiment x reading composes exactly the values it
    composed before configuration became a package and the learner settings moved into the
    experiment files (tests/data/composed_train_configs.json, written from main by
    tests/data/make_composed_reference.py before the change), but the fields added since."""
    import json
    from pathlib import Path

    from flock_torchrl.config import shipped_checkpoints_dir

    reference = json.loads((Path(__file__).parent / "data" / "composed_train_configs.json").read_text())
    nodes, compositions = reference["nodes"], reference["compositions"]
    assert len(compositions) == 12 * 5 * 2
    shipped = str(shipped_checkpoints_dir())
    for name, entry in compositions.items():
        policy, experiment, reading = name.split("/")
        if not every and (experiment, reading) != ("fast", "paper_fit"):  # make test: the shipped recipe's
            continue
        cfg = compose("train", [f"policy={policy}", f"experiment={experiment}", f"reading={reading}"])
        tree = json.loads(json.dumps(OmegaConf.to_container(cfg, resolve=True)).replace(shipped, "<checkpoints>"))
        # Added since: the instinct's crowd mode, r_f's range, r_c's shape and the actor's camera,
        # the paper's for each of the twelve.
        assert tree["scenario"].pop("instinct_mode") == "paper", name
        assert tree["scenario"].pop("cohesion_range") == "paper", name
        assert tree["scenario"].pop("collision_shape") == "paper", name
        assert tree["scenario"].pop("actor_camera") == "paper", name
        # ... and the third dimension (docs/specification.md section 11): the plane, Eq. 30's full circle.
        assert tree["scenario"].pop("dims") == 2, name
        assert tree["scenario"].pop("chi_range") == [-math.pi, math.pi], name
        for key in ("climb_max", "altitude", "laser_rings", "spawn_altitude", "spawn_height", "goal_altitude",
                    "spheres", "random_heights", "random_spheres", "random_sphere_altitude", "laser_vertical",
                    "tangential_taper"):
            tree["scenario"].pop(key)
        # and the captured update's switch, off, which a resume may change
        assert tree.pop("cudagraphs") is False, name
        tree["resumable"].remove("cudagraphs")
        # and compile, which a resume no longer changes, true by default in the paper recipe
        assert "compile" not in tree["resumable"], name
        tree["resumable"].insert(tree["resumable"].index("device") + 1, "compile")
        assert tree["compile"] is (experiment == "paper"), name
        tree["compile"] = False
        # and the reserve of fresh worlds, off
        assert tree.pop("reset_pool") == 0, name
        # and the kinds of training world, none but the scenario's
        assert tree["experiment"].pop("train_mix") == [], name
        assert set(tree) == set(entry), name
        for key, digest in entry.items():
            assert tree[key] == nodes[digest], f"{name}: {key}"


def test_app_config_composes_an_apps_config_from_names_and_values_and_checks_it():
    from pathlib import Path

    from flock_torchrl.config import ReproduceConfig, RunOptions, app_config

    cfg = app_config("reproduce", table=4, reading="literal", episodes=7, only=["Policy-MA"],
                     checkpoints_dir=Path("/tmp/none"))
    assert isinstance(cfg, ReproduceConfig) and cfg.is_checked
    assert (cfg.table, cfg.scenario.reading, cfg.episodes, cfg.only) == (4, "literal", 7, ["Policy-MA"])
    assert cfg.seed == EVAL_SEED and cfg.paper_recipe_dir == "/tmp/none/literal/paper_recipe"  # interpolations follow
    with pytest.raises(ConfigError) as info:
        app_config("reproduce", table=6)
    assert info.value.key == "table"
    # The run options every app shares are checked in one place (RunOptions), under the same keys.
    for app in ("train", "evaluate", "reproduce", "figures", "scaling", "tune_baselines"):
        assert issubclass(type(app_config(app)), RunOptions), app
        for key, bad in (("seed", -1), ("device", "gpu0"), ("threads", -2)):
            with pytest.raises(ConfigError) as info:
                app_config(app, **{key: bad})
            assert info.value.key == key, (app, key)


def test_each_experiment_file_lists_the_learner_settings_it_changes():
    """An experiment file's header names, per learner, exactly the settings its
    tuning file changes from conf/algo/<algo>.yaml (Table I), with the values a run takes."""
    import re
    from pathlib import Path

    from flock_torchrl.config import CONF_DIR

    policy_of = {"sac": "policy3_g", "ddpg": "policyd_g", "ppo": "policyp_g"}
    assert set(policy_of) == set(available("algo"))
    table_one = {a: OmegaConf.to_container(compose("train", [f"policy={p}", "experiment=paper"]).algo, resolve=True)
                 for a, p in policy_of.items()}
    for experiment in available("experiment"):
        header = (Path(CONF_DIR) / "experiment" / f"{experiment}.yaml").read_text()
        for algo, policy in policy_of.items():
            line = re.search(rf"^#   {algo}: (.*)$", header, re.M)
            assert line, f"conf/experiment/{experiment}.yaml does not list {algo}'s settings"
            listed = {} if line.group(1) == "none" else dict(kv.split("=") for kv in line.group(1).split())
            runs = OmegaConf.to_container(compose("train", [f"policy={policy}", f"experiment={experiment}"]).algo,
                                          resolve=True)
            changed = {k: v for k, v in runs.items() if table_one[algo].get(k) != v}
            assert set(listed) == set(changed), f"{experiment}/{algo}: lists {sorted(listed)}, changes {sorted(changed)}"
            for key, value in listed.items():
                assert float(value) == pytest.approx(float(changed[key])), f"{experiment}/{algo}: {key}"
