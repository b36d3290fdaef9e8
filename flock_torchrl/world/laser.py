"""The laser (docs/specification.md section 2, Eq. 16; in 3-D its rings and vertical pair, section
11): every beam of every UAV cast at once, the shortest beams selected, ``o_scan``, and the return
point of the shortest beam that the instinct reads. Part of onboard sensing (:mod:`.sensors`)."""

from __future__ import annotations

import math

import torch

from ..config.scenario import Laser
from .geometry import Obstacles, cast_rays_3d, cast_rays_along, cast_rays_worlds_last, constant, wrap
from .space import Space


def beam_offsets(n_beams: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """Beam headings relative to the UAV's heading, ``k * 2 pi / n_beams``, ``[n_beams]``."""
    # In float64, then rounded: float32 arithmetic puts beam 18 of 36 an ulp *below* pi,
    # so it would wrap to +pi instead of -pi.
    offsets = torch.arange(n_beams, device=device, dtype=torch.float64) * (2 * math.pi / n_beams)
    return offsets.to(dtype)


def beam_unit_table(n_beams: int) -> tuple[list[float], list[float]]:
    """``cos`` and ``sin`` of every beam offset ``k * 2 pi / n_beams`` as Python floats (double
    precision; rounded to the tensor's dtype where used): constants, also under ``torch.compile``."""
    step = 2 * math.pi / n_beams
    return [math.cos(k * step) for k in range(n_beams)], [math.sin(k * step) for k in range(n_beams)]


def worlds_last(per_uav: torch.Tensor) -> torch.Tensor:
    """A per-UAV ``[B, N]`` tensor as a contiguous ``[N, B]`` one, stored so (compiled code would
    otherwise keep the input's order, the UAVs innermost, in every tensor computed from it;
    ``as_strided`` onto its own strides pins the layout, and changes nothing eagerly)."""
    out = per_uav.transpose(0, 1).contiguous()
    return out.as_strided(out.shape, out.stride())


def beam_directions(heading: torch.Tensor, n_beams: int) -> torch.Tensor:
    """Unit vectors of every beam, ``[..., n_beams, 2]`` for headings ``[...]``: the heading's
    direction rotated by each beam's fixed offset (no trigonometry per beam).

    Stored component by component (``[..., n_beams, 0]`` contiguous over the beams): the ray
    casts read each component along the beams, which compiled code then loads as whole vectors
    rather than gathering every other float."""
    cos_o, sin_o = (constant(v, heading) for v in beam_unit_table(n_beams))
    cos_h, sin_h = torch.cos(heading)[..., None], torch.sin(heading)[..., None]
    return torch.stack((cos_h * cos_o - sin_h * sin_o, sin_h * cos_o + cos_h * sin_o), 0).movedim(0, -1)


def ring_tables(laser: Laser, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``cos`` and ``sin`` of every beam's elevation (:meth:`Laser.cos_sin`), ``[laser.count]`` each."""
    return tuple(constant(values, like) for values in laser.cos_sin())


def beam_azimuths(laser: Laser, index: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """Each beam's azimuth relative to the heading, ``k * 360 / n_beams`` deg, at beam indices
    ``index`` (the vertical pair's: 0, where their horizontal part, of length 0, would point)."""
    offsets = beam_offsets(laser.n_beams, like.device, like.dtype)[index % laser.n_beams]
    return torch.where(index < laser.ring_beams, offsets, 0.0) if laser.vertical else offsets


def laser_scan(position: torch.Tensor, heading: torch.Tensor, obstacles: Obstacles, n_beams: int,
               max_range: float, static_shapes: bool = False, space: Space | None = None
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """All laser beams of every UAV.

    Args:
        position: ``[B, N, 2]`` (3-D: ``[B, N, 3]``); heading: ``[B, N]``.
        static_shapes: cast every beam at every obstacle, the worlds innermost in memory (in 2-D
            :func:`~.geometry.cast_rays_worlds_last`; the results are ``[B, N, K]`` views of
            ``[K, N, B]`` tensors, which :func:`shortest_beams` reads with ``worlds_last``).
        space: section 11; its ``laser``'s rings and vertical pair, ``n_beams`` beams on each ring.

    Returns:
        ``(distance [B, N, n_beams], obstacle index [B, N, n_beams])``; beam ``k`` points at
        ``heading + k * 360/n_beams deg``; distances ``min(hit, max_range)``, 0 inside an obstacle.
        In space ``[B, N, laser.count]``, beam ``(r, k)`` at index ``r n_beams + k``, then the vertical pair.
    """
    if space is None and static_shapes:
        h = worlds_last(heading)                                      # [N, B]
        cos_o, sin_o = (constant(v, h)[:, None, None] for v in beam_unit_table(n_beams))  # [K, 1, 1]
        cos_h, sin_h = torch.cos(h), torch.sin(h)
        # beam_directions' formula, beams outermost: [K, N, B]
        dx, dy = cos_h * cos_o - sin_h * sin_o, sin_h * cos_o + cos_h * sin_o
        distance, index = cast_rays_worlds_last(worlds_last(position[..., 0]), worlds_last(position[..., 1]),
                                                dx, dy, obstacles, max_range)
        return distance.permute(2, 1, 0), index.permute(2, 1, 0)
    if space is None:
        return cast_rays_along(position, beam_directions(heading, n_beams), obstacles, max_range)
    laser, level = space.laser, beam_directions(heading, n_beams)
    horizontal = level.repeat(1, 1, len(laser.rings), 1)
    if laser.vertical:  # the pair's horizontal part is multiplied by cos_e = 0: any unit vector will do
        horizontal = torch.cat((horizontal, level[..., :1, :].expand(*level.shape[:-2], 2, 2)), -2)
    cos_e, sin_e = ring_tables(laser, position)
    return cast_rays_3d(position, horizontal, cos_e, sin_e, obstacles, max_range, static_shapes)


def smallest(values: torch.Tensor, k: int, dim: int = -1) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` smallest entries along ``dim``, ascending, ties by index (what a stable sort
    gives): ``k`` passes, each taking the minimum and the first index holding it, then masking
    that index with ``inf``.

    Along the last dimension (the eager layout) a pass is ``argmin``, a gather and a scatter.
    Along another one (the compiled step's, the worlds innermost) it is two plain reductions over
    ``dim``, the minimum and the first index where the values equal it, vectorised along the
    inner dimensions; indices are counted there in the values' float dtype (exact up to 2^24)
    and clamped into range. Both give the same values and indices (a NaN, which no checked
    action produces, is the minimum of the first and skipped by the second).

    Returns:
        ``(value, index)``, ``k`` entries along ``dim``; once the finite entries run out, values
        are ``inf`` (and their indices arbitrary).
    """
    dim = dim % values.dim()
    picks, indices = [], []
    if dim == values.dim() - 1:
        values = values.clone()  # one working copy, masked in place
        for _ in range(k):  # k = 3 selections, independent of the batch and the swarm
            index = values.argmin(-1, keepdim=True)
            picks.append(torch.gather(values, -1, index))
            indices.append(index)
            values.scatter_(-1, index, math.inf)
        return torch.cat(picks, -1), torch.cat(indices, -1)
    n = values.shape[dim]
    shape = [1] * values.dim()
    shape[dim] = n
    index = torch.arange(n, device=values.device, dtype=values.dtype).view(shape)
    for _ in range(k):
        low = values.amin(dim, keepdim=True)
        at = torch.where(values == low, index, n).amin(dim, keepdim=True).clamp_max(n - 1)
        picks.append(low)
        indices.append(at)
        values = torch.where(index == at, math.inf, values)
    return torch.cat(picks, dim), torch.cat(indices, dim).long()


def pick(values: torch.Tensor, at: torch.Tensor) -> torch.Tensor:
    """``values`` at indices ``at`` along the first dimension, ``[k, ...]`` for ``at [k, ...]``
    and ``values [M, ...]``: a masked sum over that dimension (the gather of the worlds-innermost
    layout, vectorised along the worlds; exact: one term is the value, the rest are zeros)."""
    index = torch.arange(values.shape[0], device=values.device, dtype=at.dtype).view(1, -1, *([1] * (at.dim() - 1)))
    return torch.where(index == at[:, None], values[None], 0.0).sum(1)


def shortest_beams(beams: torch.Tensor, n: int, worlds_last: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``n`` shortest beams, ascending, ties by beam index.

    Args:
        worlds_last: select along the beams held outermost (``beams`` a ``[B, N, K]`` view of a
            ``[K, N, B]`` tensor, as :func:`laser_scan` gives them with ``static_shapes``).

    Returns:
        ``(distance [B, N, n], beam index [B, N, n])``.
    """
    if worlds_last:
        d, at = smallest(beams.permute(2, 1, 0), n, 0)
        return d.permute(2, 1, 0), at.permute(2, 1, 0)
    return smallest(beams, n)


def scan_observation(beams: torch.Tensor, n: int, max_range: float,
                     shortest: tuple[torch.Tensor, torch.Tensor] | None = None, space: Space | None = None
                     ) -> torch.Tensor:
    """``o_scan`` (Eq. 16): ``[d_k / d_max^scan, alpha_k / pi]`` for the ``n`` shortest beams.

    Args:
        shortest: :func:`shortest_beams` of ``beams`` if already known (at least ``n`` of them).

    Returns:
        ``[B, N, 2 n]`` interleaved ``(d_1, alpha_1, d_2, alpha_2, ...)``; in ``space`` (its
        ``laser``; section 11) ``[B, N, 3 n]``, ``(d_k, alpha_k, e_k / pi)`` with ``e_k`` the beam's elevation
        (the vertical pair's: ``-+pi/2``, azimuth 0).
    """
    dist, idx = shortest if shortest is not None else shortest_beams(beams, n)
    dist, idx = dist[..., :n], idx[..., :n]
    if space is None:
        alpha = wrap(beam_offsets(beams.shape[-1], beams.device, beams.dtype))[idx]
        return torch.stack((dist.clamp(0.0, max_range) / max_range, alpha / math.pi), -1).flatten(-2)
    alpha = wrap(beam_azimuths(space.laser, idx, beams))
    elevation = constant(space.laser.elevations(), beams)[idx]
    return torch.stack((dist.clamp(0.0, max_range) / max_range, alpha / math.pi, elevation / math.pi),
                       -1).flatten(-2)


def beam_return_offset(beams: torch.Tensor, heading: torch.Tensor,
                       shortest: tuple[torch.Tensor, torch.Tensor] | None = None, space: Space | None = None
                       ) -> tuple[torch.Tensor, torch.Tensor]:
    """Shortest beam's length ``d_scan1`` ``[B, N]`` and its return point minus the UAV's position ``[B, N, 2]``.

    Args:
        shortest: :func:`shortest_beams` of ``beams`` if already known.
        space: section 11, its ``laser``'s beams; the offset is then ``[B, N, 3]``.
    """
    d, idx = shortest if shortest is not None else shortest_beams(beams, 1)
    d, idx = d[..., :1], idx[..., :1]
    if space is None:
        angle = heading + beam_offsets(beams.shape[-1], beams.device, beams.dtype)[idx[..., 0]]
        return d[..., 0], d * torch.stack((torch.cos(angle), torch.sin(angle)), -1)
    angle = heading + beam_azimuths(space.laser, idx[..., 0], beams)
    cos_e, sin_e = (t[idx[..., 0]] for t in ring_tables(space.laser, beams))
    return d[..., 0], d * torch.stack((cos_e * torch.cos(angle), cos_e * torch.sin(angle), sin_e), -1)


__all__ = ["beam_azimuths", "beam_directions", "beam_offsets", "beam_return_offset", "beam_unit_table", "laser_scan", "pick", "ring_tables", "scan_observation", "shortest_beams", "smallest", "worlds_last"]
