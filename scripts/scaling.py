"""Policy3-G trained with 5 UAVs, flown by 5 to 100 (a Hydra app on conf/scaling.yaml; logic:
flock_torchrl.report.scaling).

    python scripts/scaling.py reading=paper_fit
"""

from _start import start  # before anything heavy: Ctrl-C while torch loads is one line

if __name__ == "__main__":
    start("scaling")
