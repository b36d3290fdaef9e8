"""Scenario configs: every YAML composes against ScenarioConfig, the readings, bad values fail at
construction naming the field (the env's own refusals: tests/test_env.py)."""

import dataclasses
import math

import pytest
from helpers import BAD_SCENARIO_VALUES as BAD
from omegaconf import OmegaConf

from flock_torchrl import ConfigError, ScenarioConfig
from flock_torchrl.config import CONF_DIR, SCENARIO_FIELDS, available, scenario_config


def load_scenario(scenario="train", **fields):
    return scenario_config(scenario, reading=None if not isinstance(scenario, str) else "literal", **fields)

SCENARIOS = ["train", "s1", "s2", "s3", "s4", "s5", "tau_v"]


def test_all_scenarios_are_available():
    assert set(SCENARIOS) <= set(available("scenario"))


@pytest.mark.parametrize("reading", ["literal", "paper_fit"])
def test_train_yaml_and_a_reading_set_every_field_once(reading):
    # The training YAML spells out the world, a reading its own fields: together every field of
    # the dataclass, none twice, none extra.
    world = set(OmegaConf.load(CONF_DIR / "scenario" / "train.yaml").keys()) - {"defaults"}
    own = set(OmegaConf.load(CONF_DIR / "reading" / f"{reading}.yaml").keys())
    assert not world & own
    assert world | own == SCENARIO_FIELDS


@pytest.mark.parametrize("name", SCENARIOS)
def test_each_yaml_composes_against_the_dataclass(name):
    cfg = load_scenario(name)
    assert isinstance(cfg, ScenarioConfig) and cfg.name == name
    own = OmegaConf.load(CONF_DIR / "scenario" / f"{name}.yaml")
    assert set(own.keys()) - {"defaults"} <= SCENARIO_FIELDS


def test_training_defaults_match_spec():
    cfg = load_scenario("train")
    # specification section 1 table and obstacle decision.
    assert (cfg.n_uavs, cfg.dt, cfg.max_steps, cfg.tau_v, cfg.v_max) == (5, 0.2, 500, 1.0, 3.0)
    assert (cfg.goal_radius, cfg.collision_distance) == (1.0, 0.5)
    assert (cfg.camera_range, cfg.n_beams, cfg.laser_range, cfg.goal_scale) == (5.0, 36, 10.0, 80.0)
    assert cfg.fov == pytest.approx(0.5 * math.pi)
    assert (cfg.rep_gain, cfg.rep_range, cfg.safe_distance) == (1.0, 5.0, 2.0)
    assert cfg.circles == [[40.0, 40.0, 6.0]]
    assert cfg.rectangles == [[10.0, 40.0, 6.0, 16.0], [70.0, 40.0, 6.0, 16.0]]
    assert (cfg.d_env, cfg.spawn_radius, cfg.uav_collision_terminates) == (40.0, 3.0, False)
    assert (cfg.spawn_separation, cfg.spawn_clearance, cfg.reading, cfg.fov_convention) == (1.0, 1.0, "literal", "total")


def test_scenario_table():
    # specification section 6.
    assert load_scenario("s1").circles == [] and load_scenario("s1").rectangles == []
    assert load_scenario("s2").n_uavs == 9
    s3 = load_scenario("s3")
    assert s3.d_env == 60.0
    assert sorted(map(tuple, s3.circles)) == sorted([(40.0, 40.0, 6.0), (15.0, 15.0, 5.0), (15.0, 65.0, 5.0),
                                                     (65.0, 15.0, 5.0), (65.0, 65.0, 5.0)])
    assert sorted(map(tuple, s3.rectangles)) == sorted([(10.0, 40.0, 6.0, 16.0), (70.0, 40.0, 6.0, 16.0),
                                                        (40.0, 10.0, 16.0, 6.0), (40.0, 70.0, 16.0, 6.0)])
    s4 = load_scenario("s4")
    assert s4.noise and (s4.noise_scan, s4.noise_distance, s4.noise_angle) == (0.1, 0.2, 0.05)
    s5 = load_scenario("s5")
    assert (s5.n_moving, s5.moving_radius, s5.moving_speed) == (2, 3.0, 0.5)
    assert load_scenario("tau_v", tau_v=0.2).tau_v == 0.2


def test_overrides_and_other_sources():
    cfg = load_scenario("train", fov=2 * math.pi, instinct=True, n_uavs=9)
    assert (cfg.fov, cfg.instinct, cfg.n_uavs) == (2 * math.pi, True, 9)
    full = dataclasses.asdict(load_scenario("train"))
    assert load_scenario({**full, "n_uavs": 3}).n_uavs == 3
    assert load_scenario(OmegaConf.create({**full, "dt": 0.1})).dt == 0.1
    assert load_scenario(ScenarioConfig(**{**full, "n_uavs": 4})).n_uavs == 4
    assert load_scenario("S2").n_uavs == 9  # case-insensitive names
    with pytest.raises(ConfigError, match="missing"):  # a mapping must be complete
        load_scenario({"n_uavs": 3})


# ---------------------------------------------------------------- bad inputs


@pytest.mark.parametrize("overrides, field", BAD, ids=[f"{f}-{i}" for i, (_, f) in enumerate(BAD)])
def test_bad_values_raise_naming_the_field(overrides, field):
    # FlockingEnv refuses them too (tests/test_env.py); spawn feasibility (n_uavs) is the world's check.
    if field != "n_uavs":
        with pytest.raises(ConfigError, match=field):
            load_scenario("train", **overrides)


def test_circles_that_just_touch_are_allowed():
    # Centres 12 m apart with radii 6 + 6 = 12: touching, not overlapping.
    assert len(load_scenario("train", circles=[[40.0, 40.0, 6.0], [52.0, 40.0, 6.0]]).circles) == 2


def test_unknown_scenario_and_unknown_field():
    with pytest.raises(ConfigError, match="Could not find 'scenario/nowhere'"):
        load_scenario("nowhere")
    with pytest.raises(ConfigError, match="wind_speed"):
        load_scenario("train", wind_speed=3.0)
    with pytest.raises(ConfigError, match="wind_speed"):
        load_scenario({**dataclasses.asdict(load_scenario("train")), "wind_speed": 3.0})


def test_wrong_type_names_the_field():
    with pytest.raises(ConfigError, match="n_uavs"):
        load_scenario("train", n_uavs="five")


def test_readings_set_the_field_of_view_convention_and_the_spawn():
    literal = scenario_config("train", reading="literal", policy="policy3_g")
    fit = scenario_config("train", reading="paper_fit", policy="policy3_g")
    assert (literal.half_fov, fit.half_fov) == (pytest.approx(math.pi / 4), pytest.approx(math.pi / 2))
    assert (literal.spawn_separation, fit.spawn_separation) == (1.0, 2.0)  # paper_fit: d_safe
    # Spawn radius: literal 3 m up to N = 9, then 3 sqrt(N / 9); paper_fit 3 sqrt(N / 5).
    for n, lit, pf in [(5, 3.0, 3.0), (9, 3.0, 3 * math.sqrt(9 / 5)), (20, 3 * math.sqrt(20 / 9), 6.0),
                       (3, 3.0, 3 * math.sqrt(3 / 5))]:
        assert scenario_config("train", reading="literal", n_uavs=n).swarm_spawn_radius == pytest.approx(lit)
        assert scenario_config("train", reading="paper_fit", n_uavs=n).swarm_spawn_radius == pytest.approx(pf)
    # Full field of view stays unlimited under both.
    assert scenario_config("train", reading="paper_fit", policy="policy1").half_fov >= math.pi


def test_check_returns_a_checked_copy_and_leaves_the_object_as_it_was():
    """``check()`` never rewrites the object it is called on: the obstacle lists come back as
    floats on the copy, which remembers it is checked (so FlockingEnv takes it as it is)."""
    fields = dataclasses.asdict(scenario_config("train", reading="literal"))
    raw = ScenarioConfig(**{**fields, "circles": [[40, 40, 6]], "rectangles": []})
    checked = raw.check()
    assert checked is not raw and checked.is_checked and not raw.is_checked
    assert raw.circles == [[40, 40, 6]] and isinstance(raw.circles[0][0], int)
    assert checked.circles == [[40.0, 40.0, 6.0]] and all(isinstance(v, float) for v in checked.circles[0])
    assert checked.check() is checked                   # checked once
    assert not dataclasses.replace(checked, n_uavs=3).is_checked   # a changed copy is checked again
    with pytest.raises(ConfigError, match=r"^scenario\.n_uavs:"):
        dataclasses.replace(checked, n_uavs=0).check()
    from flock_torchrl import FlockingEnv

    assert FlockingEnv(checked, num_envs=1).cfg is checked
    with pytest.raises(TypeError, match="scenario_config"):
        FlockingEnv(fields, num_envs=1)                 # a mapping goes through scenario_config(mapping)


@pytest.mark.parametrize("fields", [dict(tangential=2), dict(instinct=1), dict(noise="yes")])
def test_booleans_are_booleans(fields):
    """OmegaConf takes 2, 1 or "yes" for true; a boolean field refuses them, by every door."""
    (name, value), = fields.items()
    with pytest.raises(ConfigError, match=rf"^scenario\.{name}: must be true or false, got {value!r}"):
        scenario_config("train", **fields)
    raw = ScenarioConfig(**{**dataclasses.asdict(scenario_config("train")), **fields})
    with pytest.raises(ConfigError, match=rf"^scenario\.{name}: must be true or false"):
        raw.check()


def test_boolean_overrides_are_booleans():
    from flock_torchrl.config import compose

    with pytest.raises(ConfigError, match=r"^scenario\.tangential: must be true or false, got 2$"):
        compose("train", ["scenario.tangential=2"])
    with pytest.raises(ConfigError, match=r"^progress: must be true or false, got on$"):
        compose("train", ["progress=on"])
    assert compose("train", ["scenario.tangential=false", "progress=True"]).scenario.tangential is False


def test_an_instinct_mode_without_the_instinct_is_refused_naming_both_keys():
    with pytest.raises(ConfigError, match=r"^scenario\.instinct_mode: 'saturated' .*scenario\.instinct=false") as err:
        scenario_config("train", instinct=False, instinct_mode="saturated")
    assert err.value.also == ("scenario.instinct",)
    assert scenario_config("train", instinct=True, instinct_mode="saturated").instinct_mode == "saturated"
    assert scenario_config("train", instinct=False, instinct_mode="paper").instinct is False
