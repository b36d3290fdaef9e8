"""The evaluation-time variants of the crash diagnosis (:mod:`.diagnosis`): what each variant changes
in the world and in what the actor sees, and the instincts that hold in a crowd, applied outside
the world by a wrapper (:class:`InstinctWrapper`) whose actions are velocity commands."""

from __future__ import annotations

import math
from typing import Any, Callable

import torch
from tensordict import TensorDict

from ..config import ScenarioConfig
from ..world.dynamics import action_to_command, clip_command
from ..world.instinct import hold_in_crowd, instinct_parts
from ..world.laser import smallest
from ..world.sensors import Neighbours, near_neighbours

OBS, ACTION = ("agents", "observation"), ("agents", "action")

# variant -> (scenario overrides, what the actor sees, instinct wrapper mode or None, the wrapper
# instinct's camera: "own" (the UAV's field of view) or "allround" (360 deg))
OUTSIDE = {"instinct": False, "instinct_mode": "paper", "action_mode": "velocity"}  # the world of an instinct applied by InstinctWrapper
VARIANTS: dict[str, tuple[dict[str, Any], str, str | None, str]] = {
    "paper": ({}, "own", None, "own"),                             # the paper's instinct, in the world
    "instinct_off": ({"instinct": False, "instinct_mode": "paper"}, "own", None, "own"),
    "tangential_off": ({"tangential": False}, "own", None, "own"),  # the instinct's push radial only (Eq. 28 off)
    "allround_camera": ({}, "allround", None, "own"),              # actor's camera slots from the critic's 360 deg camera
    "wrapped_paper": (OUTSIDE, "own", "paper", "own"),             # control: the same episodes as "paper"
    "nearest3": (OUTSIDE, "own", "nearest", "own"),
    "saturated": (OUTSIDE, "own", "saturated", "own"),
    "no_push_in": (OUTSIDE, "own", "no_push_in", "own"),
    "no_push_in_360": (OUTSIDE, "own", "no_push_in", "allround"),  # ... and the instinct sees UAVs all round
}


def crowd_instinct(position: torch.Tensor, heading: torch.Tensor, goal: torch.Tensor, beams: torch.Tensor,
                   neighbours: Neighbours, *, gain: float, r0: float, safe_distance: float, tangential: bool,
                   mode: str = "paper", k: int = 3, cap: float | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The repulsion instinct (specification section 3) and variants that hold in a crowd.

    ``mode``: ``paper`` (Eq. 26-29 as the world applies it); ``nearest`` (only the ``k``
    closest visible UAVs push); ``saturated`` (the UAVs' summed push is scaled down to at most
    ``cap`` m/s, default ``gain (r0 - d_safe)``, what one UAV at the switch distance gives);
    ``no_push_in`` (the part of the UAVs' push that points toward the obstacle the shortest beam
    hits is removed). The obstacle's own (virtual UAV) term and the switch are the paper's.

    Args:
        position ``[B, N, 2]``, heading ``[B, N]``, goal ``[B, 2]``, beams ``[B, N, K]``; neighbours
        as :func:`~flock_torchrl.world.sensors.near_neighbours` gives them.

    Returns:
        ``(triggered [B, N], command [B, N, 2], uav_part [B, N, 2], obstacle_part [B, N, 2])``,
        command = uav_part + obstacle_part, not clipped.
    """
    if mode not in ("paper", "nearest", "saturated", "no_push_in"):
        raise ValueError(f"mode must be paper, nearest, saturated or no_push_in; got {mode!r}")
    pushing = neighbours.visible
    if mode == "nearest":
        key = torch.where(pushing, neighbours.distance, torch.full_like(neighbours.distance, math.inf))
        kth = smallest(key, min(k, key.shape[-1]))[0][..., -1:]
        pushing = pushing & (key <= kth)
    # The switch, the UAVs' push and the obstacle's push are the world's (world/instinct.py).
    triggered, uav, obstacle = instinct_parts(position, heading, goal, beams, neighbours, gain=gain, r0=r0,
                                              safe_distance=safe_distance, tangential=tangential, pushing=pushing)
    # The crowd variants are the world's (instinct_mode); nearest is this module's own.
    uav = hold_in_crowd(uav, "paper" if mode == "nearest" else mode, beams=beams, heading=heading, gain=gain,
                        r0=r0, safe_distance=safe_distance, cap=cap)
    return triggered, uav + obstacle, uav, obstacle


class InstinctWrapper:
    """An actor plus an instinct applied outside the world: the actor's action becomes its
    velocity command (Eq. 19-20), which the UAVs whose instinct switches replace by
    :func:`crowd_instinct` of ``mode``. The env must have the instinct off, ``action_mode =
    velocity`` and the ``physics`` and ``laser`` extras (:data:`VARIANTS` builds it so)."""

    def __init__(self, actor: Callable[[TensorDict], TensorDict], cfg: ScenarioConfig, mode: str,
                 half_fov: float | None = None) -> None:
        if cfg.instinct or cfg.action_mode != "velocity":
            raise ValueError("InstinctWrapper needs a world with instinct=False and action_mode='velocity'")
        self.actor, self.cfg, self.mode = actor, cfg, mode
        self.half_fov = cfg.half_fov if half_fov is None else half_fov  # the instinct's camera (pi: all round)
        self.last_action: torch.Tensor | None = None  # the actor's own action of the last call, [B, N, 2]

    def __call__(self, td: TensorDict) -> TensorDict:
        cfg = self.cfg
        td = self.actor(td)
        self.last_action = td[ACTION].clone()
        position, heading = td["agents", "position"], td["agents", "heading"]
        command = action_to_command(td[ACTION], heading)
        neighbours = near_neighbours(position, heading, cfg.camera_range, self.half_fov)[0]
        triggered, repulsion, _, _ = crowd_instinct(
            position, heading, td["goal"], td["agents", "scan"], neighbours, gain=cfg.rep_gain, r0=cfg.rep_range,
            safe_distance=cfg.safe_distance, tangential=cfg.tangential, mode=self.mode)
        command = torch.where(triggered[..., None], repulsion, command)
        td.set(ACTION, clip_command(command, cfg.v_max))
        return td


class AllRoundCamera:
    """The actor fed the critic's camera slots (all round, phi_v = 2 pi) in place of its own:
    ``observation [..., :d]`` becomes ``state [..., :d]`` (the two share the goal and laser parts)."""

    def __init__(self, actor: Callable[[TensorDict], TensorDict]) -> None:
        self.actor = actor

    def __call__(self, td: TensorDict) -> TensorDict:
        obs = td[OBS]
        seen = td.select(OBS, ("agents", "state"))
        seen.set(OBS, td["agents", "state"][..., : obs.shape[-1]])
        td.set(ACTION, self.actor(seen)[ACTION])
        return td


__all__ = ["ACTION", "AllRoundCamera", "InstinctWrapper", "OBS", "OUTSIDE", "VARIANTS", "crowd_instinct"]
