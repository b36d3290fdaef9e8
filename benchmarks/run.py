"""Throughput figures, each against a baseline run in the same process (a Hydra app on
benchmarks/conf/benchmark.yaml; logic: benchmarks.throughput). From the repository's root:

    python -m benchmarks.run                  # make benchmark (which installs the bench extra first)
    python -m benchmarks.run quick=true
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

if not __package__:  # `python benchmarks/run.py`: the repository's root, so `benchmarks` imports
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import hydra  # noqa: E402
from hydra.core.hydra_config import HydraConfig  # noqa: E402

from benchmarks.throughput import benchmark_app, checked  # noqa: E402


@hydra.main(version_base=None, config_path="conf", config_name="benchmark")
def main(cfg: Any) -> None:
    benchmark_app(checked(cfg), Path(HydraConfig.get().runtime.output_dir))


if __name__ == "__main__":
    main()
