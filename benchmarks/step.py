"""Milliseconds per env step, eager against compiled, and the swarm-scale cost per UAV-step.

Every step starts from the same world state (no episode ends, no resets in the timing) and
takes fixed random actions; candidates alternate round by round in one process and each keeps
its best round, so load from other processes hits all of them alike (read the ratios).

From the repository's root:

    python -m benchmarks.step                          # B = 1, 64, 1024, 4096; N = 5 .. 100
    python -m benchmarks.step --batches 1 1024 --sizes --rounds 7 --vmas
    python -m benchmarks.step --profile 1024           # torch.profiler table of one compiled step
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if not __package__:  # `python benchmarks/step.py`: the repository's root, so `benchmarks` imports
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import torch  # noqa: E402

from benchmarks.rows import vmas_env  # noqa: E402
from benchmarks.timing import paired  # noqa: E402  best of alternated rounds, after a warm-up
from flock_torchrl import FlockingEnv  # noqa: E402
from flock_torchrl.world.state import STATE_KEYS  # noqa: E402


def stepper(env: FlockingEnv, steps: int, api: str = "step"):
    """A callable taking ``steps`` steps from one fixed state under fixed random actions (of the
    world's dimension): ``api`` ``step`` (TorchRL's ``env.step``), ``_step`` (the env's own step) or
    ``advance`` (the pure step function, with the episode summary)."""
    td = env.reset()
    gen = torch.Generator().manual_seed(0)
    action = torch.rand(env.num_envs, env.n_agents, env.cfg.dims, generator=gen) * 2 - 1
    td.set(("agents", "action"), action.to(env.device))
    world = env.world

    def go() -> None:
        for _ in range(steps):
            env.world = world
            if api == "step":
                env.step(td)
            elif api == "_step":
                env._step(td)
            else:
                state = {k: world[k] for k in STATE_KEYS}
                env._transition(state, world["sensed"].to_dict(), world["episode"].to_dict(), td["agents", "action"],
                                normals=None)
    return go


def vmas_stepper(num_envs: int, steps: int):
    """TorchRL's ``VmasEnv("flocking", n_agents=5)`` taking ``steps`` steps with fixed random
    actions (VMAS keeps stepping finished worlds), or ``None`` without vmas."""
    if (env := vmas_env(num_envs)) is None:
        return None
    td = env.rand_action(env.reset())

    def go() -> None:
        for _ in range(steps):
            env.step(td)
    return go


def batch_table(batches, rounds: int, scenario: str, policy: str, api: str, vmas: bool) -> None:
    print(f"ms per env step ({api}), {scenario}/{policy}, N=5; best of {rounds} alternated rounds")
    print(f"{'B':>6} {'eager':>9} {'compiled':>9} {'ratio':>7}" + (f" {'vmas':>9} {'vs vmas':>8}" if vmas else ""))
    for b in batches:
        steps = max(3, 2048 // b) if b < 1024 else 3
        envs = {name: FlockingEnv(scenario, b, "cpu", 0, policy_id=policy, compile_step=(name == "compiled"))
                for name in ("eager", "compiled")}
        candidates = {name: stepper(env, steps, api) for name, env in envs.items()}
        if vmas and (go := vmas_stepper(b, steps)) is not None:
            candidates["vmas"] = go
        best = paired(candidates, rounds)
        e, c = (1e3 * best[k] / steps for k in ("eager", "compiled"))
        line = f"{b:>6} {e:>9.3f} {c:>9.3f} {e / c:>7.2f}"
        if "vmas" in best:
            v = 1e3 * best["vmas"] / steps
            line += f" {v:>9.3f} {v / c:>8.2f}"
        print(line, flush=True)


def size_table(sizes, total: int, rounds: int, reading: str, api: str) -> None:
    print(f"swarm scale, eager ({api}), B x N = {total}, reading {reading}; best of {rounds} alternated rounds")
    envs = {n: FlockingEnv("train", max(1, total // n), "cpu", 0, reading=reading, policy_id="policy3_g", n_uavs=n)
            for n in sizes}
    best = paired({n: stepper(env, 3, api) for n, env in envs.items()}, rounds)
    per = {n: best[n] / 3 / (envs[n].num_envs * n) for n in sizes}
    print(f"{'N':>5} {'B':>6} {'ms/step':>9} {'ns/UAV-step':>12} {'vs N=' + str(sizes[0]):>9}")
    for n in sizes:
        print(f"{n:>5} {envs[n].num_envs:>6} {1e3 * best[n] / 3:>9.3f} {1e9 * per[n]:>12.1f} "
              f"{per[n] / per[sizes[0]]:>9.2f}", flush=True)


def profile(b: int, compiled: bool, scenario: str, policy: str, n_uavs: int | None) -> None:
    from torch.profiler import ProfilerActivity, profile as prof

    extra = {} if n_uavs is None else {"n_uavs": n_uavs, "reading": "paper_fit"}
    env = FlockingEnv(scenario, b, "cpu", 0, policy_id=policy, compile_step=compiled, **extra)
    go = stepper(env, 5, "_step")
    go()
    go()
    with prof(activities=[ProfilerActivity.CPU]) as p:
        go()
    print(p.key_averages().table(sort_by="self_cpu_time_total", row_limit=30))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="*", default=[1, 64, 1024, 4096])
    parser.add_argument("--sizes", type=int, nargs="*", default=[5, 20, 50, 100])
    parser.add_argument("--total", type=int, default=5120, help="B x N of the swarm-scale table")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--scenario", default="train")
    parser.add_argument("--policy", default="policy3_g")
    parser.add_argument("--reading", default="paper_fit", help="reading of the swarm-scale table")
    parser.add_argument("--api", choices=("step", "_step", "advance"), default="step")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--vmas", action="store_true", help="also time VmasEnv('flocking', n_agents=5)")
    parser.add_argument("--profile", type=int, default=None, metavar="B", help="profile one step at batch B")
    parser.add_argument("--eager", action="store_true", help="with --profile: the eager step")
    parser.add_argument("--n-uavs", type=int, default=None, help="with --profile: swarm size")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    if args.profile is not None:
        profile(args.profile, not args.eager, args.scenario, args.policy, args.n_uavs)
        return
    if args.batches:
        batch_table(args.batches, args.rounds, args.scenario, args.policy, args.api, args.vmas)
    if args.sizes:
        size_table(args.sizes, args.total, args.rounds, args.reading, args.api)


if __name__ == "__main__":
    main()
