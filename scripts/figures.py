"""The paper's figures from the training logs, checkpoints and baselines (logic: flock_torchrl.render).

    python scripts/figures.py                      # Fig. 4, 5 and 6 into figures/
    python scripts/figures.py figs=5,6 seed=7 out=figures

Keys: figs (comma-separated of 4, 5, 6), runs (training run folders, default runs),
experiment (only runs/<experiment>/..., default all), checkpoints, out, seed (default: the
evaluation seed), device, threads.
Whatever is missing (a checkpoint, a baseline, a log) is skipped with a message.
"""

import sys

from flock_torchrl.render import figures_main

if __name__ == "__main__":
    sys.exit(figures_main(sys.argv[1:]))
