"""Reproduce the paper's Table III, IV or V under one reading (a Hydra app on conf/reproduce.yaml;
logic: flock_torchrl.report.reproduce).

    python scripts/reproduce.py table=3
    python scripts/reproduce.py table=4 reading=paper_fit episodes=100 only=[Policy3-G,Policy-MA]

Writes table<k>.md/.csv (ours, the paper's, the difference), table<k>_seeds.csv,
table<k>_episodes.csv.gz, fidelity.md and summary.md into outputs/reproduce/<reading>/.
"""

from _start import start  # before anything heavy: Ctrl-C while torch loads is one line

if __name__ == "__main__":
    start("reproduce")
