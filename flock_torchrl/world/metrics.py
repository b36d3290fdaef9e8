"""Per-episode flocking metrics (docs/specification.md section 5; paper Eq. 31-36).

:data:`METRICS` declares every per-episode quantity once: its key, its kind and how a table
labels it; the env's spec, the evaluation's statistics, the training log, the tables and the
fidelity score all read their names from it. The env keeps one accumulator TensorDict of
batch ``[B]`` and folds every step into it with :func:`update_episode`;
:func:`episode_summary` turns it into the reported metrics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import torch
from tensordict import TensorDict

from .geometry import circular_mean, length, pairwise, stored, wrap
from .space import Space


@dataclass(frozen=True)
class Metric:
    """One per-episode quantity.

    ``kind``: ``rate`` (a success flag reported as a rate with its interval), ``flag`` (other
    booleans), ``cell`` (a table cell, mean +- std over episodes, paper order), ``count``, ``sum``.
    """

    key: str
    kind: str
    label: str = ""
    unit: str = ""


METRICS = (
    Metric("success", "rate", "success", ""),
    Metric("safe_success", "rate", "safe success", ""),
    Metric("reached", "flag"),
    Metric("crashed", "flag"),
    Metric("d_min_obs", "cell", "d_min^obs", "m"),
    Metric("d_min_uav", "cell", "d_min^uav", "m"),
    Metric("d_c", "cell", "d_c", "m"),
    Metric("v_error", "cell", "V_error^c", "m/s"),
    Metric("phi_error", "cell", "phi_error^c", "rad"),
    Metric("speed", "cell", "V", "m/s"),
    Metric("t_goal", "cell", "t^g", "s"),
    Metric("steps", "count"),
    Metric("return", "sum"),
)
METRIC_KEYS = tuple(m.key for m in METRICS)
RATE_METRICS = tuple(m.key for m in METRICS if m.kind == "rate")
FLAG_METRICS = tuple(m.key for m in METRICS if m.kind in ("rate", "flag"))
# The paper's table columns (Tables III-V), in its order; t_goal over the episodes that reached.
CELL_METRICS = tuple(m.key for m in METRICS if m.kind == "cell")
METRIC_BY_KEY = {m.key: m for m in METRICS}
OBSTACLE_DISTANCE_CAP = 10.0


def closest_pair(distance: torch.Tensor) -> torch.Tensor:
    """The smallest distance between two different UAVs, ``[B]`` from ``[B, N, N]`` (``inf`` for one UAV)."""
    n = distance.shape[-1]
    eye = torch.eye(n, dtype=torch.bool, device=distance.device)
    return distance.masked_fill(eye, math.inf).flatten(-2).amin(-1)


def step_statistics(position: torch.Tensor, velocity: torch.Tensor, heading: torch.Tensor,
                    obstacle_distance: torch.Tensor, pair_distance: torch.Tensor | None = None,
                    space: Space | None = None) -> dict[str, torch.Tensor]:
    """Swarm quantities of one time step, each ``[B]``.

    Args:
        position, velocity: ``[B, N, 2]`` (3-D: ``[B, N, 3]``, section 11); heading ``[B, N]``;
        obstacle_distance: ``[B, N]`` signed distance to the nearest obstacle surface (negative inside).
        pair_distance: the closest pair ``[B]`` (:func:`closest_pair`) if already known.

    Returns:
        ``obs`` (min over UAVs of the obstacle distance), ``uav`` (closest pair, ``inf`` for
        one UAV), ``d_c`` (Eq. 33 summand), ``v_error`` (Eq. 34 with the 1/N erratum),
        ``phi_error`` (Eq. 35 with the circular mean), ``speed`` (Eq. 36 summand).
    """
    uav = pair_distance if pair_distance is not None else closest_pair(pairwise(position, space)[1])
    centre = position.mean(-2, keepdim=True)
    swarm_velocity = velocity.mean(-2)
    v_c = length(swarm_velocity, space)
    v_i = length(velocity, space)
    phi_bar = circular_mean(heading, -1, keepdim=True)
    return {
        # A UAV that overshoots into an obstacle on its crash step is at distance 0, not negative.
        "obs": obstacle_distance.amin(-1).clamp_min(0.0),
        "uav": uav,
        "d_c": length(position - centre, space).mean(-1),
        "v_error": (v_i - v_c[:, None]).abs().mean(-1),
        "phi_error": wrap(stored(heading - phi_bar)).abs().mean(-1),
        "speed": v_c,
    }


def new_accumulator(batch: int, device=None, dtype=torch.float32) -> TensorDict:
    """Empty accumulators for ``batch`` episodes."""
    def full(value, kind=dtype):
        return torch.full((batch,), value, device=device, dtype=kind)

    return TensorDict(
        {"steps": full(0, torch.long), **{k: full(0.0) for k in ("sum_d_c", "sum_v_error", "sum_phi_error",
                                                                  "sum_speed", "return")},
         "d_min_obs": full(OBSTACLE_DISTANCE_CAP), "d_min_uav": full(math.inf), "reached": full(False, torch.bool),
         "crashed": full(False, torch.bool), "t_goal": full(math.nan)},
        batch_size=[batch], device=device)


def update_episode(acc: TensorDict, stats: dict[str, torch.Tensor], reached: torch.Tensor,
                   crashed: torch.Tensor, dt: float, reward: torch.Tensor | None = None) -> TensorDict:
    """Fold one step into the accumulators (in place) and return them.

    Args:
        stats: from :func:`step_statistics`; reached / crashed: ``[B]`` this step's events;
        reward: ``[B]`` the step's reward averaged over the UAVs (summed into ``return``).
    """
    if reward is not None:
        acc["return"] = acc["return"] + reward
    steps = acc["steps"] + 1
    acc["steps"] = steps
    for name in ("d_c", "v_error", "phi_error", "speed"):
        acc[f"sum_{name}"] = acc[f"sum_{name}"] + stats[name]
    acc["d_min_obs"] = torch.minimum(acc["d_min_obs"], stats["obs"].clamp_max(OBSTACLE_DISTANCE_CAP))
    acc["d_min_uav"] = torch.minimum(acc["d_min_uav"], stats["uav"])
    first = reached & ~acc["reached"]
    acc["t_goal"] = torch.where(first, steps.to(acc["t_goal"].dtype) * dt, acc["t_goal"])
    acc["reached"] = acc["reached"] | reached
    acc["crashed"] = acc["crashed"] | crashed
    return acc


def summary_values(acc: Mapping[str, torch.Tensor], collision_distance: float) -> dict[str, torch.Tensor]:
    """:func:`episode_summary` as a plain dict of ``[B]`` tensors (what the compiled step returns)."""
    steps = acc["steps"].clamp_min(1).to(acc["sum_d_c"].dtype)
    success = acc["reached"] & ~acc["crashed"]
    return {"success": success, "safe_success": success & (acc["d_min_uav"] >= collision_distance),
            **{k: acc[k].clone() for k in ("reached", "crashed", "d_min_obs", "d_min_uav")},
            **{k: acc[f"sum_{k}"] / steps for k in ("d_c", "v_error", "phi_error", "speed")},
            **{k: acc[k].clone() for k in ("t_goal", "steps", "return")}}


def episode_summary(acc: Mapping[str, torch.Tensor], collision_distance: float) -> TensorDict:
    """The section 5 metrics of each episode so far, batch ``[B]``.

    ``success``: goal reached, no crash. ``safe_success``: success and no UAV pair ever closer
    than ``collision_distance``. Means are over the steps taken (0 before the first step);
    ``t_goal`` is NaN for an episode that has not reached the goal; ``return`` is the
    undiscounted episode reward averaged over the UAVs.
    """
    values = summary_values(acc, collision_distance)
    return TensorDict(values, batch_size=values["steps"].shape, device=values["steps"].device)
