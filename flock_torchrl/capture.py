"""Functions recorded as one CUDA graph on a GPU: tensordict's ``CudaGraphModule``, in one place.

What is captured must never read a tensor's value on the host and must take its tensors as
arguments (or hold ones that never change); ``run/host_reads.py`` counts the reads the tests
hold to zero. On a CPU ``CudaGraphModule`` calls the function as it is, so the captured code
path runs (and is tested) here too; its graphs exist only on CUDA.

Used by the learners' update (``policies/learners.py``) and by the env's step
(``FlockingEnv(capture_step=True)``); the collector's policy is captured by TorchRL
(``cudagraph_policy``) with the same warm-up.
"""

from __future__ import annotations

import warnings
from typing import Callable

import torch

# Without CUDA every CudaGraphModule (ours, and TorchRL's around a collector's policy) calls its
# function as it is, which the docs say; its warning of that would only repeat it.
warnings.filterwarnings("ignore", message="This module is instantiated on a machine without CUDA")

# Calls that run as they are before the CUDA graph is recorded (an optimiser's state and a
# compiled function exist by then): tensordict's CudaGraphModule ``warmup``.
CUDAGRAPH_WARMUP = 3


def captured(function: Callable, device: torch.device, enabled: bool = True) -> Callable:
    """``function`` itself (``enabled=False``), or tensordict's ``CudaGraphModule`` around it:
    recorded on the device's first call after :data:`CUDAGRAPH_WARMUP`, replayed after (its
    inputs copied into the graph's, its outputs cloned out); a pass-through without CUDA."""
    if not enabled:
        return function
    from tensordict.nn import CudaGraphModule

    return CudaGraphModule(function, warmup=CUDAGRAPH_WARMUP, device=device if device.type == "cuda" else None)
