"""The GPU's rows of ``make benchmark`` (where CUDA exists), and the projection line.

    .venv/bin/python -m benchmarks.gpu [--frames 3000]        # on a machine with CUDA

* **env**: env-steps/s at B = 65,536 (compiled and eager) against TorchRL's ``VmasEnv`` on the
  same GPU;
* **update alone**: SAC updates of the paper recipe (minibatch 128 swarm transitions), the
  captured update (``cudagraphs=true``) against the uncaptured one, solo and as populations of
  10 and 80, member-updates/s;
* **loops**: the paper and fast recipes' whole training loops with ``cudagraphs=true`` and a
  reserve of fresh worlds (``reset_pool``, :func:`reserve_for`; the paper recipe's solo loop
  also without) (``--compile``: the loops' ``compile``, default ``false``), solo and
  populations of 10 and 80, each in a child process: member-updates/s of the loop, its split,
  the set-up time outside the loop and the peak GPU memory;
* **projection**: the wall time of the paper's study (8 policies x 10 seeds x 816k updates, as
  eight populations of ten) and of ten ``fast`` seeds of the ten learned policies at the rates
  measured; :func:`projection_line` prints it for the CPU's rows too.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

if not __package__:  # `python benchmarks/gpu.py`: the repository's root, so `benchmarks` imports
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import torch  # noqa: E402

from benchmarks.population import learner_batches, recipe_config, recipe_transitions, row_in_child  # noqa: E402
from benchmarks.rows import env_rows, format_rows  # noqa: E402
from benchmarks.timing import Lines  # noqa: E402

# The paper's study: eight learned policies, ten seeds each, and about 816k updates per run
# (docs/results.md: Policy3-G's paper-recipe run, 816,026 updates in 5000 episodes).
PAPER_POLICIES, PAPER_SEEDS, PAPER_UPDATES = 8, 10, 816_000
# Ten seeds of each of the ten learned policies under the fast recipe.
FAST_POLICIES, FAST_SEEDS = 10, 10


def fast_updates() -> int:
    """Updates of one ``experiment=fast`` run: its batches after the random frames, times the
    updates per batch (from the composed recipe)."""
    exp = recipe_config("fast").experiment
    frames = exp.num_envs * exp.steps_per_batch
    learning = math.ceil(exp.max_frames / frames) - math.ceil(exp.init_random_frames / frames) + 1
    return max(learning, 0) * exp.updates_per_batch


def projection_line(where: str, paper_rate: float, fast_rate: float, members: int = 10) -> str:
    """The study's wall time at ``paper_rate`` and ``fast_rate`` member-updates/s (each a
    population of ``members`` seeds; one population per policy, one after another)."""
    if paper_rate <= 0 or fast_rate <= 0:  # e.g. a loop shorter than its recipe's random frames
        return (f"projection ({where}): none, a loop measured no updates (paper {paper_rate:.0f}, fast "
                f"{fast_rate:.0f} member-updates/s)")
    paper_h = PAPER_POLICIES * PAPER_SEEDS * PAPER_UPDATES / paper_rate / 3600
    fast = fast_updates()
    fast_h = FAST_POLICIES * FAST_SEEDS * fast / fast_rate / 3600
    return (f"projection ({where}): the paper's study ({PAPER_POLICIES} policies x {PAPER_SEEDS} seeds x "
            f"{PAPER_UPDATES:,} updates, populations of {members}) at {paper_rate:.0f} member-updates/s: "
            f"{paper_h:.1f} h; ten fast seeds of the ten learned policies ({fast:,} updates each) at "
            f"{fast_rate:.0f} member-updates/s: {fast_h:.2f} h")


def reserve_for(recipe: str) -> int:
    """The loops' ``reset_pool``: a reserve of fresh worlds for 64 steps of the recipe's worlds
    (at least 256), so a loop reads the device for its resets once in 64 steps at most."""
    return max(256, 64 * recipe_config(recipe).experiment.num_envs)


def synchronize(device: str) -> None:
    """Wait for ``device``'s queued work (nothing to wait for on a CPU)."""
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize(device)


def update_lines(device: str, members=(1, 10, 80), calls: int = 200) -> list[str]:
    """Member-updates/s of the paper recipe's update alone on ``device``: captured against not."""
    from flock_torchrl import FlockingEnv

    cfg, _, seen = recipe_transitions("paper")
    env = FlockingEnv(cfg.train_scenario, num_envs=1, seed=0, device=device)
    seen = seen.to(device)
    lines = []
    for k in members:
        rates = {}
        for cudagraphs in (False, True):
            torch.manual_seed(0)
            learner, batches = learner_batches(cfg, env, seen, k, device=device, cudagraphs=cudagraphs)
            for batch in batches:  # warm-up (and the capture)
                learner.update(batch)
            synchronize(device)
            start = time.perf_counter()
            for i in range(calls):
                learner.update(batches[i % len(batches)])
            learner.check()
            synchronize(device)
            rates[cudagraphs] = k * calls / (time.perf_counter() - start)
        lines.append(f"GPU update alone, paper recipe, {k:2d} member(s): captured {rates[True]:9.0f} member-updates/s, "
                     f"uncaptured {rates[False]:8.0f} ({rates[True] / rates[False]:.1f}x)")
    return lines


def gpu_lines(device: str = "cuda", frames: int = 3000, members=(10, 80), row_timeout: float | None = None,
              print_each: bool = False, compile: str = "false", fast_frames: int = 4096,
              update_members=(1, 10, 80), update_calls: int = 200, env_batch: int = 65536) -> list[str]:
    """Every GPU row, and the GPU's projection line (each line printed as it is measured with
    ``print_each``); a loop row that does not finish within ``row_timeout`` seconds says so.
    ``compile``: the loops' ``compile`` (``false``: what finished within a minute on an H200;
    with ``true``, ``step`` for populations, no row finished 1000 frames within 60 s there,
    compilation included). ``device="cpu"`` with small sizes is a dry run of the same code, and
    ``tests/test_benchmark.py`` runs them with ``device="cuda"`` on CUDA simulated on the CPU
    (``tests/simulated_cuda.py``), so a GPU's scarce minutes are not spent finding their bugs."""
    lines = Lines(print_each)
    name = torch.cuda.get_device_name(device) if torch.device(device).type == "cuda" else f"none ({device}: a dry run)"
    lines.say(f"GPU: {name}, torch {torch.__version__}")
    lines.say(*update_lines(device, update_members, update_calls))
    rates: dict[tuple[str, int], float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for recipe in ("paper", "fast"):
            n = frames if recipe == "paper" else max(frames, fast_frames)
            pool = reserve_for(recipe)
            # The paper recipe's solo loop also without the reserve: TorchRL's resets, which read the device.
            for k, reserve in ([(1, 0)] if recipe == "paper" else []) + [(k, pool) for k in (1, *members)]:
                # A population's vmapped update is not compiled (captured as a whole): at most its step.
                mode = "step" if compile == "true" and k > 1 else compile
                what = f"GPU loop {recipe:5s} members {k:2d} cudagraphs=true compile={mode} reset_pool={reserve}"
                r = row_in_child(recipe, k, n, mode, Path(tmp), device, "true", row_timeout, reserve)
                if r is None:
                    lines.say(f"{what}: did not finish {n} frames within {row_timeout:.0f} s")
                    continue
                if reserve:
                    rates[recipe, k] = r["member_updates_per_s"]
                split = ", ".join(f"{key} {100 * v:.0f} %" for key, v in r["split"].items())
                lines.say(f"{what}: {r['member_updates_per_s']:9.0f} member-updates/s ({r['updates']} updates in "
                          f"{r['loop_s']:.1f} s; {split}); set-up {r['setup_s']:.1f} s; peak GPU memory "
                          f"{r['gpu_peak_mb']:.0f} MB")
    if ("paper", members[0]) in rates and ("fast", members[0]) in rates:
        lines.say(projection_line("GPU", rates["paper", members[0]], rates["fast", members[0]], members[0]))
    lines.say(*format_rows(env_rows((env_batch,), steps=4, repeat=2, device=device)).splitlines()[1:])
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=3000)
    parser.add_argument("--row-timeout", type=float, default=None, help="seconds a loop row may take")
    parser.add_argument("--compile", default="false", choices=("false", "true", "step"), help="the loops' compile")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if not torch.cuda.is_available():
        print("benchmarks.gpu: no CUDA device here (torch.cuda.is_available() is False)", file=sys.stderr)
        sys.exit(2)
    gpu_lines(frames=args.frames, row_timeout=args.row_timeout, print_each=True, compile=args.compile)


if __name__ == "__main__":
    main()
