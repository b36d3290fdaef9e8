"""metrics.py on a hand-built trajectory: Eq. 31-36 with the specification section 5 errata, success vs safe_success."""

import math

import pytest
import torch

from flock_torchrl.world.metrics import episode_summary, new_accumulator, step_statistics, update_episode

PI = math.pi
DT = 0.2


def stats_of(position, velocity, heading, obstacle_distance):
    return step_statistics(torch.tensor(position), torch.tensor(velocity), torch.tensor(heading),
                           torch.tensor(obstacle_distance))


# A two-UAV, two-step trajectory in one env (B = 1), numbers chosen to be computed by hand.
STEP1 = dict(position=[[[0.0, 0.0], [3.0, 4.0]]],
             velocity=[[[1.0, 0.0], [0.0, 1.0]]],
             heading=[[PI - 0.1, -PI + 0.1]],
             obstacle_distance=[[12.0, 7.0]])
STEP2 = dict(position=[[[0.0, 0.0], [0.3, 0.4]]],
             velocity=[[[2.0, 0.0], [2.0, 0.0]]],
             heading=[[0.0, 0.0]],
             obstacle_distance=[[15.0, 20.0]])


def test_step_statistics_by_hand():
    s = stats_of(**STEP1)
    # obs: min(12, 7) = 7 (uncapped per step); uav: |(3, 4)| = 5
    assert s["obs"].tolist() == [7.0] and s["uav"].tolist() == [5.0]
    # centre (1.5, 2): both UAVs |(1.5, 2)| = 2.5 away -> d_c = 2.5
    assert s["d_c"].item() == pytest.approx(2.5)
    # V_i = 1, 1; swarm velocity = mean = (0.5, 0.5) (erratum: 1/N), V_c = 0.707107
    # v_error = (|1 - 0.707107| + |1 - 0.707107|) / 2 = 0.292893  (without the 1/N: |1 - 1.414| = 0.414)
    assert s["v_error"].item() == pytest.approx(1 - math.sqrt(0.5), abs=1e-6)
    assert s["speed"].item() == pytest.approx(math.sqrt(0.5), abs=1e-6)
    # phi_bar = circular mean of pi - 0.1 and -pi + 0.1 = +-pi; |wrap(phi_i - phi_bar)| = 0.1, 0.1 -> 0.1
    # (the arithmetic mean 0 would give pi - 0.1 = 3.04)
    assert s["phi_error"].item() == pytest.approx(0.1, abs=1e-5)


def test_episode_summary_by_hand():
    acc = new_accumulator(1)
    s1, s2 = stats_of(**STEP1), stats_of(**STEP2)
    update_episode(acc, s1, reached=torch.tensor([False]), crashed=torch.tensor([False]), dt=DT)
    update_episode(acc, s2, reached=torch.tensor([True]), crashed=torch.tensor([False]), dt=DT)
    # Step 2: obs min(15, 20) = 15 -> capped 10; uav |(0.3, 0.4)| = 0.5; centre (0.15, 0.2), d_c 0.25;
    # V_i = 2, 2, V_c = |(2, 0)| = 2 -> v_error 0, speed 2; headings equal -> phi_error 0.
    m = episode_summary(acc, collision_distance=0.5)
    assert m["steps"].tolist() == [2]
    assert m["d_min_obs"].item() == pytest.approx(7.0)                    # min(7, min(15, 10))
    assert m["d_min_uav"].item() == pytest.approx(0.5)                    # min(5, 0.5)
    assert m["d_c"].item() == pytest.approx((2.5 + 0.25) / 2)             # 1.375
    assert m["v_error"].item() == pytest.approx((0.292893 + 0) / 2, abs=1e-6)  # 0.146447
    assert m["phi_error"].item() == pytest.approx((0.1 + 0) / 2, abs=1e-5)     # 0.05
    assert m["speed"].item() == pytest.approx((0.707107 + 2) / 2, abs=1e-6)    # 1.353553
    assert m["t_goal"].item() == pytest.approx(2 * DT)                   # first reached at step 2: 0.4 s
    assert m["reached"].tolist() == [True] and m["crashed"].tolist() == [False]
    # Goal, no crash -> success; the closest pair 0.5 is not *closer* than d_min^b = 0.5 -> safe too.
    assert m["success"].tolist() == [True] and m["safe_success"].tolist() == [True]


def test_success_versus_safe_success_and_crash():
    # B = 3 episodes, one step each, two UAVs.
    position = torch.tensor([[[0.0, 0.0], [0.3, 0.0]],     # pair 0.3 m apart (< 0.5): UAV-UAV contact
                             [[0.0, 0.0], [2.0, 0.0]],
                             [[0.0, 0.0], [2.0, 0.0]]])
    velocity = torch.zeros(3, 2, 2)
    heading = torch.zeros(3, 2)
    obstacle = torch.tensor([[5.0, 5.0], [0.2, 5.0], [5.0, 5.0]])
    acc = new_accumulator(3)
    update_episode(acc, step_statistics(position, velocity, heading, obstacle),
                   reached=torch.tensor([True, True, False]), crashed=torch.tensor([False, True, False]), dt=DT)
    m = episode_summary(acc, collision_distance=0.5)
    # 0: reached, no crash -> success (the paper's), but a pair at 0.3 < 0.5 -> not safe_success.
    # 1: reached but crashed -> neither.  2: never reached -> neither, t_goal NaN.
    assert m["success"].tolist() == [True, False, False]
    assert m["safe_success"].tolist() == [False, False, False]
    assert m["d_min_uav"].tolist() == pytest.approx([0.3, 2.0, 2.0])
    assert m["d_min_obs"].tolist() == pytest.approx([5.0, 0.2, 5.0])
    assert m["t_goal"][:2].tolist() == pytest.approx([0.2, 0.2]) and math.isnan(m["t_goal"][2].item())


def test_t_goal_is_the_first_arrival_and_crash_is_sticky():
    acc = new_accumulator(1)
    s = stats_of(**STEP1)
    for reached, crashed in [(False, False), (True, False), (True, True), (False, False)]:
        update_episode(acc, s, reached=torch.tensor([reached]), crashed=torch.tensor([crashed]), dt=DT)
    m = episode_summary(acc, 0.5)
    # First arrival at step 2 -> 2 * 0.2 = 0.4 s (not overwritten at step 3); the crash of step 3 stays.
    assert m["t_goal"].item() == pytest.approx(0.4)
    assert m["crashed"].tolist() == [True] and m["success"].tolist() == [False]
    assert m["steps"].tolist() == [4]


def test_obstacle_distance_capped_at_ten_and_lone_uav():
    # S1 has no obstacles: the distance is inf -> 10.000 exactly (the paper's S1 column); one UAV: no pair.
    acc = new_accumulator(1)
    s = step_statistics(torch.zeros(1, 1, 2), torch.tensor([[[1.0, 1.0]]]), torch.zeros(1, 1),
                        torch.full((1, 1), math.inf))
    assert math.isinf(s["uav"].item())
    update_episode(acc, s, torch.tensor([False]), torch.tensor([False]), DT)
    m = episode_summary(acc, 0.5)
    assert m["d_min_obs"].item() == 10.0
    # One UAV: V_c = |v| = sqrt 2, v_error = 0, phi_error 0, d_c 0.
    assert m["speed"].item() == pytest.approx(math.sqrt(2)) and m["v_error"].item() == pytest.approx(0.0)
    assert m["d_c"].item() == 0.0 and m["phi_error"].item() == 0.0


def test_episode_summary_before_any_step():
    m = episode_summary(new_accumulator(2), 0.5)
    assert m.batch_size == (2,)
    assert m["steps"].tolist() == [0, 0] and m["success"].tolist() == [False, False]
    assert m["d_c"].tolist() == [0.0, 0.0] and m["d_min_obs"].tolist() == [10.0, 10.0]


def test_env_episode_metrics_after_one_step(make_env, place, step_with):
    # The env feeds the same accumulators: two UAVs of S1 at (10, 10) and (10, 13) facing +x.
    env = place(make_env("s1", n_uavs=2), [[[10.0, 10.0], [10.0, 13.0]]], [[0.0, 0.0]], [[70.0, 10.0]])
    ep = step_with(env, [[[0.0, 0.0], [0.0, 0.0]]])["episode"]
    # After the step: both at x = 10.08 with v = (0.4, 0): d_min_uav 3, d_c 1.5, V_c 0.4, v_error 0,
    # phi_error 0, no obstacles -> d_min_obs 10, one step.
    assert ep["steps"].tolist() == [1]
    assert ep["d_min_uav"].item() == pytest.approx(3.0, abs=1e-5)
    assert ep["d_c"].item() == pytest.approx(1.5, abs=1e-5)
    assert ep["speed"].item() == pytest.approx(0.4, abs=1e-6)
    assert ep["v_error"].item() == pytest.approx(0.0, abs=1e-6)
    assert ep["phi_error"].item() == pytest.approx(0.0, abs=1e-6)
    assert ep["d_min_obs"].item() == 10.0
    assert ep["reached"].tolist() == [False] and math.isnan(ep["t_goal"].item())


def test_obstacle_distance_inside_an_obstacle_counts_as_zero():
    # A UAV 0.1 m inside an obstacle (signed distance -0.1) on its crash step: d_min_obs = 0.
    position = torch.tensor([[[0.0, 0.0], [5.0, 0.0]]])
    stats = step_statistics(position, torch.zeros(1, 2, 2), torch.zeros(1, 2), torch.tensor([[-0.1, 3.0]]))
    assert stats["obs"].item() == 0.0
