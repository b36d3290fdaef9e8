"""Record reference transitions of the env as it was at commit 4f36b60 (before the speed work).

    git worktree add /tmp/oldflock 4f36b60
    PYTHONPATH=/tmp/oldflock python tests/data/make_reference_rollouts.py tests/data/reference_rollouts.pt

Each case: one seeded env of 4 worlds (full reset only), 40 steps of seeded uniform actions, every key
the env emitted. tests/test_equivalence.py replays the same actions on today's env (eager
and compiled) and compares.
"""

import sys

import torch

from flock_torchrl import FlockingEnv

CASES = {
    # name: (scenario, overrides)
    "train_policy3_g": ("train", dict(fov=0.5 * torch.pi, instinct=True)),
    "train_policy1": ("train", dict(fov=2 * torch.pi, instinct=False)),
    "train_policy4_g": ("train", dict(fov=0.5 * torch.pi, instinct=False, collision_reward_source="min_uav_scan")),
    "train_policy5_g": ("train", dict(fov=0.5 * torch.pi, instinct=True, tangential=False)),
    "s2_policy3_g": ("s2", dict(instinct=True)),
    "s3_policy3_g": ("s3", dict(instinct=True)),
    "s4_policy3_g": ("s4", dict(instinct=True)),
    "s5_policy3_g": ("s5", dict(instinct=True)),
}
B, T, SEED = 4, 40, 7


def record(scenario, overrides):
    torch.manual_seed(0)
    env = FlockingEnv(scenario, num_envs=B, seed=SEED, **overrides)
    td = env.reset()
    gen = torch.Generator().manual_seed(123)
    actions = torch.rand(T, B, env.n_agents, 2, generator=gen) * 2 - 1
    steps = []
    first = td.exclude("episode").clone()
    for t in range(T):
        td.set(("agents", "action"), actions[t])
        td = env.step(td)
        steps.append(td["next"].clone())
        td = td["next"]
    steps = torch.stack(steps, 0)
    # Integer keys as int16 keep the file small (obstacle indices and step counts fit).
    steps = steps.apply(lambda x: x.to(torch.int16) if x.dtype == torch.int64 else x)
    return {"overrides": overrides, "scenario": scenario, "actions": actions, "reset": first.to_dict(),
            "steps": steps.to_dict()}


if __name__ == "__main__":
    torch.set_num_threads(1)
    out = {name: record(*case) for name, case in CASES.items()}
    torch.save(out, sys.argv[1])
    print("wrote", sys.argv[1])
