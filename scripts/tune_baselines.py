"""Tune the rule-based baselines on the training scenario (a Hydra app on conf/tune_baselines.yaml;
logic: flock_torchrl.report.tuning).

    python scripts/tune_baselines.py reading=paper_fit
    python scripts/tune_baselines.py evaluate=true episodes=500
"""

from _start import start  # before anything heavy: Ctrl-C while torch loads is one line

if __name__ == "__main__":
    start("tune_baselines")
