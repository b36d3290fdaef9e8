"""Throughput benchmarks of the repository (``make benchmark``), outside the installed package:
``throughput`` (every figure a ratio against a baseline run in the same process), ``run`` (its
Hydra app) and ``step`` (milliseconds per env step, eager against compiled, and a profiler).
They import the package's public names; nothing in ``flock_torchrl`` imports them."""
