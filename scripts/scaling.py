"""Policy3-G trained with 5 UAVs, flown by 5 to 100 (a Hydra app on conf/scaling.yaml; logic:
flock_torchrl.report.scaling).

    python scripts/scaling.py reading=paper_fit
"""


from flock_torchrl.cli import scaling_main

if __name__ == "__main__":
    scaling_main()
