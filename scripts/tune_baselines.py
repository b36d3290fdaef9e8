"""Tune the rule-based baselines on the training scenario (a Hydra app on conf/tune_baselines.yaml;
logic: flock_torchrl.report.tuning).

    python scripts/tune_baselines.py reading=paper_fit
    python scripts/tune_baselines.py evaluate=true episodes=500
"""


from flock_torchrl.cli import tune_baselines_main

if __name__ == "__main__":
    tune_baselines_main()
