"""Why learned flocks crash at 20-50 UAVs: crash forensics and evaluation-time ablations
(logic: flock_torchrl.report.diagnosis; findings: docs/scaling.md).

    python scripts/diagnose.py                                    # the full grid, into outputs/diagnosis/
    python scripts/diagnose.py --sizes 20 --scenarios forest --variants paper instinct_off --episodes 20

Each policy label pools its checkpoints (one run of --episodes per checkpoint and cell). Writes
rates.csv, crashes.csv and diagnosis.md into --out.
"""

import argparse
import time
from pathlib import Path

import torch

from flock_torchrl.io import write_csv, write_text
from flock_torchrl.report.diagnosis import (CRASH_COLUMNS, VARIANTS, crash_rows, crash_table, diagnose, rate_rows,
                                            rate_table)

POLICIES = {
    "Policy3-G (trained at 5)": [f"checkpoints/paper_fit/policy3_g/seed{k}.pt" for k in range(3)],
    "Policy3-G mixed (5+20+50)": [f"checkpoints/paper_fit/mixed/policy3_g/seed{k}.pt" for k in range(3)],
    "Policy3-G-crowd-ramp-allround-radial (cluttered)":
        [f"checkpoints/paper_fit/mixed_cluttered/policy3_g_crowd_ramp_allround_radial/seed{k}.pt" for k in range(3)],
}
# What a bare run diagnoses (the scaling policy is asked for by name,
# --policies "Policy3-G-crowd-ramp-allround-radial (cluttered)").
DEFAULT_POLICIES = ["Policy3-G (trained at 5)", "Policy3-G mixed (5+20+50)"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policies", nargs="+", choices=list(POLICIES), default=DEFAULT_POLICIES)
    parser.add_argument("--scenarios", nargs="+", default=["train", "forest"])
    parser.add_argument("--sizes", nargs="+", type=int, default=[20, 50])
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS))
    parser.add_argument("--episodes", type=int, default=50, help="per checkpoint and cell")
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("outputs/diagnosis"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    cells = diagnose({p: POLICIES[p] for p in args.policies}, args.scenarios, args.sizes, args.variants,
                     args.episodes, seed=args.seed)
    rates, crashes = rate_rows(cells), crash_rows(cells)
    write_csv(args.out / "rates.csv", list(rates[0]), rates)
    write_csv(args.out / "crashes.csv", ["policy", "scenario", "n_uavs", "variant", *CRASH_COLUMNS], crashes)
    text = ["# Crash forensics and ablations (scripts/diagnose.py)", "",
            f"Reading paper_fit, evaluation seed {args.seed}, {args.episodes} episodes per checkpoint and cell, "
            f"{time.perf_counter() - start:.0f} s.", "", *rate_table(rates), "",
            "Crashed episodes, the UAV that hit, at its last step before the crash (n: outward normal of the "
            "obstacle; negative = toward it):", "", *crash_table([r for r in crashes if r["variant"] == "paper"]), ""]
    write_text(args.out / "diagnosis.md", "\n".join(text))
    print("\n".join(text))


if __name__ == "__main__":
    main()
