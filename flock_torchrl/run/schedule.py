"""When a training run logs, evaluates, checkpoints and stops.

Each periodic task fires at the first collector batch at or past a multiple of its period in
frames, so a resumed run fires at the same frames as an uninterrupted one (its logs equal an
uninterrupted run's). A period of 0 means never (logging: every batch).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..config import ExperimentConfig


def next_multiple(frames: int, every: int) -> float:
    """The first multiple of ``every`` above ``frames`` (``inf`` if ``every`` is 0)."""
    return (frames // every + 1) * every if every else math.inf


@dataclass
class Periodic:
    """A task due every ``every`` frames (0: never, or every batch with ``zero_is_always``)."""

    every: int
    zero_is_always: bool = False
    due_at: float = field(init=False, default=math.inf)

    def start(self, frames: int) -> "Periodic":
        self.due_at = 0 if (self.zero_is_always and not self.every) else next_multiple(frames, self.every)
        return self

    def due(self, frames: int) -> bool:
        """Whether the task fires at ``frames`` (and, if so, schedule the next time)."""
        if frames < self.due_at:
            return False
        if self.every:
            self.due_at = next_multiple(frames, self.every)
        return True


@dataclass
class Schedule:
    """The periodic tasks of a run and its budget (``experiment.max_*``)."""

    experiment: ExperimentConfig
    log: Periodic = field(init=False)
    evaluate: Periodic = field(init=False)
    checkpoint: Periodic = field(init=False)

    def start(self, frames: int) -> "Schedule":
        exp = self.experiment
        self.log = Periodic(exp.log_every_frames, zero_is_always=True).start(frames)
        self.evaluate = Periodic(exp.eval_every_frames).start(frames)
        self.checkpoint = Periodic(exp.checkpoint_every_frames).start(frames)
        return self

    def finished(self, frames: int, episodes: int, seconds: float) -> bool:
        """Whether a budget is spent: frames, episodes or minutes (whichever are set)."""
        exp = self.experiment
        return bool((exp.max_frames and frames >= exp.max_frames)
                    or (exp.max_episodes and episodes >= exp.max_episodes)
                    or (exp.max_minutes and seconds >= 60 * exp.max_minutes))

    def done(self, counters: dict, evaluations: list) -> bool:
        """A run that spent its budget and ran its final evaluation (the last one at its last
        frame): what resumes to a no-op and what ``make ship-checkpoints`` ships."""
        return (self.finished(counters["frames"], counters["episodes"], counters["seconds"])
                and evaluated_at_end(counters, evaluations))


def evaluated_at_end(counters: dict, evaluations: list) -> bool:
    """Whether the last evaluation is of the last frame (a finished run's final one)."""
    return bool(evaluations) and evaluations[-1]["frames"] == counters["frames"]


__all__ = ["Periodic", "Schedule", "evaluated_at_end", "next_multiple"]
