"""Update checkpoints/ from finished training runs (a Hydra app on conf/ship.yaml; `make ship-checkpoints`).

    python scripts/ship.py reading=paper_fit
    python scripts/ship.py reading=paper_fit runs_dir=/elsewhere/runs checkpoints_dir=/tmp/checkpoints   # a trial

Every run is read and every conflict (two runs holding one policy's seed) found before the first
file is written: a conflict is one line, exit 2, and checkpoints/ is left as it was.
"""

from _start import start  # before anything heavy: Ctrl-C while torch loads is one line

if __name__ == "__main__":
    start("ship")
