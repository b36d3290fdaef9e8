"""Throughput figures, each against a baseline run in the same process (a Hydra app on
conf/benchmark.yaml; logic: flock_torchrl.report.benchmark).

    python scripts/benchmark.py
    python scripts/benchmark.py quick=true
"""


from flock_torchrl.cli import benchmark_main

if __name__ == "__main__":
    benchmark_main()
