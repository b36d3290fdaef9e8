"""Functions recorded as one CUDA graph on a GPU: tensordict's ``CudaGraphModule``, in one place.

What is captured must never read a tensor's value on the host and must take its tensors as
arguments (or hold ones that never change); ``benchmarks/counting.py`` counts the reads the tests
hold to zero. On a CPU ``CudaGraphModule`` calls the function as it is (its inputs copied, as a
replay's are), so the captured code path runs (and is tested) here too; its graphs exist only on
CUDA, and the first wrapping on a device without them says so once, in one line.

Used by the learners' update (``policies/learners.py``) and by the env's step
(``FlockingEnv(capture_step=True)``); the collector's policy is captured by TorchRL
(``cudagraph_policy``, :func:`policy_capture`) with the same warm-up.

Nothing here changes a global setting at import: tensordict's INFO line on setting a module up
and its warnings (no CUDA on this machine; TensorDicts taken out of PyTree, which it does for
every ``CudaGraphModule``) are held back only while a module is built (:func:`quiet`).
"""

from __future__ import annotations

import contextlib
import logging
import sys
import warnings
from typing import Callable, Iterator

import torch

# Calls that run as they are before the CUDA graph is recorded (an optimiser's state and a
# compiled function exist by then): tensordict's CudaGraphModule ``warmup``.
CUDAGRAPH_WARMUP = 3

# What tensordict says while a CudaGraphModule is built, which the line below says for us.
QUIET_WARNINGS = ("This module is instantiated on a machine without CUDA",
                  "Tensordict is registered in PyTree")

NO_GRAPHS = ("cudagraphs: {device} has no CUDA graphs, so nothing is recorded or replayed here: the captured "
             "functions (the update, the env's step) run eagerly, their inputs copied as a replay's are, and the "
             "collector's policy runs as it is")

_said: set[str] = set()


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """tensordict's INFO lines and its warnings of :data:`QUIET_WARNINGS` held back while a
    ``CudaGraphModule`` is built (ours or TorchRL's); everything else as the user set it."""
    log = logging.getLogger("tensordict")
    level = log.level
    log.setLevel(max(level, logging.WARNING))
    try:
        with warnings.catch_warnings():
            for message in QUIET_WARNINGS:
                warnings.filterwarnings("ignore", message=message)
            yield
    finally:
        log.setLevel(level)


def say_once(device: torch.device) -> None:
    """:data:`NO_GRAPHS`, once per process and device type, on stderr."""
    if device.type == "cuda" or device.type in _said:
        return
    _said.add(device.type)
    sys.stderr.write(NO_GRAPHS.format(device=device.type) + "\n")
    sys.stderr.flush()


def captured(function: Callable, device: torch.device, enabled: bool = True) -> Callable:
    """``function`` itself (``enabled=False``), or tensordict's ``CudaGraphModule`` around it:
    recorded on the device's first call after :data:`CUDAGRAPH_WARMUP`, replayed after (its
    inputs copied into the graph's, its outputs cloned out); a pass-through without CUDA."""
    if not enabled:
        return function
    from tensordict.nn import CudaGraphModule

    device = torch.device(device)
    say_once(device)
    with quiet():
        return CudaGraphModule(function, warmup=CUDAGRAPH_WARMUP, device=device if device.type == "cuda" else None)


def policy_capture(device: str | torch.device, enabled: bool) -> dict[str, int] | None:
    """A TorchRL collector's ``cudagraph_policy``: with ``enabled`` on a CUDA device, the policy's
    forward captured as the update is (``{"warmup": CUDAGRAPH_WARMUP}``); ``None`` elsewhere,
    where TorchRL's ``CudaGraphModule`` would only call it as it is (:data:`NO_GRAPHS`)."""
    if not enabled:
        return None
    device = torch.device(device)
    say_once(device)
    return {"warmup": CUDAGRAPH_WARMUP} if device.type == "cuda" else None


__all__ = ["CUDAGRAPH_WARMUP", "NO_GRAPHS", "captured", "policy_capture", "quiet", "say_once"]
