"""The repulsion instinct (docs/specification.md section 3; paper Eq. 26-29)."""

from __future__ import annotations

import torch

from .sensors import Neighbours, beam_return_offset


def rotate_90(vec: torch.Tensor) -> torch.Tensor:
    """Rotate ``[..., 2]`` vectors by +90 degrees: ``(x, y) -> (-y, x)``."""
    return torch.stack((-vec[..., 1], vec[..., 0]), -1)


def repulsion(offset: torch.Tensor, active: torch.Tensor, to_goal: torch.Tensor, gain: float, r0: float,
              tangential: bool = True) -> torch.Tensor:
    """Summed repulsion velocity of Eq. 26-29.

    For each counted neighbour j (``active`` and ``0 < |p_ij| < r0``):
    ``v_r = gain (r0 - |p_ij|) (p_i - p_j) / |p_ij|`` (Eq. 26), and ``v_t`` = ``v_r`` rotated
    by +-90 deg, the sign making ``(p_g - p_i) . v_t > 0``, +90 deg on a tie (Eq. 27).

    Args:
        offset: ``[B, N, M, 2]`` neighbour positions minus the UAV's, ``p_j - p_i``.
        active: ``[B, N, M]`` which of the ``M`` candidates exist (visible UAVs, virtual UAV).
        to_goal: ``[B, N, 2]`` ``p_g - p_i``.
        tangential: include ``v_t`` (Eq. 28); Policy5-G drops it.

    Returns:
        ``[B, N, 2]`` ``v_rep_i = sum_j (v_r_ij + v_t_ij)`` (Eq. 29).
    """
    dist = torch.linalg.vector_norm(offset, dim=-1)
    counted = active & (dist > 0) & (dist < r0)
    safe = torch.where(counted, dist, torch.ones_like(dist))
    magnitude = torch.where(counted, gain * (r0 - dist), torch.zeros_like(dist))
    v_r = magnitude[..., None] * (-offset) / safe[..., None]
    total = v_r
    if tangential:
        v_t = rotate_90(v_r)
        sign = torch.where((v_t * to_goal[..., None, :]).sum(-1) >= 0, 1.0, -1.0)
        total = v_r + sign[..., None] * v_t
    return total.sum(-2)


def instinct_command(position: torch.Tensor, heading: torch.Tensor, goal: torch.Tensor, beams: torch.Tensor,
                     neighbours: Neighbours, *, gain: float, r0: float, safe_distance: float,
                     tangential: bool, shortest: tuple[torch.Tensor, torch.Tensor] | None = None
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """The instinct's switch and command, from what the UAV senses (specification section 3).

    The UAV switches to repulsion when ``min(d_uav1, d_scan1) <= d_safe``; the repulsion sums
    over visible UAVs and one virtual UAV at the return point of the shortest beam.

    Args:
        position: ``[B, N, 2]``; heading ``[B, N]``; goal ``[B, 2]``; beams ``[B, N, K]`` (as sensed);
        neighbours: camera measurements (as sensed).
        shortest: ``shortest_beams(beams, k)`` if already known.

    Returns:
        ``(triggered [B, N] bool, command [B, N, 2])`` (the command is not yet clipped).
    """
    d_scan1, wall_offset = beam_return_offset(beams, heading, shortest)
    offsets = torch.cat((neighbours.offsets(heading), wall_offset[..., None, :]), -2)
    active = torch.cat((neighbours.visible, torch.ones_like(neighbours.visible[..., :1])), -1)
    command = repulsion(offsets, active, goal[:, None, :] - position, gain, r0, tangential)
    triggered = torch.minimum(neighbours.nearest_distance(), d_scan1) <= safe_distance
    return triggered, command
