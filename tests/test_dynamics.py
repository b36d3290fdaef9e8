"""dynamics.py and the env's kinematics: Eq. 1 (semi-implicit Euler), heading rule, Eq. 19-20 (specification section 1, 3)."""

import math

import pytest
import torch

from flock_torchrl.world.dynamics import (
    action_to_command, clip_command, first_order_step, reflect_in_box, update_heading,
)

PI = math.pi
F64 = torch.float64


def t(x):
    return torch.tensor(x, dtype=F64)


# ---------------------------------------------------------------- Eq. 19-20
@pytest.mark.parametrize("action, heading, expected", [
    # a = [0, 0]: dphi = 0, V = 0 + 2 = 2 -> 2 (cos 0.3, sin 0.3) = (1.91067, 0.59104)
    ([0.0, 0.0], 0.3, [2 * math.cos(0.3), 2 * math.sin(0.3)]),
    # a = [1, 1]: dphi = pi/2, V = 3 -> heading 0 + pi/2: (0, 3)
    ([1.0, 1.0], 0.0, [0.0, 3.0]),
    # a = [-1, -1]: dphi = -pi/2, V = 1 -> heading -pi/2: (0, -1)
    ([-1.0, -1.0], 0.0, [0.0, -1.0]),
    # a = [0.5, 0]: dphi = pi/4, V = 2, heading pi -> 5 pi/4: 2 (-0.70711, -0.70711) = (-1.41421, -1.41421)
    ([0.5, 0.0], PI, [-math.sqrt(2), -math.sqrt(2)]),
    # a = [1, 1] at heading pi/4: 3 at 3 pi/4 = (-2.12132, 2.12132)
    ([1.0, 1.0], PI / 4, [-3 / math.sqrt(2), 3 / math.sqrt(2)]),
])
def test_action_to_command(action, heading, expected):
    out = action_to_command(t(action), t(heading))
    assert out.tolist() == pytest.approx(expected, abs=1e-12)


def test_action_to_command_batched():
    # [B=2, N=3] headings, same action [0, 0]: speed 2 along each heading.
    heading = torch.tensor([[0.0, PI / 2, PI], [-PI / 2, 0.0, 0.0]])
    out = action_to_command(torch.zeros(2, 3, 2), heading)
    assert out.shape == (2, 3, 2)
    assert torch.allclose(out, torch.tensor([[[2.0, 0.0], [0.0, 2.0], [-2.0, 0.0]],
                                             [[0.0, -2.0], [2.0, 0.0], [2.0, 0.0]]]), atol=1e-6)


def test_clip_command_is_per_axis():
    # (4, -5) -> (3, -3); (3, 3) keeps both axes even though its norm 4.24 > 3; (2.9, -1) untouched.
    out = clip_command(t([[4.0, -5.0], [3.0, 3.0], [2.9, -1.0]]), 3.0)
    assert out.tolist() == [[3.0, -3.0], [3.0, 3.0], [2.9, -1.0]]


# ---------------------------------------------------------------- Eq. 1
def test_first_order_step_by_hand():
    p, v, cmd = t([1.0, 2.0]), t([0.5, 0.0]), t([2.0, -1.0])
    # tau = 1, dt = 0.2: v = (0.5 + 0.2 (2 - 0.5), 0 + 0.2 (-1 - 0)) = (0.8, -0.2);
    # p = (1 + 0.2 * 0.8, 2 + 0.2 * -0.2) = (1.16, 1.96)  (semi-implicit: the *new* v moves p)
    p1, v1 = first_order_step(p, v, cmd, 0.2, 1.0)
    assert v1.tolist() == pytest.approx([0.8, -0.2]) and p1.tolist() == pytest.approx([1.16, 1.96])
    # tau = 0.5: dt/tau = 0.4: v = (0.5 + 0.4 * 1.5, 0.4 * -1) = (1.1, -0.4); p = (1.22, 1.92)
    p1, v1 = first_order_step(p, v, cmd, 0.2, 0.5)
    assert v1.tolist() == pytest.approx([1.1, -0.4]) and p1.tolist() == pytest.approx([1.22, 1.92])
    # tau = dt: the velocity jumps to the command: v = (2, -1), p = (1.4, 1.8)
    p1, v1 = first_order_step(p, v, cmd, 0.2, 0.2)
    assert v1.tolist() == pytest.approx([2.0, -1.0]) and p1.tolist() == pytest.approx([1.4, 1.8])


def test_update_heading_threshold():
    heading = t([0.7, 0.7, 0.7, 0.7, 0.7])
    velocity = t([[0.04, 0.0],    # speed 0.04 <= 0.05: kept 0.7
                  [0.05, 0.0],    # speed exactly 0.05 does not *exceed* the threshold: kept
                  [0.0, 0.06],    # 0.06 > 0.05: atan2(0.06, 0) = pi/2
                  [-1.0, 0.0],    # atan2(0, -1) = pi
                  [1.0, -1.0]])   # atan2(-1, 1) = -pi/4
    out = update_heading(heading, velocity, 0.05)
    assert out.tolist() == pytest.approx([0.7, 0.7, PI / 2, PI, -PI / 4])


def test_reflect_in_box():
    pos = t([[-1.0, 50.0], [81.0, 79.0], [40.0, 40.0]])
    vel = t([[-0.5, 0.2], [0.3, 0.4], [0.1, -0.1]])
    p, v = reflect_in_box(pos, vel, 0.0, 80.0)
    # -1 -> 2*0 - (-1) = 1 (vx flipped), 81 -> 2*80 - 81 = 79 (vx flipped), inside: untouched.
    assert p.tolist() == [[1.0, 50.0], [79.0, 79.0], [40.0, 40.0]]
    assert v.tolist() == [[0.5, 0.2], [-0.3, 0.4], [0.1, -0.1]]


# ---------------------------------------------------------------- in the env
def test_env_one_step_by_hand(make_env, place, step_with):
    env = make_env("s1", n_uavs=2)
    place(env, [[[10.0, 10.0], [20.0, 20.0]]], [[0.0, PI / 2]], [[70.0, 70.0]],
          velocity=[[[1.0, 0.0], [0.0, 0.0]]])
    out = step_with(env, [[[0.0, 0.0], [1.0, 1.0]]])
    # UAV 0: command 2 (cos 0, sin 0) = (2, 0); v = 1 + 0.2 (2 - 1) = 1.2 -> (1.2, 0); p = 10 + 0.24 = 10.24
    # UAV 1: a = [1, 1] -> 3 at pi/2 + pi/2 = pi: command (-3, 0); v = 0.2 * (-3) = -0.6 -> (-0.6, 0);
    #        p = (20 - 0.12, 20) = (19.88, 20); heading atan2(0, -0.6) = pi
    a = out["agents"]
    assert torch.allclose(a["command"][0], torch.tensor([[2.0, 0.0], [-3.0, 0.0]]), atol=1e-6)
    assert torch.allclose(a["velocity"][0], torch.tensor([[1.2, 0.0], [-0.6, 0.0]]), atol=1e-6)
    assert torch.allclose(a["position"][0], torch.tensor([[10.24, 10.0], [19.88, 20.0]]), atol=1e-5)
    assert a["heading"][0, 0].item() == pytest.approx(0.0, abs=1e-6)
    assert abs(a["heading"][0, 1].item()) == pytest.approx(PI, abs=1e-6)


def test_env_tau_v_and_dt_are_used(make_env, place, step_with):
    env = make_env("tau_v", tau_v=0.5, dt=0.1, n_uavs=1)
    place(env, [[[10.0, 10.0]]], [[0.0]], [[70.0, 10.0]])
    out = step_with(env, [[[0.0, 1.0]]])
    # command (3, 0); dt/tau = 0.1/0.5 = 0.2: v = 0.2 * 3 = 0.6; p = 10 + 0.1 * 0.6 = 10.06
    assert out["agents", "velocity"][0, 0].tolist() == pytest.approx([0.6, 0.0], abs=1e-6)
    assert out["agents", "position"][0, 0].tolist() == pytest.approx([10.06, 10.0], abs=1e-5)


def test_env_heading_kept_below_threshold(make_env, place, step_with):
    # tau_v = 10: a command of speed 1 at heading + pi/2 gives v = 0.2/10 * 1 = 0.02 < 0.05.
    env = make_env("s1", n_uavs=1, tau_v=10.0)
    place(env, [[[10.0, 10.0]]], [[0.4]], [[70.0, 70.0]])
    out = step_with(env, [[[1.0, -1.0]]])
    assert out["agents", "heading"][0, 0].item() == pytest.approx(0.4)  # kept
    assert torch.linalg.vector_norm(out["agents", "velocity"][0, 0]).item() == pytest.approx(0.02, abs=1e-6)
    # tau_v = 1: v = 0.2 * 1 = 0.2 > 0.05 along 0.4 + pi/2 = 1.9708 -> the heading follows.
    env = make_env("s1", n_uavs=1, tau_v=1.0)
    place(env, [[[10.0, 10.0]]], [[0.4]], [[70.0, 70.0]])
    out = step_with(env, [[[1.0, -1.0]]])
    assert out["agents", "heading"][0, 0].item() == pytest.approx(0.4 + PI / 2, abs=1e-5)


def test_env_command_clipped_per_axis_in_velocity_mode(make_env, place, step_with):
    # action_mode "velocity": the action is the command itself; (3, -3) stays, and the per-axis
    # clip at v_max = 3 keeps the diagonal (3, 3) at norm 4.24 (not rescaled to 3).
    env = make_env("s1", n_uavs=2, action_mode="velocity")
    place(env, [[[10.0, 10.0], [20.0, 20.0]]], [[0.0, 0.0]], [[70.0, 70.0]])
    out = step_with(env, [[[3.0, -3.0], [3.0, 3.0]]])
    assert out["agents", "command"][0].tolist() == [[3.0, -3.0], [3.0, 3.0]]
    # v = 0.2 * (3, 3) = (0.6, 0.6)
    assert out["agents", "velocity"][0, 1].tolist() == pytest.approx([0.6, 0.6], abs=1e-6)


def test_env_policy_actions_clamped_to_unit_box(make_env, place, step_with):
    # An out-of-range policy action is clamped to [-1, 1] first: [5, 5] acts as [1, 1] -> (0, 3) at heading 0.
    env = make_env("s1", n_uavs=1)
    place(env, [[[10.0, 10.0]]], [[0.0]], [[70.0, 70.0]])
    out = step_with(env, [[[5.0, 5.0]]])
    assert out["agents", "command"][0, 0].tolist() == pytest.approx([0.0, 3.0], abs=1e-6)
