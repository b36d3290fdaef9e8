"""Train one learned policy (a Hydra app on conf/train.yaml; logic: flock_torchrl.run.trainer).

    python scripts/train.py policy=policy3_g experiment=fast seed=0
    python scripts/train.py -m policy=policy1,policy3_g seed=0,1,2       # a sweep, one folder per job
    python scripts/train.py -cd runs/fast/paper_fit/policy3_g/seed0 -cn resume   # continue a stopped run
    python scripts/train.py policy=policy3_g --cfg job                    # print what would run
"""

import signal


_noted: list = []


def _note(signum, frame):
    # A stop signal while Python loads torch and the package (seconds) is noted, and the app
    # stops on it once the run is checked, before anything is written: raised inside a library's
    # import, it could leave that library half-built and surface as another error.
    _noted.append(signum)


if __name__ == "__main__":
    for _signum in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", signal.SIGTERM)):
        signal.signal(_signum, _note)
    from flock_torchrl.cli import train_main

    train_main(_noted)
