"""Populations against solo runs: member-updates per second of the whole training loop.

    .venv/bin/python benchmarks/population.py [--frames 3000] [--members 10] [--recipes paper,fast]

Each row trains into a temporary folder: one solo run and one population of ``--members`` seeds
under the same recipe and frame budget per member, the population's update eager (torch.vmap) and
the solo run's both eager and compiled (the paper recipe's shipped runs compiled it). A row's rate
counts the loop's own time (env, collection, buffer, sampling, update: the run's time split without
evaluation, checkpoints or the first compiled update) and prints where that time went. Each row
trains in a fresh child process, so its peak resident memory (``ru_maxrss``) is its own: a
population's memory per member is its peak over the members, and what each member beyond the first
adds is the population's peak less the solo run's, over ``members - 1``. The paper recipe's rows end
with what its collector costs per step (:mod:`benchmarks.collection`). The GPU's rows are
:mod:`benchmarks.gpu`'s. Run with one thread (``OMP_NUM_THREADS=1``), as the recipes' trainings do.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if not __package__:  # `python benchmarks/population.py`: the repository's root, so `benchmarks` imports
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import torch  # noqa: E402

from benchmarks.timing import Lines  # noqa: E402
from flock_torchrl.config import TrainConfig  # noqa: E402
from flock_torchrl.policies.learners import OffPolicyLearner, make_learner  # noqa: E402
from flock_torchrl.run.launch import train  # noqa: E402
from flock_torchrl.run.setup import make_train_config  # noqa: E402

LOOP = ("collection", "buffer", "sampling", "update", "members")
# A training run cut to its loop: no episode limit, evaluation, checkpoints, progress bar or logger.
SHORT_RUN = ("experiment.max_episodes=0", "experiment.eval_every_frames=0", "experiment.eval_episodes=1",
             "experiment.checkpoint_every_frames=0", "progress=false", "logger=none")


def recipe_config(recipe: str, overrides=()) -> TrainConfig:
    """Policy3-G's checked training config under ``recipe`` and ``overrides``."""
    return TrainConfig.from_config(make_train_config("policy3_g", recipe, overrides))


def recipe_transitions(recipe: str):
    """``(config, env, transitions)``: Policy3-G under ``recipe`` and 200 steps of one world's
    swarm transitions (random actions), what the in-process measurements feed the learners."""
    from flock_torchrl import FlockingEnv
    from flock_torchrl.run.batches import TRANSITION_KEYS, agentwise_done

    cfg = recipe_config(recipe, ["progress=false", "logger=none", "reading=paper_fit"])
    env = FlockingEnv(cfg.train_scenario, num_envs=1, seed=0)
    seen = agentwise_done(env.rollout(200, break_when_any_done=False), env.n_agents)
    return cfg, env, seen.select(*TRANSITION_KEYS, strict=False).reshape(-1)


def learner_batches(cfg: TrainConfig, env, seen, members: int, count: int = 8, device: str = "cpu",
                    cudagraphs: bool = False):
    """``(learner, batches)``: a solo learner (``members`` 1) or a population's (vmapped), and
    ``count`` minibatches drawn from ``seen`` for it (``[batch_size]``, or ``[batch_size, members]``)."""
    if members == 1:
        learner = make_learner(env, cfg.algo, cfg.policy.critic_input, cudagraphs=cudagraphs)
    else:
        learner = OffPolicyLearner(env, cfg.algo, cfg.policy.critic_input, list(range(members)),
                                   cudagraphs=cudagraphs)
    size = cfg.algo.batch_size
    batches = [seen[torch.randint(0, seen.shape[0], (size * members,), device=device)] for _ in range(count)]
    return learner, batches if members == 1 else [batch.reshape(size, members) for batch in batches]


def update_arithmetic(recipe: str, members: int) -> tuple[float, float]:
    """``(MFLOP of one member-update, GFLOP/s of this core's matmul at the update's shape)``.

    The FLOPs are the matrix products of one member's update of Policy3-G under ``recipe`` (what
    ``torch.profiler`` counts with ``with_flops`` in a population of two, halved: the networks'
    linear layers, forward and backward); the rate is a ``[members, rows, 128] x [128, 128]``
    batched product, ``rows`` the UAV rows of one minibatch, the hidden layers' shape, timed here.
    Their ratio bounds what any batching of the members' updates can reach on this core."""
    from torch.profiler import profile

    cfg, env, seen = recipe_transitions(recipe)
    # Two members under vmap: the batched products (bmm) the population runs, counted once each.
    learner, (batch,) = learner_batches(cfg, env, seen, 2, count=1)
    learner.update(batch)
    with profile(with_flops=True) as prof:
        learner.update(batch)
    flop = sum(e.flops for e in prof.key_averages() if e.flops) / 2
    rows = cfg.algo.batch_size * env.n_agents
    a, b = torch.randn(members, rows, 128), torch.randn(members, 128, 128)
    for _ in range(5):
        torch.bmm(a, b)
    start, repeats = time.perf_counter(), 100
    for _ in range(repeats):
        torch.bmm(a, b)
    rate = 2 * members * rows * 128 * 128 * repeats / (time.perf_counter() - start)
    return flop / 1e6, rate / 1e9


def run_row(recipe: str, members: int, frames: int, compile: str, folder: Path, device: str = "cpu",
            cudagraphs: str = "false", reset_pool: int = 0) -> dict:
    """One training run; its loop's member-updates/s and split, its set-up time (the run's wall
    time outside the loop, evaluation and checkpoints: envs, learner, collectors, first
    compilation), its peak memory (and the GPU's, on one)."""
    cfg = recipe_config(recipe, [f"population={members}", f"experiment.max_frames={frames}", *SHORT_RUN,
                                 f"compile={compile}", "reading=paper_fit", f"device={device}",
                                 f"cudagraphs={cudagraphs}", f"reset_pool={reset_pool}"])
    start = time.perf_counter()
    result = train(cfg, folder / f"{recipe}_{members}_{compile}_{device}_{cudagraphs}_{reset_pool}")
    wall = time.perf_counter() - start
    loop = sum(result.split.get(k, 0.0) for k in LOOP)
    return {"recipe": recipe, "members": members, "compile": compile, "device": device, "cudagraphs": cudagraphs,
            "reset_pool": reset_pool, "updates": result.updates,
            "member_updates_per_s": members * result.updates / loop, "loop_s": loop,
            "setup_s": wall - sum(result.split.values()),
            "split": {k: result.split.get(k, 0.0) / loop for k in LOOP if result.split.get(k, 0.0)},
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,   # Linux: KiB
            "gpu_peak_mb": torch.cuda.max_memory_allocated() / 2**20 if device.startswith("cuda") else 0.0}


def row_in_child(recipe: str, members: int, frames: int, compile: str, folder: Path, device: str,
                 cudagraphs: str = "false", timeout: float | None = None, reset_pool: int = 0) -> dict | None:
    """:func:`run_row` in a fresh Python process (its peak memory is its own); ``None`` if it
    did not finish within ``timeout`` seconds."""
    try:
        done = subprocess.run([sys.executable, __file__, "--row", recipe, str(members), str(frames), compile,
                               str(folder), device, cudagraphs, "--reset-pool", str(reset_pool)],
                              capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return None
    if done.returncode:
        raise RuntimeError(f"benchmark row {recipe} x{members} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def interleaved_updates(recipe: str, members: int, rounds: int = 5, block: int = 60) -> dict[str, list[float]]:
    """Member-updates per second of the update alone, solo (TorchRL's SACLoss, eager) and a
    population of ``members`` (vmapped), measured in this process in alternating blocks of
    ``block`` member-updates, ``rounds`` times: both sides see the same machine at the same
    minutes, which rows trained one after another in child processes do not (a shared
    machine's speed drifts by tens of per cent within minutes)."""
    cfg, env, seen = recipe_transitions(recipe)
    sides = {name: (*learner_batches(cfg, env, seen, k), k) for name, k in (("solo", 1), ("population", members))}
    for learner, batches, _ in sides.values():  # warm-up
        for batch in batches[:3]:
            learner.update(batch)
    rates: dict[str, list[float]] = {name: [] for name in sides}
    for _ in range(rounds):
        for name, (learner, batches, k) in sides.items():
            calls = max(1, block // k)
            start = time.perf_counter()
            for i in range(calls):
                learner.update(batches[i % len(batches)])
            rates[name].append(calls * k / (time.perf_counter() - start))
    return rates


def evaluation_line(recipe: str, members: int, episodes: int = 1) -> str:
    """A population's evaluation: its members' actors evaluated one after another (as
    :func:`~flock_torchrl.run.rollout.evaluate` does for one) against together in one batched
    rollout (:func:`~flock_torchrl.run.rollout.evaluate_members`, what a population runs), the
    same episodes, in this process."""
    import copy

    from flock_torchrl.run.rollout import evaluate, evaluate_members

    cfg, env, _ = recipe_transitions(recipe)
    learner = OffPolicyLearner(env, cfg.algo, cfg.policy.critic_input, list(range(members)))
    actor = copy.deepcopy(learner.actor)
    start = time.perf_counter()
    for k in range(members):
        actor.load_state_dict(learner.actor_state(k))
        evaluate(actor, cfg.scenario, n_episodes=episodes, seed=cfg.eval_seed)
    apart = time.perf_counter() - start
    start = time.perf_counter()
    evaluate_members(actor, learner.params.get("actor_network_params").detach(), cfg.scenario, episodes, cfg.eval_seed)
    together = time.perf_counter() - start
    return (f"population {recipe:5s} cpu  evaluation of {members} untrained members, {episodes} episode(s) each: one "
            f"after another {apart:.1f} s, together {together:.1f} s ({apart / together:.1f}x)")


def population_lines(frames: int = 3000, members: int = 10, recipes: str = "paper,fast",
                     print_each: bool = True, rates: dict | None = None) -> list[str]:
    """The rows of every recipe, each line printed as soon as it is measured with ``print_each``;
    ``rates``, if given, receives each row's member-updates/s under ``(recipe, members, compile)``."""
    lines = Lines(print_each)
    rates = {} if rates is None else rates
    with tempfile.TemporaryDirectory() as tmp:
        for recipe in recipes.split(","):
            n = frames if recipe == "paper" else max(frames, 4096)
            mflop, peak = update_arithmetic(recipe, members)
            lines.say(f"population {recipe:5s} cpu  arithmetic: {mflop:.0f} MFLOP of matmuls per member-update; this "
                      f"core's batched matmul at the update's shape runs {peak:.1f} GFLOP/s, so no batching of the "
                      f"updates passes {1000 * peak / mflop:.0f} member-updates/s of update time on one core")
            alone = interleaved_updates(recipe, members)
            solo, pop = (statistics.median(alone[k]) for k in ("solo", "population"))
            lines.say(f"population {recipe:5s} cpu  the update alone, interleaved in one process "
                      f"({len(alone['solo'])} rounds, medians): solo {solo:.0f} updates/s, population of {members} "
                      f"{pop:.0f} member-updates/s = {pop / solo:.2f}x")
            # The CPU's rows (the GPU's, captured, are benchmarks/gpu.py's); the paper recipe's solo run compiled too.
            base = solo_mb = None
            for k, compile in [(1, "false")] + ([(1, "true")] if recipe == "paper" else []) + [(members, "false")]:
                r = row_in_child(recipe, k, n, compile, Path(tmp), "cpu")
                rates[recipe, k, compile] = r["member_updates_per_s"]
                base = base or r["member_updates_per_s"]
                solo_mb = solo_mb or r["peak_mb"]
                in_update = r["member_updates_per_s"] / max(r["split"].get("update", 0.0), 1e-9)
                split = ", ".join(f"{key} {100 * v:.0f} %" for key, v in r["split"].items())
                memory = (f"peak {r['peak_mb']:.0f} MB, {r['peak_mb'] / k:.0f} MB per member, each member past "
                          f"the first {(r['peak_mb'] - solo_mb) / (k - 1):.0f} MB" if k > 1
                          else f"peak {r['peak_mb']:.0f} MB")
                lines.say(f"population {recipe:5s} cpu  members {r['members']:2d} compile={r['compile']:5s}: "
                          f"{r['member_updates_per_s']:8.1f} member-updates/s ({r['member_updates_per_s'] / base:.2f}x "
                          f"the eager solo row; {r['updates']} updates in {r['loop_s']:.1f} s; {split}; the update "
                          f"alone {in_update:.0f} member-updates/s, {in_update * mflop / 1000:.1f} GFLOP/s; {memory})")
            if recipe == "paper":
                lines.say(evaluation_line(recipe, members))
                from benchmarks.collection import collection_lines  # the solo loop's collection, per step
                lines.say(*collection_lines(compile=True, steps=300 if frames >= 3000 else 100,
                                            rounds=7 if frames >= 3000 else 3))
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=3000)
    parser.add_argument("--members", type=int, default=10)
    parser.add_argument("--recipes", default="paper,fast")
    parser.add_argument("--row", nargs=7, metavar=("RECIPE", "MEMBERS", "FRAMES", "COMPILE", "FOLDER", "DEVICE",
                                                   "CUDAGRAPHS"),
                        help="one row, printed as JSON (what population_lines runs in a child process)")
    parser.add_argument("--reset-pool", type=int, default=0, help="the row's reset_pool")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.row:
        recipe, k, frames, compile, folder, device, cudagraphs = args.row
        print(json.dumps(run_row(recipe, int(k), int(frames), compile, Path(folder), device, cudagraphs,
                                 args.reset_pool)))
        return
    population_lines(args.frames, args.members, args.recipes)


if __name__ == "__main__":
    main()
