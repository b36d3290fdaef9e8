"""Evaluate one policy on one scenario (Hydra entry point; all logic lives in flock_torchrl.evaluation).

    python scripts/evaluate.py policy=policy3_g scenario=s2 episodes=500
    python scripts/evaluate.py policy=policy_op scenario=tau_v scenario.tau_v=0.5
    python scripts/evaluate.py policy=checkpoints/policy3_g/seed1.pt scenario=s5

Writes <out>/<policy>_<scenario>.csv (one row per episode) and .json (summary and config).
"""

import sys

import hydra
from omegaconf import DictConfig

import flock_torchrl.config  # noqa: F401  (registers the ${pi:...} resolver)
from flock_torchrl.evaluation import evaluate_from_config, policy_path_override


@hydra.main(version_base=None, config_path="../conf", config_name="evaluate")
def main(cfg: DictConfig) -> None:
    result, paths = evaluate_from_config(cfg)
    print(result)
    print("wrote " + " and ".join(str(p) for p in paths))


if __name__ == "__main__":
    sys.argv = policy_path_override(sys.argv)  # policy=<path> -> checkpoint=<path>
    main()
