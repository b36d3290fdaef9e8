"""A controller of your own, as a row of the paper's tables (README, "Your controller as a row").

Its code lives in the package, ``flock_torchrl/examples/goal_separation.py``, so that the wheel
carries it (``contender=flock_torchrl.examples.goal_separation.make`` from any folder); this
file is the clone's path to the same factory:

    python scripts/reproduce.py table=3 episodes=100 only=[Policy-MA] \
        'contenders=[examples/goal_separation.py:make]'
    python scripts/evaluate.py contender=examples/goal_separation.py:make scenario=s2 episodes=100
"""

from flock_torchrl.examples.goal_separation import GoalSeparation, make

__all__ = ["GoalSeparation", "make"]
