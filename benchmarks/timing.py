"""Timing two or more candidates fairly on a loaded machine, and the lines a benchmark prints."""

from __future__ import annotations

import math
import time
from typing import Callable


def paired(candidates: dict[str, Callable[[], None]], repeat: int = 3) -> dict[str, float]:
    """Best wall time (s) of each candidate over ``repeat`` alternated rounds, after a warm-up."""
    for fn in candidates.values():
        fn()
    best = {name: math.inf for name in candidates}
    for _ in range(repeat):
        for name, fn in candidates.items():
            start = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - start)
    return best


class Lines(list):
    """A benchmark's lines as they are measured, each also printed at once with ``echo``."""

    def __init__(self, echo: bool) -> None:
        super().__init__()
        self.echo = echo

    def say(self, *new: str) -> None:
        self.extend(new)
        if self.echo:
            print(*new, sep="\n", flush=True)


__all__ = ["Lines", "paired"]
