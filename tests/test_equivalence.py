"""Today's env against the env as it was before the speed work (commit 4f36b60), and the
compiled step against its eager twin: the same actions from the same seeded starts give the
same transitions up to float round-off (tests/data/make_reference_rollouts.py recorded them).

Round-off enters where the speed work changed the arithmetic: beam directions are the
heading's unit vector rotated by fixed offsets instead of ``cos(heading + offset)``, pairwise
offsets are taken per axis, and a compiled step fuses and reorders float32 operations: about
1e-6 after one step. Over 40 steps of a swarm under its instinct the trajectories drift
apart by up to ~2e-4 m, and a beam grazing an obstacle turns that into up to ~1e-2 m of
range; every discrete outcome (which obstacle a beam hits, which UAVs see each other, the
instinct's switch, done) stays identical.

The compiled step senses with the worlds innermost (world/lanes.py), by the same formulas: run
eagerly, that code must give what the eager sensing gives, in every scenario."""

import math
from pathlib import Path

import pytest
import torch

from flock_torchrl import FlockingEnv

REFERENCE = Path(__file__).parent / "data" / "reference_rollouts.pt"
CASES = {  # recorded case -> (scenario, policy whose scenario fields it used)
    "train_policy3_g": ("train", "policy3_g"), "train_policy1": ("train", "policy1"),
    "train_policy4_g": ("train", "policy4_g"), "train_policy5_g": ("train", "policy5_g"),
    "s2_policy3_g": ("s2", "policy3_g"), "s3_policy3_g": ("s3", "policy3_g"),
    "s4_policy3_g": ("s4", "policy3_g"), "s5_policy3_g": ("s5", "policy3_g"),
}
KEYS = [("agents", "observation"), ("agents", "state"), ("agents", "reward"), ("agents", "position"),
        ("agents", "velocity"), ("agents", "heading"), ("agents", "command"), ("agents", "instinct"),
        ("agents", "scan"), ("agents", "scan_obstacle"), ("episode", "d_c"), ("episode", "d_min_uav"),
        ("episode", "d_min_obs"), ("episode", "return"), ("done",), ("terminated",)]
DISCRETE = {("agents", "scan_obstacle"), ("agents", "instinct"), ("done",), ("terminated",)}
ATOL = {("agents", "scan"): 3e-2}  # metres along a grazing beam; everything else below
DEFAULT_ATOL = 3e-3                # metres, m/s, rad and normalised readings


def close(a: torch.Tensor, b: torch.Tensor, key) -> bool:
    if key in DISCRETE:
        return torch.equal(a, b.to(a.dtype))
    return torch.allclose(a.double(), b.double(), atol=ATOL.get(key, DEFAULT_ATOL), rtol=0, equal_nan=True)


def replay(case: dict, scenario: str, policy: str, **kwargs) -> list:
    env = FlockingEnv(scenario, num_envs=4, seed=7, reading="literal", policy_id=policy, extras="all", **kwargs)
    td = env.reset()
    out = [td]
    for action in case["actions"]:
        td.set(("agents", "action"), action)
        td = env.step(td)["next"]
        out.append(td)
    return out


@pytest.fixture(scope="module")
def reference():
    return torch.load(REFERENCE, weights_only=True)


@pytest.mark.parametrize("name", list(CASES))
def test_eager_step_matches_the_recorded_one(reference, name):
    case = reference[name]
    steps = replay(case, *CASES[name])
    assert close(steps[0]["agents", "observation"], case["reset"]["agents"]["observation"], "observation")
    recorded = case["steps"]
    for t, td in enumerate(steps[1:]):
        for key in KEYS:
            want = recorded
            for k in key:
                want = want[k]
            assert close(td[key], want[t], key), (name, t, key, (td[key].double() - want[t].double()).abs().max())


@pytest.mark.parametrize("name", ["train_policy3_g", "s4_policy3_g", "s5_policy3_g"])
@pytest.mark.slow
def test_compiled_step_matches_its_eager_twin(reference, name):
    case = reference[name]
    eager = replay(case, *CASES[name])
    compiled = replay(case, *CASES[name], compile_step=True)
    for a, b in zip(eager[1:], compiled[1:]):
        for key in KEYS:
            assert close(b[key], a[key], key), (name, key, (b[key].double() - a[key].double()).abs().max())


@pytest.mark.slow
def test_compiled_forest_matches_its_eager_twin():
    # The forest (obstacles drawn per episode, per world) has no recorded reference: the compiled
    # step must match its eager twin along 30 steps of seeded random actions, with episodes of 12
    # steps (or fewer: crashes), so worlds are reset and draw new fields mid-rollout in both.
    actions = torch.rand(30, 4, 5, 2, generator=torch.Generator().manual_seed(3)) * 2 - 1
    runs = []
    for compile_step in (False, True):
        env = FlockingEnv("forest", num_envs=4, seed=7, reading="literal", policy_id="policy3_g", extras="all",
                          max_steps=12, compile_step=compile_step)
        td, steps = env.reset(), []
        for action in actions:
            td.set(("agents", "action"), action)
            out, td = env.step_and_maybe_reset(td)
            steps.append(out["next"])
        runs.append(steps)
    assert any(bool(td["done"].any()) for td in runs[0])  # some world did start a new field
    for a, b in zip(*runs):
        assert torch.equal(a["obstacles", "drawn_circles"], b["obstacles", "drawn_circles"])
        assert torch.equal(a["obstacles", "drawn_rectangles"], b["obstacles", "drawn_rectangles"])
        for key in KEYS:
            assert close(b[key], a[key], key), ("forest", key, (b[key].double() - a[key].double()).abs().max())


# The compiled step runs as world/lanes.py (worlds innermost); run eagerly, its sense and advance
# must give what step.sense and step.advance give, key by key, along random rollouts and in the
# corner cases (one UAV, fewer UAVs than camera slots, no obstacles, moving obstacles, S4 noise,
# obstacles drawn per world).
LANES_CASES = [("train", "policy3_g", {}), ("s1", "policy3_g", {"n_uavs": 1}), ("s1", "policy1", {"n_uavs": 2}),
               ("s2", "policy5_g", {}), ("s3", "policy4_g", {}), ("s4", "policy3_g", {}), ("s5", "policy1", {}),
               ("train", "policy3_g", {"n_uavs": 20, "reading": "paper_fit"}), ("forest", "policy3_g", {}),
               ("forest", "policy4_g", {"n_moving": 2})]


# A beam that grazes a circle hits at -b - sqrt(b^2 - c): float32 round-off in b^2 - c (about
# 1e-7 * 10^2 m^2 at the 10 m range) becomes up to sqrt(1e-5) ~ 3e-3 m in the hit distance,
# whichever of two correct formulas computes it. Raw beam lengths (metres) get that margin; the
# observation divides them by the 10 m range, so 1e-4 still covers it there.
GRAZING_ATOL = {"scan": 3e-3}


def same_values(a: dict, b: dict, atol: float = 1e-4) -> None:
    """Equal keys, shapes, dtypes; discrete values equal, floats within ``atol`` (the same
    formulas, but sums over the swarm may add in another order; raw beams within
    ``GRAZING_ATOL``). An angle at the wrap (+-pi, or +-1 once divided by pi) may come out on
    either side: the same direction."""
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


@pytest.mark.parametrize("scenario, policy, overrides", LANES_CASES)
def test_lanes_step_matches_the_eager_step(scenario, policy, overrides):
    from flock_torchrl.world import lanes
    from flock_torchrl.world.state import STATE_KEYS
    from flock_torchrl.world.step import advance, noise_draws, sense

    kwargs = {"reading": "literal", **overrides}
    torch.manual_seed(0)  # rand_action draws from the global generator
    env = FlockingEnv(scenario, num_envs=16, seed=5, policy_id=policy, **kwargs)
    td = env.reset()
    for t in range(12):
        world, cfg = env.world, env.cfg
        normals = noise_draws(cfg, env.num_envs, torch.Generator().manual_seed(t))
        same_values(sense(world, env._static, cfg, normals), lanes.sense(world, env._static, cfg, normals))
        td = env.rand_action(td)
        args = ({k: world[k] for k in STATE_KEYS}, world["sensed"].to_dict(), world["episode"].to_dict(),
                td["agents", "action"], env._static, cfg, normals)
        for a, b in zip(advance(*args), lanes.advance(*args)):  # state, sensed, episode, reward
            same_values(*(x if isinstance(x, dict) else {"reward": x} for x in (a, b)))
        td = env.step_and_maybe_reset(td)[1]


def test_lanes_smallest_orders_ties_by_index_like_the_eager_one():
    from flock_torchrl.world import lanes
    from flock_torchrl.world.sensors import smallest

    values = torch.tensor([[3.0, 1.0, 1.0, 2.0, 1.0, float("inf")],
                           [float("inf")] * 6,
                           [5.0, 4.0, 4.0, 4.0, 0.0, 0.0]])
    eager = smallest(values, 4)
    outer = lanes.smallest(values.T, 4)
    assert torch.equal(outer[0].T, eager[0])
    assert outer[1].T[0].tolist() == eager[1][0].tolist() == [1, 2, 4, 3]
    assert outer[1].T[2].tolist() == eager[1][2].tolist() == [4, 5, 1, 2]
