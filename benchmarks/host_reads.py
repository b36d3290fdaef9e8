"""Host reads per training iteration: what makes a GPU wait for the host, counted on any device.

    .venv/bin/python -m benchmarks.host_reads [--iterations 200] [--recipe paper] [--members 1] [--launches]
        [-- override ...]

Trains Policy3-G under ``--recipe`` with ``cudagraphs=true`` (the captured update; a pass-through
on a CPU) and the env's static-shape step run eagerly (the step ``compile=true`` compiles, so
that :class:`~benchmarks.counting.HostReads` sees inside it), warms up for the
recipe's random frames plus 20 iterations, counts ``--iterations`` iterations of the loop
(collection, buffer, sampling, update, bookkeeping; logging, evaluation and checkpoints are
off) and prints the reads per iteration by the line that made them. Reads inside the captured
update are listed apart: a CUDA graph's replay never makes them. ``--launches``: also the
kernels launched per iteration outside the captured graphs (one by one on a GPU) and inside.
"""

from __future__ import annotations

import argparse
import functools
import sys
import tempfile
from pathlib import Path

if not __package__:  # `python benchmarks/host_reads.py`: the repository's root, so `benchmarks` imports
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.counting import HostReads  # noqa: E402
from benchmarks.population import SHORT_RUN, recipe_config  # noqa: E402
from flock_torchrl.capture import captured  # noqa: E402
from flock_torchrl.run.trainer import Training  # noqa: E402
from flock_torchrl.world.step import transition  # noqa: E402

WARMUP = 20  # iterations after the random frames before counting: every capture's warm-up is over
LAUNCH_PLACES = 8  # places listed under the kernel count


def counted(start: int, launches: bool, as_compiled: bool) -> type[Training]:
    """:class:`Training` whose envs step by the static-shape step run eagerly (``as_compiled``),
    and whose loop counts host reads (``launches``: and kernels) from iteration ``start`` on (the
    class's ``reads``, over its ``iterations``). The run is to be eager (``compile=false``, the
    default): the counter sees what compiled code's eager twins do."""

    class Counted(Training):
        reads: HostReads | None = None
        iterations = 0

        def _build(self, payload):
            super()._build(payload)
            # As the env builds it with compile_step=False (captured with cudagraphs=true).
            for env in self.envs if as_compiled else ():
                env._transition = captured(functools.partial(transition, static_shapes=True, static=env._static,
                                                             cfg=env.cfg), env.device, env.capture_step)

        def _consume(self, batches):
            if self.counters["iterations"] == start:
                Counted.reads = HostReads(launches=launches).__enter__()
            out = super()._consume(batches)
            if Counted.reads is not None:
                Counted.iterations += 1
            return out

        def _loop(self, schedule, signals):
            try:
                super()._loop(schedule, signals)
            finally:
                if Counted.reads is not None:
                    Counted.reads.__exit__(None, None, None)

    return Counted


def count_reads(recipe: str = "paper", members: int = 1, iterations: int = 200,
                overrides: tuple[str, ...] = (), launches: bool = False,
                as_compiled: bool = True) -> tuple[HostReads, int]:
    """``(the reads counted, the iterations they span)`` of a short run (see the module's
    docstring); ``launches``: the kernels launched too (``HostReads(launches=True)``, slower);
    ``as_compiled=False``: the env steps as the run builds it (not the static-shape step)."""
    exp = recipe_config(recipe, ["progress=false", "logger=none", "reading=paper_fit", *overrides]).experiment
    per_iteration = exp.num_envs * exp.steps_per_batch
    start = -(-exp.init_random_frames // per_iteration) + WARMUP
    frames = (start + iterations) * per_iteration
    # log_every_frames past the end: never logged (0 would log every batch, reading the statistics each iteration).
    cfg = recipe_config(recipe, [*SHORT_RUN, "reading=paper_fit", "cudagraphs=true", f"population={members}",
                                 f"experiment.max_frames={frames}", f"experiment.log_every_frames={2 * frames}",
                                 *overrides])
    cls = counted(start, launches, as_compiled)
    with tempfile.TemporaryDirectory() as folder:
        cls(cfg, Path(folder) / "run").run()
    return cls.reads, cls.iterations


def host_read_lines(recipe: str = "paper", members: int = 1, iterations: int = 200,
                    overrides: tuple[str, ...] = (), launches: bool = False) -> list[str]:
    reads, n = count_reads(recipe, members, iterations, overrides, launches)
    captured = sum(reads.in_captured.values())
    shown = " ".join(overrides)
    head = (f"host reads per iteration, {recipe} recipe, {'solo' if members == 1 else f'population of {members}'}"
            f"{', ' + shown if shown else ''}: {reads.total / n:.3f} ({captured / n:.2f} more inside the captured "
            f"update, which a CUDA graph's replay never makes); {n} iterations counted; tensors made from Python "
            f"numbers (a copy from the host on a GPU): {sum(reads.made.values()) / n:.3f}")
    made = [f"{count / n:8.3f}  made from numbers    {place}" for place, count in reads.made.most_common()]
    lines = [head] + ["  " + line for line in [*reads.table(per=n).splitlines(), *made]]
    if launches:
        outside = sum(reads.launched.values())
        lines.append(f"kernels per iteration, the same run: {outside / n:.1f} launched one by one (each a launch "
                     f"the host pays for on a GPU), {reads.launched_in_graphs / n:.1f} inside the captured graphs; "
                     "the most by place:")
        lines += [f"  {count / n:8.2f}  {place}" for place, count in reads.launched.most_common(LAUNCH_PLACES)]
    return lines


def launch_lines(recipe: str = "paper", iterations: int = 200) -> list[str]:
    """The kernels a solo loop of ``recipe`` launches one by one per iteration, as it runs eagerly
    (``cudagraphs=false``, ``reset_pool=0``: the default step) against captured (``cudagraphs=true``
    with a reserve: the update, the policy, the static-shape step and the hand-out as graphs), and
    where each launches them."""
    runs = {}
    for name, overrides in (("uncaptured", ("cudagraphs=false", "reset_pool=0")), ("captured", ("reset_pool=256",))):
        reads, n = count_reads(recipe, 1, iterations, overrides, launches=True, as_compiled=False)
        runs[name] = (sum(reads.launched.values()) / n, reads.launched_in_graphs / n, reads.launched, n)
    (plain, _, plain_places, n), (ours, graphs, places, _) = runs["uncaptured"], runs["captured"]
    lines = [f"kernels launched one by one per iteration, {recipe} recipe, solo ({n} iterations): {ours:.1f} "
             f"captured (cudagraphs=true reset_pool=256; {graphs:.1f} more inside its graphs) against {plain:.1f} "
             f"uncaptured (cudagraphs=false reset_pool=0): {plain / ours:.1f}x fewer"]
    for name, counts in (("uncaptured", plain_places), ("captured", places)):
        lines += [f"  {name:10s} {count / n:8.2f}  {place}" for place, count in counts.most_common(LAUNCH_PLACES)]
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recipe", default="paper")
    parser.add_argument("--members", type=int, default=1)
    parser.add_argument("--iterations", type=int, default=200)
    parser.add_argument("--launches", action="store_true", help="count the kernels launched too")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides of the run (e.g. reset_pool=64)")
    args = parser.parse_args()
    print(*host_read_lines(args.recipe, args.members, args.iterations, tuple(args.overrides), args.launches),
          sep="\n", flush=True)


if __name__ == "__main__":
    main()
