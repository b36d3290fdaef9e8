"""Evaluate one policy on one scenario (a Hydra app on conf/evaluate.yaml; logic: flock_torchrl.run.rollout).

    python scripts/evaluate.py policy=policy3_g scenario=s2 episodes=500
    python scripts/evaluate.py policy=policy_op scenario=tau_v scenario.tau_v=0.5
    python scripts/evaluate.py policy=policy3_g checkpoint=runs/fast/literal/policy3_g/seed0/last.pt scenario=s5

Writes episodes.csv (one row per episode) and summary.json into outputs/evaluate/...
"""

from _start import start  # before anything heavy: Ctrl-C while torch loads is one line

if __name__ == "__main__":
    start("evaluate")
