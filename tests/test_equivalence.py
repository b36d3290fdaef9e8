"""Today's env against the env as it was before the speed work (commit 4f36b60): the same
actions from the same seeded starts give the same transitions, bit for bit or within float
round-off (tests/data/make_reference_rollouts.py recorded them)."""

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
# Float round-off allowance: a compiled step may fuse and reorder float32 arithmetic.
ATOL = {"eager": 0.0}


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
def test_eager_step_is_bitwise_the_recorded_one(reference, name):
    case = reference[name]
    steps = replay(case, *CASES[name])
    assert torch.equal(steps[0]["agents", "observation"], case["reset"]["agents"]["observation"])
    recorded = case["steps"]
    for t, td in enumerate(steps[1:]):
        for key in KEYS:
            want = recorded
            for k in key:
                want = want[k]
            assert torch.equal(td[key].to(want.dtype), want[t]), (name, t, key)
