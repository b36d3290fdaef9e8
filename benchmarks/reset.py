"""What partial resets cost against a step: milliseconds to reset ``k`` of ``B`` worlds (TorchRL's
``env.reset`` with a ``"_reset"`` mask, as ``step_and_maybe_reset`` calls it) beside one eager
step of all ``B`` worlds, and env-steps per second of ``step_and_maybe_reset`` with random
actions when worlds end often (the bare world: no instinct) against Policy3-G's world.

    .venv/bin/python -m benchmarks.reset [--batch 1024] [--rounds 3]

Candidates alternate round by round in one process and each keeps its best round
(``benchmarks.timing.paired``), so load from other processes hits all of them alike.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if not __package__:  # `python benchmarks/reset.py`: the repository's root, so `benchmarks` imports
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import torch  # noqa: E402
from tensordict import TensorDict  # noqa: E402

from benchmarks.step import stepper  # noqa: E402
from benchmarks.timing import Lines, paired  # noqa: E402
from flock_torchrl import FlockingEnv  # noqa: E402


def resetter(env: FlockingEnv, k: int, repeat: int):
    """A callable resetting the first ``k`` worlds ``repeat`` times (TorchRL pops ``"_reset"``
    from its input, so each call gets a fresh mask)."""
    mask = torch.zeros(env.num_envs, 1, dtype=torch.bool, device=env.device)
    mask[:k] = True

    def go() -> None:
        for _ in range(repeat):
            env.reset(TensorDict({"_reset": mask.clone()}, batch_size=env.batch_size, device=env.device))
    return go


def rollout(env: FlockingEnv, steps: int):
    """A callable taking ``steps`` random-action ``step_and_maybe_reset`` steps; it counts the
    worlds that ended."""
    state = {"td": env.reset(), "ended": 0, "steps": 0}
    gen = torch.Generator(device=env.device).manual_seed(0)

    def go() -> None:
        td = state["td"]
        for _ in range(steps):
            action = torch.rand(env.num_envs, env.n_agents, 2, generator=gen, device=env.device)
            td.set(("agents", "action"), action * 2 - 1)
            out, td = env.step_and_maybe_reset(td)
            state["ended"] += int(out["next", "done"].sum())
            state["steps"] += 1
        state["td"] = td
    return go, state


def reset_lines(batch: int = 1024, rounds: int = 3, print_each: bool = True) -> list[str]:
    """The rows: reset of 2, 32 and all of ``batch`` worlds against one eager step, then the
    random-action rollout of the bare world against Policy3-G's."""
    lines = Lines(print_each)
    env = FlockingEnv(num_envs=batch, reading="paper_fit", policy_id="policy3_g")
    repeat = 5
    candidates = {"step": stepper(env, repeat)}
    for k in sorted({k for k in (2, 32) if k < batch} | {batch}):
        candidates[f"reset {k}"] = resetter(env, k, repeat)
    best = paired(candidates, rounds)
    step_ms = 1e3 * best.pop("step") / repeat
    lines.say(f"partial reset, B = {batch}: one eager step of every world {step_ms:.2f} ms")
    for name, seconds in best.items():
        ms = 1e3 * seconds / repeat
        lines.say(f"partial reset, B = {batch}: {name:>10s} worlds {ms:8.2f} ms ({ms / step_ms:.2f} steps)")
    steps = 10
    worlds = {name: FlockingEnv(num_envs=batch, reading="paper_fit", policy_id=policy)
              for name, policy in (("bare world (no instinct)", "policy1"), ("Policy3-G's world", "policy3_g"))}
    runs = {name: rollout(env, steps) for name, env in worlds.items()}
    best = paired({name: go for name, (go, _) in runs.items()}, rounds)
    base = None
    for name, seconds in best.items():
        state = runs[name][1]
        rate = steps * batch / seconds
        base = base or rate
        lines.say(f"random actions, B = {batch}, {name:26s}: {rate:9.0f} env-steps/s ({rate / base:.2f}x the first "
                  f"row; {state['ended'] / state['steps']:.2f} worlds ending per step)")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(1)
    reset_lines(args.batch, args.rounds)


if __name__ == "__main__":
    main()
