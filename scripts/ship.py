"""Update checkpoints/ from finished training runs (a Hydra app on conf/ship.yaml; `make ship-checkpoints`).

    python scripts/ship.py reading=paper_fit experiment=fast
"""


from flock_torchrl.cli import ship_main

if __name__ == "__main__":
    ship_main()
