"""Reporting: the paper's tables with the fidelity score, its figures, baseline tuning and
throughput benchmarks."""
