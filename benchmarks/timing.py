"""Timing two or more candidates fairly on a loaded machine."""

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


__all__ = ["paired"]
