"""Each member's bookkeeping in a training run of K members (:mod:`.trainer`; K = 1 the solo run).

Counters are per member: ``frames`` is each member's (all collect alike), episodes are counted
per member, and the budget ``max_episodes`` is spent when every member has spent it. A member
that reaches it first is *final* from then on: its actor, counters and training curve at that
batch are what it ships (it keeps stepping with the others, but nothing it does later is kept),
so each member's budget means what a solo run's does.

Where a member's files go: one member writes the solo run's (``<run>/episodes.csv``, scalars
``train/...`` and ``eval/...``, the solo checkpoint layout); several write ``<run>/seed<s>/episodes.csv``,
scalars under ``seed<s>/...`` with their mean under the solo names, and a checkpoint that holds
every member's slim policy (``members``), which ``make ship-checkpoints`` exports as
``<policy>/seed<s>.pt``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Sequence

import torch

from .batches import EPISODE_COLUMNS, episode_rows
from .run_folder import EpisodeLog

STEPS = EPISODE_COLUMNS.index("steps")
# An evaluation's values logged as scalars: all but the frames and the two copies of the rates.
UNLOGGED = ("frames", "success", "safe_success")


class Members:
    """The episodes, logs, evaluations and final snapshots of the members ``seeds`` of a run in ``run_dir``."""

    def __init__(self, seeds: Sequence[int], run_dir: Path) -> None:
        self.seeds, self.k, self.run_dir = list(seeds), len(seeds), run_dir
        self.episodes = [0] * self.k
        self.evaluations: list[list[dict[str, float]]] = [[] for _ in self.seeds]
        self.final: list[dict[str, Any] | None] = [None] * self.k  # a member's frozen result, once final
        self.logs: list[EpisodeLog] = []
        self.recent: list[list[tuple[float, bool, float]]] = [[] for _ in self.seeds]

    def prefix(self, k: int) -> str:
        """Where member ``k``'s scalars go: the solo names for one member, ``seed<s>/`` for several."""
        return "" if self.k == 1 else f"seed{self.seeds[k]}/"

    def restore(self, payload: dict[str, Any], counters: dict[str, Any]) -> None:
        """Each member's episodes, evaluations and final snapshot from a run's checkpoint."""
        if self.k == 1:
            self.episodes[0], self.evaluations[0] = int(counters["episodes"]), list(payload.get("evaluations", []))
            return
        for k, member in enumerate(payload["members"]):
            self.episodes[k] = int(member["episodes_seen"])
            self.evaluations[k] = list(member["evaluations"])
            if member["final"]:
                self.final[k] = {"actor": member["actor"], "counters": dict(member["counters"]),
                                 "curve": member["curve"]}

    def open_logs(self, resumed: bool) -> None:
        """Each member's episode log, cut back to its checkpoint's episodes on a resume; the running
        means over its last 100 episodes continue from it."""
        paths = [self.run_dir / "episodes.csv"] if self.k == 1 else \
            [self.run_dir / f"seed{s}" / "episodes.csv" for s in self.seeds]
        self.logs = [EpisodeLog(path, EPISODE_COLUMNS, self.episodes[k] if resumed else None)
                     for k, path in enumerate(paths)]
        self.recent = [[(row[2], bool(row[3]), row[STEPS]) for row in log.rows()[-100:]] for log in self.logs]

    def close(self) -> None:
        for log in self.logs:
            log.close()

    # ---------------------------------------------------------------- episodes
    def live(self) -> list[int]:
        """The members still training (not final)."""
        return [k for k in range(self.k) if self.final[k] is None]

    def could_spend(self, budget: int, pending: int) -> bool:
        """Whether a member still training could have spent ``budget`` episodes with the ``pending`` ones."""
        live = [self.episodes[k] for k in self.live()]
        return bool(live) and max(live) + pending >= budget

    def tally(self, finished: list[Any]) -> int:
        """Each member's episodes of ``finished`` (PendingEpisodes.flush: the member of each episode
        from its world's index) as rows of its episode log; returns the episodes every member has."""
        for batch in finished:
            member = (batch.source.member_of(torch.tensor(batch.worlds)).tolist() if self.k > 1
                      else [0] * len(batch.values))
            for k in sorted(set(member)):                                   # members with finished episodes
                mine = [v for m, v in zip(member, batch.values) if m == k]
                first = self.episodes[k]
                self.episodes[k] += len(mine)
                if self.final[k] is not None:
                    continue  # a final member's later episodes are not its run's
                rows = episode_rows(mine, first, batch.frames)
                self.logs[k].write(rows)
                self.recent[k] = (self.recent[k] + [(r[2], bool(r[3]), r[STEPS]) for r in rows])[-100:]
        return min(self.episodes)

    def freeze_spent(self, budget: int, learner: Any, counters: dict[str, Any]) -> None:
        """A member (of several) that spent ``budget`` episodes is final: keep its actor, counters and
        curve now (one member's run ends at that batch)."""
        if self.k == 1:
            return
        for k, episodes in enumerate(self.episodes):
            if self.final[k] is None and episodes >= budget:
                self.final[k] = {"actor": learner.actor_state(k), "counters": {**counters, "episodes": episodes},
                                 "curve": self.curve(k)}

    def curve(self, k: int) -> torch.Tensor:
        """Member ``k``'s training curve: its episode log's rows."""
        return torch.tensor(self.logs[k].rows(), dtype=torch.float64).reshape(-1, len(EPISODE_COLUMNS))

    # ---------------------------------------------------------------- scalars, evaluations
    def training_scalars(self, stats: dict[str, torch.Tensor]) -> dict[str, float]:
        """Each member's update statistics and running means over its last 100 episodes (reward,
        success, length), and for several members their mean under the solo run's names."""
        log: dict[str, float] = {}
        for k in range(self.k):
            p = self.prefix(k)
            log.update({f"{p}train/{name}": float(v.reshape(-1)[k]) for name, v in stats.items()})
            recent = self.recent[k]
            if recent:
                for i, name in enumerate(("episode_reward", "success_rate", "episode_length")):
                    log[f"{p}train/{name}"] = sum(r[i] for r in recent) / len(recent)
        if self.k > 1:
            for name in {key.split("/train/")[1] for key in log}:
                values = [log[key] for key in (f"seed{s}/train/{name}" for s in self.seeds) if key in log]
                log[f"train/{name}"] = sum(values) / len(values)
        return log

    def evaluated(self, batched: dict[int, dict[str, float]], alone: Callable[[int, Any, int], dict[str, float]],
                  learner: Any, frames: int) -> tuple[dict[str, float], dict[str, float]]:
        """Every member's evaluation row at ``frames``: ``batched`` (members evaluated together), a
        final member's last one if it evaluated since it became final, or ``alone(k, actor, frames)``;
        returns the run's (their mean, at ``frames``) and the scalars to log."""
        rows, scalars = [], {}
        for k in range(self.k):
            final, mine = self.final[k], self.evaluations[k]
            if final is not None and mine and mine[-1]["frames"] >= final["counters"]["frames"]:
                rows.append(mine[-1])
                continue
            row = batched.get(k)
            if row is None:
                row = (alone(k, final["actor"], final["counters"]["frames"]) if final is not None
                       else alone(k, learner.actor_state(k), frames))
            mine.append(row)
            if self.k > 1:
                scalars.update({f"{self.prefix(k)}eval/{key}": v for key, v in row.items() if key not in UNLOGGED})
            rows.append(row)
        summary = {key: sum(r[key] for r in rows) / len(rows) for key in rows[0] if key != "frames"}
        summary["frames"] = frames
        scalars.update({f"eval/{key}": v for key, v in summary.items() if key not in UNLOGGED})
        return summary, scalars

    # ---------------------------------------------------------------- checkpoints
    def state(self, learner: Any, counters: dict[str, Any], meta: dict[str, Any], resolved: dict[str, Any]
              ) -> dict[str, Any]:
        """The members' part of the checkpoint: one member's actor and curve (the solo layout), or
        every member's slim policy (``members``) with the first one's actor and curve beside."""
        if self.k == 1:
            return {"actor": learner.actor_state(0), "curve": self.curve(0)}
        members = []
        for k, seed in enumerate(self.seeds):
            final = self.final[k]
            members.append({
                "seed": seed, "final": final is not None, "meta": {**meta, "seed": seed},
                "config": {**resolved, "seed": seed, "population": 1},
                "counters": dict(final["counters"]) if final is not None else {**counters, "episodes": self.episodes[k]},
                "actor": final["actor"] if final is not None else learner.actor_state(k),
                "evaluations": list(self.evaluations[k]),
                "curve": final["curve"] if final is not None else self.curve(k),
                "episodes_seen": self.episodes[k],
            })
        return {"members": members, "actor": members[0]["actor"], "curve": members[0]["curve"]}


__all__ = ["Members"]
