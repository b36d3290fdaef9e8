"""Obstacles drawn per episode (the forest; docs/specification.md section 6, decision): seeded,
inside their region, clear of the starts, the goal, the moving circles and each other, sensed
and scored like any obstacle, refused at config time when the region cannot always hold them.

Distances are computed here by hand (the formulas sit next to them), never with the world's
own geometry."""

from __future__ import annotations

import math

import pytest
import torch

from flock_torchrl import FlockingEnv, load_policy, make_policy
from flock_torchrl.config import ConfigError, default_checkpoints_dir, scenario_config

FOREST = {"reading": "literal"}
FAR = 500.0  # metres: where a test parks the drawn obstacles it does not want in the way


# ---------------------------------------------------------------------------- hand geometry
def point_to_rectangle(px, py, rect):
    """Distance from points to an axis-aligned rectangle ``(cx, cy, w, h)`` (0 inside):
    ``hypot(max(|dx| - w/2, 0), max(|dy| - h/2, 0))``."""
    ox = ((px - rect[..., 0]).abs() - rect[..., 2] / 2).clamp_min(0)
    oy = ((py - rect[..., 1]).abs() - rect[..., 3] / 2).clamp_min(0)
    return torch.hypot(ox, oy)


def gaps(circles: torch.Tensor, rectangles: torch.Tensor) -> torch.Tensor:
    """Smallest surface gap between two different drawn obstacles of each world, ``[B]``:
    circle-circle ``|c1 - c2| - r1 - r2``; circle-rectangle ``point_to_rectangle(c) - r``;
    rectangle-rectangle the point distance to a rectangle grown by the other's sides."""
    c, r = circles[:, :, None], circles[:, None]                                       # pairs [B, C, C, 3]
    cc = torch.hypot(c[..., 0] - r[..., 0], c[..., 1] - r[..., 1]) - c[..., 2] - r[..., 2]
    cc = cc + torch.eye(circles.shape[1]) * 1e9
    cx, cy, radius = circles[:, :, None, 0], circles[:, :, None, 1], circles[:, :, None, 2]
    cr = point_to_rectangle(cx, cy, rectangles[:, None]) - radius
    a, b = rectangles[:, :, None], rectangles[:, None]
    a, b = torch.broadcast_tensors(a, b)                                               # [B, R, R, 4]
    grown = torch.cat((b[..., :2], b[..., 2:] + a[..., 2:]), -1)
    rr = point_to_rectangle(a[..., 0], a[..., 1], grown) + torch.eye(rectangles.shape[1]) * 1e9
    return torch.cat((cc.flatten(1), cr.flatten(1), rr.flatten(1)), 1).amin(1)


def distance_to_drawn(points: torch.Tensor, circles: torch.Tensor, rectangles: torch.Tensor) -> torch.Tensor:
    """Distance from points ``[B, P, 2]`` to the nearest drawn obstacle surface, ``[B, P]``."""
    px, py = points[..., 0, None], points[..., 1, None]
    to_circles = torch.hypot(px - circles[:, None, :, 0], py - circles[:, None, :, 1]) - circles[:, None, :, 2]
    to_rectangles = point_to_rectangle(px, py, rectangles[:, None])
    return torch.cat((to_circles, to_rectangles), -1).amin(-1)


def swarm_centre(env: FlockingEnv) -> torch.Tensor:
    """Eq. 30: the swarm centre is the goal mirrored through the area centre, ``[B, 2]``."""
    return 2 * torch.tensor(env.cfg.area_center) - env.world["goal"]


def check_field(env: FlockingEnv) -> None:
    """Every invariant of a drawn field, in every world of ``env``."""
    cfg, world = env.cfg, env.world
    circles, rectangles = world["drawn_circles"], world["drawn_rectangles"]
    assert circles.shape[1:] == (cfg.random_circles, 3) and rectangles.shape[1:] == (cfg.random_rectangles, 4)
    x0, y0, x1, y1 = cfg.random_region
    c, eps = cfg.random_clearance, 1e-4
    # Sizes in their ranges.
    low, high = cfg.random_circle_radius
    assert ((circles[..., 2] >= low - eps) & (circles[..., 2] <= high + eps)).all()
    low, high = cfg.random_rectangle_size
    assert ((rectangles[..., 2:] >= low - eps) & (rectangles[..., 2:] <= high + eps)).all()
    # Wholly inside the region: centre +- radius, centre +- half side.
    x, y, r = circles[..., 0], circles[..., 1], circles[..., 2]
    assert (x - r >= x0 - eps).all() and (x + r <= x1 + eps).all()
    assert (y - r >= y0 - eps).all() and (y + r <= y1 + eps).all()
    assert (rectangles[..., 0] - rectangles[..., 2] / 2 >= x0 - eps).all()
    assert (rectangles[..., 0] + rectangles[..., 2] / 2 <= x1 + eps).all()
    assert (rectangles[..., 1] - rectangles[..., 3] / 2 >= y0 - eps).all()
    assert (rectangles[..., 1] + rectangles[..., 3] / 2 <= y1 + eps).all()
    # Apart from each other by the clearance.
    if cfg.random_circles + cfg.random_rectangles > 1:
        assert gaps(circles, rectangles).amin().item() >= c - eps
    # The start disc (radius R around the swarm centre) + max(clearance, spawn_clearance); the goal disc + clearance.
    disc = distance_to_drawn(swarm_centre(env)[:, None], circles, rectangles)[:, 0] - cfg.swarm_spawn_radius
    assert disc.amin().item() >= max(c, cfg.spawn_clearance) - eps
    goal = distance_to_drawn(world["goal"][:, None], circles, rectangles)[:, 0] - cfg.goal_radius
    assert goal.amin().item() >= c - eps
    # No start overlaps a drawn obstacle: every UAV at least spawn_clearance (and the clearance) away.
    starts = distance_to_drawn(world["position"], circles, rectangles)
    assert starts.amin().item() >= max(c, cfg.spawn_clearance) - eps
    # The moving circles' starts: surface gap >= clearance (|m - c| - r_m - r, etc.).
    if cfg.n_moving:
        moving = distance_to_drawn(world["moving_position"], circles, rectangles) - cfg.moving_radius
        assert moving.amin().item() >= c - eps


# ---------------------------------------------------------------------------- the scenario
def test_forest_scenario_values():
    cfg = scenario_config("forest")
    assert (cfg.circles, cfg.rectangles, cfg.n_moving) == ([], [], 0)
    assert (cfg.random_circles, cfg.random_rectangles) == (12, 3)
    assert cfg.random_region == [10.0, 10.0, 70.0, 70.0] and cfg.random_clearance == 4.0
    # 12 circles + 0 moving + 3 rectangles: the laser's indices 0..14.
    assert cfg.n_obstacles == 15
    # Every other scenario draws none.
    assert scenario_config("train").random_circles == scenario_config("s5").random_rectangles == 0


@pytest.mark.parametrize("overrides", [{}, {"n_moving": 2},
                                       {"reading": "paper_fit", "n_uavs": 9}])
def test_every_drawn_field_keeps_its_clearances(overrides):
    kwargs = {**FOREST, **overrides}
    env = FlockingEnv("forest", num_envs=128, seed=1, **kwargs)
    for _ in range(3):
        env.reset()
        check_field(env)


def test_the_cell_fallback_keeps_the_clearances_too(monkeypatch):
    # One rejection round and 20 obstacles: most worlds cannot place them all by rejection and take
    # the grid (12 m cells, 5 x 5 in the 60 m region), which must keep every clearance as well.
    from flock_torchrl.world import forest

    placed = []
    original = forest.place_on_cells

    def counting(cfg, shapes, fixed, generator):
        placed.append(shapes.shape[0])
        return original(cfg, shapes, fixed, generator)

    monkeypatch.setattr(forest, "place_on_cells", counting)
    env = FlockingEnv("forest", num_envs=64, seed=2, spawn_max_tries=1, random_circles=18, random_rectangles=2,
                      **FOREST)
    env.reset()
    assert sum(placed) > 0
    check_field(env)


def test_fixed_obstacles_and_drawn_ones_keep_apart():
    env = FlockingEnv("train", num_envs=64, seed=3, random_circles=2, random_rectangles=1, **FOREST)
    env.reset()
    check_field(env)
    circles, rectangles = env.world["drawn_circles"], env.world["drawn_rectangles"]
    clearance = env.cfg.random_clearance - 1e-4
    # The fixed circle (40, 40, r 6): |c - (40, 40)| - r - 6 for drawn circles; for the drawn
    # rectangle, the distance from (40, 40) to it, less 6.
    assert (torch.hypot(circles[..., 0] - 40, circles[..., 1] - 40) - circles[..., 2] - 6).amin() >= clearance
    assert (point_to_rectangle(torch.tensor(40.0), torch.tensor(40.0), rectangles) - 6).amin() >= clearance
    # The fixed rectangles (10 / 70, 40, 6 x 16): circle centres to the rectangle, less r; the
    # drawn rectangle's centre to the fixed one grown by the drawn one's sides.
    for cx, cy, w, h in env.cfg.rectangles:
        fixed = torch.tensor([cx, cy, w, h])
        assert (point_to_rectangle(circles[..., 0], circles[..., 1], fixed) - circles[..., 2]).amin() >= clearance
        grown = torch.cat((fixed[:2].expand(64, 1, 2), fixed[2:] + rectangles[..., 2:]), -1)
        assert point_to_rectangle(rectangles[..., 0], rectangles[..., 1], grown).amin() >= clearance


# ---------------------------------------------------------------------------- seeding
def test_same_seed_same_obstacles_other_seed_other_obstacles():
    a = FlockingEnv("forest", num_envs=8, seed=11, **FOREST)
    b = FlockingEnv("forest", num_envs=8, seed=11, **FOREST)
    c = FlockingEnv("forest", num_envs=8, seed=12, **FOREST)
    for env in (a, b, c):
        env.reset()
    for key in ("drawn_circles", "drawn_rectangles", "position", "goal"):
        assert torch.equal(a.world[key], b.world[key]), key
        assert not torch.equal(a.world[key], c.world[key]), key
    # Each world has its own field.
    assert not torch.equal(a.world["drawn_circles"][0], a.world["drawn_circles"][1])


def test_every_policy_meets_the_same_forest():
    # The evaluation protocol (section 5): one seed, one reset, the same episodes whatever the policy.
    learned = FlockingEnv("forest", num_envs=16, seed=5, policy_id="policy3_g", **FOREST)
    rule = FlockingEnv("forest", num_envs=16, seed=5, policy_id="policy_ma", **FOREST)
    learned.reset(), rule.reset()
    for key in ("drawn_circles", "drawn_rectangles", "position", "goal"):
        assert torch.equal(learned.world[key], rule.world[key]), key


def test_partial_reset_redraws_only_the_reset_worlds():
    env = FlockingEnv("forest", num_envs=4, seed=4, extras="physics", **FOREST)
    before = env.reset()
    td = before.clone()
    td["_reset"] = torch.tensor([[True], [False], [False], [True]])
    out = env.reset(td)
    for key in ("drawn_circles", "drawn_rectangles"):
        old, new = before["obstacles", key], out["obstacles", key]
        assert torch.equal(new[1:3], old[1:3]), key
        assert not torch.equal(new[0], old[0]) and not torch.equal(new[3], old[3]), key
        assert torch.equal(env.world[key], new), key
    check_field(env)


def test_state_subset_and_place_carry_the_drawn_obstacles():
    env = FlockingEnv("forest", num_envs=3, seed=6, **FOREST)
    env.reset()
    saved = env.get_state()
    circles = env.world["drawn_circles"].clone()
    env.reset()
    assert not torch.equal(env.world["drawn_circles"], circles)
    env.set_state(saved)
    assert torch.equal(env.world["drawn_circles"], circles)
    small = env.subset([2, 0])
    assert torch.equal(small.world["drawn_rectangles"], env.world["drawn_rectangles"][[2, 0]])
    # place() keeps the current field unless given one.
    world = env.world
    env.place(world["position"], world["heading"], world["goal"])
    assert torch.equal(env.world["drawn_circles"], circles)


def test_a_state_saved_before_the_drawn_obstacles_existed_still_restores():
    # A training checkpoint's env state from before these fields: no drawn_* entries. Where the
    # scenario draws none, they hold nothing, so the state restores as it is.
    env = FlockingEnv("train", num_envs=2, seed=0, **FOREST)
    env.reset()
    state = env.get_state()
    del state["world"]["drawn_circles"], state["world"]["drawn_rectangles"]
    env.set_state(state)
    assert env.world["drawn_circles"].shape == (2, 0, 3)
    # In a forest they hold the field: their absence is an error naming the key.
    forest = FlockingEnv("forest", num_envs=2, seed=0, **FOREST)
    forest.reset()
    state = forest.get_state()
    del state["world"]["drawn_circles"]
    with pytest.raises(ValueError, match="'drawn_circles'"):
        forest.set_state(state)


# ---------------------------------------------------------------------------- sensing and scoring
def park(env: FlockingEnv, circles=(), rectangles=()) -> tuple[torch.Tensor, torch.Tensor]:
    """A field of one world with the given circles and rectangles first and the rest parked
    far away (radius 1 m, sides 1 m, 10 m apart along y = FAR)."""
    cfg = env.cfg
    drawn_circles = torch.tensor([[FAR + 10 * j, FAR, 1.0] for j in range(cfg.random_circles)])
    drawn_rectangles = torch.tensor([[FAR + 10 * j, FAR + 50, 1.0, 1.0] for j in range(cfg.random_rectangles)])
    for j, circle in enumerate(circles):
        drawn_circles[j] = torch.tensor(circle)
    for j, rect in enumerate(rectangles):
        drawn_rectangles[j] = torch.tensor(rect)
    return drawn_circles[None], drawn_rectangles[None]


def test_the_laser_hits_drawn_obstacles_at_a_hand_checked_distance():
    env = FlockingEnv("forest", num_envs=1, seed=0, extras="all", n_uavs=1, **FOREST)
    env.reset()
    # UAV at (10, 40) facing +x (beam 0). Circle (20, 40, r 2): 20 - 2 - 10 = 8 m, drawn circle 0
    # is obstacle 0 (no fixed circles, no moving ones). Rectangle (10, 45, 4 x 2) on beam 9 (+y,
    # 90 deg): its lower edge at 45 - 1 = 44, 44 - 40 = 4 m; it is obstacle 12 + 0 = 12 (after
    # the 12 drawn circles).
    circles, rectangles = park(env, [(20.0, 40.0, 2.0)], [(10.0, 45.0, 4.0, 2.0)])
    td = env.place([[[10.0, 40.0]]], [[0.0]], [[70.0, 70.0]], drawn_circles=circles, drawn_rectangles=rectangles)
    scan, hit = td["agents", "scan"][0, 0], td["agents", "scan_obstacle"][0, 0]
    assert scan[0].item() == pytest.approx(8.0, abs=1e-5) and hit[0].item() == 0
    assert scan[9].item() == pytest.approx(4.0, abs=1e-5) and hit[9].item() == 12
    # Beam 18 (-x) sees nothing within 10 m: range 10, index -1.
    assert scan[18].item() == pytest.approx(10.0) and hit[18].item() == -1


def test_drawn_obstacles_come_after_the_fixed_ones_in_the_laser_index():
    # train + 1 drawn circle + 1 drawn rectangle: circles [fixed (40, 40, 6), drawn], then
    # rectangles [fixed (10, 40), fixed (70, 40), drawn]: the drawn circle is 1, the drawn rectangle 4.
    env = FlockingEnv("train", num_envs=1, seed=0, extras="all", n_uavs=1, random_circles=1, random_rectangles=1,
                      **FOREST)
    env.reset()
    assert env.cfg.n_obstacles == 5
    # UAV at (40, 20) facing +y: the drawn circle (40, 28, r 2) is in front (beam 0) at
    # 28 - 2 - 20 = 6 m, before the fixed circle (edge at 34); the drawn rectangle (50, 20, 2 x 2)
    # is on beam 27 (90 + 270 = 360 deg: +x), its left edge at 49: 49 - 40 = 9 m.
    td = env.place([[[40.0, 20.0]]], [[math.pi / 2]], [[40.0, 75.0]], drawn_circles=[[[40.0, 28.0, 2.0]]],
                   drawn_rectangles=[[[50.0, 20.0, 2.0, 2.0]]])
    scan, hit = td["agents", "scan"][0, 0], td["agents", "scan_obstacle"][0, 0]
    assert scan[0].item() == pytest.approx(6.0, abs=1e-5) and hit[0].item() == 1
    assert scan[27].item() == pytest.approx(9.0, abs=1e-5) and hit[27].item() == 4


def test_d_min_obs_and_crashes_see_drawn_obstacles():
    # Velocity commands of 0 keep the UAV still (action_mode velocity).
    env = FlockingEnv("forest", num_envs=2, seed=0, extras="all", n_uavs=1, action_mode="velocity", **FOREST)
    env.reset()
    # World 0: UAV at (10, 40), drawn circle (16, 40, r 3): gap 16 - 3 - 10 = 3 m -> d_min_obs 3.
    # World 1: UAV at (30, 30), drawn rectangle (30, 31.4, 2 x 2): lower edge 30.4, gap 0.4 m < 0.5 m -> crash.
    c0, r0 = park(env, [(16.0, 40.0, 3.0)])
    c1, r1 = park(env, rectangles=[(30.0, 31.4, 2.0, 2.0)])
    env.place([[[10.0, 40.0]], [[30.0, 30.0]]], [[0.0], [0.0]], [[70.0, 70.0], [70.0, 70.0]],
              drawn_circles=torch.cat((c0, c1)), drawn_rectangles=torch.cat((r0, r1)))
    td = env.current()
    td["agents", "action"] = torch.zeros(2, 1, 2)
    out = env.step(td)["next"]
    assert out["episode", "d_min_obs"][0].item() == pytest.approx(3.0, abs=1e-5)
    assert out["episode", "d_min_obs"][1].item() == pytest.approx(0.4, abs=1e-5)
    assert out["episode", "crashed"].tolist() == [False, True]
    assert out["terminated"].tolist() == [[False], [True]]


def test_place_refuses_a_drawn_obstacle_without_size():
    env = FlockingEnv("forest", num_envs=1, seed=0, n_uavs=1, **FOREST)
    env.reset()
    circles, rectangles = park(env)
    circles[0, 0, 2] = 0.0
    with pytest.raises(ValueError, match="place: drawn_circles has a size <= 0"):
        env.place([[[10.0, 40.0]]], [[0.0]], [[70.0, 70.0]], drawn_circles=circles)
    with pytest.raises(ValueError, match=r"'drawn_rectangles' has shape \[1, 2, 4\], expected \[1, 3, 4\]"):
        env.place([[[10.0, 40.0]]], [[0.0]], [[70.0, 70.0]], drawn_rectangles=rectangles[:, :2])


# ---------------------------------------------------------------------------- config time
def test_a_forest_too_dense_for_its_region_is_refused_naming_the_key():
    # 12 m cells (largest obstacle 2 x 4 m, plus the 4 m clearance) tile the 60 m region 5 x 5:
    # 25 cells cannot always hold 30 obstacles.
    with pytest.raises(ConfigError, match=r"^scenario\.random_circles: 30 circles and 3 rectangles .* 5 x 5 cells"):
        FlockingEnv("forest", random_circles=30, **FOREST)
    with pytest.raises(ConfigError, match=r"^scenario\.random_rectangles: 0 circles and 40 rectangles"):
        FlockingEnv("forest", random_circles=0, random_rectangles=40, **FOREST)
    # A region smaller than one cell (12 m) has room for none.
    with pytest.raises(ConfigError, match=r"^scenario\.random_circles: .*leave room for 0"):
        FlockingEnv("forest", random_region=[30.0, 30.0, 41.0, 41.0], **FOREST)


def test_moving_circles_take_their_share_of_the_cells():
    # A moving circle of radius r takes the cells within r + 4 / 2 m of its centre (an obstacle
    # stays 2 m inside its 12 m cell). r = 3, reach 5 m: a centre at (x, y) in its cell reaches
    # the cell to its left only if x < 5, to its right only if x > 7 (never both), likewise below
    # and above, so at most its own, one beside, one across and the one diagonal: 4.
    from flock_torchrl.world.forest import cells_near_a_moving_circle

    assert cells_near_a_moving_circle(scenario_config("forest", n_moving=2)) == 4
    # r = 6, reach 8 m: a centre at (4.1, 6) reaches both columns beside it (4.1, 7.9 < 8), the
    # rows above and below (6 < 8) and the left column's cells there (hypot(4.1, 6) = 7.3 < 8):
    # 7; an eighth would need a second diagonal, hypot(x, 6) and hypot(12 - x, 6) both < 8: none.
    assert cells_near_a_moving_circle(scenario_config("forest", n_moving=2, moving_radius=6.0)) == 7
    # 25 cells less 2 x 4 leave 17, enough for 15 even where the spawn disc and the goal take
    # theirs; less 2 x 7 leave 11: refused.
    FlockingEnv("forest", n_moving=2, **FOREST)
    with pytest.raises(ConfigError, match=r"^scenario\.random_circles: 12 circles and 3 rectangles"):
        FlockingEnv("forest", n_moving=2, moving_radius=6.0, **FOREST)


@pytest.mark.parametrize("field, value, message", [
    ("random_circles", -1, "must be an integer >= 0"),
    ("random_circle_radius", [4.0, 1.5], r"must be \[min, max\] with 0 < min <= max"),
    ("random_rectangle_size", [0.0, 2.0], r"must be \[min, max\] with 0 < min <= max"),
    ("random_region", [70.0, 10.0, 10.0, 70.0], r"must be \[x0, y0, x1, y1\] with x0 < x1"),
    ("random_region", [0.0, 0.0, 2e6, 10.0], r"inside \[-1e6, 1e6\]"),
    ("random_region", [0.0, 0.0, 6.0, 60.0], "cannot hold a circle of radius 4"),
    ("random_clearance", -1.0, "must be a finite number >= 0"),
])
def test_drawn_obstacle_fields_are_checked_by_name(field, value, message):
    with pytest.raises(ConfigError, match=rf"^scenario\.{field}: .*{message}"):
        scenario_config("forest", **{field: value})


def test_a_scenario_saved_before_the_fields_still_builds():
    # A checkpoint's scenario from before the forest lacks the random_* fields: they take the
    # training scenario's YAML values, which mean none.
    import dataclasses

    from flock_torchrl.config import ScenarioConfig, saved_scenario

    saved = {k: v for k, v in dataclasses.asdict(scenario_config("train")).items() if not k.startswith("random_")}
    cfg = ScenarioConfig(**saved_scenario(saved)).check()
    assert (cfg.random_circles, cfg.random_rectangles, cfg.n_obstacles) == (0, 0, 3)


# ---------------------------------------------------------------------------- policies and pictures
@pytest.mark.parametrize("name", ["policy_ma", "policy_op"])
def test_rule_based_baselines_fly_the_forest(name):
    env = FlockingEnv("forest", num_envs=4, seed=0, policy_id=name, extras=("physics", "laser"), **FOREST)
    td = env.rollout(30, policy=make_policy(name, env), break_when_any_done=False)
    assert td["next", "agents", "position"].isfinite().all()
    assert td["next", "agents", "scan_obstacle"].max().item() <= env.cfg.n_obstacles - 1


def test_rule_based_baselines_tell_drawn_obstacles_apart():
    from flock_torchrl.policies.baselines.sensing import obstacle_count

    assert obstacle_count(scenario_config("forest")) == 15


def test_a_learned_checkpoint_flies_the_forest():
    policy = load_policy(default_checkpoints_dir() / "paper_fit" / "policy3_g" / "seed0.pt")
    meta = policy.flock_meta
    env = FlockingEnv("forest", num_envs=4, seed=0, reading=meta["reading"], policy_id=meta["policy_id"])
    with torch.no_grad():
        td = env.rollout(30, policy=policy, break_when_any_done=False)
    assert td["agents", "action"].shape == (4, 30, 5, 2)
    assert td["next", "agents", "reward"].isfinite().all()


def test_frames_draw_each_worlds_own_obstacles():
    from flock_torchrl.world.frame import rollout_states

    env = FlockingEnv("forest", num_envs=2, seed=0, extras="all", n_uavs=1, **FOREST)
    env.reset()
    # 4 pixels per metre over (0, 80): a drawn circle of radius 4 at (40, 40) in world 0 only.
    c0, r0 = park(env, [(40.0, 40.0, 4.0)])
    c1, r1 = park(env)
    env.place([[[5.0, 5.0]], [[5.0, 5.0]]], [[0.0], [0.0]], [[75.0, 75.0], [75.0, 75.0]],
              drawn_circles=torch.cat((c0, c1)), drawn_rectangles=torch.cat((r0, r1)))
    frames = [env.render(env_index=i, size=320, extent=(0.0, 80.0, 0.0, 80.0), show_fov=False) for i in (0, 1)]
    red, green, blue = (int(v) for v in frames[0][160, 160])  # row 160, column 160: (40, 40)
    assert red > 200 and green < 100 and blue < 100           # the obstacle's red
    assert tuple(int(v) for v in frames[1][160, 160]) == (255, 255, 255)  # world 1: nothing there
    # A rollout's states carry the episode's field (no reset: the placed one).
    td = env.rollout(2, break_when_any_done=False, auto_reset=False, tensordict=env.current())
    states = rollout_states(td, env.cfg, env_index=0)
    assert states[0].circles.shape == (12, 3) and states[0].circles[0].tolist() == [40.0, 40.0, 4.0]

