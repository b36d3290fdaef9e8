"""Copy the slim policy of every finished run under a sweep folder into checkpoints/.

    python scripts/export_checkpoints.py runs/fast [--dest checkpoints]

runs/<experiment>/<policy>/seed<k>/last.pt  ->  checkpoints/<policy>/seed<k>.pt, plus
checkpoints/MANIFEST.md (command, frames, wall-clock, final evaluation of each).
"""

import argparse
from pathlib import Path

from flock_torchrl.checkpoint import export_policy, load_checkpoint
from flock_torchrl.evaluation import write_text_atomic


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sweep", type=Path, help="a sweep folder such as runs/fast")
    parser.add_argument("--dest", type=Path, default=Path("checkpoints"))
    args = parser.parse_args()
    lines = ["# Shipped checkpoints", "",
             "Slim policies (actor + metadata) exported from training runs by "
             "`python scripts/export_checkpoints.py <sweep>`; `flock_torchrl.load_policy(path)` loads them.", "",
             "| policy | seed | experiment | frames | episodes | minutes | final eval success | safe_success |",
             "|---|---|---|---|---|---|---|---|"]
    for last in sorted(args.sweep.glob("*/seed*/last.pt")):
        policy, seed = last.parent.parent.name, last.parent.name
        dest = export_policy(last, args.dest / policy / f"{seed}.pt")
        payload = load_checkpoint(dest)
        c, ev = payload["counters"], (payload.get("evaluations") or [{}])[-1]
        exp = payload["config"].get("experiment", {}).get("name", "?")
        lines.append(f"| {payload['meta']['policy']} | {seed[4:]} | {exp} | {c['frames']} | {c['episodes']} | "
                     f"{c['seconds'] / 60:.1f} | {ev.get('success', float('nan')):.3f} | "
                     f"{ev.get('safe_success', float('nan')):.3f} |")
        print(f"{last} -> {dest}")
    manifest = args.dest / f"MANIFEST_{args.sweep.name}.md"
    write_text_atomic(manifest, "\n".join(lines) + "\n")
    print(f"wrote {manifest}")


if __name__ == "__main__":
    main()
