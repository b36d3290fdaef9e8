"""Example controllers of the user's kind (contenders, README): shipped in the wheel, so
``contender=flock_torchrl.examples.goal_separation.make`` works from any folder; a clone also
has them as ``examples/<name>.py:make``."""
