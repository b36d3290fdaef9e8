"""Put this folder on a child process's ``PYTHONPATH`` and it runs under ``tests/simulated_cuda.py``
(the benchmarks measure each loop in a child process of its own)."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import simulated_cuda  # noqa: E402

simulated_cuda.start()
