"""Reporting: the paper's tables with the fidelity score, its figures, baseline tuning and
swarm-size scaling (the throughput benchmarks are in the repository's ``benchmarks/``)."""
