"""The paper's Fig. 4, 5 and 6 under one reading (a Hydra app on conf/figures.yaml; logic:
flock_torchrl.report.figures).

    python scripts/figures.py
    python scripts/figures.py reading=paper_fit figs=[5,6] seed=7

Writes into outputs/figures/<reading>/.
"""

from _start import start  # before anything heavy: Ctrl-C while torch loads is one line

if __name__ == "__main__":
    start("figures")
