"""Crash forensics and evaluation-time ablations (flock_torchrl/report/diagnosis.py, scripts/diagnose.py).

Hand-built scenes with answers worked out on paper (arithmetic in the comments), and one
control: the paper's instinct applied by the wrapper gives the built-in instinct's episodes.
"""

import math

import pytest
import torch
from helpers import first_fast, run_script

from flock_torchrl import scenario_config
from flock_torchrl.report.diagnosis import along, binomial_ci, crash_forensics, outward_normal, run_cell
from flock_torchrl.report.variants import crowd_instinct
from flock_torchrl.world.geometry import Obstacles
from flock_torchrl.world.laser import laser_scan
from flock_torchrl.world.sensors import Neighbours


def test_binomial_interval_is_clopper_pearson():
    # k = 0 of n = 10: upper bound 1 - 0.025^(1/10) = 1 - exp(ln 0.025 / 10) = 1 - exp(-0.368888) = 0.308497
    low, high = binomial_ci(0, 10)
    assert low == 0.0 and high == pytest.approx(0.308497, abs=1e-6)
    # k = n = 10: the mirror image
    low, high = binomial_ci(10, 10)
    assert low == pytest.approx(1 - 0.308497, abs=1e-6) and high == 1.0


def neighbours_of(offsets, visible):
    """Neighbours [1, 1, M] of one UAV at the origin with these world-frame offsets p_j - p_i."""
    off = torch.tensor(offsets, dtype=torch.float32)[None, None]
    dist = torch.linalg.vector_norm(off, dim=-1)
    zero = torch.zeros_like(dist)
    return Neighbours(dist, zero, zero, torch.tensor(visible)[None, None], off[..., 0].contiguous(),
                      off[..., 1].contiguous())


def scene(offsets, visible):
    """A UAV at the origin heading +x, the goal far along -y (so it plays no part in the radial
    terms), an obstacle 1 m ahead: beam 0 (straight ahead) returns 1 m, every other beam 10 m."""
    beams = torch.full((1, 1, 36), 10.0)
    beams[0, 0, 0] = 1.0
    return dict(position=torch.zeros(1, 1, 2), heading=torch.zeros(1, 1), goal=torch.tensor([[0.0, -50.0]]),
                beams=beams, neighbours=neighbours_of(offsets, visible), gain=1.0, r0=5.0, safe_distance=2.0,
                tangential=False)


def test_paper_instinct_of_a_crowd_pushes_a_uav_into_the_obstacle():
    # Neighbour 2 m behind (p_j - p_i = (-2, 0)): v_r = 1 (5 - 2) (p_i - p_j)/2 = 3 (1, 0) = (3, 0), toward
    # the obstacle. Virtual UAV at the return point (1, 0): 1 (5 - 1) (-1, 0) = (-4, 0). Sum (-1, 0).
    # The switch: min(d_uav1 = 2, d_scan1 = 1) = 1 <= 2.
    triggered, command, uav, obstacle = crowd_instinct(**scene([[-2.0, 0.0]], [True]), mode="paper")
    assert bool(triggered[0, 0])
    assert uav[0, 0].tolist() == pytest.approx([3.0, 0.0])
    assert obstacle[0, 0].tolist() == pytest.approx([-4.0, 0.0])
    assert command[0, 0].tolist() == pytest.approx([-1.0, 0.0])


def test_crowd_variants_by_hand():
    # Two neighbours behind, at 2 m and 4 m: (3, 0) + 1 (5 - 4) (4, 0)/4 = (3, 0) + (1, 0) = (4, 0).
    two = scene([[-2.0, 0.0], [-4.0, 0.0]], [True, True])
    assert crowd_instinct(**two, mode="paper")[2][0, 0].tolist() == pytest.approx([4.0, 0.0])
    # nearest k = 1: only the 2 m one pushes: (3, 0)
    assert crowd_instinct(**two, mode="nearest", k=1)[2][0, 0].tolist() == pytest.approx([3.0, 0.0])
    # saturated at 2.5 m/s: (4, 0) scaled to length 2.5
    assert crowd_instinct(**two, mode="saturated", cap=2.5)[2][0, 0].tolist() == pytest.approx([2.5, 0.0])
    # default cap gain (r0 - d_safe) = 3 m/s
    assert crowd_instinct(**two, mode="saturated")[2][0, 0].tolist() == pytest.approx([3.0, 0.0])
    # no_push_in: the outward normal of the seen obstacle is (-1, 0); (4, 0) . n = -4 < 0 is removed -> (0, 0),
    # and the command is the obstacle's own (-4, 0)
    _, command, uav, _ = crowd_instinct(**two, mode="no_push_in")
    assert uav[0, 0].tolist() == pytest.approx([0.0, 0.0]) and command[0, 0].tolist() == pytest.approx([-4.0, 0.0])
    # a neighbour to the side, (0, 2): v_r = 3 (0, -1) = (0, -3), orthogonal to n: kept as it is
    side = scene([[0.0, 2.0]], [True])
    assert crowd_instinct(**side, mode="no_push_in")[2][0, 0].tolist() == pytest.approx([0.0, -3.0])
    # an invisible neighbour never pushes
    assert crowd_instinct(**scene([[-2.0, 0.0]], [False]), mode="paper")[2][0, 0].tolist() == pytest.approx([0, 0])
    with pytest.raises(ValueError, match="mode"):
        crowd_instinct(**two, mode="bogus")


def test_outward_normal_and_components():
    # a circle of radius 1 at the origin; the point (0, 3) is 2 m above its surface: normal (0, 1)
    obstacles = Obstacles(torch.tensor([[[0.0, 0.0, 1.0]]]), torch.zeros(1, 0, 4))
    n = outward_normal(torch.tensor([[[0.0, 3.0]]]), obstacles)
    assert n[0, 0].tolist() == pytest.approx([0.0, 1.0], abs=1e-4)
    # (3, -4) along (0, 1): component -4, cosine -4/5
    comp, cos = along(torch.tensor([3.0, -4.0]), torch.tensor([0.0, 1.0]))
    assert float(comp) == pytest.approx(-4.0) and float(cos) == pytest.approx(-0.8)
    assert math.isnan(float(along(torch.zeros(2), torch.tensor([0.0, 1.0]))[1]))


def test_crash_forensics_of_a_hand_built_crash():
    # Circle (3, 0) r = 1: its surface at x = 2. UAV 0 at (1, 0) facing -x (heading pi), 1 m from it, with
    # UAV 1 at (-1, 0) 2 m ahead of it (bearing 0: visible). Its instinct: UAV part 1 (5 - 2) (2, 0)/2 =
    # (3, 0) -> along n = (-1, 0): -3 (into the obstacle); the obstacle part (the beam behind it returns
    # 1 m): 4 (-1, 0) -> +4; the tangential terms are orthogonal to n. The actor's action (0, 0): speed 2
    # along the heading (-1, 0) -> +2 along n. One window step, the crash then at (1.6, 0).
    cfg = scenario_config("train", reading="paper_fit", policy="policy3_g")
    obstacles = Obstacles(torch.tensor([[[3.0, 0.0, 1.0]]]), torch.zeros(1, 0, 4))
    position = torch.tensor([[[1.0, 0.0], [-1.0, 0.0]]])
    heading = torch.tensor([[math.pi, math.pi]])
    scan, _ = laser_scan(position, heading, obstacles, cfg.n_beams, cfg.laser_range)
    steps = {"position": position[:, None], "heading": heading[:, None], "scan": scan[:, None],
             "action": torch.zeros(1, 1, 2, 2), "instinct": torch.tensor([[[True, False]]]),
             "goal": torch.tensor([[-40.0, 0.0]]), "valid": torch.tensor([[True]])}
    out = crash_forensics(steps, torch.tensor([[[1.6, 0.0], [-0.5, 0.0]]]), obstacles, cfg)
    assert int(out["crasher"][0]) == 0
    expected = {"d_obstacle_last": 1.0, "d_scan1_last": 1.0, "nearest_uav_last": 2.0, "uavs_within_2m_last": 0.0,
                "uavs_within_r0_last": 1.0, "visible_uavs_last": 1.0, "camera_slots_filled_last": 1.0,
                "uavs_on_shortest_beam_last": 0.0, "heading_cos_last": 1.0, "instinct_on_last": 1.0,
                "instinct_uav_outward_last": -3.0, "instinct_uav_radial_outward_last": -3.0,
                "instinct_obstacle_outward_last": 4.0,
                "policy_outward_last": 2.0, "policy_cos_last": 1.0}
    for key, value in expected.items():
        assert float(out[key][0]) == pytest.approx(value, abs=1e-3), key
    # the UAV part's speed, with its tangential twin of the same length: 3 sqrt(2)
    assert float(out["instinct_uav_speed_last"][0]) == pytest.approx(3 * math.sqrt(2), abs=1e-4)


@pytest.mark.slow
def test_the_wrapped_paper_instinct_flies_the_built_in_one():
    """The control of every wrapper variant: the paper's instinct applied outside the world
    (instinct off, velocity commands) gives the same episodes as the world's own."""
    from flock_torchrl.policies.registry import resolve

    handle = resolve("checkpoints/paper_fit/policy3_g/seed0.pt", "paper_fit")[0]
    built_in = run_cell(handle, "forest", "paper_fit", 9, "paper", n_episodes=6)
    wrapped = run_cell(handle, "forest", "paper_fit", 9, "wrapped_paper", n_episodes=6)
    for key in ("success", "crashed", "steps", "d_min_uav"):
        assert torch.equal(built_in.episodes[key], wrapped.episodes[key]), key
    with pytest.raises(ValueError, match="variant"):
        run_cell(handle, "train", "paper_fit", 5, "nope", n_episodes=1)


@pytest.mark.slow
def test_the_tangential_off_variant_drops_only_eq_28():
    """Policy5-G's instinct has no tangential term: the variant flies its episodes unchanged.
    Policy3-G's has one: dropping it changes the episodes."""
    from flock_torchrl.policies.registry import resolve

    for policy, same in (("policy5_g", True), ("policy3_g", False)):
        handle = resolve(f"checkpoints/paper_fit/{policy}/seed0.pt", "paper_fit")[0]
        paper = run_cell(handle, "forest", "paper_fit", 9, "paper", n_episodes=4)
        radial = run_cell(handle, "forest", "paper_fit", 9, "tangential_off", n_episodes=4)
        assert torch.equal(paper.episodes["d_min_uav"], radial.episodes["d_min_uav"]) is same, policy


def test_the_instinct_wrapper_refuses_a_world_that_applies_its_own():
    from flock_torchrl.report.variants import InstinctWrapper

    cfg = scenario_config("train", reading="paper_fit", policy="policy3_g")  # instinct on, policy actions
    with pytest.raises(ValueError, match="instinct=False"):
        InstinctWrapper(lambda td: td, cfg, "paper")
    outside = scenario_config("train", reading="paper_fit", policy="policy3_g", instinct=False,
                              action_mode="velocity")
    assert InstinctWrapper(lambda td: td, outside, "no_push_in", math.pi).half_fov == math.pi
    assert InstinctWrapper(lambda td: td, outside, "no_push_in").half_fov == outside.half_fov


# ---------------------------------------------------------------------------- the app
@pytest.mark.parametrize("args, start", first_fast([
    (["sizes=[0]"], "error: sizes: must be an integer >= 1 and <= 2000, got 0"),
    (["sizes=[100000]"], "error: sizes: must be an integer >= 1 and <= 2000, got 100000"),
    (["episodes=0"], "error: episodes: must be an integer >= 1"),
    (["scenarios=[bogus]"], "error: scenarios: must be one of"),
    (["variants=[bogus]"], "error: variants: must be among paper,"),
    (["policies=[nope]"], "error: policies: must be one of policy3_g, mixed"),
    (["episodes=10000000"], "error: episodes: diagnosing 10000000 episodes at once needs about"),
    (["checkpoints_dir={tmp}/broken", "policies=[policy3_g]"], "error: {tmp}/broken/paper_fit/policy3_g/seed0.pt is "
                                                                "not a readable checkpoint"),
    (["hydra.run.dir={tmp}/a_file/out"], "error: hydra.run.dir: {tmp}/a_file/out cannot be made"),
]))
def test_diagnose_refuses_bad_input_in_one_line_before_any_episode(tmp_path, args, start):
    """Every bad input of scripts/diagnose.py is one line and exit 2, from any working folder,
    before the first episode (and before an output folder that cannot be written is needed)."""
    (tmp_path / "a_file").write_text("")
    broken = tmp_path / "broken" / "paper_fit" / "policy3_g"
    broken.mkdir(parents=True)
    for k in range(3):
        (broken / f"seed{k}.pt").write_text("not a checkpoint")
    args = [a.format(tmp=tmp_path) for a in args]
    proc = run_script("diagnose.py", *args, cwd=tmp_path, check=False, timeout=300)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.startswith(start.format(tmp=tmp_path)) and len(proc.stderr.strip().splitlines()) == 1
    assert "[1]" not in proc.stdout and not (tmp_path / "outputs").exists()


@pytest.mark.slow
def test_diagnose_finds_the_shipped_checkpoints_from_any_folder(tmp_path):
    proc = run_script("diagnose.py", "policies=[policy3_g]", "scenarios=[forest]", "sizes=[9]", "variants=[paper]",
                      "episodes=2", cwd=tmp_path)
    out = tmp_path / "outputs" / "diagnosis"
    assert "[1] Policy3-G (trained at 5) forest N=9 paper" in proc.stdout
    assert {p.name for p in out.iterdir()} == {"rates.csv", "crashes.csv", "diagnosis.md"}
    assert "| Policy3-G (trained at 5) | forest | 9 | paper | 6 |" in (out / "diagnosis.md").read_text()
