"""The 3-D world (docs/specification.md section 11).

The 2-D world is its exact special case: a 3-D scenario whose UAVs, goal and obstacles lie in
one plane (fixed altitude, unbounded cylinders and boxes), with climb disabled and one laser ring
at elevation 0, flown with a zero third action, gives the 2-D scenario's trajectories, rewards,
termination and metrics bit for bit, and its observation and state with the elevation and climb
entries inserted. Then hand-computed answers for the 3-D geometry, kinematics and instinct."""

import math

import imageio.v2 as imageio
import numpy as np
import pytest
import torch

from flock_torchrl import FlockingEnv
from flock_torchrl.config.compose import scenario_config
from flock_torchrl.config.scenario import FULL_HEIGHT, ConfigError
from flock_torchrl.config.scenario import Laser
from flock_torchrl.world.dynamics import action_to_command, clamp_altitude, update_attitude
from flock_torchrl.world.geometry import Obstacles, cast_rays_3d, distance_to_obstacles
from flock_torchrl.world.instinct import repulsion
from flock_torchrl.world.sensors import off_axis, planar_entries
from flock_torchrl.world.space import Space

# The plane lifted into space: every UAV, the goal and every obstacle at 10 m.
LIFTED = {"dims": 3, "climb_max": 0.0, "laser_rings": [0.0], "laser_vertical": False, "spawn_height": 0.0,
          "spawn_altitude": [10.0, 10.0], "goal_altitude": [10.0, 10.0]}
SCENARIOS = ["train", "s1", "s2", "s3", "s4", "s5"]


def _pair(scenario: str, reading: str, policy: str, num_envs: int, compile_step: bool = False):
    if compile_step:  # a fresh compiler per case: one process compiles the step for many worlds
        torch.compiler.reset()
    kwargs = dict(num_envs=num_envs, seed=3, reading=reading, policy_id=policy, extras="all", compile_step=compile_step)
    return FlockingEnv(scenario, **kwargs), FlockingEnv(scenario, **kwargs, **LIFTED)


def _equal(x: torch.Tensor, y: torch.Tensor, key, exact: bool) -> None:
    """Bit for bit (NaN where NaN), or, compiled, within float round-off with discrete values equal.

    Compiled, the plane and space are two graphs: the compiler vectorises and fuses their
    transcendental functions differently, so they agree to float round-off only (within the tolerances of
    tests/test_equivalence.py), while every flag, index and count stays identical."""
    if exact or x.dtype in (torch.bool, torch.long):
        assert torch.equal(x.nan_to_num(-1.0) if x.is_floating_point() else x,
                           y.nan_to_num(-1.0) if y.is_floating_point() else y), key
    else:
        torch.testing.assert_close(x, y, atol=3e-2 if key == "scan" else 3e-3, rtol=0, equal_nan=True,
                                   msg=lambda m: f"{key}: {m}")


def _assert_special_case(flat: FlockingEnv, lifted: FlockingEnv, steps: int, seed: int = 0) -> int:
    """Reset both, fly ``steps`` steps of the same random actions; every quantity bit for bit (eager).
    Returns how many UAV-steps flew the instinct's command (so a test can ask that it was exercised)."""
    obs_keep = planar_entries(lifted.cfg)
    state_keep = planar_entries(lifted.cfg, critic=True)
    generator = torch.Generator().manual_seed(seed)
    exact = not flat.compile_step
    a, b = flat.reset(), lifted.reset()
    instinct = 0

    def same(x, y):
        _equal(x["agents", "observation"], y["agents", "observation"][..., obs_keep], "observation", exact)
        _equal(x["agents", "state"], y["agents", "state"][..., state_keep], "state", exact)
        _equal(x["agents", "position"], y["agents", "position"][..., :2], "position", exact)
        assert bool((y["agents", "position"][..., 2] == 10.0).all())
        _equal(x["agents", "velocity"], y["agents", "velocity"][..., :2], "velocity", exact)
        _equal(x["agents", "heading"], y["agents", "heading"], "heading", exact)
        assert bool((y["agents", "climb"] == 0).all())
        _equal(x["agents", "scan"], y["agents", "scan"], "scan", exact)
        _equal(x["agents", "scan_obstacle"], y["agents", "scan_obstacle"], "scan_obstacle", exact)
        _equal(x["goal"], y["goal"][..., :2], "goal", exact)
        for key in x["episode"].keys():
            _equal(x["episode", key], y["episode", key], ("episode", key), exact)

    same(a, b)
    for _ in range(steps):
        action = torch.rand(flat.num_envs, flat.n_agents, 2, generator=generator) * 2 - 1
        a["agents", "action"] = action
        b["agents", "action"] = torch.cat((action, torch.zeros_like(action[..., :1])), -1)
        a, a_next = flat.step_and_maybe_reset(a)
        b, b_next = lifted.step_and_maybe_reset(b)
        for key in ("observation", "state", "reward", "position", "velocity", "heading", "scan", "command",
                    "instinct"):
            x, y = a["next", "agents", key], b["next", "agents", key]
            if key == "observation":
                y = y[..., obs_keep]
            elif key == "state":
                y = y[..., state_keep]
            elif key in ("position", "velocity", "command"):
                y = y[..., :2]
            _equal(x, y, key, exact)
        assert torch.equal(a["next", "done"], b["next", "done"])
        instinct += int(a["next", "agents", "instinct"].sum())
        same(a_next, b_next)
        a, b = a_next, b_next
    return instinct


# The training scenario under both readings, S4's noise and S5's moving obstacles in the fast tier; the rest in
# the full one.
FAST_SPECIAL_CASES = {("train", "literal"), ("train", "paper_fit"), ("s4", "literal"), ("s5", "paper_fit")}


@pytest.mark.parametrize("scenario, reading", [
    (s, r) if (s, r) in FAST_SPECIAL_CASES else pytest.param(s, r, marks=pytest.mark.slow)
    for s in SCENARIOS for r in ("literal", "paper_fit")])
def test_the_plane_is_the_special_case_of_space_eager(scenario, reading):
    flat, lifted = _pair(scenario, reading, "policy3_g", num_envs=6)
    assert lifted.obs_dim == 27 and lifted.state_dim == 32 and flat.obs_dim == 17
    assert _assert_special_case(flat, lifted, steps=40) > 0  # the instinct was exercised


@pytest.mark.parametrize("policy", ["policy4_g", "policy5_g", "policy1"])
def test_the_special_case_holds_for_every_sensing_variant(policy):
    flat, lifted = _pair("train", "paper_fit", policy, num_envs=4)
    _assert_special_case(flat, lifted, steps=25, seed=1)


def test_the_special_case_holds_for_the_rule_based_baselines_velocity_commands():
    kwargs = dict(num_envs=3, seed=2, reading="literal", policy_id="policy_ma", extras="all")
    flat, lifted = FlockingEnv("s5", **kwargs), FlockingEnv("s5", **kwargs, **LIFTED)
    a, b = flat.reset(), lifted.reset()
    generator = torch.Generator().manual_seed(4)
    for _ in range(20):
        command = (torch.rand(3, flat.n_agents, 2, generator=generator) * 2 - 1) * 3
        a["agents", "action"] = command
        b["agents", "action"] = torch.cat((command, torch.zeros_like(command[..., :1])), -1)
        a, _ = flat.step_and_maybe_reset(a)
        b, _ = lifted.step_and_maybe_reset(b)
        assert torch.equal(a["next", "agents", "reward"], b["next", "agents", "reward"])
        assert torch.equal(a["next", "agents", "position"], b["next", "agents", "position"][..., :2])


@pytest.mark.parametrize("scenario, reading", [pytest.param("train", "paper_fit", marks=pytest.mark.slow),
                                               ("s4", "literal")])
def test_the_special_case_holds_compiled(scenario, reading):
    flat, lifted = _pair(scenario, reading, "policy3_g", num_envs=4, compile_step=True)
    _assert_special_case(flat, lifted, steps=6)


@pytest.mark.slow
@pytest.mark.parametrize("reading", ["literal", "paper_fit"])
@pytest.mark.parametrize("scenario", SCENARIOS)
def test_the_special_case_holds_compiled_on_every_scenario(scenario, reading):
    flat, lifted = _pair(scenario, reading, "policy3_g", num_envs=4, compile_step=True)
    _assert_special_case(flat, lifted, steps=30)


def test_space_compiled_matches_eager():
    """The compiled 3-D step is the eager one's twin (up to float reordering), in a world that climbs."""
    torch.compiler.reset()
    kwargs = dict(num_envs=4, seed=0, reading="paper_fit", policy_id="policy3_g", extras="all")
    eager = FlockingEnv("train3d", **kwargs)
    compiled = FlockingEnv("train3d", **kwargs, compile_step=True)
    a, b = eager.reset(), compiled.reset()
    generator = torch.Generator().manual_seed(0)
    for _ in range(5):
        action = torch.rand(4, 5, 3, generator=generator) * 2 - 1
        a["agents", "action"], b["agents", "action"] = action, action.clone()
        a, _ = eager.step_and_maybe_reset(a)
        b, _ = compiled.step_and_maybe_reset(b)
        torch.testing.assert_close(a["next", "agents", "position"], b["next", "agents", "position"], atol=1e-4, rtol=0)
        torch.testing.assert_close(a["next", "agents", "reward"], b["next", "agents", "reward"], atol=1e-4, rtol=0)


# ---------------------------------------------------------------------------- hand-computed answers
def test_action_to_command_in_space():
    # a = (0, 1, 1): straight on at V = 3 m/s, climbing at gamma_max = 30 deg: (3 cos 30, 0, 3 sin 30).
    command = action_to_command(torch.tensor([[0.0, 1.0, 1.0]]), torch.tensor([0.0]), Space(climb_max=math.pi / 6))
    torch.testing.assert_close(command, torch.tensor([[3 * math.sqrt(3) / 2, 0.0, 1.5]]))
    # a0 = 1 turns by 90 deg; a2 = -1 dives.
    command = action_to_command(torch.tensor([[1.0, -1.0, -1.0]]), torch.tensor([0.0]), Space(climb_max=math.pi / 6))
    torch.testing.assert_close(command, torch.tensor([[0.0, math.sqrt(3) / 2, -0.5]]), atol=1e-6, rtol=0)


def test_attitude_and_altitude_limits():
    heading, climb = update_attitude(torch.tensor([0.3]), torch.tensor([0.0]), torch.tensor([[0.0, 1.0, 1.0]]), 0.05)
    torch.testing.assert_close(heading, torch.tensor([math.pi / 2]))
    torch.testing.assert_close(climb, torch.tensor([math.pi / 4]))
    # Straight up: the heading is kept (no horizontal speed), the climb is +90 deg.
    heading, climb = update_attitude(torch.tensor([0.3]), torch.tensor([0.0]), torch.tensor([[0.0, 0.0, 2.0]]), 0.05)
    assert heading.item() == pytest.approx(0.3) and climb.item() == pytest.approx(math.pi / 2)
    position, velocity = clamp_altitude(torch.tensor([[1.0, 2.0, 31.0], [0.0, 0.0, 5.0]]),
                                        torch.tensor([[1.0, 0.0, 2.0], [0.0, 0.0, -1.0]]), 0.5, 30.0)
    assert position.tolist() == [[1.0, 2.0, 30.0], [0.0, 0.0, 5.0]]
    assert velocity.tolist() == [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]


def _one(t):
    return t[None]


def test_rays_hit_finite_cylinders_boxes_and_spheres():
    # A cylinder of radius 1 at (5, 0) from z = 0 to 2; a box 2 x 2 at (0, 5), z 0-2; a sphere r 1 at (0, 0, 5).
    obstacles = Obstacles(_one(torch.tensor([[5.0, 0.0, 1.0, 0.0, 2.0]])),
                          _one(torch.tensor([[0.0, 5.0, 2.0, 2.0, 0.0, 2.0]])),
                          _one(torch.tensor([[0.0, 0.0, 5.0, 1.0]])))
    origin = torch.tensor([[[0.0, 0.0, 1.0]]])
    # Beams: level along +x (hits the cylinder at 4), level along +y (box at 4), up 45 deg along +x
    # (passes over the cylinder: at horizontal distance 4 it is at z = 5), straight-ish up (sphere).
    e = torch.tensor([0.0, 0.0, math.pi / 4, 1.5])
    horizontal = torch.tensor([[[[1.0, 0.0], [0.0, 1.0], [1.0, 0.0], [1.0, 0.0]]]])
    for static_shapes in (False, True):
        d, idx = cast_rays_3d(origin, horizontal, torch.cos(e), torch.sin(e), obstacles, 10.0, static_shapes)
        assert d[0, 0, 0].item() == pytest.approx(4.0) and idx[0, 0, 0].item() == 0
        assert d[0, 0, 1].item() == pytest.approx(4.0) and idx[0, 0, 1].item() == 1
        assert d[0, 0, 2].item() == pytest.approx(10.0) and idx[0, 0, 2].item() == -1
        # The near-vertical beam meets the sphere: |o + t u - c| = 1 with o - c = (0, 0, -4), so
        # t = 4 sin 1.5 - sqrt(16 sin^2 1.5 - 15).
        expected = 4 * math.sin(1.5) - math.sqrt(16 * math.sin(1.5) ** 2 - 15)
        assert idx[0, 0, 3].item() == 2 and d[0, 0, 3].item() == pytest.approx(expected, abs=1e-5)
    # Signed distances: 1 m above the cylinder's top edge at its axis; inside the box; 1 m under the sphere.
    points = torch.tensor([[[5.0, 0.0, 3.0], [0.0, 5.0, 1.0], [0.0, 0.0, 3.0]]])
    d = distance_to_obstacles(points, obstacles, Space())[0]
    assert d[0, 0].item() == pytest.approx(1.0) and d[1, 1].item() == pytest.approx(-1.0)
    assert d[2, 2].item() == pytest.approx(1.0)
    # A corner: 1 m beyond the cylinder's rim and 1 m above its top: sqrt(2).
    d = distance_to_obstacles(torch.tensor([[[7.0, 0.0, 3.0]]]), obstacles, Space())[0]
    assert d[0, 0].item() == pytest.approx(math.sqrt(2))


def test_the_camera_is_a_cone_about_the_direction_of_flight():
    # Level flight along +x; a UAV straight above is 90 deg off axis; climbing at 90 deg it is on axis.
    assert off_axis(torch.tensor(0.0), torch.tensor(math.pi / 2), torch.tensor(0.0)).item() == pytest.approx(
        math.pi / 2)
    assert off_axis(torch.tensor(0.0), torch.tensor(math.pi / 2), torch.tensor(math.pi / 2)).item() == pytest.approx(
        0.0, abs=1e-6)
    # 60 deg to the side and 30 deg up, level flight: cos theta = cos 60 cos 30 -> theta = acos(sqrt(3) / 4).
    theta = off_axis(torch.tensor(math.pi / 3), torch.tensor(math.pi / 6), torch.tensor(0.0)).item()
    assert theta == pytest.approx(math.acos(math.sqrt(3) / 4), abs=1e-6)
    # Level and in the plane it is |alpha| exactly.
    assert off_axis(torch.tensor(-0.7), torch.tensor(0.0), torch.tensor(0.0)).item() == torch.tensor(0.7).item()


def test_the_tangential_term_leads_towards_the_goal_in_space():
    # A neighbour 1 m ahead (+x) within r0 = 5: v_r = 1 * (5 - 1) * (-1, 0, 0) = (-4, 0, 0). The goal
    # lies straight up and ahead, (10, 0, 10): its part orthogonal to v_r is (0, 0, 10), so v_t = (0, 0, 4).
    v = repulsion(torch.tensor([[[[1.0, 0.0, 0.0]]]]), torch.tensor([[[True]]]), torch.tensor([[[10.0, 0.0, 10.0]]]),
                  1.0, 5.0, space=Space())
    torch.testing.assert_close(v, torch.tensor([[[-4.0, 0.0, 4.0]]]))
    # Level goal: the 2-D answer, v_r turned by +-90 deg towards the goal (here +y).
    v = repulsion(torch.tensor([[[[1.0, 0.0, 0.0]]]]), torch.tensor([[[True]]]), torch.tensor([[[10.0, 3.0, 0.0]]]),
                  1.0, 5.0, space=Space())
    torch.testing.assert_close(v, torch.tensor([[[-4.0, -4.0, 0.0]]]) * torch.tensor([1.0, -1.0, 1.0]))
    # Without the tangential term only the radial push.
    v = repulsion(torch.tensor([[[[0.0, 0.0, -2.0]]]]), torch.tensor([[[True]]]), torch.tensor([[[10.0, 0.0, 0.0]]]),
                  1.0, 5.0, tangential=False, space=Space())
    torch.testing.assert_close(v, torch.tensor([[[0.0, 0.0, 3.0]]]))


def test_the_tapered_tangential_term_fades_on_the_line_of_the_push():
    # A neighbour 1 m ahead (+x): v_r = (-4, 0, 0). The goal 10 m behind the neighbour's side of the
    # line, 1.2 cm below it, (-10, 0, -0.012): g_perp = (0, 0, -0.012), |g| = sqrt(100 + 0.012^2).
    head_on = torch.tensor([[[-10.0, 0.0, -0.012]]])
    ahead = (torch.tensor([[[[1.0, 0.0, 0.0]]]]), torch.tensor([[[True]]]))
    # Untapered (taper 0, the shipped checkpoints): |v_t| = |v_r| straight down, whatever 1.2 cm says.
    torch.testing.assert_close(repulsion(*ahead, head_on, 1.0, 5.0, space=Space()), torch.tensor([[[-4.0, 0.0, -4.0]]]))
    # Tapered by 15 deg: |v_t| = 4 * 0.012 / (sin 15 deg * 10.0000072) = 0.0185461, still downward.
    taper = math.pi / 12
    v_t = 4 * 0.012 / (math.sin(taper) * math.sqrt(100 + 0.012 ** 2))
    torch.testing.assert_close(repulsion(*ahead, head_on, 1.0, 5.0, taper=taper, space=Space()),
                               torch.tensor([[[-4.0, 0.0, -v_t]]]), atol=1e-6, rtol=0)
    # A goal 1.2 cm *above* the line gives the mirror image: the push is continuous through the line.
    above = repulsion(*ahead, head_on * torch.tensor([1.0, 1.0, -1.0]), 1.0, 5.0, taper=taper, space=Space())
    torch.testing.assert_close(above, torch.tensor([[[-4.0, 0.0, v_t]]]), atol=1e-6, rtol=0)
    # On the line (the tie), no tangential part for any v_r, here a slanted one.
    slanted = torch.tensor([[[[1.0, 0.5, -2.0]]]])
    radial = repulsion(slanted, ahead[1], -3 * slanted[0], 1.0, 5.0, tangential=False, space=Space())
    torch.testing.assert_close(repulsion(slanted, ahead[1], -3 * slanted[0], 1.0, 5.0, taper=taper, space=Space()),
                               radial)
    # Outside the taper (the goal 90 deg off the line, (0, 10, 1)) the full length, as untapered:
    # v_t = 4 (0, 10, 1) / sqrt(101).
    side = torch.tensor([[[0.0, 10.0, 1.0]]])
    expected = torch.tensor([[[-4.0, 40.0 / math.sqrt(101), 4.0 / math.sqrt(101)]]])
    for t in (0.0, taper):
        torch.testing.assert_close(repulsion(*ahead, side, 1.0, 5.0, taper=t, space=Space()), expected)
    # Level push and goal: section 3's planar term at full length, even inside the taper (the 2-D case).
    level = torch.tensor([[[-10.0, 0.01, 0.0]]])
    torch.testing.assert_close(repulsion(*ahead, level, 1.0, 5.0, taper=taper, space=Space()),
                               torch.tensor([[[-4.0, 4.0, 0.0]]]))


def test_the_vertical_beam_pair_reads_the_clearance_above_and_below():
    from flock_torchrl.world.instinct import instinct_command
    from flock_torchrl.world.laser import laser_scan, scan_observation, shortest_beams
    from flock_torchrl.world.sensors import near_neighbours

    # wall3d's wall (y 38-42 m, z 4-20 m); one UAV 2 m under it at (40, 40, 2), level, heading +x.
    wall = Obstacles(_one(torch.zeros(0, 5)), _one(torch.tensor([[40.0, 40.0, 2000.0, 4.0, 4.0, 20.0]])),
                     _one(torch.zeros(0, 4)))
    position, heading = torch.tensor([[[40.0, 40.0, 2.0]]]), torch.zeros(1, 1)
    rings = (-math.pi / 6, 0.0, math.pi / 6)
    for vertical, nearest, index in ((False, 4.0, None), (True, 2.0, 109)):
        laser = Laser(36, rings, vertical)
        for static_shapes in (False, True):
            beams, _ = laser_scan(position, heading, wall, 36, 10.0, static_shapes, Space(laser=laser))
            assert beams.shape[-1] == laser.count == 108 + 2 * vertical
            # The +30 deg ring meets the underside 2 / sin 30 deg = 4 m away: twice the clearance.
            assert beams[0, 0, :108].min().item() == pytest.approx(4.0, abs=1e-5)
            d, at = shortest_beams(beams, 3)
            assert d[0, 0, 0].item() == pytest.approx(nearest, abs=1e-5)
        if vertical:  # straight up: 2 m; straight down: nothing (the ground is not an obstacle)
            assert at[0, 0, 0].item() == index and beams[0, 0, 108].item() == 10.0
            slot = scan_observation(beams, 3, 10.0, (d, at), Space(laser=laser))[0, 0, :3]
            torch.testing.assert_close(slot, torch.tensor([0.2, 0.0, 0.5]))
            # The instinct's virtual UAV 2 m above pushes straight down: (5 - 2) (0, 0, -1).
            alone = near_neighbours(position, heading, 5.0, math.pi / 2, space=Space(climb=torch.zeros(1, 1)))[0]
            on, command = instinct_command(position, heading, torch.tensor([[0.0, 40.0, 2.0]]), beams, alone,
                                           gain=1.0, r0=5.0, safe_distance=2.0, tangential=False,
                                           space=Space(laser=laser))
            assert on.item() and command[0, 0].tolist() == pytest.approx([0.0, 0.0, -3.0], abs=1e-6)


def test_config_checks_name_the_field():
    with pytest.raises(ConfigError, match="scenario.dims"):
        scenario_config("train", dims=4)
    with pytest.raises(ConfigError, match="scenario.spheres"):
        scenario_config("train", spheres=[[1.0, 2.0, 3.0, 1.0]])  # needs dims: 3
    with pytest.raises(ConfigError, match="scenario.laser_rings"):
        scenario_config("train", dims=3, laser_rings=[1.6])
    with pytest.raises(ConfigError, match="scenario.spawn_altitude"):
        scenario_config("train", dims=3, spawn_altitude=[40.0, 45.0])
    cfg = scenario_config("train", dims=3)
    assert cfg.circles == [[40.0, 40.0, 6.0, -FULL_HEIGHT, FULL_HEIGHT]] and cfg.n_laser == 110
    with pytest.raises(ConfigError, match="scenario.tangential_taper"):
        scenario_config("train", dims=3, tangential_taper=2.0)


# ---------------------------------------------------------------------------- the 3-D env, end to end
@pytest.mark.parametrize("scenario, overrides", [("train3d", {}), ("forest3d", {}), ("wall3d", {}),
                                                 ("s5", {"dims": 3}), ("s4", {"dims": 3, "spawn_height": 2.0})])
def test_check_env_specs_in_space(scenario, overrides):
    from torchrl.envs.utils import check_env_specs

    env = FlockingEnv(scenario, num_envs=3, seed=0, extras="all", **overrides)
    check_env_specs(env)
    td = env.rollout(4)
    assert td["agents", "action"].shape[-1] == 3 and td["agents", "position"].shape[-1] == 3
    assert td["agents", "scan"].shape[-1] == 110  # three rings of 36 and the vertical pair


@pytest.mark.slow
def test_space_spawns_in_altitude_and_keeps_the_limits():
    env = FlockingEnv("train3d", num_envs=64, seed=0, extras="physics")
    td = env.reset()
    z = td["agents", "position"][..., 2]
    # Each start within +-1.5 m of its swarm's altitude, drawn in [8, 12] m.
    assert float((z.amax(-1) - z.amin(-1)).max()) <= 3.0 + 1e-5
    assert bool(((z >= 8 - 1.5 - 1e-5) & (z <= 12 + 1.5 + 1e-5)).all())
    assert z.std() > 0.3 and bool(((td["goal"][:, 2] >= 8) & (td["goal"][:, 2] <= 12)).all())
    # Climbing at full command for 100 s never leaves [ground, ceiling].
    for _ in range(150):
        td["agents", "action"] = torch.tensor([0.0, 1.0, 1.0]).expand(64, 5, 3).clone()
        td, _ = env.step_and_maybe_reset(td)
        assert float(td["next", "agents", "position"][..., 2].max()) <= 30.0


@pytest.mark.slow
def test_wall3d_can_only_be_passed_over_or_under():
    """The box spans the area: flying level into it crashes; the starts face it from the north."""
    env = FlockingEnv("wall3d", num_envs=32, seed=0, extras="physics")
    td = env.reset()
    assert bool((td["agents", "position"][..., 1] > 60).all()) and bool((td["goal"][:, 1] < 20).all())
    crashed = torch.zeros(32, dtype=torch.bool)
    for _ in range(100):
        # Steer straight at the goal, level (a2 = 0): o_g's azimuth over pi is alpha_g / pi.
        turn = (2 * td["agents", "observation"][..., 1]).clamp(-1, 1)
        td["agents", "action"] = torch.stack((turn, torch.ones_like(turn), torch.zeros_like(turn)), -1)
        stepped, td = env.step_and_maybe_reset(td)
        crashed |= stepped["next", "episode", "crashed"]
        assert not bool(stepped["next", "episode", "reached"].any())
    assert bool(crashed.all())


def test_packed_and_static_sensing_agree_in_space():
    """The eager step's pruning (pairs within camera range, obstacles within laser range) and the
    compiled step's every-pair measurement give the same 3-D sensing."""
    from flock_torchrl.world.step import sense

    env = FlockingEnv("forest3d", num_envs=4, seed=1, n_uavs=20, policy_id="policy3_g", spawn_height=6.0,
                      spawn_altitude=[9.0, 11.0])
    env.reset()
    state = {k: env.world[k] for k in env.world.keys() if k not in ("episode", "sensed")}
    packed = sense(state, env._static, env.cfg, static_shapes=False)
    full = sense(state, env._static, env.cfg, static_shapes=True)
    for key in packed:
        if packed[key].dtype in (torch.bool, torch.long):
            assert torch.equal(packed[key], full[key]), key
        else:
            torch.testing.assert_close(packed[key], full[key], atol=1e-5, rtol=0, msg=key)


@pytest.mark.parametrize("policy", ["policy_ma", "policy_op"])
def test_the_baselines_fly_in_space(policy):
    from flock_torchrl import make_policy

    env = FlockingEnv("train3d", num_envs=2, seed=0, policy_id=policy, extras=("physics", "laser"))
    td = env.rollout(30, policy=make_policy(policy, env))
    command = td["agents", "action"]
    assert command.shape[-1] == 3 and bool(torch.isfinite(command).all())
    assert float(command[..., 2].abs().max()) > 0  # they steer in altitude (towards the goal's)


def test_baseline_sensing_in_space_by_hand():
    from flock_torchrl.policies.baselines.sensing import nearest_hits, neighbour_view
    from flock_torchrl.policies.baselines.vasarhelyi import repulsion as op_repulsion

    # Beam 1 of ring 1 (rings at 0 and +30 deg, 4 beams each: index 4 + 1) hits obstacle 0 at 2 m,
    # heading 0: the hit is 2 (cos 30 cos 90, cos 30 sin 90, sin 30) = (0, sqrt 3, 1) m away.
    scan = torch.full((1, 1, 8), 10.0)
    scan[0, 0, 5] = 2.0
    ids = torch.full((1, 1, 8), -1)
    ids[0, 0, 5] = 0
    view = nearest_hits(scan, ids, torch.zeros(1, 1), 1, space=Space(laser=Laser(4, (0.0, math.pi / 6))))
    torch.testing.assert_close(view.offset[0, 0, 0], torch.tensor([0.0, math.sqrt(3), 1.0]), atol=1e-6, rtol=0)
    torch.testing.assert_close(view.normal[0, 0, 0], -torch.tensor([0.0, math.sqrt(3), 1.0]) / 2, atol=1e-6, rtol=0)
    # A UAV 1 m straight above another, both climbing at 90 deg: each sees the other only if it is
    # ahead of it; the lower one sees the upper one (on axis), and is pushed down by it.
    position = torch.tensor([[[0.0, 0.0, 10.0], [0.0, 0.0, 11.0]]])
    seen = neighbour_view(position, torch.zeros(1, 2, 3), torch.zeros(1, 2), 5.0, math.pi / 4,
                          space=Space(climb=torch.full((1, 2), math.pi / 2)))
    assert seen.visible[0].tolist() == [[False, True], [False, False]]
    push = op_repulsion(seen.offset, seen.distance, seen.visible, 1.0, 5.0)
    torch.testing.assert_close(push[0, 0], torch.tensor([0.0, 0.0, -4.0]))


def test_a_3d_episode_renders_as_top_and_side_views_and_a_gif(tmp_path):
    from flock_torchrl.report.figures import save_animation

    env = FlockingEnv("wall3d", num_envs=1, seed=0, extras="physics")
    env.reset()
    img = env.render(size=(200, 400))
    assert img.shape == (200, 400, 3) and img.dtype == np.uint8
    red = (img[..., 0] > 180) & (img[..., 1] < 120) & (img[..., 2] < 120)
    assert red[:, :200].any() and red[:, 220:].any()  # the wall in the top view and in the side view
    td = env.rollout(12, break_when_any_done=False)
    gif = save_animation(td, env, tmp_path / "wall3d.gif", size=(100, 200), stride=4)
    frames = imageio.mimread(gif)
    assert len(frames) == 4 and frames[0].shape[:2] == (100, 200)


def test_the_3d_benchmark_rows_run():
    """The rows `make benchmark` prints for the 3-D step (figures are read there, never asserted)."""
    from benchmarks.threed import threed_lines

    lines = threed_lines(batch=4, n_uavs=5, rounds=1, compiled=False, steps=1, print_each=False)
    assert len(lines) == 3 and all("us per UAV-step" in line for line in lines)
    assert "1.00x the 2-D step" in lines[0]


# ---------------------------------------------------------------------------- learning in space, through the apps
TINY_3D = ("experiment=tiny", "scenario=train3d", "experiment.max_frames=64",
           "experiment.eval_every_frames=0", "experiment.eval_episodes=1", "scenario.max_steps=20", "progress=false")


@pytest.mark.parametrize("overrides, expected", [
    ((), -2.0), (("scenario=forest",), -2.0), (("experiment=mixed",), -2.0), (("scenario=train3d",), -3.0),
    (("scenario=wall3d", "policy=policy2_g"), -3.0), (("scenario=train3d", "algo.target_entropy=-1.5"), -1.5)])
def test_sac_target_entropy_is_minus_the_action_dimension(overrides, expected):
    """Table I's H-bar = -2 is -|A| in the plane; in space the action has three numbers (section 11)."""
    from flock_torchrl.config import compose
    from flock_torchrl.config.learners import sac_target_entropy

    cfg = compose("train", list(overrides))
    value = cfg.algo.target_entropy
    assert value == expected and isinstance(value, float)
    # The 2-D value is the same float as Table I's literal -2.0 of every run trained before.
    assert (sac_target_entropy(2), sac_target_entropy(3)) == (-2.0, -3.0)
    assert str(sac_target_entropy(2)) == "-2.0"


@pytest.mark.slow
def test_policy3_g_trains_in_space_through_the_train_app(tmp_path):
    from helpers import run_script

    from flock_torchrl import load_policy
    from flock_torchrl.world.env import FlockingEnv as Env

    run = tmp_path / "run"
    run_script("train.py", *TINY_3D, f"hydra.run.dir={run}", cwd=tmp_path)
    policy = load_policy(run / "last.pt")
    assert policy.dims == 3 and policy.flock_meta["scenario"]["dims"] == 3
    assert "target_entropy: -3.0" in (run / "config.yaml").read_text()   # -|A| without an override
    env = Env("wall3d", num_envs=2, seed=0, reading=policy.flock_meta["reading"], policy_id="policy3_g")
    td = env.rollout(5, policy=policy)
    assert td["agents", "action"].shape[-1] == 3


@pytest.mark.slow
def test_a_3d_checkpoint_evaluates_on_3d_scenarios_and_is_refused_on_2d_ones(tmp_path):
    from helpers import run_script

    run = tmp_path / "run"
    run_script("train.py", *TINY_3D, f"hydra.run.dir={run}", cwd=tmp_path)
    proc = run_script("evaluate.py", f"checkpoint={run / 'last.pt'}", "scenario=forest3d", "episodes=2", "max_steps=10",
                      f"hydra.run.dir={tmp_path / 'eval'}", cwd=tmp_path)
    assert (tmp_path / "eval" / "summary.json").is_file(), proc.stdout
    proc = run_script("evaluate.py", f"checkpoint={run / 'last.pt'}", "scenario=train", "episodes=2", "max_steps=10",
                      f"hydra.run.dir={tmp_path / 'eval2d'}", cwd=tmp_path, check=False)
    assert proc.returncode != 0 and "scenario.dims" in proc.stdout + proc.stderr


def test_the_3d_table_pools_seeds_by_hand():
    from flock_torchrl.report.threed import COLUMNS, pooled_rows, published_markdown

    def row(policy, success, d_min_uav, checkpoint):
        values = dict.fromkeys(COLUMNS, 1.0) | {"success_rate": success, "d_min_uav": d_min_uav, "t_goal": math.nan}
        return {"scenario": "wall3d", "policy": policy, "checkpoint": checkpoint, "n_episodes": 10, **values}

    rows = [row("Policy3-G", 0.2, 1.0, "a/seed0.pt"), row("Policy3-G", 0.4, 2.0, "a/seed1.pt"),
            row("Policy-OP", 0.0, 1.5, "baseline:policy_op")]
    pooled = {r["policy"]: r for r in pooled_rows(rows)}
    # Two seeds: the mean of their scores, inside its interval over seeds; one score: no interval (rates in %).
    mine = pooled["Policy3-G"]
    assert mine["seeds"] == 2 and mine["episodes"] == 20
    assert mine["success_rate"] == pytest.approx(0.3) and mine["d_min_uav"] == pytest.approx(1.5)
    assert mine["success_rate_low"] <= 0.3 <= mine["success_rate_high"]
    assert pooled["Policy-OP"]["d_min_uav"] == 1.5 and math.isnan(pooled["Policy-OP"]["d_min_uav_low"])
    assert math.isnan(mine["t_goal"])
    text = published_markdown(rows, "make publish-threed")
    assert "| wall3d | Policy-OP | 1 | 10 | 0.0 | 100.0 | 1.000 | 1.500 |" in text and text.rstrip().endswith("|")


@pytest.mark.slow
def test_episode_gifs_of_a_3d_scenario(tmp_path):
    from flock_torchrl.report.threed import episode_gifs

    (gif,) = episode_gifs(tmp_path, "policy_op", ("wall3d",), size=(100, 200), stride=100)
    frames = imageio.mimread(gif)
    assert gif.name == "wall3d_policy_op.gif" and len(frames) >= 2 and frames[0].shape[:2] == (100, 200)


# ---------------------------------------------------------------------------- shipping and publishing the 3-D runs
@pytest.fixture(scope="module")
def tiny_3d_run(tmp_path_factory):
    """One finished tiny Policy3-G run on train3d, trained through the train app."""
    from helpers import run_script

    tmp = tmp_path_factory.mktemp("run3d")
    run_script("train.py", *TINY_3D, f"hydra.run.dir={tmp / 'run'}", cwd=tmp)
    return tmp / "run"


@pytest.mark.slow  # a tiny 3-D training and two runs of scripts/ship.py (~10 s)
def test_make_ship_threed_ships_the_3d_runs_alone_under_both_folder_names(tiny_3d_run, tmp_path, monkeypatch):
    import shutil

    from helpers import run_script

    from flock_torchrl import load_policy

    runs, ckpts = tmp_path / "runs" / "threed", tmp_path / "checkpoints"
    folder = runs / "tiny" / "paper_fit" / "policy3_g"
    for name in ("seed0__scenario-train3d", "seed1__scenario-train3d",
                 "seed2", "seed3__algo.lr_actor-0.1__scenario-train3d"):   # the last two are not the collection's
        shutil.copytree(tiny_3d_run, folder / name)
    (ckpts / "paper_fit" / "policy3_g").mkdir(parents=True)
    (ckpts / "paper_fit" / "policy3_g" / "seed0.pt").write_bytes(b"a 2-D checkpoint, left alone")
    args = ("reading=paper_fit", "only=threed", f"scenario_collections.threed.runs_dir={runs}",
            "scenario_collections.threed.experiment=tiny", f"checkpoints_dir={ckpts}")
    run_script("ship.py", *args, cwd=tmp_path)
    dest = ckpts / "paper_fit" / "threed"
    assert sorted(p.relative_to(dest).as_posix() for p in dest.rglob("*.pt")) == ["policy3_g/seed0.pt",
                                                                                 "policy3_g/seed1.pt"]
    assert load_policy(dest / "policy3_g" / "seed1.pt").dims == 3
    manifest = (dest / "MANIFEST.md").read_text()
    assert manifest.count("| Policy3-G | ") == 2 and "| Policy3-G | 1 | tiny |" in manifest
    assert "`make ship-threed` (scripts/ship.py only=threed)" in manifest
    assert (ckpts / "paper_fit" / "policy3_g" / "seed0.pt").read_bytes() == b"a 2-D checkpoint, left alone"
    assert sorted(p.name for p in (ckpts / "paper_fit").iterdir()) == ["policy3_g", "threed"]
    # A collection of two names holding one seed under both: a conflict, one line, exit 2, nothing rewritten.
    shutil.copytree(tiny_3d_run, folder / "seed0__algo.target_entropy--3.0__scenario-train3d")
    before = {p: p.stat().st_mtime_ns for p in dest.rglob("*")}
    two_names = "scenario_collections.threed.names=[scenario-train3d,algo.target_entropy--3.0__scenario-train3d]"
    proc = run_script("ship.py", *args, two_names, cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "both hold policy3_g seed0" in proc.stderr, proc.stderr
    assert {p: p.stat().st_mtime_ns for p in dest.rglob("*")} == before
    # While another publication holds the folder (a make publish-... under way): one line, exit 2, nothing rewritten.
    from flock_torchrl.run.publication import Publication

    monkeypatch.chdir(tmp_path)   # the publication's root is the ship's: its working directory
    with Publication("a publication under way", [ckpts / "paper_fit"], log=lambda line: None):
        proc = run_script("ship.py", *args, cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("error: another publication is under way"), proc.stderr
    assert {p: p.stat().st_mtime_ns for p in dest.rglob("*")} == before


def test_a_scenario_collections_make_target_is_a_name_or_none():
    """conf/ship.yaml names the make target that ships each collection (its MANIFEST says so); a
    collection without one is shipped by the script alone; anything else is refused naming the key."""
    from flock_torchrl.config.compose import app_config

    spec = {"runs_dir": "runs", "experiment": "fast3d", "names": ["scenario-train3d"]}
    for target in ("ship-threed", None):
        cfg = app_config("ship", scenario_collections={"threed": {**spec, "target": target}})
        assert cfg.scenario_collections["threed"]["target"] == target
    assert "target" not in app_config("ship", scenario_collections={"threed": spec}).scenario_collections["threed"]
    with pytest.raises(ConfigError, match=r"scenario_collections\.threed\.target: the make target"):
        app_config("ship", scenario_collections={"threed": {**spec, "target": 3}})
    with pytest.raises(ConfigError, match=r"scenario_collections\.threed: must hold runs_dir"):
        app_config("ship", scenario_collections={"threed": {**spec, "made_by": "me"}})


@pytest.mark.slow
def test_ship_refuses_an_unknown_collection(tmp_path):
    from helpers import run_script

    proc = run_script("ship.py", "reading=paper_fit", "only=fourd", f"checkpoints_dir={tmp_path}", cwd=tmp_path,
                      check=False)
    assert proc.returncode != 0 and "only" in proc.stderr and "threed" in proc.stderr, proc.stderr


@pytest.mark.slow  # six shipped checkpoints flown and two GIFs drawn (~20 s)
def test_publish_threed_writes_the_table_verdicts_and_figures(tmp_path):
    """make publish-threed's writer on two episodes: the seeds' rows, the pooled table whose cells are
    the seeds' means with scipy's bootstrap interval, section 11's verdicts, the GIFs and the frames."""
    import csv

    from flock_torchrl.report.seeds import summarise
    from flock_torchrl.report.threed import publish
    from helpers import ROOT

    shipped = ROOT / "checkpoints" / "paper_fit" / "threed"
    seeds = [str(shipped / p / f"seed{k}.pt") for p in ("policy3_g", "policy2_g") for k in range(3)]
    results, figures = tmp_path / "results", tmp_path / "figures"
    # One scenario and small GIFs: make publish-threed's own settings otherwise.
    publish(seeds, results, figures, "paper_fit", 2, command="make publish-threed", scenarios=("wall3d",),
            gif_size=(60, 120), gif_stride=250)
    with (results / "table3_3d_seeds.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [(r["policy"], r["checkpoint"].rsplit("/", 2)[-2:]) for r in rows][:1] == [("Policy3-G", ["policy3_g", "seed0.pt"])]
    assert [r["policy"] for r in rows].count("Policy2-G") == 3 and rows[-1]["checkpoint"] == "baseline:policy_op"
    assert {r["n_episodes"] for r in rows} == {"2"} and {r["scenario"] for r in rows} == {"wall3d"}
    with (results / "table3_3d.csv").open() as handle:
        pooled = {r["policy"]: r for r in csv.DictReader(handle)}
    mine = [float(r["d_min_uav"]) for r in rows if r["policy"] == "Policy3-G"]
    m = summarise(mine)
    # The pooled table writes five decimals: within half its last digit.
    assert float(pooled["Policy3-G"]["d_min_uav"]) == pytest.approx(sum(mine) / 3, abs=5e-6)
    assert (float(pooled["Policy3-G"]["d_min_uav_low"]), float(pooled["Policy3-G"]["d_min_uav_high"])) == \
        pytest.approx((m.mean_low, m.mean_high), abs=5e-6)
    assert pooled["Policy-MA"]["seeds"] == "1" and pooled["Policy-MA"]["d_min_uav_low"] == ""
    text = (results / "table3_3d.md").read_text()
    for other in ("Policy2-G", "Policy-MA", "Policy-OP"):
        for metric in ("success_rate", "safe_success_rate", "d_min_uav"):
            assert f"| wall3d | Policy3-G above {other} | {metric} | 3 / {3 if other == 'Policy2-G' else 1} |" in text
    assert "make publish-threed" in text
    brief = (results / "table3_3d_brief.md").read_text()
    assert "| scenario | Policy3-G (3) | Policy2-G (3) | Policy-MA (1) | Policy-OP (1) | Policy3-G above" in brief
    assert brief.count("| wall3d | ") == 1 and len(brief.splitlines()) == 5
    names = sorted(p.name for p in figures.iterdir())
    assert names == ["threed_wall3d_frames.png", "threed_wall3d_policy3_g.gif", "threed_wall3d_policy_op.gif"]
    assert imageio.imread(figures / "threed_wall3d_frames.png").shape[:2] == (3 * 360, 720)
