"""Where a training loop's time goes, and its progress bar."""

from __future__ import annotations

import math
import time
from contextlib import contextmanager
from typing import Any, Iterable, Iterator

import torch

# The parts of a training loop's wall time, in the order a time split is printed.
# "compile": a compiled learner's first update and a compiled env's first step in this process,
# where torch.compile works.
_END = object()
BUCKETS = ("env", "collection", "buffer", "sampling", "update", "compile", "logging", "evaluation", "checkpoints")


class TimeSplit(dict):
    """Seconds of a loop by part (a ``dict`` of :data:`BUCKETS`, and any added): ``with
    split.timer("buffer"): ...`` adds that block's wall time to its part.

    ``device``: where the loop's tensors live. On a CUDA device the host runs ahead of the
    GPU, so each timed block starts and ends with ``torch.cuda.synchronize``: a part is booked
    the GPU work it launched, not the next part that waits for it (a few synchronisations per
    iteration, at the part boundaries only). On the CPU nothing waits."""

    def __init__(self, *more: str, device: torch.device | str | None = None) -> None:
        super().__init__(dict.fromkeys((*BUCKETS, *more), 0.0))
        device = torch.device("cpu" if device is None else device)
        self.synchronize = (lambda: torch.cuda.synchronize(device)) if device.type == "cuda" else None

    @contextmanager
    def timer(self, bucket: str) -> Iterator[None]:
        if self.synchronize is not None:
            self.synchronize()
        start = time.perf_counter()
        try:
            yield
        finally:
            if self.synchronize is not None:
                self.synchronize()
            self[bucket] += time.perf_counter() - start

    def timed(self, iterable: Iterable[Any], bucket: str) -> Iterator[Any]:
        """The items of ``iterable``, the time each takes to come booked under ``bucket``."""
        items = iter(iterable)
        while True:
            with self.timer(bucket):
                item = next(items, _END)
            if item is _END:
                return
            yield item

    def move(self, seconds: float, source: str, target: str) -> None:
        """Book ``seconds`` already counted under ``source`` under ``target`` instead."""
        self[source] -= seconds
        self[target] += seconds


def rates(split: dict[str, float], counters: dict[str, Any], members: int = 1, prefix: str = "perf/"
          ) -> dict[str, float]:
    """Updates and frames per second of a loop's own time (times ``members``, a population's)."""
    return {f"{prefix}updates_per_s": members * counters["updates"] / max(split["sampling"] + split["update"], 1e-9),
            f"{prefix}frames_per_s": members * counters["frames"] / max(split["env"] + split["collection"], 1e-9)}


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
    """tqdm bar over frames."""

    def __init__(self, total: int, counters: dict, description: str) -> None:
        from tqdm.auto import tqdm

        self.bar = tqdm(total=total or None, initial=counters["frames"], unit="frame", dynamic_ncols=True,
                        desc=description)
        self.last = counters["frames"]

    def update(self, counters: dict, log: dict[str, Any]) -> None:
        self.bar.update(counters["frames"] - self.last)
        self.last = counters["frames"]
        self.bar.set_postfix(episodes=counters["episodes"], reward=f"{log.get('train/episode_reward', math.nan):.2f}",
                             success=f"{log.get('train/success_rate', math.nan):.2f}", refresh=False)

    def write(self, message: str) -> None:
        self.bar.write(message)

    def close(self) -> None:
        self.bar.close()


__all__ = ["BUCKETS", "Progress", "TimeSplit", "rates", "seeds_label", "split_line"]
