"""Train one learned policy (a Hydra app on conf/train.yaml; logic: flock_torchrl.run.trainer).

    python scripts/train.py policy=policy3_g experiment=fast seed=0
    python scripts/train.py -m policy=policy1,policy3_g seed=0,1,2       # a sweep, one folder per job
    python scripts/train.py -cd runs/fast/paper_fit/policy3_g/seed0 -cn resume   # continue a stopped run
    python scripts/train.py policy=policy3_g --cfg job                    # print what would run
"""

from _start import start  # before anything heavy: Ctrl-C while torch loads is one line

if __name__ == "__main__":
    start("train")
