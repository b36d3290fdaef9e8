"""sensors.py and the env's two views: laser / o_scan, camera / o_cam, o_g, s_c, S4 noise (specification section 2)."""

import math

import pytest
import torch

from flock_torchrl.world.geometry import Obstacles
from flock_torchrl.world.laser import beam_offsets, laser_scan, scan_observation, shortest_beams
from flock_torchrl.world.sensors import (
    Neighbours, add_sensor_noise, camera_observation, goal_observation, observe_neighbours, swarm_centre_state,
    visibility,
)

PI = math.pi
FOV = 0.5 * PI  # phi_v of the G policies


def no_obstacles():
    return Obstacles(torch.zeros(1, 0, 3), torch.zeros(1, 0, 4))


# ---------------------------------------------------------------- laser
def test_beam_offsets_are_ten_degrees_apart():
    off = beam_offsets(36)
    assert off.shape == (36,)
    assert off[1].item() == pytest.approx(PI / 18)    # 10 deg
    assert off[9].item() == pytest.approx(PI / 2)     # 90 deg
    assert off[18].item() == pytest.approx(PI)        # 180 deg


def test_laser_scan_circle_from_known_pose():
    # Circle (0, 3) r 1; UAV 0 at the origin facing +y (heading pi/2), UAV 1 inside the circle.
    obstacles = Obstacles(torch.tensor([[[0.0, 3.0, 1.0]]]), torch.zeros(1, 0, 4))
    position = torch.tensor([[[0.0, 0.0], [0.0, 2.5]]])
    beams, hit = laser_scan(position, torch.tensor([[PI / 2, 0.3]]), obstacles, 36, 10.0)
    assert beams.shape == hit.shape == (1, 2, 36)
    b = beams[0, 0]
    # Beam 0 points at heading + 0 = +y: hits y = 3 - 1 = 2 -> 2.
    assert b[0].item() == pytest.approx(2.0, abs=1e-5)
    # Beams 1 and 35 (+-10 deg): t = 3 cos 10 - sqrt(9 cos^2 10 - 8) = 2.95442 - 0.85359 = 2.10083.
    assert b[1].item() == pytest.approx(2.100833, abs=1e-5)
    assert b[35].item() == pytest.approx(2.100833, abs=1e-5)
    # Beam 9 (world angle pi, -x) and beam 18 (-y) miss: capped at 10.
    assert b[9].item() == 10.0 and b[18].item() == 10.0
    assert hit[0, 0, 0].item() == 0 and hit[0, 0, 18].item() == -1
    # UAV 1 is inside the circle ((0, 2.5) is 0.5 from the centre): every beam is 0.
    assert torch.equal(beams[0, 1], torch.zeros(36))


def test_laser_in_env_rectangle_and_range(make_env, place):
    # Training world; UAV at (20, 40) facing +x. Beam 18 (-x) hits the rectangle face x = 13:
    # 20 - 13 = 7. Beams 17 / 19 (+-10 deg off -x): 7 / cos 10 deg = 7.10803 (y = 40 -+ 1.234, on
    # the face). Beam 0 (+x) would hit the circle at x = 34 after 14 m > 10: capped.
    env = make_env("train", n_uavs=1)
    place(env, [[[20.0, 40.0]]], [[0.0]], [[20.0, 0.0]])
    scan = env.world["sensed"]["scan"][0, 0]
    assert scan[18].item() == pytest.approx(7.0, abs=1e-5)
    assert scan[17].item() == pytest.approx(7 / math.cos(PI / 18), abs=1e-5)
    assert scan[19].item() == pytest.approx(7 / math.cos(PI / 18), abs=1e-5)
    assert scan[0].item() == 10.0
    # Rectangles come after the circle: index 1 = the rectangle at (10, 40).
    assert env.world["sensed"]["scan_obstacle"][0, 0, 18].item() == 1
    # o_scan = observation[2:8]: [7/10, alpha(beam 18) = -pi -> -1.0], then 0.71080 with alphas
    # 170 deg -> 17/18 = 0.94444 and -170 deg -> -0.94444 (the two may come in either order: their
    # float lengths differ by an ulp).
    o_scan = env.world["sensed"]["observation"][0, 0, 2:8]
    assert o_scan[0].item() == pytest.approx(0.7, abs=1e-6)
    assert o_scan[1].item() == -1.0
    assert o_scan[2].item() == pytest.approx(0.710803, abs=1e-5)
    assert o_scan[4].item() == pytest.approx(0.710803, abs=1e-5)
    assert sorted([o_scan[3].item(), o_scan[5].item()]) == pytest.approx([-17 / 18, 17 / 18], abs=1e-6)
    # Facing +y instead, the rectangle (world angle pi) sits at +90 deg: beam 9, alpha 0.5.
    place(env, [[[20.0, 40.0]]], [[PI / 2]], [[20.0, 0.0]])
    o_scan = env.world["sensed"]["observation"][0, 0, 2:8]
    assert o_scan[:2].tolist() == pytest.approx([0.7, 0.5], abs=1e-6)
    # Inside an obstacle every beam is 0: o_scan's distances are 0, at beams 0, 1, 2.
    place(env, [[[40.0, 41.0]]], [[0.0]], [[20.0, 0.0]])
    assert torch.equal(env.world["sensed"]["scan"][0, 0], torch.zeros(36))
    assert env.world["sensed"]["observation"][0, 0, 2:8].tolist() == pytest.approx([0, 0, 0, 1 / 18, 0, 2 / 18])


def test_o_scan_ordering_ties_and_alpha():
    beams = torch.full((1, 1, 36), 10.0)
    beams[0, 0, 5] = 3.0    # 50 deg
    beams[0, 0, 2] = 3.0    # 20 deg, ties with beam 5 -> beam 2 first (lower index)
    beams[0, 0, 30] = 1.0   # 300 deg = -60 deg
    dist, idx = shortest_beams(beams, 3)
    assert idx[0, 0].tolist() == [30, 2, 5] and dist[0, 0].tolist() == [1.0, 3.0, 3.0]
    # [d/10, alpha/pi]: [0.1, -60/180 = -0.33333], [0.3, 20/180 = 0.11111], [0.3, 50/180 = 0.27778]
    out = scan_observation(beams, 3, 10.0)
    assert out.shape == (1, 1, 6)
    assert out[0, 0].tolist() == pytest.approx([0.1, -1 / 3, 0.3, 1 / 9, 0.3, 5 / 18], abs=1e-6)


def test_o_scan_beam_18_is_minus_one():
    # Beam 18 points backwards: alpha = wrap(180 deg) = -pi (the range is [-pi, pi)) -> -1.0 exactly.
    beams = torch.full((1, 1, 36), 10.0)
    beams[0, 0, 18] = 4.0
    beams[0, 0, 27] = 5.0  # 270 deg = -90 deg -> -0.5
    beams[0, 0, 9] = 6.0   # 90 deg -> 0.5
    out = scan_observation(beams, 3, 10.0)[0, 0]
    assert out.tolist() == pytest.approx([0.4, -1.0, 0.5, -0.5, 0.6, 0.5], abs=1e-6)
    assert out[1].item() == -1.0


def test_o_scan_all_ties_take_the_first_beams():
    # Nothing in range: all 36 beams are 10 -> beams 0, 1, 2: [1, 0], [1, 10/180], [1, 20/180].
    out = scan_observation(torch.full((2, 3, 36), 10.0), 3, 10.0)
    assert out.shape == (2, 3, 6)
    assert torch.allclose(out, torch.tensor([1.0, 0.0, 1.0, 1 / 18, 1.0, 1 / 9]).expand(2, 3, 6))


# ---------------------------------------------------------------- camera
def test_visibility_fov_edges_and_strict_range():
    # UAV 0 at the origin facing +x (heading 0, so bearings are exact atan2 values).
    d = 2.0
    position = torch.tensor([[[0.0, 0.0],
                              [1.0, 1.0],                                   # bearing +pi/4 = +phi_v/2: visible
                              [1.0, -1.0],                                  # bearing -pi/4: visible
                              [d * math.cos(PI / 4 + 1e-3), d * math.sin(PI / 4 + 1e-3)],   # just outside
                              [d * math.cos(-PI / 4 - 1e-3), d * math.sin(-PI / 4 - 1e-3)],  # just outside
                              [5.0, 0.0],                                   # d = d_v = 5: not (strict <)
                              [4.99, 0.0]]])                                # 4.99 < 5: visible
    heading = torch.zeros(1, 7)
    nb = observe_neighbours(position, heading, 5.0, FOV / 2)
    assert nb.visible[0, 0].tolist() == [False, True, True, False, False, False, True]
    assert nb.bearing[0, 0, 1].item() == pytest.approx(PI / 4)
    # The visibility rule itself on raw numbers: |alpha| <= phi_v/2 and d < d_v, never oneself.
    v = visibility(torch.tensor([[[0.0, 5.0, 4.999, 1.0]]]), torch.tensor([[[0.0, 0.0, PI / 4, -PI / 4 - 1e-4]]]),
                   5.0, FOV / 2)
    assert v[0, 0].tolist() == [False, False, True, False]


def test_fov_two_pi_sees_all_within_range():
    # Neighbours straight behind (bearing wrap(pi) = -pi), beside, ahead; one beyond 5 m.
    position = torch.tensor([[[0.0, 0.0], [-2.0, 0.0], [0.0, 3.0], [1.0, 0.0], [0.0, -6.0]]])
    nb = observe_neighbours(position, torch.zeros(1, 5), 5.0, PI)
    assert nb.visible[0, 0].tolist() == [False, True, True, True, False]
    assert nb.bearing[0, 0, 1].item() == pytest.approx(-PI)
    # With phi_v = pi/2 only the one ahead.
    assert observe_neighbours(position, torch.zeros(1, 5), 5.0, FOV / 2).visible[0, 0].tolist() == [
        False, False, False, True, False]


def test_o_cam_ordering_padding_and_heading_difference():
    # UAV 0 at the origin, heading 0; three UAVs ahead at 3, 1, 2 m, one behind (invisible).
    position = torch.tensor([[[0.0, 0.0], [3.0, 0.0], [1.0, 0.0], [0.0, 0.0], [-1.0, 0.0]]])
    position[0, 3] = torch.tensor([2 * math.cos(0.5), 2 * math.sin(0.5)])  # 2 m at bearing 0.5
    heading = torch.tensor([[0.0, 0.5, -0.3, 3.0, 0.0]])
    nb = observe_neighbours(position, heading, 5.0, FOV / 2)
    out = camera_observation(nb, 3, 5.0)
    assert out.shape == (1, 5, 9)
    # Ascending: UAV 2 (1 m, bearing 0, dphi = wrap(0 - (-0.3)) = 0.3 -> 0.3/pi = 0.095493),
    #            UAV 3 (2 m, bearing 0.5 -> 0.159155, dphi = wrap(0 - 3.0) = -3.0 -> -0.954930),
    #            UAV 1 (3 m, bearing 0, dphi = wrap(0 - 0.5) = -0.5 -> -0.159155).
    expected = [1 / 5, 0.0, 0.3 / PI,
                2 / 5, 0.5 / PI, -3.0 / PI,
                3 / 5, 0.0, -0.5 / PI]
    assert out[0, 0].tolist() == pytest.approx(expected, abs=1e-6)
    # UAV 4 at (-1, 0), heading 0 sees UAV 0 (1 m, bearing 0), UAV 2 (2 m, bearing 0), UAV 3 at
    # offset (1.755 + 1, 0.959) = (2.75517, 0.95885): sqrt(7.5910 + 0.9194) = 2.91725 m, bearing
    # atan2(0.95885, 2.75517) = 0.33491 rad (< pi/4, visible), and UAV 1 at 4 m (4th, dropped).
    # dphi = wrap(0 - phi_j): 0, wrap(0.3) = 0.3, wrap(-3.0) = -3.0.
    d3, b3 = math.hypot(2 * math.cos(0.5) + 1, 2 * math.sin(0.5)), math.atan2(2 * math.sin(0.5), 2 * math.cos(0.5) + 1)
    assert out[0, 4].tolist() == pytest.approx([0.2, 0.0, 0.0, 0.4, 0.0, 0.3 / PI,
                                                d3 / 5, b3 / PI, -3.0 / PI], abs=1e-6)
    # UAV 3 at (1.75517, 0.95885) facing 3.0 rad (almost -x):
    #   UAV 0: offset (-1.75517, -0.95885), 2 m, world angle -(pi - 0.5) = -2.64159,
    #          relative wrap(-2.64159 - 3.0) = wrap(-5.64159) = 0.64159 < 0.7854: visible;
    #   UAV 4: 2.91725 m, world -2.80668, relative wrap(-5.80668) = 0.47650: visible;
    #   UAV 2: world -2.23791, relative wrap(-5.23791) = 1.04527 > pi/4: not; UAV 1: 2.62684: not.
    # dphi = wrap(3.0 - 0) = 3.0 for both. Ascending: UAV 0 (2 m), UAV 4 (2.917 m), then padding.
    assert out[0, 3].tolist() == pytest.approx([2 / 5, 0.64159265 / PI, 3.0 / PI,
                                                2.91724703 / 5, 0.47650198 / PI, 3.0 / PI,
                                                1.0, 0.0, 0.0], abs=1e-6)


def test_o_cam_padding_with_nobody_visible_and_fewer_uavs_than_slots():
    # Two UAVs, the second behind the first: UAV 0 sees nobody -> [1, 0, 0] x 3.
    position = torch.tensor([[[0.0, 0.0], [-1.0, 0.0]]])
    nb = observe_neighbours(position, torch.zeros(1, 2), 5.0, FOV / 2)
    out = camera_observation(nb, 3, 5.0)
    assert out[0, 0].tolist() == [1.0, 0.0, 0.0] * 3
    # UAV 1 sees UAV 0 (1 m ahead, same heading) then two padded slots (only one other UAV exists).
    assert out[0, 1].tolist() == pytest.approx([0.2, 0.0, 0.0] + [1.0, 0.0, 0.0] * 2)
    # A single UAV: all padding.
    nb1 = observe_neighbours(torch.zeros(1, 1, 2), torch.zeros(1, 1), 5.0, FOV / 2)
    assert camera_observation(nb1, 3, 5.0)[0, 0].tolist() == [1.0, 0.0, 0.0] * 3


def test_heading_difference_sign_wraps():
    # phi_i = 3.0, phi_j = -3.0: wrap(6.0) = 6 - 2 pi = -0.28319 -> /pi = -0.090140 (not 6/pi).
    position = torch.tensor([[[0.0, 0.0], [1.0, 0.0]]])
    nb = observe_neighbours(position, torch.tensor([[3.0, -3.0]]), 5.0, PI)
    assert nb.heading_difference[0, 0, 1].item() == pytest.approx(6.0 - 2 * PI, abs=1e-6)
    assert nb.heading_difference[0, 1, 0].item() == pytest.approx(2 * PI - 6.0, abs=1e-6)
    out = camera_observation(nb, 3, 5.0)
    assert out[0, 0, 2].item() == pytest.approx((6.0 - 2 * PI) / PI, abs=1e-6)


# ---------------------------------------------------------------- o_g and s_c
def test_goal_observation():
    position = torch.tensor([[[70.0, 40.0], [0.0, 0.0], [0.0, 0.0]]])
    heading = torch.tensor([[0.0, PI / 2, 0.0]])
    goal = torch.tensor([[30.0, 40.0]])
    out = goal_observation(position, heading, goal, 80.0)
    # UAV 0: d = 40 -> 40/80 = 0.5; the goal is at world pi, heading 0 -> wrap(pi) = -pi -> -1.
    assert out[0, 0].tolist() == pytest.approx([0.5, -1.0], abs=1e-6)
    # UAV 1: offset (30, 40), d = 50 -> 0.625; angle atan2(40, 30) = 0.927295 - pi/2 = -0.643501 -> /pi = -0.204833
    assert out[0, 1].tolist() == pytest.approx([0.625, (math.atan2(40, 30) - PI / 2) / PI], abs=1e-6)
    # Far goal: d = 100 > 80 -> capped at 1.
    far = goal_observation(torch.zeros(1, 1, 2), torch.zeros(1, 1), torch.tensor([[100.0, 0.0]]), 80.0)
    assert far[0, 0].tolist() == pytest.approx([1.0, 0.0])


def test_swarm_centre_state_circular_mean():
    # Two UAVs at (0, 0) and (2, 0), headings pi - 0.1 and -pi + 0.1. Centre (1, 0), each 1 m away -> 1/5 = 0.2.
    # phi_bar = circular mean = +-pi (NOT the arithmetic mean 0):
    #   UAV 0: wrap(pi - 0.1 - pi) = -0.1 -> -0.031831 ; UAV 1: wrap(-pi + 0.1 - pi) = wrap(-2 pi + 0.1) = 0.1 -> 0.031831
    # (with phi_bar = 0 they would be +-(pi - 0.1)/pi = +-0.968).
    # alpha_c: UAV 0 looks at world 0 from heading pi - 0.1 -> wrap(-pi + 0.1) = -pi + 0.1 -> -0.968169;
    #          UAV 1 looks at world pi from heading -pi + 0.1 -> wrap(2 pi - 0.1) = -0.1 -> -0.031831.
    position = torch.tensor([[[0.0, 0.0], [2.0, 0.0]]])
    heading = torch.tensor([[PI - 0.1, -PI + 0.1]])
    out = swarm_centre_state(position, heading, 5.0)
    assert out[0, 0].tolist() == pytest.approx([0.2, (-PI + 0.1) / PI, -0.1 / PI], abs=1e-5)
    assert out[0, 1].tolist() == pytest.approx([0.2, -0.1 / PI, 0.1 / PI], abs=1e-5)
    # d_c is capped at 1: UAVs 20 m apart -> 10 m from the centre -> min(10/5, 1) = 1.
    far = swarm_centre_state(torch.tensor([[[0.0, 0.0], [20.0, 0.0]]]), torch.zeros(1, 2), 5.0)
    assert far[0, :, 0].tolist() == [1.0, 1.0]


def test_observation_and_state_layout_in_env(make_env, place):
    # S1 (no obstacles: every beam is 10). UAV 0 at (10, 10) heading 0; UAV 1 2 m behind it at
    # (8, 10), heading 0.5; goal (50, 10).
    env = make_env("s1", n_uavs=2)
    place(env, [[[10.0, 10.0], [8.0, 10.0]]], [[0.0, 0.5]], [[50.0, 10.0]])
    obs, state = env.world["sensed"]["observation"][0], env.world["sensed"]["state"][0]
    assert obs.shape == (2, 17) and state.shape == (2, 20)
    o_scan = [1.0, 0.0, 1.0, 1 / 18, 1.0, 1 / 9]  # beams 0, 1, 2 all at 10
    pad = [1.0, 0.0, 0.0]
    # UAV 0: o_g = [40/80, 0]; camera (pi/2) sees nobody (UAV 1 is behind).
    # s_cam (2 pi): UAV 1 at 2 m -> 0.4, bearing wrap(pi) = -pi -> -1, dphi wrap(0 - 0.5) = -0.5 -> -0.159155.
    # s_c: centre (9, 10): 1 m -> 0.2; direction world pi -> -1; phi_bar = circmean(0, 0.5) = 0.25:
    #      wrap(0 - 0.25)/pi = -0.079577.
    assert obs[0].tolist() == pytest.approx([0.5, 0.0] + o_scan + pad * 3, abs=1e-6)
    assert state[0].tolist() == pytest.approx(
        [0.5, 0.0] + o_scan + [0.4, -1.0, -0.5 / PI] + pad * 2 + [0.2, -1.0, -0.25 / PI], abs=1e-6)
    # UAV 1: o_g = [42/80 = 0.525, wrap(0 - 0.5)/pi = -0.159155]; camera sees UAV 0 2 m ahead at
    # bearing -0.5 (|-0.5| < pi/4): [0.4, -0.159155, wrap(0.5 - 0)/pi = 0.159155];
    # s_c: centre 1 m at world 0 -> [0.2, -0.5/pi, wrap(0.5 - 0.25)/pi = 0.079577].
    cam1 = [0.4, -0.5 / PI, 0.5 / PI]
    assert obs[1].tolist() == pytest.approx([0.525, -0.5 / PI] + o_scan + cam1 + pad * 2, abs=1e-6)
    assert state[1].tolist() == pytest.approx(
        [0.525, -0.5 / PI] + o_scan + cam1 + pad * 2 + [0.2, -0.5 / PI, 0.25 / PI], abs=1e-6)


# ---------------------------------------------------------------- S4 noise
def test_add_sensor_noise_statistics_and_clipping():
    g = torch.Generator().manual_seed(0)
    n = 64
    beams = torch.full((4, n, 36), 5.0)
    beams[..., 0] = 10.0  # at the range: noise may only lower it
    beams[..., 1] = 0.0   # inside: noise may only raise it
    dist = torch.full((4, n, n), 3.0)
    dist[..., 0] = 0.0
    nb = Neighbours(dist, torch.zeros(4, n, n), torch.full((4, n, n), PI - 0.01),
                    torch.ones(4, n, n, dtype=torch.bool), dist.clone(), torch.zeros(4, n, n))
    noisy_beams, noisy = add_sensor_noise(beams, nb, scan_std=0.1, distance_std=0.2, angle_std=0.05,
                                          max_range=10.0, generator=g)
    # Standard deviations 0.1 m (beams), 0.2 m (distance), 0.05 rad (bearing), within ~5 %.
    assert (noisy_beams[..., 2:] - 5.0).std().item() == pytest.approx(0.1, rel=0.05)
    assert (noisy.distance[..., 1:] - 3.0).std().item() == pytest.approx(0.2, rel=0.05)
    assert noisy.bearing.std().item() == pytest.approx(0.05, rel=0.05)
    assert (noisy_beams[..., 0] <= 10.0).all() and (noisy_beams[..., 0] < 10.0).any()
    assert (noisy_beams[..., 1] >= 0.0).all() and (noisy_beams[..., 1] > 0.0).any()
    assert (noisy.distance >= 0).all()
    # The heading difference near pi stays wrapped into [-pi, pi).
    assert (noisy.heading_difference >= -PI).all() and (noisy.heading_difference < PI).all()
    assert (noisy.heading_difference < 0).any()
    # Visibility (detection) is never perturbed.
    assert torch.equal(noisy.visible, nb.visible)


def test_s4_noise_reaches_observation_not_state_reward_or_metrics(make_env):
    clean, noisy = make_env("train", num_envs=2, seed=3), make_env("s4", num_envs=2, seed=3)
    # Same seed, same spawn (the noise is drawn after the layout).
    assert torch.equal(clean.world["position"], noisy.world["position"])
    assert not torch.equal(clean.world["sensed"]["observation"], noisy.world["sensed"]["observation"])
    assert torch.equal(clean.world["sensed"]["state"], noisy.world["sensed"]["state"])
    td_c, td_n = clean.current(), noisy.current()
    action = torch.rand(2, 5, 2, generator=torch.Generator().manual_seed(1)) * 2 - 1
    td_c["agents", "action"] = action
    td_n["agents", "action"] = action.clone()
    out_c, out_n = clean.step(td_c)["next"], noisy.step(td_n)["next"]
    assert torch.equal(out_c["agents", "state"], out_n["agents", "state"])
    assert torch.equal(out_c["agents", "reward"], out_n["agents", "reward"])
    assert torch.equal(out_c["done"], out_n["done"])
    for key in ("d_min_obs", "d_min_uav", "d_c", "v_error", "phi_error", "speed"):
        assert torch.equal(out_c["episode", key], out_n["episode", key]), key
    assert not torch.equal(out_c["agents", "observation"], out_n["agents", "observation"])


def test_s4_noise_reaches_the_instinct(make_env, place):
    # Two UAVs 1.5 m apart, UAV 1 ahead of UAV 0: the repulsion uses the (noisy) camera.
    layout = ([[[40.0, 10.0], [41.5, 10.0]]], [[0.0, 0.0]], [[40.0, 70.0]])
    clean = place(make_env("s1", n_uavs=2, instinct=True), *layout)
    noisy = place(make_env("s1", n_uavs=2, instinct=True, noise=True), *layout)
    assert not torch.allclose(clean.world["sensed"]["instinct_command"][0, 0], noisy.world["sensed"]["instinct_command"][0, 0])


# ---------------------------------------------------------------- packed neighbours (large swarms)
@pytest.mark.parametrize("spacing", [3.5, 0.9])  # sparse: packed per UAV; dense: every pair kept
def test_near_neighbours_sense_what_all_pairs_sense(spacing):
    from flock_torchrl.world.instinct import instinct_command
    from flock_torchrl.world.metrics import closest_pair
    from flock_torchrl.world.sensors import near_neighbours, sensor_normals

    # 3 worlds of 36 UAVs on a jittered 6 x 6 grid; two exact distance ties in world 0 (UAV 0
    # sees UAVs 1 and 6 at the same distance) keep the order-by-index rule honest.
    g = torch.Generator().manual_seed(0)
    grid = torch.stack(torch.meshgrid(torch.arange(6.0), torch.arange(6.0), indexing="ij"), -1).reshape(36, 2)
    position = (grid * spacing + 0.3 * torch.rand(3, 36, 2, generator=g)) + 10.0
    position[0, 0] = torch.tensor([20.0, 20.0])
    position[0, 1] = torch.tensor([20.0 + spacing, 20.0])
    position[0, 6] = torch.tensor([20.0, 20.0 + spacing])
    heading = (torch.rand(3, 36, generator=g) * 2 - 1) * PI
    heading[0, 0] = PI / 4  # both tied UAVs inside the field of view
    dense = observe_neighbours(position, heading, 5.0, FOV / 2)
    near, pairs, closest = near_neighbours(position, heading, 5.0, FOV / 2)
    assert (near.distance.shape[-1] < 36) == (spacing > 1)
    assert dense.distance[0, 0, 1] == dense.distance[0, 0, 6] and dense.visible[0, 0, [1, 6]].all()
    assert torch.equal(closest, closest_pair(dense.distance))
    assert torch.equal(near.nearest_distance(), dense.nearest_distance())
    # Same formulas; atan2 may round its last bit differently where an entry falls in another
    # lane of the vectorised loop.
    def same_camera(a, b):
        assert torch.allclose(camera_observation(a, 3, 5.0), camera_observation(b, 3, 5.0), atol=1e-6, rtol=0)

    same_camera(near, dense)
    wide = (visibility(dense.distance, dense.bearing, 5.0, PI),
            visibility(near.distance, near.bearing, 5.0, PI, pairs.valid))
    assert torch.equal(wide[0].sum(-1), wide[1].sum(-1))
    same_camera(near.with_visibility(wide[1]), dense.with_visibility(wide[0]))
    beams, goal = torch.full((3, 36, 36), 10.0), torch.tensor([[70.0, 70.0]] * 3)
    for nb_dense, nb_near in [(dense, near)] + [
            tuple(add_sensor_noise(beams, nb, scan_std=0.1, distance_std=0.2, angle_std=0.05, max_range=10.0,
                                   normals=dict(normals, **{k: take(normals[k]) for k in
                                                            ("distance", "bearing", "heading_difference")}))[1]
                  for nb, take in ((dense, lambda x: x), (near, pairs.take)))
            for normals in [sensor_normals(3, 36, 36, torch.Generator().manual_seed(1))]]:
        same_camera(nb_near, nb_dense)
        a = instinct_command(position, heading, goal, beams, nb_dense, gain=1.0, r0=5.0, safe_distance=2.0,
                             tangential=True)
        b = instinct_command(position, heading, goal, beams, nb_near, gain=1.0, r0=5.0, safe_distance=2.0,
                             tangential=True)
        assert torch.equal(a[0], b[0]) and torch.allclose(a[1], b[1], atol=1e-5, rtol=0)


# ---------------------------------------------------------------- actor_camera (beyond the paper)
def test_actor_camera_all_round_by_hand(make_env, place):
    # UAV 0 at (40, 10) heading east; UAV 1 1.5 m behind it at (38.5, 10), heading east too.
    # The paper's camera (literal: 0.5 pi total, +-45 deg) does not see UAV 1: slot [1, 0, 0].
    # actor_camera=all_round fills the slot as the critic's camera does: distance 1.5 / 5 = 0.3,
    # bearing pi / pi = 1 (behind, wrapped to +-pi), heading difference 0. The instinct keeps the
    # field of view, so UAV 1 behind UAV 0 (within d_safe = 2 m) triggers nothing either way.
    layout = ([[[40.0, 10.0], [38.5, 10.0]]], [[0.0, 0.0]], [[40.0, 70.0]])
    seen = {}
    for view in ("paper", "all_round"):
        env = place(make_env("s1", n_uavs=2, instinct=True, actor_camera=view), *layout)
        td = env.current()
        seen[view] = (td["agents", "observation"][0, 0, 8:11], td["agents", "state"][0, 0, 8:11],
                      env.world["sensed"]["instinct_triggered"][0].tolist())
    assert seen["paper"][0].tolist() == [1.0, 0.0, 0.0]
    slot = seen["all_round"][0]
    assert slot[0].item() == pytest.approx(0.3) and abs(slot[1].item()) == pytest.approx(1.0)
    assert slot[2].item() == pytest.approx(0.0)
    assert torch.equal(seen["all_round"][0], seen["all_round"][1])  # the critic's slot, without noise
    assert torch.equal(seen["paper"][1], seen["all_round"][1])      # the critic's state is untouched
    assert seen["paper"][2] == seen["all_round"][2] == [False, True]  # UAV 1 sees UAV 0 ahead, 1.5 m


# ---------------------------------------------------------------- the compiled step's layout
def test_smallest_along_the_worlds_innermost_layout_takes_what_the_last_dimension_takes():
    from flock_torchrl.world.laser import pick, smallest

    # By hand: beams 30 (1 m), then 2 and 5 (3 m each: the lower index first), as along the last dimension.
    beams = torch.full((1, 1, 36), 10.0)
    beams[0, 0, 5], beams[0, 0, 2], beams[0, 0, 30] = 3.0, 3.0, 1.0
    dist, idx = shortest_beams(beams.permute(2, 1, 0).contiguous().permute(2, 1, 0), 3, worlds_last=True)
    assert idx[0, 0].tolist() == [30, 2, 5] and dist[0, 0].tolist() == [1.0, 3.0, 3.0]
    # Many rows with ties and values past the last finite one (inf).
    g = torch.Generator().manual_seed(0)
    values = torch.randint(0, 6, (7, 4, 9), generator=g).float()
    values[values == 5] = math.inf
    for k in (1, 3, 9):
        last = smallest(values, k)
        first = smallest(values.permute(2, 1, 0), k, 0)
        assert torch.equal(last[0], first[0].permute(2, 1, 0))
        finite = torch.isfinite(last[0])  # past the finite entries the index is arbitrary
        assert torch.equal(last[1][finite], first[1].permute(2, 1, 0)[finite])
        assert torch.equal(pick(values.permute(2, 1, 0), first[1])[torch.isfinite(first[0])],
                           first[0][torch.isfinite(first[0])])


def test_laser_of_the_compiled_step_casts_what_eager_casting_casts():
    from flock_torchrl.world.geometry import cast_rays_along, cast_rays_worlds_last
    from flock_torchrl.world.laser import beam_directions, worlds_last

    # 64 worlds of 5 UAVs among 3 circles and 2 rectangles each, some UAVs inside an obstacle,
    # some on a rectangle's edge (integer coordinates), some beams grazing.
    g = torch.Generator().manual_seed(2)
    b, n = 64, 5
    position = torch.rand(b, n, 2, generator=g) * 30
    position[:8] = position[:8].round()
    heading = (torch.rand(b, n, generator=g) * 2 - 1) * PI
    heading[:4] = 0.0
    circles = torch.cat((torch.rand(b, 3, 2, generator=g) * 30, 1 + 3 * torch.rand(b, 3, 1, generator=g)), -1)
    rects = torch.cat((torch.rand(b, 2, 2, generator=g) * 30, 2 + 6 * torch.rand(b, 2, 2, generator=g)), -1)
    rects[:8] = rects[:8].round()
    rects[:, :, 2:] = rects[:, :, 2:].clamp_min(1.0)
    obstacles = Obstacles(circles, rects)
    eager = cast_rays_along(position, beam_directions(heading, 36), obstacles, 10.0)
    directions = beam_directions(heading, 36).permute(3, 2, 1, 0)  # [2, K, N, B]
    lanes = cast_rays_worlds_last(worlds_last(position[..., 0]), worlds_last(position[..., 1]), directions[0],
                                  directions[1], obstacles, 10.0)
    assert torch.equal(eager[1], lanes[1].permute(2, 1, 0))
    assert torch.allclose(eager[0], lanes[0].permute(2, 1, 0), atol=1e-5, rtol=0)
    assert (eager[0] < 10).float().mean() > 0.2 and (eager[0] == 0).any()  # hits, and UAVs inside
    static = laser_scan(position, heading, obstacles, 36, 10.0, static_shapes=True)
    assert torch.equal(static[1], eager[1]) and torch.allclose(static[0], eager[0], atol=1e-5, rtol=0)
    none = laser_scan(position, heading, no_obstacles(), 36, 10.0, static_shapes=True)
    assert none[0].shape == (b, n, 36) and (none[0] == 10.0).all() and (none[1] == -1).all()


def test_pairs_of_the_compiled_step_sense_what_all_pairs_sense():
    from flock_torchrl.world.instinct import instinct_command
    from flock_torchrl.world.sensors import near_neighbours

    g = torch.Generator().manual_seed(3)
    position = torch.rand(16, 6, 2, generator=g) * 8
    position[0, 1] = position[0, 0] + torch.tensor([2.0, 0.0])  # a distance tie seen by UAV 0
    position[0, 2] = position[0, 0] + torch.tensor([0.0, 2.0])
    heading = (torch.rand(16, 6, generator=g) * 2 - 1) * PI
    heading[0, 0] = PI / 4
    dense, pairs, closest = near_neighbours(position, heading, 5.0, FOV / 2, static_shapes=True)
    lanes, lane_pairs, lane_closest = near_neighbours(position, heading, 5.0, FOV / 2, static_shapes=True,
                                                      worlds_last=True)
    assert lanes.pair_dim == 0 and lanes.distance.shape == (6, 6, 16)
    assert torch.equal(lane_closest, closest)
    assert torch.equal(lanes.visible.permute(2, 1, 0), dense.visible)
    assert torch.equal(lanes.nearest_distance(), dense.nearest_distance())
    assert torch.equal(camera_observation(lanes, 3, 5.0), camera_observation(dense, 3, 5.0))
    wide = visibility(lanes.distance, lanes.bearing, 5.0, PI, lane_pairs.valid)
    assert torch.equal(camera_observation(lanes.with_visibility(wide), 3, 5.0),
                       camera_observation(dense.with_visibility(visibility(dense.distance, dense.bearing, 5.0, PI,
                                                                          pairs.valid)), 3, 5.0))
    beams, goal = torch.full((16, 6, 36), 10.0), torch.tensor([[40.0, 40.0]] * 16)
    beams[:, :, 7] = 1.5  # the wall's push as well
    for tangential in (True, False):
        a = instinct_command(position, heading, goal, beams, dense, gain=1.0, r0=5.0, safe_distance=2.0,
                             tangential=tangential)
        b = instinct_command(position, heading, goal, beams, lanes, gain=1.0, r0=5.0, safe_distance=2.0,
                             tangential=tangential)
        assert torch.equal(a[0], b[0]) and torch.allclose(a[1], b[1], atol=1e-5, rtol=0)
        assert a[0].any() and a[1].abs().sum() > 0
