"""One step, measured two ways: the eager step measures only the UAV pairs and the (beam,
obstacle) pairs within range (data-dependent shapes), the compiled step every pair
(``static_shapes=True``, what ``torch.compile(fullgraph=True)`` needs). The formulas are the
same functions either way, so the same sensing, instinct, kinematics, reward and metrics come
out, up to float round-off (a vectorised ``atan2`` rounds its last bit differently).

The static-shape step run eagerly is the compiled step's twin: the compiled env must give what
the eager env gives, step by step, up to the reordering of float32 operations a compiler does.
Over a few dozen steps of a swarm under its instinct that drifts by up to ~2e-4 m, and a beam
grazing an obstacle turns that into up to ~1e-2 m of range; every discrete outcome (which
obstacle a beam hits, which UAVs see each other, the instinct's switch, done) stays identical."""

import math

import pytest
import torch

from flock_torchrl import FlockingEnv
from flock_torchrl.world.state import STATE_KEYS
from flock_torchrl.world.step import advance, noise_draws, sense

# Every kind of world: one UAV, fewer UAVs than camera slots, no obstacles, moving obstacles,
# S4 noise, a spread swarm of 20 (where the eager step packs the pairs in range), obstacles
# drawn per world (where it casts beams only at the obstacles in range).
# The fast tier: the training world, one UAV, S4's noise, the spread swarm and the forest with moving
# obstacles; the rest in the full tier.
SLOW = pytest.mark.slow
CASES = [("train", "policy3_g", {}), ("s1", "policy3_g", {"n_uavs": 1}),
         pytest.param("s1", "policy1", {"n_uavs": 2}, marks=SLOW), pytest.param("s2", "policy5_g", {}, marks=SLOW),
         pytest.param("s3", "policy4_g", {}, marks=SLOW), ("s4", "policy3_g", {}),
         pytest.param("s5", "policy1", {}, marks=SLOW), ("train", "policy3_g", {"n_uavs": 20, "reading": "paper_fit"}),
         pytest.param("forest", "policy3_g", {}, marks=SLOW), ("forest", "policy4_g", {"n_moving": 2})]

# A beam that grazes a circle hits at -b - sqrt(b^2 - c): float32 round-off in b^2 - c (about
# 1e-7 * 10^2 m^2 at the 10 m range) becomes up to sqrt(1e-5) ~ 3e-3 m in the hit distance.
# Raw beam lengths (metres) get that margin; the observation divides them by the 10 m range.
GRAZING_ATOL = {"scan": 3e-3}


def same_values(a: dict, b: dict, atol: float = 1e-4) -> None:
    """Equal keys, shapes, dtypes; discrete values equal, floats within ``atol`` (raw beams
    within ``GRAZING_ATOL``). An angle at the wrap (+-pi, or +-1 once divided by pi) may come
    out on either side: the same direction."""
    assert a.keys() == b.keys()
    base = atol
    for key in a:
        atol = GRAZING_ATOL.get(key, base)
        x, y = a[key], b[key]
        assert x.shape == y.shape and x.dtype == y.dtype, key
        if x.dtype in (torch.bool, torch.long):
            assert torch.equal(x, y), key
            continue
        diff = (x - y).abs()
        wrapped = ((diff - 2).abs() <= atol) & ((x.abs() - 1).abs() <= atol) | (
            ((diff - 2 * math.pi).abs() <= atol) & ((x.abs() - math.pi).abs() <= atol))
        ok = (diff <= atol) | wrapped | (x.isnan() & y.isnan()) | (x == y)
        assert ok.all(), (key, diff[~ok].max())


@pytest.mark.parametrize("scenario, policy, overrides", CASES)
def test_static_shape_step_matches_the_packed_step(scenario, policy, overrides):
    kwargs = {"reading": "literal", **overrides}
    torch.manual_seed(0)  # rand_action draws from the global generator
    env = FlockingEnv(scenario, num_envs=16, seed=5, policy_id=policy, **kwargs)
    td = env.reset()
    for t in range(12):
        world, cfg = env.world, env.cfg
        normals = noise_draws(cfg, env.num_envs, torch.Generator().manual_seed(t))
        same_values(sense(world, env._static, cfg, normals), sense(world, env._static, cfg, normals, True))
        td = env.rand_action(td)
        args = ({k: world[k] for k in STATE_KEYS}, world["sensed"].to_dict(), world["episode"].to_dict(),
                td["agents", "action"], env._static, cfg, normals)
        for a, b in zip(advance(*args), advance(*args, static_shapes=True)):  # state, sensed, episode, reward
            same_values(*(x if isinstance(x, dict) else {"reward": x} for x in (a, b)))
        td = env.step_and_maybe_reset(td)[1]


def test_static_shape_step_matches_the_packed_step_in_a_spread_swarm():
    # Spawned swarms are dense (every pair kept either way); spread out fourfold, fewer than a
    # quarter of the pairs are in camera range and the eager step packs them.
    torch.manual_seed(0)
    env = FlockingEnv("train", num_envs=16, seed=5, policy_id="policy3_g", reading="paper_fit", n_uavs=40)
    td = env.rand_action(env.reset())
    world, cfg = env.world.clone(), env.cfg
    centre = world["position"].mean(1, keepdim=True)
    world["position"] = centre + 4 * (world["position"] - centre)
    distance = torch.cdist(world["position"], world["position"])
    assert 4 * int((distance < cfg.camera_range).sum()) < distance.numel()
    same_values(sense(world, env._static, cfg), sense(world, env._static, cfg, None, True))
    args = ({k: world[k] for k in STATE_KEYS}, world["sensed"].to_dict(), world["episode"].to_dict(),
            td["agents", "action"], env._static, cfg)
    for a, b in zip(advance(*args), advance(*args, static_shapes=True)):
        same_values(*(x if isinstance(x, dict) else {"reward": x} for x in (a, b)))


KEYS = [("agents", "observation"), ("agents", "state"), ("agents", "reward"), ("agents", "position"),
        ("agents", "velocity"), ("agents", "heading"), ("agents", "command"), ("agents", "instinct"),
        ("agents", "scan"), ("agents", "scan_obstacle"), ("episode", "d_c"), ("episode", "d_min_uav"),
        ("episode", "d_min_obs"), ("episode", "return"), ("done",), ("terminated",)]
DISCRETE = {("agents", "scan_obstacle"), ("agents", "instinct"), ("done",), ("terminated",)}
ATOL = {("agents", "scan"): 3e-2}  # metres along a grazing beam; everything else below
DEFAULT_ATOL = 3e-3                # metres, m/s, rad and normalised readings


def rollouts(scenario: str, steps: int, **kwargs) -> list[list]:
    """The eager and the compiled env along the same seeded random actions (episodes restart)."""
    actions = torch.rand(steps, 4, 5, 2, generator=torch.Generator().manual_seed(3)) * 2 - 1
    runs = []
    for compile_step in (False, True):
        env = FlockingEnv(scenario, num_envs=4, seed=7, reading="literal", policy_id="policy3_g", extras="all",
                          compile_step=compile_step, **kwargs)
        td, out = env.reset(), []
        for action in actions:
            td.set(("agents", "action"), action)
            step, td = env.step_and_maybe_reset(td)
            out.append(step["next"])
        runs.append(out)
    return runs


def assert_twins(eager: list, compiled: list) -> None:
    for t, (a, b) in enumerate(zip(eager, compiled)):
        for key in KEYS:
            if key in DISCRETE:
                assert torch.equal(a[key], b[key]), (t, key)
            else:
                assert torch.allclose(a[key].double(), b[key].double(), atol=ATOL.get(key, DEFAULT_ATOL), rtol=0,
                                      equal_nan=True), (t, key, (a[key].double() - b[key].double()).abs().max())


def test_compiled_step_matches_its_eager_twin():
    assert_twins(*rollouts("train", 10))


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["s4", "s5"])
def test_compiled_step_matches_its_eager_twin_along_long_rollouts(scenario):
    assert_twins(*rollouts(scenario, 40))


@pytest.mark.slow
def test_compiled_forest_matches_its_eager_twin():
    # Obstacles drawn per episode, per world: with episodes of 12 steps (or fewer: crashes),
    # worlds are reset and draw new fields mid-rollout in both.
    eager, compiled = rollouts("forest", 30, max_steps=12)
    assert any(bool(td["done"].any()) for td in eager)  # some world did start a new field
    for a, b in zip(eager, compiled):
        assert torch.equal(a["obstacles", "drawn_circles"], b["obstacles", "drawn_circles"])
        assert torch.equal(a["obstacles", "drawn_rectangles"], b["obstacles", "drawn_rectangles"])
    assert_twins(eager, compiled)


def test_static_shape_sensing_hands_back_the_eager_layout():
    # The compiled step reads some of its own outputs back on the next step; a reset writes them
    # by eager sensing. Different strides would make it compile anew, alternately.
    for scenario in ("train", "train3d"):
        env = FlockingEnv(scenario, num_envs=8, seed=1, policy_id="policy3_g")
        env.reset()
        eager, static = sense(env.world, env._static, env.cfg), sense(env.world, env._static, env.cfg, None, True)
        for key in static:
            if key not in ("scan", "scan_obstacle"):  # the laser's [B, N, K] views of [K, N, B]
                assert static[key].is_contiguous(), (scenario, key)
        for key in ("instinct_triggered", "instinct_command", "d_goal"):  # what advance reads back
            assert static[key].stride() == eager[key].stride(), (scenario, key)


def test_compiled_step_compiles_once_across_resets():
    env = FlockingEnv("train", num_envs=4, seed=2, policy_id="policy3_g", compile_step=True)
    gen = torch.Generator().manual_seed(0)
    td = env.reset()
    td.set(("agents", "action"), torch.rand(4, 5, 2, generator=gen) * 2 - 1)
    td = env.step_and_maybe_reset(td)[1]  # compiles
    with torch.compiler.set_stance("fail_on_recompile"):
        for t in range(6):
            if t == 2:
                td = env.reset()  # every world anew
            if t == 4:
                td = env.reset(td.empty().set("_reset", torch.tensor([[True], [False], [False], [True]])))
            td.set(("agents", "action"), torch.rand(4, 5, 2, generator=gen) * 2 - 1)
            td = env.step_and_maybe_reset(td)[1]
