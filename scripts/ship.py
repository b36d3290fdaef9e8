"""Update checkpoints/ from finished training runs (a Hydra app on conf/ship.yaml; `make ship-checkpoints`).

    python scripts/ship.py reading=paper_fit
    python scripts/ship.py reading=paper_fit runs_dir=/elsewhere/runs checkpoints_dir=/tmp/checkpoints   # a trial

Every run is read and every conflict (two runs holding one policy's seed) found before the first
file is written: a conflict is one line, exit 2, and checkpoints/ is left as it was.
"""


from flock_torchrl.cli import ship_main

if __name__ == "__main__":
    ship_main()
