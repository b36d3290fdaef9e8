"""reward.py and the env's reward: Eq. 21-25 in raw units, Policy4-G's r_c (specification section 4)."""

import math

import pytest
import torch

from flock_torchrl.world.reward import (
    cohesion_range, collision_reward, flocking_reward, goal_reward, smoothness_reward, total_reward,
)

PI = math.pi
F64 = torch.float64


def t(x):
    return torch.tensor(x, dtype=F64)


# ---------------------------------------------------------------- r_g (Eq. 22)
def test_goal_reward_inside_and_outside():
    d_prev = t([1.3, 1.3, 10.0, 10.0, 5.0])
    d = t([0.99, 1.0, 9.5, 10.0, 5.2])
    alpha = t([2.0, 0.0, 0.5, -PI, 0.0])
    out = goal_reward(d, d_prev, alpha, 1.0).tolist()
    # 0.99 < 1: 20 (whatever the bearing).
    assert out[0] == 20.0
    # d = 1.0 is not < 1: shaping 0.2 (1.3 - 1.0) + 0.02 (pi/2 - 0) - 0.02 = 0.06 + 0.031416 - 0.02 = 0.071416
    assert out[1] == pytest.approx(0.06 + 0.02 * PI / 2 - 0.02)
    # 0.2 * 0.5 + 0.02 (1.570796 - 0.5) - 0.02 = 0.1 + 0.021416 - 0.02 = 0.101416
    assert out[2] == pytest.approx(0.101416, abs=1e-6)
    # no progress, goal behind: 0 + 0.02 (1.570796 - 3.141593) - 0.02 = -0.031416 - 0.02 = -0.051416
    assert out[3] == pytest.approx(-0.051416, abs=1e-6)
    # moving away 0.2 m: 0.2 * -0.2 + 0.031416 - 0.02 = -0.04 + 0.011416 = -0.028584
    assert out[4] == pytest.approx(-0.028584, abs=1e-6)


# ---------------------------------------------------------------- r_c (Eq. 23)
@pytest.mark.parametrize("d, expected", [
    (10.0, 0.0), (3.01, 0.0),                    # beyond 3: nothing
    (3.0, -0.2), (2.5, -0.2), (2.0001, -0.2),    # (2, 3]
    (2.0, -0.5), (1.0, -0.5), (0.5001, -0.5),    # (0.5, 2]
    (0.5, -1.0), (0.2, -1.0), (0.0, -1.0),       # [0, 0.5]
])
def test_collision_reward_intervals(d, expected):
    assert collision_reward(t([d])).item() == expected


def test_collision_reward_keeps_dtype_and_shape():
    out = collision_reward(torch.tensor([[3.0, 2.0], [0.5, 3.01]]))
    assert out.dtype == torch.float32 and torch.equal(out, torch.tensor([[-0.2, -0.5], [-1.0, 0.0]]))


# ---------------------------------------------------------------- r_f (Eq. 24), r_v (Eq. 25)
def test_flocking_reward():
    dev = t([0.0, PI / 2, -PI, 0.0, -PI / 4])
    d_c = t([0.0, 1.5, 3.0, 6.0, 0.75])
    out = flocking_reward(dev, d_c).tolist()
    # 0.05 (1 - 0) + 0.05 (1 - 0) = 0.1
    # 0.05 (1 - 0.5) + 0.05 (1 - 0.5) = 0.05
    # 0.05 (1 - 1) + 0.05 (1 - 1) = 0
    # 0.05 * 1 + 0.05 (1 - 2) = 0           (far from the centre costs)
    # 0.05 (1 - 0.25) + 0.05 (1 - 0.25) = 0.075   (|dev| is used)
    assert out == pytest.approx([0.1, 0.05, 0.0, 0.0, 0.075])


def test_cohesion_range_by_swarm_size():
    # paper: 3 m at every size; sqrt_n: 3 sqrt(N / 5): 3 m at 5, 6 m at 20, 3 sqrt(10) = 9.486833 m at 50.
    assert [cohesion_range("paper", n) for n in (5, 20, 50)] == [3.0, 3.0, 3.0]
    assert [cohesion_range("sqrt_n", n) for n in (5, 20, 50)] == pytest.approx([3.0, 6.0, 9.486833])
    # r_f at d_c = 3 m, heading on the mean: 0.05 + 0.05 (1 - 3/6) = 0.075 with a 6 m range (paper: 0.05).
    assert flocking_reward(t([0.0]), t([3.0]), reach=6.0).item() == pytest.approx(0.075)
    with pytest.raises(ValueError, match="cohesion_range"):
        cohesion_range("linear", 5)


def test_smoothness_reward():
    a = t([[0.5, -0.5], [0.2, 0.3], [1.0, -1.0]])
    prev = t([[0.0, 0.0], [0.2, 0.3], [-1.0, 1.0]])
    # -0.02 (0.5 + 0.5) = -0.02; identical actions: 0; -0.02 (2 + 2) = -0.08
    assert smoothness_reward(a, prev).tolist() == pytest.approx([-0.02, 0.0, -0.08])


def test_total_reward_is_the_sum():
    kwargs = dict(d_goal=t([9.5]), d_goal_prev=t([10.0]), alpha_goal=t([0.5]), goal_radius=1.0,
                  d_collision=t([2.5]), heading_deviation=t([PI / 2]), d_centre=t([1.5]),
                  action=t([[0.5, -0.5]]), prev_action=t([[0.0, 0.0]]))
    # r_g 0.101416 + r_c -0.2 + r_f 0.05 + r_v -0.02 = -0.068584
    assert total_reward(**kwargs).item() == pytest.approx(-0.068584, abs=1e-6)


# ---------------------------------------------------------------- in the env
def test_env_reward_two_steps_by_hand(make_env, place, step_with):
    # S1, two UAVs at (10, 10) and (10, 14) facing +x at rest; goal (50, 10).
    env = place(make_env("s1", n_uavs=2), [[[10.0, 10.0], [10.0, 14.0]]], [[0.0, 0.0]], [[50.0, 10.0]])
    out = step_with(env, [[[0.0, 0.0], [0.0, 0.0]]])
    # Step 1: command (2, 0), v = 0.4, both x -> 10.08; headings stay 0.
    # UAV 0: d_g 40 -> 39.92; r_g = 0.2 * 0.08 + 0.02 (pi/2 - 0) - 0.02 = 0.016 + 0.011416 = 0.027416
    # UAV 1: d_g sqrt(40^2 + 4^2) = 40.199502 -> sqrt(39.92^2 + 16) = 40.119900;
    #        alpha = atan2(-4, 39.92) = -0.099867; r_g = 0.2 * 0.079602 + 0.02 (1.570796 - 0.099867) - 0.02
    #        = 0.015920 + 0.029419 - 0.02 = 0.025339
    # r_c: no obstacles, every beam 10 -> 0.  r_v: first step, a_{t-1} := a_t -> 0.
    # r_f: headings equal -> 0.05; centre (10.08, 12): d_c = 2 -> 0.05 (1 - 2/3) = 0.016667 -> 0.066667
    r1 = out["agents", "reward"][0, :, 0].tolist()
    assert r1 == pytest.approx([0.027416 + 0.066667, 0.025339 + 0.066667], abs=2e-6)
    out = step_with(env, [[[0.0, 0.5], [0.0, 0.0]]])
    # Step 2: UAV 0 a = [0, 0.5]: command (2.5, 0), v = 0.4 + 0.2 (2.5 - 0.4) = 0.82, x = 10.08 + 0.164 = 10.244
    #         UAV 1 a = [0, 0]:   command (2, 0),   v = 0.4 + 0.2 (2 - 0.4) = 0.72,   x = 10.08 + 0.144 = 10.224
    # UAV 0: r_g = 0.2 (39.92 - 39.756) + 0.011416 = 0.0328 + 0.011416 = 0.044216
    #        r_v = -0.02 |0.5 - 0| = -0.01
    #        centre (10.234, 12): d_c = sqrt(0.01^2 + 2^2) = 2.000025 -> r_f = 0.05 + 0.05 (1 - 0.666675) = 0.066666
    # UAV 1: d_g = sqrt(39.776^2 + 16) = 39.976620, alpha = -atan(4/39.776) = -0.100224
    #        r_g = 0.2 (40.119900 - 39.976620) + 0.02 (1.570796 - 0.100224) - 0.02 = 0.028656 + 0.009411 = 0.038067
    #        r_v = 0 (same action as before); r_f = 0.066666
    d1 = math.hypot(39.776, 4.0)
    r_g1 = 0.2 * (math.hypot(39.92, 4.0) - d1) + 0.02 * (PI / 2 - math.atan(4 / 39.776)) - 0.02
    assert r_g1 == pytest.approx(0.038067, abs=1e-6)
    r_f = 0.05 + 0.05 * (1 - math.hypot(0.01, 2.0) / 3)
    r2 = out["agents", "reward"][0, :, 0].tolist()
    assert r2 == pytest.approx([0.044216 - 0.01 + r_f, r_g1 + r_f], abs=3e-6)


def test_env_cohesion_range_sqrt_n_by_hand(make_env, place, step_with):
    # The two-UAV placement of the test above, now with 20 UAVs' range in a 2-UAV world:
    # sqrt_n at N = 2 gives 3 sqrt(2/5) = 1.897367 m. Step 1: d_c = 2 for both, so
    # r_f = 0.05 + 0.05 (1 - 2 / 1.897367) = 0.05 - 0.002705 = 0.047295, against 0.066667 under paper.
    rewards = {}
    for mode in ("paper", "sqrt_n"):
        env = place(make_env("s1", n_uavs=2, cohesion_range=mode), [[[10.0, 10.0], [10.0, 14.0]]], [[0.0, 0.0]],
                    [[50.0, 10.0]])
        rewards[mode] = step_with(env, [[[0.0, 0.0], [0.0, 0.0]]])["agents", "reward"][0, :, 0]
    assert (rewards["sqrt_n"] - rewards["paper"]).tolist() == pytest.approx([0.047295 - 0.066667] * 2, abs=2e-6)


def test_env_first_step_smoothness_is_zero_and_reset_forgets_the_last_action(make_env, place, step_with):
    # One UAV at (10, 10) facing +x, goal (50, 10), a = [0, 0.5]: command (2.5, 0), v = 0.5, x -> 10.1.
    # r_g = 0.2 (40 - 39.9) + 0.02 (pi/2 - 0) - 0.02 = 0.02 + 0.011416 = 0.031416; r_c = 0;
    # r_f = 0.05 + 0.05 = 0.1 (alone, it is the swarm centre); r_v = 0 since a_{t-1} := a_t
    # (with a_{t-1} = 0 it would be -0.02 * 0.5 = -0.01). Total 0.131416.
    env = place(make_env("s1", n_uavs=1), [[[10.0, 10.0]]], [[0.0]], [[50.0, 10.0]])
    assert step_with(env, [[[0.0, 0.5]]])["agents", "reward"].item() == pytest.approx(0.131416, abs=1e-6)
    # A new episode forgets the previous action: same placement, a = [0, 0.5] again after
    # a step with a very different action and a reset -> r_v = 0 again.
    step_with(env, [[[-1.0, -1.0]]])
    env.reset()
    place(env, [[[10.0, 10.0]]], [[0.0]], [[50.0, 10.0]])
    assert step_with(env, [[[0.0, 0.5]]])["agents", "reward"].item() == pytest.approx(0.131416, abs=1e-6)


def test_env_goal_reward_inside_goal(make_env, place, step_with):
    # One UAV at (10, 10) facing +x, goal (10.58, 10): after the step it is at 10.08, d_g = 0.5 < 1:
    # r_g = 20; r_c = 0; r_f = 0.05 (1 - 0) + 0.05 (1 - 0/3) = 0.1 (alone: it is the centre); r_v = 0 -> 20.1.
    env = place(make_env("s1", n_uavs=1), [[[10.0, 10.0]]], [[0.0]], [[10.58, 10.0]])
    out = step_with(env, [[[0.0, 0.0]]])
    assert out["agents", "reward"][0, 0, 0].item() == pytest.approx(20.1, abs=1e-5)
    assert out["terminated"].tolist() == [[True]]


def test_env_collision_reward_from_the_laser(make_env, place, step_with):
    # Same placement in the training world and in S1 (no obstacles): the rewards differ by r_c only.
    # Step with a = [0, 0]: every UAV moves +0.08 m in x.
    #  UAV 0 (31, 40) -> (31.08, 40): shortest beam to the circle (40, 40) r 6: 40 - 6 - 31.08 = 2.92 -> -0.2
    #  UAV 1 (40, 47.5) -> (40.08, 47.5): straight down to 40 + sqrt(36 - 0.08^2) = 45.99947: 1.50053 -> -0.5
    #  UAV 2 (40, 60) -> 14 m from the circle, 24+ from the rectangles: all beams 10 -> 0
    layout = ([[[31.0, 40.0], [40.0, 47.5], [40.0, 60.0]]], [[0.0, 0.0, 0.0]], [[40.0, 80.0]])
    action = [[[0.0, 0.0]] * 3]
    r_world = step_with(place(make_env("train", n_uavs=3), *layout), action)["agents", "reward"][0, :, 0]
    r_free = step_with(place(make_env("s1", n_uavs=3), *layout), action)["agents", "reward"][0, :, 0]
    assert (r_world - r_free).tolist() == pytest.approx([-0.2, -0.5, 0.0], abs=1e-6)


def test_env_policy4g_collision_reward_uses_nearest_visible_uav(make_env, place, step_with):
    # S1 (no laser returns). UAV 1 is 1.5 m ahead of UAV 0, both facing +x, both move 0.08 m:
    # UAV 0 sees UAV 1 at 1.5 m: min(d_uav1, d_scan1) = min(1.5, 10) = 1.5 -> r_c = -0.5;
    # UAV 1 sees nobody (UAV 0 is behind it): min(inf, 10) = 10 -> 0.
    # The default r_c (laser only) is 0 for both, so the difference is [-0.5, 0].
    layout = ([[[10.0, 10.0], [11.5, 10.0]]], [[0.0, 0.0]], [[50.0, 10.0]])
    action = [[[0.0, 0.0], [0.0, 0.0]]]
    r4 = step_with(place(make_env("s1", n_uavs=2, collision_reward_source="min_uav_scan"), *layout),
                   action)["agents", "reward"][0, :, 0]
    r = step_with(place(make_env("s1", n_uavs=2), *layout), action)["agents", "reward"][0, :, 0]
    assert (r4 - r).tolist() == pytest.approx([-0.5, 0.0], abs=1e-6)


def test_collision_reward_ramp_by_hand():
    # ramp: -1 up to 0.5 m, then -(3 - d) / 2.5 up to 0 at 3 m:
    # 0.2 -> -1; 0.5 -> -1; 1.0 -> -(3 - 1) / 2.5 = -0.8; 1.75 -> -1.25 / 2.5 = -0.5;
    # 2.5 -> -0.5/2.5 = -0.2; 3.0 -> 0; 10 -> 0.
    d = t([0.2, 0.5, 1.0, 1.75, 2.5, 3.0, 10.0])
    assert collision_reward(d, "ramp").tolist() == pytest.approx([-1.0, -1.0, -0.8, -0.5, -0.2, 0.0, 0.0])
    # The paper's bands at the same distances, for contrast: flat -0.5 from 0.5 m to 2 m.
    assert collision_reward(d).tolist() == pytest.approx([-1.0, -1.0, -0.5, -0.5, -0.2, -0.2, 0.0])
    with pytest.raises(ValueError, match="collision_shape"):
        collision_reward(d, "smooth")


def test_env_collision_shape_ramp_by_hand(make_env, place, step_with):
    # The placement of the test above (UAV 0 sees UAV 1 at 1.5 m; UAV 1 sees nobody), now
    # with the ramp: r_c = -(3 - 1.5) / 2.5 = -0.6 for UAV 0 against the bands' -0.5; 0 for UAV 1.
    layout = ([[[10.0, 10.0], [11.5, 10.0]]], [[0.0, 0.0]], [[50.0, 10.0]])
    action = [[[0.0, 0.0], [0.0, 0.0]]]
    rewards = {}
    for shape in ("paper", "ramp"):
        env = place(make_env("s1", n_uavs=2, collision_reward_source="min_uav_scan", collision_shape=shape), *layout)
        rewards[shape] = step_with(env, action)["agents", "reward"][0, :, 0]
    assert (rewards["ramp"] - rewards["paper"]).tolist() == pytest.approx([-0.1, 0.0], abs=1e-6)


def test_env_reward_stores_the_policy_action_even_under_the_instinct(make_env, place, step_with):
    # With the instinct driving UAV 0, r_v still compares *policy* actions: two identical actions
    # give r_v = 0 at step 2, whatever the executed commands were.
    env = place(make_env("s1", n_uavs=2, instinct=True), [[[40.0, 40.0], [41.0, 40.0]]], [[0.0, 0.0]],
                [[40.0, 80.0]])
    td = env.current()
    td["agents", "action"] = torch.tensor([[[0.3, -0.2], [0.3, -0.2]]])
    out = env.step(td)
    assert out["next", "agents", "instinct"][0].tolist() == [True, False]
    # The stored action is the policy's, not the repulsion command that was executed.
    assert torch.equal(out["agents", "action"], torch.tensor([[[0.3, -0.2], [0.3, -0.2]]]))
    assert torch.allclose(env.world["prev_action"], torch.tensor([[[0.3, -0.2], [0.3, -0.2]]]))
