"""What TorchRL's ``Collector`` costs per step around the env, on the paper recipe's one world:
milliseconds per collected step of the training run's collector (:func:`~flock_torchrl.run.parts.make_collectors`
as an off-policy run builds it) against a bare loop of the same policy and
``env.step_and_maybe_reset``, and against the collector TorchRL's defaults give (a fresh copy of
every batch, the SAC actor's ``ProbabilisticActor`` as the policy); the policy calls alone, too.

    .venv/bin/python -m benchmarks.collection [--compile true] [--steps 300] [--rounds 7]

Each candidate steps its own env (same scenario and seed) with Policy3-G's untrained SAC actor.
Candidates alternate round by round in one process and each keeps its best round
(:func:`benchmarks.timing.paired`), so load from other processes hits all of them alike. Run with
one thread (``OMP_NUM_THREADS=1``), as the recipes' trainings do.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if not __package__:  # `python benchmarks/collection.py`: the repository's root, so `benchmarks` imports
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import torch  # noqa: E402
from torchrl.collectors import Collector  # noqa: E402
from torchrl.envs.utils import ExplorationType, set_exploration_type  # noqa: E402

from benchmarks.timing import paired  # noqa: E402
from flock_torchrl.config import TrainConfig  # noqa: E402
from flock_torchrl.policies.learners import make_learner  # noqa: E402
from flock_torchrl.run.batches import AgentwiseDone  # noqa: E402
from flock_torchrl.run.parts import make_collectors, make_envs  # noqa: E402
from flock_torchrl.run.setup import make_train_config  # noqa: E402


def collection_lines(compile: bool = True, steps: int = 300, rounds: int = 7) -> list[str]:
    """The rows, as printed: ms per step of each candidate, its ratio to the bare loop."""
    cfg = TrainConfig.from_config(make_train_config("policy3_g", "paper", [
        f"compile={str(compile).lower()}", "reading=paper_fit", "progress=false", "logger=none"]))
    device = torch.device(cfg.device)
    torch.manual_seed(cfg.seed)

    def env():
        return make_envs(cfg, device)[0][0]

    bare_env, run_env, default_env = env(), env(), env()
    learner = make_learner(bare_env, cfg.algo, cfg.policy.critic_input, compile=cfg.compile_loss)
    policy, actor = learner.collector_policy, learner.actor
    run = make_collectors(cfg, [run_env], None, policy, 1, 0, device, reuse_batch=True)[0]
    default = Collector(default_env, actor, frames_per_batch=1, total_frames=-1, device=device,
                        exploration_type=ExplorationType.RANDOM, auto_register_policy_transforms=False,
                        track_traj_ids=False, postproc=AgentwiseDone(default_env.n_agents))
    run_batches, default_batches = iter(run), iter(default)
    carrier = bare_env.reset()
    policy_input = bare_env.reset()

    def bare() -> None:
        nonlocal carrier
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
            for _ in range(steps):
                carrier = policy(carrier)
                _, carrier = bare_env.step_and_maybe_reset(carrier)

    def collect(batches):
        def go() -> None:
            for _ in range(steps):
                next(batches)
        return go

    def act(module):
        def go() -> None:
            with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
                for _ in range(steps):
                    module(policy_input.copy())
        return go

    candidates = {"bare": (bare, bare_env), "run": (collect(run_batches), run_env),
                  "default": (collect(default_batches), default_env),
                  "policy": (act(policy), None), "actor": (act(actor), None)}
    best = paired({name: fn for name, (fn, _) in candidates.items()}, repeat=rounds)
    ms = {name: 1000 * t / steps for name, t in best.items()}
    head = f"collection paper cpu compile={str(compile).lower():5s}"
    return [
        f"{head} bare loop (policy + env.step_and_maybe_reset): {ms['bare']:.3f} ms/step",
        f"{head} the training run's Collector: {ms['run']:.3f} ms/step = {ms['run'] / ms['bare']:.2f}x the bare loop, "
        f"{ms['run'] - ms['bare']:+.3f} ms",
        f"{head} TorchRL's defaults (a copy of every batch, the ProbabilisticActor): {ms['default']:.3f} ms/step = "
        f"{ms['default'] / ms['bare']:.2f}x the bare loop; the run's Collector is {ms['default'] / ms['run']:.2f}x "
        f"faster",
        f"{head} the policy call alone: the run's SamplingActor {ms['policy']:.3f} ms, the ProbabilisticActor "
        f"{ms['actor']:.3f} ms ({ms['actor'] / ms['policy']:.2f}x)",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--compile", default="true", choices=["true", "false"])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(*collection_lines(args.compile == "true", args.steps, args.rounds), sep="\n", flush=True)


if __name__ == "__main__":
    main()
