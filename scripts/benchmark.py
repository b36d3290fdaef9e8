"""Print throughput figures with ratios against baselines run in the same process.

    python scripts/benchmark.py            # about a minute on a 2-core CPU
    python scripts/benchmark.py --quick
"""

import argparse

from flock_torchrl.benchmark import format_rows, run_all

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = parser.parse_args()
    print(format_rows(run_all(quick=args.quick)))
