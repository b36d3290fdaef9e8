"""Where a training loop's time goes, and its progress bar."""

from __future__ import annotations

import math
import sys
import time
from contextlib import contextmanager
from typing import Any, Iterable, Iterator

import torch

# The parts of a training loop's wall time, in the order a time split is printed. "collection": the
# collector's batches, the env's steps included; "compile": a compiled learner's first update in this
# process, where torch.compile works.
_END = object()
BUCKETS = ("collection", "buffer", "sampling", "update", "compile", "logging", "evaluation", "checkpoints")


class TimeSplit(dict):
    """Seconds of a loop by part (a ``dict`` of :data:`BUCKETS`, and any added): ``with
    split.timer("buffer"): ...`` adds that block's time to its part, timed from outside what it
    times (as TorchRL's sota scripts do with ``timeit``).

    ``device``: where the loop's tensors live. On a CPU a block is the host's wall time. On a CUDA
    device the host runs ahead of the GPU, so a block is timed on the device, between two CUDA
    events recorded on its stream, and nothing waits: the events are read by :meth:`settle`, which
    the loop calls where it reads the host anyway (logging, the end). ``profile``: on CUDA,
    synchronise at each block's start and end instead and book host wall time (a part then holds
    the GPU work it launched, at the cost of two synchronisations a block)."""

    def __init__(self, *more: str, device: torch.device | str | None = None, profile: bool = False) -> None:
        super().__init__(dict.fromkeys((*BUCKETS, *more), 0.0))
        cuda = torch.device("cpu" if device is None else device).type == "cuda"
        self.synchronize = (lambda: torch.cuda.synchronize(device)) if cuda and profile else None
        self.events: list[tuple[str, Any, Any]] | None = [] if cuda and not profile else None

    @contextmanager
    def timer(self, bucket: str) -> Iterator[None]:
        if self.events is not None:
            start = torch.cuda.Event(enable_timing=True)
            start.record()
            try:
                yield
            finally:
                end = torch.cuda.Event(enable_timing=True)
                end.record()
                self.events.append((bucket, start, end))
            return
        if self.synchronize is not None:
            self.synchronize()
        begun = time.perf_counter()
        try:
            yield
        finally:
            if self.synchronize is not None:
                self.synchronize()
            self[bucket] += time.perf_counter() - begun

    def settle(self) -> "TimeSplit":
        """Book the blocks timed on the device since the last call (waits for the last of them)."""
        if self.events:
            self.events[-1][2].synchronize()
            for bucket, start, end in self.events:
                self[bucket] += start.elapsed_time(end) / 1000.0
            self.events.clear()
        return self

    def timed(self, iterable: Iterable[Any], bucket: str) -> Iterator[Any]:
        """The items of ``iterable``, the time each takes to come booked under ``bucket``."""
        items = iter(iterable)
        while True:
            with self.timer(bucket):
                item = next(items, _END)
            if item is _END:
                return
            yield item


def rates(split: dict[str, float], counters: dict[str, Any], members: int = 1) -> dict[str, float]:
    """Updates and frames per second of a loop's own time: the process's (every member's, for
    ``members``), and for several members each one's (``member_...``)."""
    updates = counters["updates"] / max(split["sampling"] + split["update"], 1e-9)  # each member's
    frames = counters["frames"] / max(split["collection"], 1e-9)
    out = {"perf/updates_per_s": members * updates, "perf/frames_per_s": members * frames}
    if members > 1:
        out.update({"perf/member_updates_per_s": updates, "perf/member_frames_per_s": frames})
    return out


def split_line(split: dict[str, float]) -> str:
    """``time split (..): env 10.2 s (31 %), collection ...`` over a training loop."""
    total = sum(split.values())
    parts = ", ".join(f"{k} {v:.1f} s ({100 * v / total:.0f} %)" for k, v in split.items())
    return f"time split ({total:.0f} s of training loop): {parts}"


def seeds_label(seeds: list[int]) -> str:
    """What a progress bar calls a run's seeds: ``seed 3``; a population's ``seeds 0-9``."""
    seeds = list(seeds)
    if len(seeds) == 1:
        return f"seed {seeds[0]}"
    contiguous = seeds == list(range(seeds[0], seeds[0] + len(seeds)))
    return f"seeds {seeds[0]}-{seeds[-1]}" if contiguous else "seeds " + ",".join(map(str, seeds))


class Progress:
    """A training's progress over frames (each member's). On a terminal, a tqdm bar; off one (a
    redirected log), a line every ``every`` seconds instead, as an evaluation's progress is, with no
    carriage return in the file. Its total is the frame budget rounded up to whole batches of
    ``per_batch`` frames (what the run collects before it stops), and its rate, so its time left,
    counts only the frames after the first ``random_frames`` (collected with random actions and no
    update: several times faster than the rest)."""

    def __init__(self, total: int, counters: dict, description: str, per_batch: int = 1, random_frames: int = 0,
                 every: float = 60.0, write: Any = None) -> None:
        from tqdm.auto import tqdm

        self.total = -(-total // per_batch) * per_batch if total else None
        self.random_frames, self.every, self.description = random_frames, every, description
        self.last, self.learning = counters["frames"], counters["frames"] >= random_frames
        self.bar = tqdm(total=self.total, initial=counters["frames"], unit="frame", dynamic_ncols=True,
                        desc=description, smoothing=0, disable=None)
        self._write = write or (lambda line: print(line, file=sys.stderr, flush=True))
        self.since = (time.perf_counter(), counters["frames"])  # where the rate is measured from
        self.printed = time.perf_counter()

    def update(self, counters: dict, log: dict[str, Any]) -> None:
        frames = counters["frames"]
        if not self.learning and frames >= self.random_frames:  # the rate from here on: learning frames
            self.learning, self.since = True, (time.perf_counter(), frames)
            if not self.bar.disable:  # tqdm's rate: from the frames and the time the learning began at
                self.bar.update(frames - self.last)
                self.last = self.bar.initial = frames
                self.bar.start_t = time.time()
        self.bar.update(frames - self.last)
        self.last = frames
        shown = dict(episodes=counters["episodes"], reward=f"{log.get('train/episode_reward', math.nan):.2f}",
                     success=f"{log.get('train/success_rate', math.nan):.2f}")
        self.bar.set_postfix(refresh=False, **shown)
        now = time.perf_counter()
        if self.bar.disable and now - self.printed >= self.every:
            self.printed = now
            start, done = self.since
            rate = (frames - done) / max(now - start, 1e-9)
            left = f", about {(self.total - frames) / rate / 60:.0f} min left" if self.total and rate > 0 else ""
            share = f"/{self.total} ({100 * frames / self.total:.0f} %)" if self.total else ""
            self._write(f"[{self.description}] {frames}{share} frames, {rate:.0f} frames/s{left}; "
                        + ", ".join(f"{k} {v}" for k, v in shown.items()))

    def write(self, message: str) -> None:
        self.bar.write(message)

    def close(self) -> None:
        self.bar.close()


__all__ = ["BUCKETS", "Progress", "TimeSplit", "rates", "seeds_label", "split_line"]
