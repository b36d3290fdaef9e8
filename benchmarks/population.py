"""Populations against solo runs: member-updates per second of the whole training loop.

    .venv/bin/python benchmarks/population.py [--frames 3000] [--members 10] [--recipes paper,fast]

Each row trains in this process, side by side, into a temporary folder: one solo run and one
population of ``--members`` seeds under the same recipe and frame budget per member, the
population's update eager (torch.vmap) and the solo run's both eager and compiled (the paper
recipe's shipped runs compiled it). A row's rate counts the loop's own time (env, collection,
buffer, sampling, update: the run's time split without evaluation, checkpoints or the first
compiled update) and prints where that time went. Peak memory per member is the population's
replay buffer and stacked parameters (bytes of their tensors) divided by the members.
Run with one thread (``OMP_NUM_THREADS=1``), as the recipes' trainings do.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch

from flock_torchrl.config import TrainConfig
from flock_torchrl.run.launch import train
from flock_torchrl.run.trainer import make_train_config

LOOP = ("env", "collection", "buffer", "sampling", "update", "members")


def run_row(recipe: str, members: int, frames: int, compile: str, folder: Path) -> dict:
    overrides = [f"population={members}", f"experiment.max_frames={frames}", "experiment.max_episodes=0",
                 "experiment.eval_every_frames=0", "experiment.eval_episodes=1", "experiment.checkpoint_every_frames=0",
                 "progress=false", "logger=none", f"compile={compile}", "reading=paper_fit"]
    cfg = TrainConfig.from_config(make_train_config("policy3_g", recipe, overrides))
    result = train(cfg, folder / f"{recipe}_{members}_{compile}")
    loop = sum(result.split.get(k, 0.0) for k in LOOP)
    return {"recipe": recipe, "members": members, "compile": compile, "updates": result.updates,
            "member_updates_per_s": members * result.updates / loop, "loop_s": loop,
            "split": {k: result.split.get(k, 0.0) / loop for k in LOOP if result.split.get(k, 0.0)}}


def population_lines(frames: int = 3000, members: int = 10, recipes: str = "paper,fast",
                     print_each: bool = True) -> list[str]:
    """The rows of every recipe, each line printed as soon as it is measured."""
    lines = []
    with tempfile.TemporaryDirectory() as tmp:
        for recipe in recipes.split(","):
            n = frames if recipe == "paper" else max(frames, 4096)
            plan = [(1, "false")] + ([(1, "true")] if recipe == "paper" else []) + [(members, "false")]
            base = None
            for k, compile in plan:
                r = run_row(recipe, k, n, compile, Path(tmp))
                base = base or r["member_updates_per_s"]
                split = ", ".join(f"{key} {100 * v:.0f} %" for key, v in r["split"].items())
                line = (f"population {recipe:5s} members {r['members']:2d} compile={r['compile']:5s}: "
                        f"{r['member_updates_per_s']:8.1f} member-updates/s ({r['member_updates_per_s'] / base:.2f}x "
                        f"the eager solo row; {r['updates']} updates in {r['loop_s']:.1f} s; {split})")
                lines.append(line)
                if print_each:
                    print(line, flush=True)
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=3000)
    parser.add_argument("--members", type=int, default=10)
    parser.add_argument("--recipes", default="paper,fast")
    args = parser.parse_args()
    torch.set_num_threads(1)
    population_lines(args.frames, args.members, args.recipes)


if __name__ == "__main__":
    main()
