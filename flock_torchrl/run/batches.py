"""What a training loop makes of a collector's batch: per-UAV done flags (the collector's
``postproc``), the replay buffer's items, and the episode log's rows."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

from ..world.metrics import CELL_METRICS

# One row per finished training episode (Fig. 4 reads episode, reward).
EPISODE_COLUMNS = ("episode", "frames", "reward", "success", "safe_success", *CELL_METRICS, "steps")
EPISODE_METRICS = ("return", "success", "safe_success", *CELL_METRICS, "steps")
# Keys a learner needs from a transition; everything else stays out of the replay buffer.
TRANSITION_KEYS = [("agents", "observation"), ("agents", "state"), ("agents", "action"),
                   ("agents", "action_log_prob"), ("next", "agents", "observation"), ("next", "agents", "state"),
                   ("next", "agents", "reward"), ("next", "agents", "done"), ("next", "agents", "terminated"),
                   ("next", "done"), ("next", "terminated")]


def agentwise_done(batch: TensorDictBase, n_agents: int) -> TensorDictBase:
    """Give the losses per-UAV ``done`` / ``terminated`` (the env shares them across the swarm)."""
    for key in ("done", "terminated"):
        value = batch.get(("next", key))
        batch.set(("next", "agents", key), value.unsqueeze(-2).expand(*value.shape[:-1], n_agents, 1))
    return batch


class AgentwiseDone:
    """:func:`agentwise_done` as a collector's ``postproc`` (as TorchRL's multi-agent examples
    attach a done transform): every batch leaves the collector with per-UAV flags."""

    def __init__(self, n_agents: int) -> None:
        self.n_agents = n_agents

    def __call__(self, batch: TensorDictBase) -> TensorDictBase:
        return agentwise_done(batch, self.n_agents)


def per_uav(batch: TensorDictBase, lead: int = 0) -> TensorDictBase:
    """Swarm transitions ``[*L, M]`` (agents ``[*L, M, N]``) as single-UAV ones ``[*L, M * N]``
    (agents ``[*L, M * N, 1]``): what a replay buffer shared by several swarm sizes holds. The
    networks are per UAV and the done flags per UAV (:func:`agentwise_done`), so the losses see
    the same terms. UAV ``j`` of swarm transition ``m`` lands at row ``m * N + j``.

    Args:
        lead: how many leading dimensions ``L`` to keep (a population's members: 1); the
            others are flattened into ``M``.
    """
    picked = batch.select(*(k for k in TRANSITION_KEYS if "agents" in k), strict=False)
    lead_shape = list(picked.batch_size[:lead])
    flat = picked.reshape(*lead_shape, -1)
    *_, m, n = flat.get("agents").batch_size
    out = TensorDict({"agents": TensorDict({}, [*lead_shape, m * n, 1]),
                      "next": {"agents": TensorDict({}, [*lead_shape, m * n, 1])}},
                     batch_size=[*lead_shape, m * n], device=flat.device)
    for key in flat.keys(True, True):
        value = flat.get(key)
        out.set(key, value.reshape(*lead_shape, m * n, 1, *value.shape[lead + 2:]))
    return out


def replay_rows(batch: TensorDictBase, k: int, single_uavs: bool) -> TensorDictBase:
    """A collector batch as the replay buffer's items: swarm transitions, or single-UAV ones
    (:func:`per_uav`) when the sizes are mixed; for ``k`` members (member-major worlds), rows
    ``[R, k]`` with member j's transitions in column j."""
    if k == 1:
        return per_uav(batch) if single_uavs else batch.select(*TRANSITION_KEYS, strict=False).reshape(-1)
    if single_uavs:
        return per_uav(batch.reshape(k, -1), lead=1).transpose(0, 1).contiguous()
    return batch.select(*TRANSITION_KEYS, strict=False).reshape(k, -1).transpose(0, 1).contiguous()


def episode_values(episodes: TensorDictBase) -> torch.Tensor:
    """The :data:`EPISODE_METRICS` of ``"episode"`` entries ``[*S]`` as one float64 tensor
    ``[*S, M]`` (a copy, on their device)."""
    return torch.stack([episodes[k].double() for k in EPISODE_METRICS], -1)


def episode_rows(values: list[list[float]], first: int, frames: int) -> list[list[Any]]:
    """:data:`EPISODE_COLUMNS` rows of finished episodes (``values``: their
    :func:`episode_values`, one list per episode), numbered from ``first + 1``, all counted at
    ``frames``."""
    return [[first + 1 + i, frames, round(v[0], 5), int(v[1]), int(v[2]), *(round(x, 4) for x in v[3:-1]), int(v[-1])]
            for i, v in enumerate(values)]


@dataclass
class Finished:
    """The episodes that ended in one collector batch ``[worlds, steps]``: ``frames`` counted at
    the batch's end, ``worlds`` the world each ended in, ``values`` their :func:`episode_values`
    (world-major, as boolean indexing of the batch gives them), ``source`` what the batch was
    added with."""

    frames: int
    worlds: list[int]
    values: list[list[float]]
    source: Any = None


class PendingEpisodes:
    """The finished episodes of the batches not yet written, kept on the batches' device.

    Adding a batch reads nothing on the host (on a GPU, no synchronisation per batch); :meth:`flush`
    reads every pending batch's episodes at once. ``slots`` bounds how many episodes are pending
    (one per world and step), so a loop with an episode budget reads only when it could be spent.
    """

    def __init__(self) -> None:
        self._batches: list[tuple[int, int, torch.Tensor, torch.Tensor, Any]] = []
        self.slots = 0

    def add(self, batch: TensorDictBase, frames: int, source: Any = None) -> None:
        """Keep the episodes ending in ``batch`` (``[worlds, steps]``), counted at ``frames``."""
        steps = batch.batch_size[-1] if batch.batch_dims > 1 else 1
        done = batch.get(("next", "done")).reshape(-1).clone()  # a collector may hand out the same batch again
        values = episode_values(batch.get(("next", "episode"))).reshape(done.shape[0], -1)
        self._batches.append((frames, steps, done, values, source))
        self.slots += done.numel()

    def flush(self) -> list[Finished]:
        """The pending batches that had finished episodes, in order (one host read for all)."""
        if not self._batches:
            return []
        done = torch.cat([b[2] for b in self._batches])
        where = done.nonzero().squeeze(-1)
        values = torch.cat([b[3] for b in self._batches])[where].tolist()
        where = where.tolist()
        out, start, i = [], 0, 0
        for frames, steps, batch_done, _, source in self._batches:
            end, j = start + batch_done.numel(), i
            while j < len(where) and where[j] < end:
                j += 1
            if j > i:
                out.append(Finished(frames, [(w - start) // steps for w in where[i:j]], values[i:j], source))
            start, i = end, j
        self._batches, self.slots = [], 0
        return out


__all__ = ["AgentwiseDone", "EPISODE_COLUMNS", "EPISODE_METRICS", "Finished", "PendingEpisodes", "TRANSITION_KEYS",
           "agentwise_done", "episode_rows", "episode_values", "per_uav", "replay_rows"]
