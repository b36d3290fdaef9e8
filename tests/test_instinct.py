"""instinct.py and its use in the env: Eq. 26-29, the virtual UAV, the switch (specification section 3)."""

import math

import pytest
import torch

from flock_torchrl.world.instinct import hold_in_crowd, instinct_command, repulsion, rotate_90
from flock_torchrl.world.sensors import observe_neighbours

PI = math.pi
FOV = 0.5 * PI


def rep(offsets, to_goal, tangential=True, active=None, gain=1.0, r0=5.0):
    """repulsion() for one UAV (B = N = 1) with M candidates given as a list of offsets p_j - p_i."""
    off = torch.tensor([[offsets]], dtype=torch.float64)  # [1, 1, M, 2]
    act = torch.ones(off.shape[:-1], dtype=torch.bool) if active is None else torch.tensor([[active]])
    return repulsion(off, act, torch.tensor([[to_goal]], dtype=torch.float64), gain, r0, tangential)[0, 0].tolist()


def test_rotate_90():
    # (x, y) -> (-y, x): (1, 0) -> (0, 1); (-2, 0) -> (0, -2)
    assert rotate_90(torch.tensor([[1.0, 0.0], [-2.0, 0.0]])).tolist() == [[0.0, 1.0], [0.0, -2.0]]


def test_radial_term_points_away_with_magnitude_gain_times_r0_minus_d():
    # Neighbour 3 m ahead (offset p_j - p_i = (3, 0)), r0 = 5, p_rep = 1:
    # v_r = 1 * (5 - 3) * (p_i - p_j)/|p_ij| = 2 * (-1, 0) = (-2, 0).
    assert rep([[3.0, 0.0]], [0.0, 10.0], tangential=False) == pytest.approx([-2.0, 0.0])
    # p_rep = 0.5, neighbour at (0, -4): 0.5 * (5 - 4) * (0, 1) = (0, 0.5).
    assert rep([[0.0, -4.0]], [0.0, 10.0], tangential=False, gain=0.5) == pytest.approx([0.0, 0.5])
    # Diagonal neighbour (3, 4) at 5 m = r0: not counted (strict <); at (0.6, 0.8), 1 m:
    # 4 * (-0.6, -0.8) = (-2.4, -3.2).
    assert rep([[3.0, 4.0]], [0.0, 10.0], tangential=False) == [0.0, 0.0]
    assert rep([[0.6, 0.8]], [0.0, 10.0], tangential=False) == pytest.approx([-2.4, -3.2])


def test_tangential_term_sign():
    # v_r = (-2, 0) (neighbour at (3, 0)). +90 deg: (0, -2); -90 deg: (0, 2).
    # Goal straight up (p_g - p_i = (0, 10)): (0, -2).(0, 10) = -20 < 0 -> use -90 deg: v_t = (0, 2);
    # v_rep = (-2, 0) + (0, 2) = (-2, 2).
    assert rep([[3.0, 0.0]], [0.0, 10.0]) == pytest.approx([-2.0, 2.0])
    # Goal straight down: (0, -2).(0, -10) = 20 > 0 -> +90 deg: (-2, -2).
    assert rep([[3.0, 0.0]], [0.0, -10.0]) == pytest.approx([-2.0, -2.0])
    # Tie: goal along v_r's line, (0, -2).(-10, 0) = 0 -> +90 deg: (-2, 0) + (0, -2) = (-2, -2).
    assert rep([[3.0, 0.0]], [-10.0, 0.0]) == pytest.approx([-2.0, -2.0])
    assert rep([[3.0, 0.0]], [10.0, 0.0]) == pytest.approx([-2.0, -2.0])
    # |v_t| = |v_r| and v_t perpendicular to v_r: (-2, 2) has both components of size 2.
    # Policy5-G (tangential=False) drops v_t: just (-2, 0).
    assert rep([[3.0, 0.0]], [0.0, 10.0], tangential=False) == pytest.approx([-2.0, 0.0])


def test_sum_over_neighbours_and_exclusions():
    # Neighbours at (3, 0) and (0, 4), goal (10, 10):
    #  j1: v_r = 2 (-1, 0) = (-2, 0); +90: (0, -2), (0, -2).(10, 10) = -20 < 0 -> (0, 2): (-2, 2)
    #  j2: v_r = 1 (0, -1) = (0, -1); +90: (1, 0), (1, 0).(10, 10) = 10 > 0 -> keep: (1, -1)
    #  sum: (-1, 1)
    assert rep([[3.0, 0.0], [0.0, 4.0]], [10.0, 10.0]) == pytest.approx([-1.0, 1.0])
    # An inactive candidate (not visible) adds nothing; one at distance 0 adds nothing (no direction).
    assert rep([[3.0, 0.0], [0.0, 4.0]], [10.0, 10.0], active=[True, False]) == pytest.approx([-2.0, 2.0])
    assert rep([[0.0, 0.0], [3.0, 0.0]], [10.0, 10.0]) == pytest.approx([-2.0, 2.0])
    # Beyond r0: nothing at all.
    assert rep([[6.0, 0.0], [0.0, -5.5]], [10.0, 10.0]) == [0.0, 0.0]


def scene(position, heading, beams, fov=FOV):
    """Camera measurements (exact) and a beams tensor for ``instinct_command``."""
    p = torch.tensor([position])
    h = torch.tensor([heading])
    return p, h, observe_neighbours(p, h, 5.0, fov / 2), torch.tensor([beams])


def call(p, h, goal, beams, nb, tangential=True, safe=2.0):
    return instinct_command(p, h, torch.tensor([goal]), beams, nb, gain=1.0, r0=5.0, safe_distance=safe,
                            tangential=tangential)


def test_virtual_uav_at_shortest_beam_return_point():
    # One UAV at (0, 0) heading 0; beam 9 (90 deg) is the shortest, 1.5 m: the virtual UAV sits at
    # (0, 1.5). v_r = (5 - 1.5) (0, -1) = (0, -3.5); +90 deg: (3.5, 0); goal (10, 0): 35 > 0 -> keep.
    # v_rep = (3.5, -3.5). d_scan1 = 1.5 <= 2: triggered.
    beams = [10.0] * 36
    beams[9] = 1.5
    p, h, nb, b = scene([[0.0, 0.0]], [0.0], [beams])
    triggered, cmd = call(p, h, [10.0, 0.0], b, nb)
    assert triggered.tolist() == [[True]]
    assert cmd[0, 0].tolist() == pytest.approx([3.5, -3.5], abs=1e-5)
    # Heading pi/2 turns beam 9 towards world pi: virtual UAV at (-1.5, 0); v_r = (3.5, 0);
    # +90: (0, 3.5); goal (0, -10): (0, 3.5).(0, -10) = -35 < 0 -> -90: (0, -3.5); v_rep = (3.5, -3.5).
    triggered, cmd = call(p, torch.tensor([[PI / 2]]), [0.0, -10.0], b, nb)
    assert cmd[0, 0].tolist() == pytest.approx([3.5, -3.5], abs=1e-5)


def test_virtual_uav_only_within_r0_and_not_at_zero():
    # Shortest beam 6 m > r0 = 5: no repulsion and not triggered (6 > d_safe).
    beams = [10.0] * 36
    beams[4] = 6.0
    p, h, nb, b = scene([[0.0, 0.0]], [0.0], [beams])
    triggered, cmd = call(p, h, [10.0, 0.0], b, nb)
    assert triggered.tolist() == [[False]] and cmd[0, 0].tolist() == [0.0, 0.0]
    # Inside an obstacle every beam is 0: triggered (0 <= 2), but the virtual UAV at distance 0 adds nothing.
    p, h, nb, b = scene([[0.0, 0.0]], [0.0], [[0.0] * 36])
    triggered, cmd = call(p, h, [10.0, 0.0], b, nb)
    assert triggered.tolist() == [[True]] and cmd[0, 0].tolist() == [0.0, 0.0]


def test_trigger_uses_min_of_visible_uav_and_scan():
    far = [10.0] * 36
    # UAV 1 2 m straight ahead of UAV 0 (visible), beams all 10: d_uav1 = 2 <= 2 -> triggered.
    # UAV 1 faces away (heading 0) so it does not see UAV 0 behind it: not triggered.
    p, h, nb, b = scene([[0.0, 0.0], [2.0, 0.0]], [0.0, 0.0], [far, far])
    triggered, cmd = call(p, h, [0.0, 20.0], b, nb)
    assert triggered.tolist() == [[True, False]]
    # UAV 0: v_r = (5 - 2)(-1, 0) = (-3, 0); +90: (0, -3), .(0, 20) < 0 -> (0, 3): (-3, 3).
    assert cmd[0, 0].tolist() == pytest.approx([-3.0, 3.0], abs=1e-5)
    # UAV 1 would count nobody: the visible set is empty, the beams are all 10 (> r0).
    assert cmd[0, 1].tolist() == [0.0, 0.0]
    # 2.01 m: neither triggers.
    p, h, nb, b = scene([[0.0, 0.0], [2.01, 0.0]], [0.0, 0.0], [far, far])
    assert call(p, h, [0.0, 20.0], b, nb)[0].tolist() == [[False, False]]
    # A UAV 1 m *behind* (invisible with phi_v = pi/2) neither triggers nor repels UAV 0.
    p, h, nb, b = scene([[0.0, 0.0], [-1.0, 0.0]], [0.0, 0.0], [far, far])
    triggered, cmd = call(p, h, [0.0, 20.0], b, nb)
    assert triggered[0, 0].item() is False and cmd[0, 0].tolist() == [0.0, 0.0]
    # ... but UAV 1, facing +x too, sees UAV 0 1 m ahead: triggered, pushed to -x:
    # v_r = 4 (-1, 0) = (-4, 0); +90: (0, -4), .(1, 20) = -80 < 0 -> (0, 4): (-4, 4).
    assert triggered[0, 1].item() is True
    assert cmd[0, 1].tolist() == pytest.approx([-4.0, 4.0], abs=1e-5)
    # A short beam alone (d_scan1 = 2.0 exactly) triggers.
    beams = list(far)
    beams[0] = 2.0
    p, h, nb, b = scene([[0.0, 0.0]], [0.0], [beams])
    assert call(p, h, [0.0, 20.0], b, nb)[0].tolist() == [[True]]


# ---------------------------------------------------------------- in the env
LAYOUT = ([[[40.0, 40.0], [41.0, 40.0]]],  # UAV 1 one metre ahead of UAV 0
          [[0.0, 0.0]],
          [[40.0, 80.0]])                  # goal straight up (+y)


def test_env_uses_clipped_repulsion_when_triggered(make_env, place, step_with):
    # S1 (no obstacles), two UAVs, instinct on. UAV 0 sees UAV 1 at 1 m: triggered.
    #   v_r = (5 - 1)(-1, 0) = (-4, 0); +90: (0, -4), .(0, 40) < 0 -> (0, 4); v_rep = (-4, 4) -> clip 3: (-3, 3).
    # UAV 1 sees nobody (UAV 0 behind it), no beam returns: policy command, a = [0, 0] -> (2, 0).
    env = place(make_env("s1", n_uavs=2, instinct=True), *LAYOUT)
    out = step_with(env, [[[0.0, 0.0], [0.0, 0.0]]])
    assert out["agents", "instinct"][0].tolist() == [True, False]
    assert torch.allclose(out["agents", "command"][0], torch.tensor([[-3.0, 3.0], [2.0, 0.0]]), atol=1e-5)
    # The velocity follows the executed command: 0.2 * (-3, 3) = (-0.6, 0.6).
    assert out["agents", "velocity"][0, 0].tolist() == pytest.approx([-0.6, 0.6], abs=1e-5)


def test_env_policy5g_drops_the_tangential_term(make_env, place, step_with):
    # tangential=False: v_rep = (-4, 0) -> clip: (-3, 0).
    env = place(make_env("s1", n_uavs=2, instinct=True, tangential=False), *LAYOUT)
    out = step_with(env, [[[0.0, 0.0], [0.0, 0.0]]])
    assert out["agents", "command"][0, 0].tolist() == pytest.approx([-3.0, 0.0], abs=1e-5)


def test_env_without_instinct_keeps_the_policy_command(make_env, place, step_with):
    env = place(make_env("s1", n_uavs=2, instinct=False), *LAYOUT)
    out = step_with(env, [[[0.0, 0.0], [0.0, 0.0]]])
    assert out["agents", "instinct"][0].tolist() == [False, False]
    assert torch.allclose(out["agents", "command"][0], torch.tensor([[2.0, 0.0], [2.0, 0.0]]), atol=1e-6)


def test_env_instinct_from_an_obstacle(make_env, place, step_with):
    # Training world; one UAV at (32.5, 40) facing +x: beam 0 meets the circle (40, 40) r 6 at
    # x = 34, 34 - 32.5 = 1.5 m <= d_safe = 2 -> triggered. Virtual UAV at (34, 40):
    # v_r = (5 - 1.5)(-1, 0) = (-3.5, 0); +90: (0, -3.5); goal (32.5, 80) -> (0, 40): -140 < 0 -> (0, 3.5).
    # v_rep = (-3.5, 3.5) -> clip (-3, 3).
    env = place(make_env("train", n_uavs=1, instinct=True), [[[32.5, 40.0]]], [[0.0]], [[32.5, 80.0]])
    out = step_with(env, [[[0.0, 0.0]]])
    assert out["agents", "instinct"][0].tolist() == [True]
    assert out["agents", "command"][0, 0].tolist() == pytest.approx([-3.0, 3.0], abs=1e-5)


# ---------------------------------------------------------------- crowd modes (beyond the paper)
def crowd(uav, beam0, mode, cap=None):
    """hold_in_crowd for one UAV at heading 0 whose shortest beam is beam 0 (+x) at ``beam0`` m."""
    beams = torch.full((1, 1, 36), 10.0)
    beams[0, 0, 0] = beam0
    return hold_in_crowd(torch.tensor([[uav]]), mode, beams=beams, heading=torch.zeros(1, 1), gain=1.0, r0=5.0,
                         safe_distance=2.0, cap=cap)[0, 0].tolist()


def test_hold_in_crowd_by_hand():
    # The obstacle's return point is (3, 0): outward normal n = (-1, 0).
    # no_push_in: (4, 1) . n = -4 < 0 -> remove -4 n: (4, 1) - (4, 0) = (0, 1).
    assert crowd([4.0, 1.0], 3.0, "no_push_in") == pytest.approx([0.0, 1.0])
    # A push away from the obstacle ((-2, 1) . n = 2 > 0) stays; so does any push when the beam is beyond r0.
    assert crowd([-2.0, 1.0], 3.0, "no_push_in") == pytest.approx([-2.0, 1.0])
    assert crowd([4.0, 1.0], 6.0, "no_push_in") == pytest.approx([4.0, 1.0])
    # saturated: at most gain (r0 - d_safe) = 3 m/s: (3, 4) (length 5) -> 3/5 (3, 4) = (1.8, 2.4); (1, 1) stays.
    assert crowd([3.0, 4.0], 3.0, "saturated") == pytest.approx([1.8, 2.4])
    assert crowd([1.0, 1.0], 3.0, "saturated") == pytest.approx([1.0, 1.0])
    assert crowd([3.0, 4.0], 3.0, "saturated", cap=2.5) == pytest.approx([1.5, 2.0])
    assert crowd([3.0, 4.0], 3.0, "paper") == pytest.approx([3.0, 4.0])
    with pytest.raises(ValueError, match="instinct mode"):
        crowd([3.0, 4.0], 3.0, "nearest")


@pytest.mark.parametrize("mode, command", [("paper", [0.5, 3.0]), ("no_push_in", [-3.0, 3.0]),
                                           ("saturated", [-3.5 + 3 / math.sqrt(2), 3.0])])
def test_env_instinct_modes(make_env, place, step_with, mode, command):
    # Training world; UAV 0 at (32.5, 40) faces -x (heading pi), its back 1.5 m from the circle
    # (40, 40) r 6 (beam 18 returns 1.5 m: triggered); UAV 1 1 m ahead of it, at (31.5, 40), visible.
    # Goal (32.5, 80): to_goal (0, 40).
    #   UAVs' part: v_r = (5 - 1)(1, 0) = (4, 0); +90: (0, 4), .(0, 40) > 0: (4, 4).
    #   Obstacle's part: v_r = (5 - 1.5)(-1, 0) = (-3.5, 0); +90: (0, -3.5) -> flipped (0, 3.5): (-3.5, 3.5).
    #   paper: (0.5, 7.5) -> clip 3 per axis: (0.5, 3).
    #   no_push_in: n = (-1, 0), (4, 4) . n = -4 removed: (0, 4); sum (-3.5, 7.5) -> (-3, 3).
    #   saturated: (4, 4) -> 3 / (4 sqrt 2) (4, 4) = (3/sqrt 2, 3/sqrt 2); sum (-3.5 + 2.121, 5.621) -> y clip 3.
    env = place(make_env("train", n_uavs=2, instinct=True, instinct_mode=mode),
                [[[32.5, 40.0], [31.5, 40.0]]], [[PI, PI]], [[32.5, 80.0]])
    out = step_with(env, [[[0.0, 0.0], [0.0, 0.0]]])
    assert out["agents", "instinct"][0, 0].item() is True
    assert out["agents", "command"][0, 0].tolist() == pytest.approx(command, abs=1e-5)


def test_instinct_mode_is_checked(make_env):
    from flock_torchrl.config import ConfigError

    with pytest.raises(ConfigError, match="instinct_mode"):
        make_env("train", instinct_mode="nearest")
