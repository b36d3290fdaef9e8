"""Train one learned policy (Hydra entry point; all logic lives in flock_torchrl.trainer).

    python scripts/train.py policy=policy3_g experiment=fast seed=0
    python scripts/train.py -m policy=policy1,policy3_g seed=0,1,2       # sweep
    python scripts/train.py policy=policy3_g resume=true                  # continue a killed run
"""

import hydra
from omegaconf import DictConfig

import flock_torchrl.config  # noqa: F401  (registers the ${pi:...} resolver)
from flock_torchrl.trainer import train


@hydra.main(version_base=None, config_path="../conf", config_name="train")
def main(cfg: DictConfig) -> None:
    result = train(cfg)
    print(f"checkpoint: {result.checkpoint} ({result.frames} frames, {result.episodes} episodes, "
          f"{result.updates} updates, {result.seconds:.0f} s)")
    if result.evaluations:
        last = result.evaluations[-1]
        print(f"evaluation ({int(last['n_episodes'])} episodes, seed {cfg.eval_seed}, deterministic): "
              f"success {last['success']:.3f}, safe_success {last['safe_success']:.3f}, "
              f"d_min_uav {last['d_min_uav']:.3f}, d_c {last['d_c']:.3f}, t_goal {last['t_goal']:.2f} s")


if __name__ == "__main__":
    main()
