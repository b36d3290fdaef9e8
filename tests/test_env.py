"""FlockingEnv as a TorchRL env: specs, shapes, spawn (Eq. 30), S5, termination, partial reset, seeding."""

import dataclasses
import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from helpers import BAD_SCENARIO_VALUES

from flock_torchrl import FlockingEnv
from flock_torchrl.world.geometry import distance_to_obstacles, Obstacles

PI = math.pi
SCENARIOS = ["train", "s1", "s2", "s3", "s4", "s5", "tau_v"]


def zero_policy(td):
    """Deterministic policy: a = [0, 0] (speed 2 along the heading) for every UAV."""
    shape = td["agents", "observation"].shape[:-1]
    td.set(("agents", "action"), torch.zeros(*shape, 2))
    return td


@pytest.mark.parametrize("num_envs", [1, 3])
@pytest.mark.parametrize("scenario", SCENARIOS)
def test_check_env_specs(scenario, num_envs):
    torch.manual_seed(0)
    check_env_specs(FlockingEnv(scenario, num_envs=num_envs, seed=0, extras="all"))


@pytest.mark.parametrize("overrides", [dict(instinct=True), dict(instinct=True, noise=True, tangential=False),
                                       dict(fov=2 * PI), dict(action_mode="velocity"),
                                       dict(collision_reward_source="min_uav_scan")])
def test_check_env_specs_policy_variants(overrides):
    torch.manual_seed(0)
    check_env_specs(FlockingEnv("train", num_envs=2, seed=0, extras="all", **overrides))


@pytest.mark.parametrize("scenario, n", [("train", 5), ("s2", 9), ("s5", 5)])
def test_rollout_shapes_and_keys(scenario, n):
    b, t = 2, 4
    torch.manual_seed(0)
    env = FlockingEnv(scenario, num_envs=b, seed=0, extras="all")
    td = env.rollout(t)
    assert td.batch_size == (b, t)
    assert td["agents", "observation"].shape == (b, t, n, 17)
    assert td["agents", "state"].shape == (b, t, n, 20)
    assert td["agents", "action"].shape == (b, t, n, 2)
    assert td["next", "agents", "reward"].shape == (b, t, n, 1)
    assert td["next", "done"].shape == (b, t, 1)
    assert td["next", "terminated"].shape == td["next", "truncated"].shape == (b, t, 1)
    nxt = td["next"]
    assert nxt["agents", "position"].shape == nxt["agents", "velocity"].shape == (b, t, n, 2)
    assert nxt["agents", "heading"].shape == (b, t, n)
    assert nxt["agents", "command"].shape == (b, t, n, 2)
    assert nxt["agents", "instinct"].shape == (b, t, n) and nxt["agents", "instinct"].dtype == torch.bool
    assert nxt["agents", "scan"].shape == (b, t, n, 36)
    assert nxt["goal"].shape == (b, t, 2)
    for key in ("success", "safe_success", "d_min_obs", "d_min_uav", "d_c", "v_error", "phi_error", "speed",
                "t_goal", "steps"):
        assert nxt["episode", key].shape == (b, t), key
    assert nxt["episode", "steps"][0].tolist() == [1, 2, 3, 4]
    if scenario == "s5":
        assert nxt["obstacles", "position"].shape == (b, t, 2, 2)
    else:
        assert "obstacles" not in nxt.keys()
    # Every observation and state value lies in [-1, 1].
    assert td["agents", "observation"].abs().max() <= 1 and td["agents", "state"].abs().max() <= 1


def test_spawn_follows_eq30(make_env):
    env = make_env("train", num_envs=64, seed=1)
    centre = torch.tensor([40.0, 40.0])
    # Goal at chi + pi: goal - (40, 40) = -(swarm centre - (40, 40)), both d_env = 40 from the middle.
    goal_dir = env.world["goal"] - centre
    assert torch.allclose(torch.linalg.vector_norm(goal_dir, dim=-1), torch.full((64,), 40.0), atol=1e-4)
    swarm = centre - goal_dir                                     # [B, 2]
    offset = torch.linalg.vector_norm(env.world["position"] - swarm[:, None], dim=-1)
    assert (offset <= 3.0 + 1e-4).all()                           # inside the 3 m disc
    d = torch.linalg.vector_norm(env.world["position"][:, :, None] - env.world["position"][:, None], dim=-1)
    d = d + torch.eye(5) * 100
    assert (d >= 1.0).all()                                       # >= 1 m apart
    obstacles = env.obstacles()
    assert (distance_to_obstacles(env.world["position"], obstacles).amin(-1) >= 1.0).all()  # >= 1 m from obstacles
    assert torch.equal(env.world["velocity"], torch.zeros_like(env.world["velocity"]))
    assert (env.world["heading"] >= -PI).all() and (env.world["heading"] < PI).all()
    # chi is uniform: the goals do not all fall on one side.
    assert (goal_dir[:, 0] > 0).any() and (goal_dir[:, 0] < 0).any()
    # S3 uses d_env = 60.
    s3 = make_env("s3", num_envs=8, seed=1)
    assert torch.allclose(torch.linalg.vector_norm(s3.world["goal"] - centre, dim=-1), torch.full((8,), 60.0), atol=1e-4)


def test_s5_moving_circles(make_env, place, step_with):
    env = make_env("s5", num_envs=16, seed=2)
    start = env.world["moving_position"].clone()
    assert start.shape == (16, 2, 2)
    assert ((start >= 10) & (start <= 70)).all()                # starts in [10, 70]^2
    static = Obstacles(torch.tensor(env.cfg.circles).expand(16, -1, -1), torch.tensor(env.cfg.rectangles).expand(16, -1, -1))
    assert (distance_to_obstacles(start, static).amin(-1) >= 3.0).all()    # radius 3, clear of static ones
    gap = torch.linalg.vector_norm(start[:, :, None] - env.world["position"][:, None], dim=-1).amin(-1)
    assert (gap >= 8.0).all()                                     # >= 8 m from the swarm
    assert (torch.linalg.vector_norm(start - env.world["goal"][:, None], dim=-1) >= 8.0).all()  # ... and the goal
    speed = torch.linalg.vector_norm(env.world["moving_velocity"], dim=-1)
    assert torch.allclose(speed, torch.full_like(speed, 0.5))
    td = env.current()
    td["agents", "action"] = torch.zeros(16, 5, 2)
    out = env.step(td)["next"]
    # 0.5 m/s for 0.2 s: 0.1 m per step (no reflection that close to the start box).
    moved = torch.linalg.vector_norm(out["obstacles", "position"] - start, dim=-1)
    assert torch.allclose(moved, torch.full_like(moved, 0.1), atol=1e-5)
    # The laser sees the moving circles: one at (20, 20), r 3, UAV at (10, 20) facing +x -> 20 - 3 - 10 = 7.
    env = make_env("s5", num_envs=1, seed=2)
    env.place([[[10.0, 20.0], [10.0, 5.0], [5.0, 5.0], [5.0, 10.0], [2.0, 2.0]]], [[0.0] * 5], [[70.0, 70.0]],
              moving_position=[[[20.0, 20.0], [60.0, 70.0]]])
    assert env.world["sensed"]["scan"][0, 0, 0].item() == pytest.approx(7.0, abs=1e-5)
    assert env.world["sensed"]["scan_obstacle"][0, 0, 0].item() == 1   # static circle 0, then the moving ones


def test_s5_circles_reflect_off_the_box(make_env):
    env = make_env("s5", num_envs=1, seed=0)
    env.world["moving_position"] = torch.tensor([[[79.95, 40.0], [40.0, 0.02]]])
    env.world["moving_velocity"] = torch.tensor([[[0.5, 0.0], [0.0, -0.5]]])
    td = env.current()
    td["agents", "action"] = torch.zeros(1, 5, 2)
    env.step(td)
    # 79.95 + 0.1 = 80.05 -> 2 * 80 - 80.05 = 79.95, vx -> -0.5; 0.02 - 0.1 = -0.08 -> 0.08, vy -> 0.5.
    assert env.world["moving_position"][0].tolist() == [pytest.approx([79.95, 40.0], abs=1e-4),
                                               pytest.approx([40.0, 0.08], abs=1e-5)]
    assert env.world["moving_velocity"][0].tolist() == [[-0.5, 0.0], [0.0, 0.5]]


# ---------------------------------------------------------------- termination
def test_goal_reached_terminates(make_env, place, step_with):
    # UAV 0 at (10, 10) facing +x, goal (11, 10): after a = [0, 0] it is at 10.08, d_g = 0.92 < 1.
    env = place(make_env("s1", n_uavs=2), [[[10.0, 10.0], [10.0, 20.0]]], [[0.0, 0.0]], [[11.0, 10.0]])
    out = step_with(env, [[[0.0, 0.0], [0.0, 0.0]]])
    assert out["terminated"].tolist() == [[True]] and out["done"].tolist() == [[True]]
    assert out["truncated"].tolist() == [[False]]
    ep = out["episode"]
    assert ep["reached"].tolist() == [True] and ep["success"].tolist() == [True]
    assert ep["t_goal"].item() == pytest.approx(0.2)   # first step: 1 * dt
    # 1.1 m away after the step (goal (11.18, 10)): not reached.
    env = place(make_env("s1", n_uavs=2), [[[10.0, 10.0], [10.0, 20.0]]], [[0.0, 0.0]], [[11.18, 10.0]])
    assert step_with(env, [[[0.0, 0.0], [0.0, 0.0]]])["done"].tolist() == [[False]]


def test_crash_uses_true_distance_not_the_laser(make_env, place, step_with):
    # A tiny circle (r 0.01) 0.46 m from the UAV at bearing 5 deg, between two beams: every beam misses
    # it (closest approach 0.46 sin 5 deg = 0.040 > 0.01), yet the true distance 0.46 - 0.01 = 0.45 < 0.5.
    # Velocity mode with a zero command: nothing moves.
    c = [10.0 + 0.46 * math.cos(PI / 36), 10.0 + 0.46 * math.sin(PI / 36)]
    env = make_env("s1", n_uavs=1, circles=[[c[0], c[1], 0.01]], action_mode="velocity")
    place(env, [[[10.0, 10.0]]], [[0.0]], [[70.0, 70.0]])
    assert torch.equal(env.world["sensed"]["scan"], torch.full((1, 1, 36), 10.0))
    out = step_with(env, [[[0.0, 0.0]]])
    assert out["terminated"].tolist() == [[True]]
    assert out["episode", "crashed"].tolist() == [True] and out["episode", "success"].tolist() == [False]
    assert out["episode", "d_min_obs"].item() == pytest.approx(0.45, abs=1e-5)


def test_crash_threshold_in_the_training_world(make_env, place, step_with):
    # Circle (40, 40) r 6, surface at x = 34. Facing +x from 33.5: 33.58 -> 0.42 < 0.5: crash.
    env = place(make_env("train", n_uavs=1), [[[33.5, 40.0]]], [[0.0]], [[40.0, 80.0]])
    assert step_with(env, [[[0.0, 0.0]]])["terminated"].tolist() == [[True]]
    # Facing -x from 33.5: 33.42 -> 0.58 >= 0.5: no crash.
    env = place(make_env("train", n_uavs=1), [[[33.5, 40.0]]], [[PI]], [[40.0, 80.0]])
    assert step_with(env, [[[0.0, 0.0]]])["terminated"].tolist() == [[False]]


def test_truncation_at_max_steps(make_env):
    env = FlockingEnv("s1", num_envs=2, seed=0, max_steps=3)
    td = env.rollout(3, policy=zero_policy)
    assert td["next", "truncated"][:, :, 0].tolist() == [[False, False, True]] * 2
    assert td["next", "terminated"][:, :, 0].tolist() == [[False, False, False]] * 2
    assert td["next", "done"][:, :, 0].tolist() == [[False, False, True]] * 2


def test_uav_contact_terminates_only_when_configured(make_env, place, step_with):
    # Two UAVs 0.3 m apart, velocity mode, zero command: they stay 0.3 < 0.5 apart.
    layout = ([[[10.0, 10.0], [10.3, 10.0]]], [[0.0, 0.0]], [[70.0, 70.0]])
    env = place(make_env("s1", n_uavs=2, action_mode="velocity"), *layout)
    out = step_with(env, [[[0.0, 0.0], [0.0, 0.0]]])
    assert out["done"].tolist() == [[False]]
    assert out["episode", "d_min_uav"].item() == pytest.approx(0.3, abs=1e-5)
    env = place(make_env("s1", n_uavs=2, action_mode="velocity", uav_collision_terminates=True), *layout)
    out = step_with(env, [[[0.0, 0.0], [0.0, 0.0]]])
    assert out["terminated"].tolist() == [[True]] and out["done"].tolist() == [[True]]


def test_done_is_per_env(make_env, place, step_with):
    # B = 2: only env 0 has its goal within reach.
    env = make_env("s1", num_envs=2, n_uavs=1)
    place(env, [[[10.0, 10.0]], [[10.0, 10.0]]], [[0.0], [0.0]], [[11.0, 10.0], [60.0, 10.0]])
    out = step_with(env, [[[0.0, 0.0]], [[0.0, 0.0]]])
    assert out["done"].tolist() == [[True], [False]]


# ---------------------------------------------------------------- resets
def test_partial_reset_only_changes_masked_envs(make_env):
    env = make_env("train", num_envs=3, seed=4)
    td = env.current()
    td["agents", "action"] = torch.zeros(3, 5, 2)
    env.step(td)
    before = env.current()
    # TorchRL's contract: a partial reset receives the current data (as rollout passes it) plus the mask.
    td_in = before.clone()
    td_in["_reset"] = torch.tensor([[True], [False], [True]])
    out = env.reset(td_in)
    # Env 1 is untouched: physical state, goal, views and its running episode.
    for key in (("agents", "position"), ("agents", "velocity"), ("agents", "heading"), ("agents", "observation"),
                ("agents", "state"), "goal", ("episode", "steps"), ("episode", "d_c")):
        assert torch.equal(out[key][1], before[key][1]), key
    assert out["episode", "steps"].tolist() == [0, 1, 0]
    # Envs 0 and 2 start afresh: new positions and goals, velocity 0.
    for i in (0, 2):
        assert not torch.equal(out["agents", "position"][i], before["agents", "position"][i])
        assert not torch.equal(out["goal"][i], before["goal"][i])
        assert torch.equal(out["agents", "velocity"][i], torch.zeros(5, 2))
    # The env's own state agrees with what reset returned.
    assert torch.equal(env.world["position"], out["agents", "position"])
    # An all-False mask changes nothing.
    position = env.world["position"].clone()
    env.reset(TensorDict({"_reset": torch.zeros(3, 1, dtype=torch.bool)}, batch_size=[3]))
    assert torch.equal(env.world["position"], position)


def test_rollout_continues_across_episode_ends():
    env = FlockingEnv("s1", num_envs=2, seed=0, max_steps=2, extras="all")
    td = env.rollout(5, policy=zero_policy, break_when_any_done=False)
    assert td.batch_size == (2, 5)
    # Episodes of 2 steps: truncated at steps 2 and 4, then a fresh episode.
    assert td["next", "done"][:, :, 0].tolist() == [[False, True, False, True, False]] * 2
    assert td["next", "episode", "steps"].tolist() == [[1, 2, 1, 2, 1]] * 2
    # After each end the env was reset: the next step starts from a new spawn with zero velocity.
    assert td["episode", "steps"].tolist() == [[0, 1, 0, 1, 0]] * 2
    assert torch.equal(td["agents", "velocity"][:, 2], torch.zeros(2, 5, 2))
    assert not torch.equal(td["agents", "position"][:, 2], td["next", "agents", "position"][:, 1])


# ---------------------------------------------------------------- seeding
def _positions(env, steps=4):
    return env.rollout(steps, policy=zero_policy, break_when_any_done=False)


@pytest.mark.parametrize("scenario", ["train", "s4", "s5"])
def test_same_seed_same_rollout(scenario):
    a = _positions(FlockingEnv(scenario, num_envs=2, seed=11, extras="all"))
    b = _positions(FlockingEnv(scenario, num_envs=2, seed=11, extras="all"))
    for key in (("next", "agents", "position"), ("next", "agents", "observation"), ("next", "agents", "reward"),
                ("next", "goal")):
        assert torch.equal(a[key], b[key]), key
    c = _positions(FlockingEnv(scenario, num_envs=2, seed=12, extras="all"))
    assert not torch.equal(a["next", "agents", "position"], c["next", "agents", "position"])


def test_set_seed_restarts_the_stream():
    env = FlockingEnv("s4", num_envs=2, seed=0, extras="all")
    env.set_seed(11)
    a = _positions(env)
    b = _positions(FlockingEnv("s4", num_envs=2, seed=11, extras="all"))
    assert torch.equal(a["next", "agents", "observation"], b["next", "agents", "observation"])
    # With random actions, seeding torch as well reproduces the whole rollout.
    torch.manual_seed(5)
    r1 = FlockingEnv("train", num_envs=2, seed=3).rollout(3)
    torch.manual_seed(5)
    r2 = FlockingEnv("train", num_envs=2, seed=3).rollout(3)
    assert torch.equal(r1["next", "agents", "reward"], r2["next", "agents", "reward"])


def test_torchrl_multi_agent_conventions():
    # TorchRL's multi-agent scripts read env.group_map and call env.render(mode=...).
    env = FlockingEnv("s2", num_envs=2, seed=0)
    assert env.group_map == {"agents": [f"agent_{i}" for i in range(9)]}
    assert list(env.full_action_spec.keys(True, True)) == [("agents", "action")]
    assert env.full_done_spec["done"].shape == (2, 1)
    env.reset()
    assert env.render(mode="rgb_array", size=64).shape == (64, 64, 3)


def test_extras_are_opt_in():
    env = FlockingEnv("s5", num_envs=2, seed=0)
    keys = set(env.reset().keys(True, True))
    assert ("agents", "position") not in keys and ("agents", "scan") not in keys and "goal" not in keys
    full = set(FlockingEnv("s5", num_envs=2, seed=0, extras="all").reset().keys(True, True))
    assert {("agents", "position"), ("agents", "scan"), ("agents", "command"), "goal", ("obstacles", "position")} <= full
    with pytest.raises(ValueError, match="extras"):
        FlockingEnv("train", extras=("lidar",))


# ---------------------------------------------------------------- state declaration and sizes
def test_world_state_follows_its_declaration(make_env):
    from flock_torchrl.world.sensors import observation_size, state_size
    from flock_torchrl.world.state import WORLD_STATE

    env = make_env("s5", num_envs=3)  # 5 UAVs, 2 moving circles
    assert (env.obs_dim, env.state_dim) == (observation_size(env.cfg), state_size(env.cfg)) == (17, 20)
    wider = dataclasses.replace(env.cfg, n_scan=2, n_cam=4)
    assert (observation_size(wider), state_size(wider)) == (2 + 2 * 2 + 3 * 4, 2 + 2 * 2 + 3 * 4 + 3)
    expected = {"position": (3, 5, 2), "velocity": (3, 5, 2), "heading": (3, 5), "climb": (3, 0), "goal": (3, 2),
                "moving_position": (3, 2, 2), "moving_velocity": (3, 2, 2), "drawn_circles": (3, 0, 3),
                "drawn_rectangles": (3, 0, 4), "drawn_spheres": (3, 0, 4), "command": (3, 5, 2),
                "instinct": (3, 5), "prev_action": (3, 5, 2), "has_prev_action": (3,), "terminated": (3, 1),
                "truncated": (3, 1)}
    assert list(WORLD_STATE) == list(expected)
    td = env.current()
    td["agents", "action"] = torch.zeros(3, 5, 2)
    env.step(td)
    for key, field in WORLD_STATE.items():
        assert env.world[key].shape == expected[key] and env.world[key].dtype == field.dtype, key


# ---------------------------------------------------------------- misuse of the env API
def test_check_actions_false_skips_only_the_host_checks():
    nan = torch.full((2, 5, 2), math.nan)
    env = FlockingEnv("train", num_envs=2, seed=0)
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(env.reset().set(("agents", "action"), nan))
    lax = FlockingEnv("train", num_envs=2, seed=0, check_actions=False, extras="physics")
    out = lax.step(lax.reset().set(("agents", "action"), nan))["next"]  # not refused: NaN flows into the world
    assert out["agents", "position"].isnan().all()
    # A done world is stepped too (max_steps = 1: done after one step).
    lax = FlockingEnv("train", num_envs=2, seed=0, check_actions=False, max_steps=1)
    td = lax.step(lax.reset().set(("agents", "action"), torch.zeros(2, 5, 2)))["next"]
    assert td["done"].all()
    lax.step(td.set(("agents", "action"), torch.zeros(2, 5, 2)))
    # Shape and dtype are still checked (no synchronisation needed for those).
    with pytest.raises(ValueError, match="expected \\[2, 5, 2\\]"):
        lax.step(lax.reset().set(("agents", "action"), torch.zeros(2, 5, 3)))
    assert lax.subset([1]).check_actions is False


def test_subset_takes_indices_or_a_boolean_mask(make_env):
    env = make_env("train", num_envs=4, seed=3)
    small = env.subset(torch.tensor([True, False, True, False]))
    assert small.num_envs == 2
    assert torch.equal(small.world["position"], env.world["position"][[0, 2]])
    assert torch.equal(env.subset([3, 1]).world["goal"], env.world["goal"][[3, 1]])
    with pytest.raises(ValueError, match="one flag per world"):
        env.subset(torch.tensor([True, False]))
    with pytest.raises(ValueError, match="dtype torch.float32"):
        env.subset(torch.tensor([0.0, 2.0]))
    with pytest.raises(ValueError, match="out of range"):
        env.subset([4])
    with pytest.raises(ValueError, match="no world selected"):
        env.subset(torch.zeros(4, dtype=torch.bool))


def test_stepping_before_reset_is_refused():
    env = FlockingEnv("train", num_envs=2, seed=0)
    td = TensorDict({"agents": TensorDict({"action": torch.zeros(2, 5, 2)}, batch_size=[2, 5])}, batch_size=[2])
    with pytest.raises(ValueError, match=r"call reset\(\) first"):
        env.step(td)


def test_reset_mask_must_be_boolean(make_env):
    env = make_env("train", num_envs=2)
    with pytest.raises(ValueError, match=r"_reset.*torch\.bool.*got torch\.float32"):
        env.reset(TensorDict({"_reset": torch.ones(2, 1)}, batch_size=[2]))
    with pytest.raises(ValueError, match=r"_reset.*shape \[2, 2\]"):
        env.reset(TensorDict({"_reset": torch.ones(2, 2, dtype=torch.bool)}, batch_size=[2]))


def test_set_state_refuses_other_dtypes_and_shapes(make_env):
    env = make_env("train", num_envs=2)
    state = env.get_state()
    state["world"]["position"] = state["world"]["position"].double()
    with pytest.raises(ValueError, match=r"'position' has dtype torch\.float64, expected torch\.float32"):
        env.set_state(state)
    state = env.get_state()
    state["world"]["sensed"]["observation"] = state["world"]["sensed"]["observation"].double()
    with pytest.raises(ValueError, match=r"observation.*dtype torch\.float64, expected torch\.float32"):
        env.set_state(state)
    state = env.get_state()
    state["world"]["heading"] = state["world"]["heading"][:, :3]
    with pytest.raises(ValueError, match=r"'heading' has shape \[2, 3\], expected \[2, 5\]"):
        env.set_state(state)
    env.set_state(env.get_state())  # the env's own state passes


@pytest.mark.parametrize("argument", ["position", "heading", "goal", "velocity"])
def test_place_refuses_nan(make_env, argument):
    env = make_env("train", num_envs=1, n_uavs=2)
    layout = {"position": [[[10.0, 10.0], [12.0, 10.0]]], "heading": [[0.0, 0.0]], "goal": [[70.0, 70.0]],
              "velocity": [[[0.0, 0.0], [0.0, 0.0]]]}
    bad = torch.tensor(layout[argument]).flatten()
    bad[0] = math.nan
    layout[argument] = bad.reshape(torch.tensor(layout[argument]).shape)
    with pytest.raises(ValueError, match=f"place: {argument} contains NaN"):
        env.place(**layout)


def test_a_baseline_on_an_env_without_its_extras_names_them():
    from flock_torchrl import make_policy

    env = FlockingEnv("s1", num_envs=2, seed=0, policy_id="policy_ma")
    with pytest.raises(ValueError, match=r"Policy-MA reads the env's extra keys \('physics', 'laser'\)"):
        make_policy("policy_ma", env)
    ok = FlockingEnv("s1", num_envs=2, seed=0, policy_id="policy_ma", extras=("physics", "laser"))
    assert make_policy("policy_ma", ok)(ok.reset())["agents", "action"].shape == (2, 5, 2)


# ---------------------------------------------------------------- bad input at construction and step
@pytest.mark.parametrize("overrides, field", BAD_SCENARIO_VALUES,
                         ids=[f"{f}-{i}" for i, (_, f) in enumerate(BAD_SCENARIO_VALUES)])
def test_bad_values_are_refused_at_construction_naming_the_field(overrides, field):
    # ConfigError is a ValueError; n_uavs=60 in a 3 m disc is the spawn's refusal, made by every env.
    with pytest.raises(ValueError, match=field):
        FlockingEnv("train", **overrides)


def test_unknown_scenario_and_unknown_field_are_refused():
    with pytest.raises(ValueError, match="nowhere"):
        FlockingEnv("nowhere")
    with pytest.raises(ValueError, match="wind_speed"):
        FlockingEnv("train", wind_speed=3.0)


def test_bad_num_envs():
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="num_envs"):
            FlockingEnv("train", num_envs=bad)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_actions_raise_at_step(make_env, bad):
    env = make_env("train", num_envs=2)
    td = env.reset()
    action = torch.zeros(2, 5, 2)
    action[1, 3, 0] = bad
    td["agents", "action"] = action
    with pytest.raises(ValueError, match="action"):
        env.step(td)


# ---------------------------------------------------------------------------- misuse
@pytest.fixture
def short_env():
    env = FlockingEnv("train", num_envs=2, seed=0, max_steps=2)
    env.reset()
    return env


def test_env_names_a_wrong_action(short_env):
    env = short_env
    td = env.current()
    with pytest.raises(ValueError, match=r"\('agents', 'action'\) has shape \[2, 5, 3\], expected \[2, 5, 2\]"):
        env.step(td.set(("agents", "action"), torch.zeros(2, 5, 3)))
    td = env.current()
    with pytest.raises(ValueError, match=r"no \('agents', 'action'\) entry"):
        env.step(td)
    with pytest.raises(ValueError, match="dtype torch.int64, expected a floating point"):
        env.step(env.current().set(("agents", "action"), torch.zeros(2, 5, 2, dtype=torch.int64)))
    # float64 is cast: the env's state and outputs stay float32.
    out = env.step(env.current().set(("agents", "action"), torch.zeros(2, 5, 2, dtype=torch.float64)))["next"]
    assert out["agents", "observation"].dtype == torch.float32 and env.world["position"].dtype == torch.float32


def test_env_refuses_to_step_a_done_world(short_env):
    env = short_env
    td = env.current().set(("agents", "action"), torch.zeros(2, 5, 2))
    td = env.step(td)["next"]
    td = env.step(td.set(("agents", "action"), torch.zeros(2, 5, 2)))["next"]
    assert td["done"].all()  # max_steps = 2
    with pytest.raises(ValueError, match=r"world\(s\) 0, 1 are done; reset them first"):
        env.step(td.set(("agents", "action"), torch.zeros(2, 5, 2)))
    # TorchRL's way continues: step_and_maybe_reset resets the done worlds.
    td = env.rand_action(env.reset())
    for _ in range(5):
        _, td = env.step_and_maybe_reset(env.rand_action(td))


def test_copies_of_the_env_share_the_default_seed_until_a_batched_env_seeds_them_apart():
    """Every FlockingEnv defaults to seed 0 (a run is reproducible without asking), so TorchRL's
    batched envs built from one constructor hold identical copies; their ``set_seed`` gives each
    copy its own stream (TorchRL seeds copy k from the seed copy k - 1 returned)."""
    import functools

    from torchrl.envs import SerialEnv

    env = SerialEnv(2, functools.partial(FlockingEnv, "train", num_envs=2))
    obs = env.reset()["agents", "observation"]
    assert torch.equal(obs[0], obs[1])
    env.set_seed(7)
    obs = env.reset()["agents", "observation"]
    assert not torch.equal(obs[0], obs[1])
    env.close()


@pytest.mark.parametrize("scenario", ["s1", "s5", "forest"])
def test_set_state_refuses_a_non_finite_state_and_takes_a_finite_one(scenario):
    env = FlockingEnv(scenario, num_envs=2, seed=0)
    env.rollout(3, break_when_any_done=False)
    state = env.get_state()
    env.set_state(state)  # a real state round-trips
    bad = {"world": {**state["world"]}, "generator": state["generator"]}
    bad["world"]["position"] = state["world"]["position"].clone()
    bad["world"]["position"][1, 0, 0] = float("nan")
    with pytest.raises(ValueError, match=r"^env state: 'position' contains NaN or inf"):
        env.set_state(bad)
    assert torch.equal(env.world["position"], state["world"]["position"])  # unchanged


@pytest.mark.parametrize("seed", [-1, 2**64, 1.5, float("nan"), "3", True])
def test_bad_seeds_are_refused_naming_seed(seed):
    with pytest.raises(ValueError, match=r"^seed must be None or an integer in \[0, 2\*\*64 - 1\], got"):
        FlockingEnv("s1", num_envs=1, seed=seed)
    env = FlockingEnv("s1", num_envs=1, seed=2**64 - 1)  # the largest one works
    with pytest.raises(ValueError, match=r"^seed must be"):
        env.set_seed(seed)


def test_cuda_without_cuda_is_one_line_naming_device():
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(ValueError, match=r"^device 'cuda': this machine has no CUDA device") as info:
        FlockingEnv("s1", num_envs=1, device="cuda")
    assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match=r"^device 'gpu0' is not a torch device"):
        FlockingEnv("s1", num_envs=1, device="gpu0")
