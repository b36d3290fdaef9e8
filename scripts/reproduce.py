"""Reproduce the paper's Table III, IV or V from the shipped checkpoints and the two baselines.

    python scripts/reproduce.py table=3 episodes=500
    python scripts/reproduce.py table=4 episodes=100 only=Policy3-G,Policy-MA
    python scripts/reproduce.py table=5 checkpoints=checkpoints results=results

Keys (flock_torchrl.tables.ReproduceConfig): table, episodes, seed, device, checkpoints,
results, only, threads, episodes_csv. Writes <results>/table<k>.md and .csv (ours, the paper's,
the difference), table<k>_seeds.csv (per checkpoint) and table<k>_episodes.csv (per episode).
Exits 1 if an evaluation failed; policies without checkpoints are skipped with a message.
"""

import sys

from flock_torchrl.tables import reproduce_main

if __name__ == "__main__":
    sys.exit(reproduce_main(sys.argv[1:]))
