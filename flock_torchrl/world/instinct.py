"""The repulsion instinct (docs/specification.md section 3; paper Eq. 26-29; in 3-D section 11)."""

from __future__ import annotations

import math

import torch

from ..config.scenario import INSTINCT_MODES
from .geometry import length, stored
from .laser import beam_return_offset
from .sensors import Neighbours
from .space import Space


def rotate_90(vec: torch.Tensor) -> torch.Tensor:
    """Rotate ``[..., 2]`` vectors by +90 degrees: ``(x, y) -> (-y, x)``."""
    return torch.stack((-vec[..., 1], vec[..., 0]), -1)


def repulsion(offset: torch.Tensor, active: torch.Tensor, to_goal: torch.Tensor, gain: float, r0: float,
              tangential: bool = True, taper: float = 0.0, space: Space | None = None) -> torch.Tensor:
    """Summed repulsion velocity of Eq. 26-29.

    For each counted neighbour j (``active`` and ``0 < |p_ij| < r0``):
    ``v_r = gain (r0 - |p_ij|) (p_i - p_j) / |p_ij|`` (Eq. 26), and ``v_t`` = ``v_r`` rotated
    by +-90 deg, the sign making ``(p_g - p_i) . v_t > 0``, +90 deg on a tie (Eq. 27).

    Args:
        offset: ``[B, N, M, 2]`` neighbour positions minus the UAV's, ``p_j - p_i``.
        active: ``[B, N, M]`` which of the ``M`` candidates exist (visible UAVs, virtual UAV).
        to_goal: ``[B, N, 2]`` ``p_g - p_i``.
        tangential: include ``v_t`` (Eq. 28); Policy5-G drops it.
        taper: in space, the angle (rad) within which ``v_t`` fades to 0 about ``v_r``'s line (section 11).
        space: in space (section 11) the offsets and ``to_goal`` have three components.

    Returns:
        ``[B, N, 2]`` ``v_rep_i = sum_j (v_r_ij + v_t_ij)`` (Eq. 29).
    """
    dx, dy = offset[..., 0].contiguous(), offset[..., 1].contiguous()
    goal = to_goal[..., None].unbind(-2)  # per component, [B, N, 1]
    if space is not None:  # section 11
        dz = offset[..., 2].contiguous()
        return torch.stack(repulsion_xy(dx, dy, torch.sqrt(dx * dx + dy * dy + dz * dz), active, goal, gain, r0,
                                        tangential, space, dz, taper=taper), -1)
    vx, vy = repulsion_xy(dx, dy, torch.sqrt(dx * dx + dy * dy), active, goal, gain, r0, tangential)
    return torch.stack((vx, vy), -1)


def repulsion_xy(dx: torch.Tensor, dy: torch.Tensor, dist: torch.Tensor, active: torch.Tensor,
                 to_goal: tuple[torch.Tensor, ...], gain: float, r0: float, tangential: bool = True,
                 space: Space | None = None, dz: torch.Tensor | None = None, dim: int = -1, taper: float = 0.0
                 ) -> tuple[torch.Tensor, ...]:
    """Eq. 26-29 (:func:`repulsion`) on the offset's components ``dx, dy`` and length ``dist``
    (each ``[B, N, M]``), summed over ``M``: ``(v_x, v_y)``, each ``[B, N]``. The one home of
    the repulsion's formula: :func:`repulsion` and :func:`instinct_command` call it.

    ``to_goal``: the components of ``p_g - p_i``, each broadcasting against ``dx`` (``[B, N, 1]``).
    ``dim``: the axis of the neighbours, summed over (0 for the compiled step's ``[M, N, B]``).

    In ``space`` (with the offsets' ``dz``, ``to_goal`` of three components; section 11): ``(v_x, v_y,
    v_z)``, with ``v_t``
    along the goal's component orthogonal to ``v_r`` (:func:`tangential_3d`, faded within ``taper`` of
    ``v_r``'s line); where ``v_r`` and the goal are both level it is the 2-D ``v_t``, computed as in 2-D."""
    counted = active & (dist > 0) & (dist < r0)
    # Per neighbour: v_r = -scale * (dx, dy), scale = gain (r0 - d) / d where counted, else 0.
    scale = torch.where(counted, gain * (r0 - dist) / torch.where(counted, dist, torch.ones_like(dist)),
                        torch.zeros_like(dist))
    rx, ry = -scale * dx, -scale * dy
    if space is not None:
        rz = -scale * dz
        if not tangential:
            return rx.sum(dim), ry.sum(dim), rz.sum(dim)
        return tangential_3d(rx, ry, rz, to_goal, dim, taper)
    if not tangential:
        return rx.sum(dim), ry.sum(dim)
    # v_t = rotate(v_r, +90 deg) = (-ry, rx), flipped where it points away from the goal.
    gx, gy = to_goal[0], to_goal[1]
    sign = torch.where(-ry * gx + rx * gy >= 0, 1.0, -1.0)
    return (rx - sign * ry).sum(dim), (ry + sign * rx).sum(dim)


def tangential_3d(rx: torch.Tensor, ry: torch.Tensor, rz: torch.Tensor, to_goal: tuple[torch.Tensor, ...],
                  dim: int = -1, taper: float = 0.0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``sum_j (v_r + v_t)`` in 3-D for radial terms ``(rx, ry, rz) [B, N, M]`` (section 11, Eq. 27-28 in
    space), summed over ``dim``; ``to_goal`` the components of ``g = p_g - p_i``.

    ``v_t = |v_r| g_perp / max(|g_perp|, |g| sin(taper))`` with ``g_perp`` the part of ``g`` orthogonal
    to ``v_r``: of length ``|v_r|`` where the goal lies more than ``taper`` off ``v_r``'s line, fading
    linearly in the sine to 0 on it (the tie: ``v_t = 0`` for any ``v_r``), so a continuous function of
    the geometry. ``taper = 0``: ``|v_r| g_perp / |g_perp|``, whose direction near the line is set by
    round-off; its tie is the planar one (shipped checkpoints before the taper). Where ``v_r`` and
    ``g`` are both level, section 3's ``v_t``, computed in the plane (the 2-D special case)."""
    gx, gy, gz = to_goal
    sign = torch.where(-ry * gx + rx * gy >= 0, 1.0, -1.0)  # the planar form, as in 2-D
    rr = rx * rx + ry * ry + rz * rz
    k = (gx * rx + gy * ry + gz * rz) / torch.where(rr > 0, rr, torch.ones_like(rr))
    px, py, pz = gx - k * rx, gy - k * ry, gz - k * rz        # the goal's part orthogonal to v_r
    pn = torch.sqrt(px * px + py * py + pz * pz)
    if taper > 0:
        floor = math.sin(taper) * torch.sqrt(gx * gx + gy * gy + gz * gz)
        reach = torch.maximum(pn, floor)
        m = torch.sqrt(rr) / torch.where(reach > 0, reach, torch.ones_like(reach))
        planar = (rz == 0) & (gz == 0)
    else:
        m = torch.sqrt(rr) / torch.where(pn > 0, pn, torch.ones_like(pn))
        planar = ((rz == 0) & (gz == 0)) | (pn == 0)
    tx = torch.where(planar, -sign * ry, m * px)
    ty = torch.where(planar, sign * rx, m * py)
    tz = torch.where(planar, torch.zeros_like(rz), m * pz)
    return (rx + tx).sum(dim), (ry + ty).sum(dim), (rz + tz).sum(dim)


def instinct_parts(position: torch.Tensor, heading: torch.Tensor, goal: torch.Tensor, beams: torch.Tensor,
                   neighbours: Neighbours, *, gain: float, r0: float, safe_distance: float, tangential: bool,
                   shortest: tuple[torch.Tensor, torch.Tensor] | None = None, pushing: torch.Tensor | None = None,
                   space: Space | None = None, taper: float = 0.0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The instinct's switch and its two parts, from what the UAV senses (specification section 3).

    The UAV switches to repulsion when ``min(d_uav1, d_scan1) <= d_safe``; the repulsion sums
    over visible UAVs and one virtual UAV at the return point of the shortest beam.

    Args:
        position: ``[B, N, 2]``; heading ``[B, N]``; goal ``[B, 2]``; beams ``[B, N, K]`` (as sensed);
        neighbours: camera measurements (as sensed).
        shortest: ``shortest_beams(beams, k)`` if already known.
        pushing: ``[B, N, M]``, the camera neighbours that push (default: every visible one; the
            switch always reads every visible one). Variants beyond the paper narrow it.
        space: section 11, its ``laser``'s beams; positions, goal and pushes are then 3-D.
        taper: in space, the tangential term's taper (:func:`tangential_3d`).

    Returns:
        ``(triggered [B, N] bool, uav_part [B, N, 2], obstacle_part [B, N, 2])``: the pushes of
        the UAVs and of the virtual UAV on the obstacle (not yet summed or clipped).
    """
    d_scan1, wall_offset = beam_return_offset(beams, heading, shortest, space)
    to_goal = stored(goal[:, None, :] - position)
    uav = repulsion_xy(neighbours.dx, neighbours.dy, neighbours.distance,
                       neighbours.visible if pushing is None else pushing,
                       tuple(neighbours.against_pairs(g) for g in to_goal.unbind(-1)), gain, r0, tangential,
                       neighbours.space, neighbours.dz, neighbours.pair_dim, taper)
    uav = tuple(neighbours.per_uav(u) for u in uav)
    wall = repulsion_xy(wall_offset[..., 0, None], wall_offset[..., 1, None], d_scan1[..., None],
                        torch.ones_like(d_scan1[..., None], dtype=torch.bool), to_goal[..., None].unbind(-2), gain,
                        r0, tangential, space, None if space is None else wall_offset[..., 2, None], taper=taper)
    triggered = torch.minimum(neighbours.nearest_distance(), d_scan1) <= safe_distance
    return triggered, torch.stack(uav, -1), torch.stack(wall, -1)


def hold_in_crowd(uav: torch.Tensor, mode: str, *, beams: torch.Tensor, heading: torch.Tensor, gain: float,
                  r0: float, safe_distance: float, shortest: tuple[torch.Tensor, torch.Tensor] | None = None,
                  cap: float | None = None, space: Space | None = None) -> torch.Tensor:
    """The UAVs' push ``uav [B, N, 2]`` of :func:`instinct_parts` under an instinct mode.

    - ``paper``: unchanged (Eq. 29).
    - ``no_push_in``: where the shortest beam returns within ``r0``, the component of the push
      along the obstacle's inward normal (from the UAV toward the beam's return point) is
      removed, so a crowd never pushes a UAV into what its laser sees; the outward and
      tangential components stay.
    - ``saturated``: the push is scaled down to at most ``cap`` m/s (default ``gain (r0 -
      d_safe)``, what one UAV at the switch distance gives), its direction kept.
    """
    if mode == "paper":
        return uav
    if mode == "saturated":
        limit = gain * (r0 - safe_distance) if cap is None else cap
        norm = length(uav, space)[..., None]
        return uav * torch.where(norm > limit, limit / norm.clamp_min(1e-12), torch.ones_like(norm))
    if mode == "no_push_in":
        d_scan1, wall = beam_return_offset(beams, heading, shortest, space)
        seen = (d_scan1 > 0) & (d_scan1 < r0)
        normal = -wall / d_scan1.clamp_min(1e-12)[..., None]  # outward: from the return point to the UAV
        inward = (uav * normal).sum(-1, keepdim=True).clamp_max(0.0)
        return torch.where(seen[..., None], uav - inward * normal, uav)
    raise ValueError(f"instinct mode must be one of {', '.join(INSTINCT_MODES)}; got {mode!r}")


def instinct_command(position: torch.Tensor, heading: torch.Tensor, goal: torch.Tensor, beams: torch.Tensor,
                     neighbours: Neighbours, *, gain: float, r0: float, safe_distance: float,
                     tangential: bool, shortest: tuple[torch.Tensor, torch.Tensor] | None = None,
                     mode: str = "paper", space: Space | None = None, taper: float = 0.0
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """The instinct's switch and command (:func:`instinct_parts`, the UAVs' part under
    :func:`hold_in_crowd`'s ``mode``, summed): ``(triggered [B, N] bool, command [B, N, 2])``,
    the command not yet clipped."""
    triggered, uav, obstacle = instinct_parts(position, heading, goal, beams, neighbours, gain=gain, r0=r0,
                                              safe_distance=safe_distance, tangential=tangential, shortest=shortest,
                                              space=space, taper=taper)
    uav = hold_in_crowd(uav, mode, beams=beams, heading=heading, gain=gain, r0=r0, safe_distance=safe_distance,
                        shortest=shortest, space=space)
    return triggered, uav + obstacle
