"""Onboard sensing (docs/specification.md section 2; paper Eq. 14-18): laser, camera, goal, swarm centre.

All functions take batched tensors ``[B, N, ...]`` and return the normalised pieces of the
observation ``[o_g, o_scan, o_cam]`` and the critic state ``[o_g, o_scan, s_cam, s_c]``.
"""

from __future__ import annotations

import math
import dataclasses
from dataclasses import dataclass

import torch

from .geometry import circular_mean, constant, length, relative_angle, stored, wrap
# The laser's half of sensing lives in .laser (imported from there); these three helpers serve both halves.
from .laser import pick, smallest, worlds_last
from .space import Space

# Numbers per piece of the observation and the critic state (section 2).
GOAL_SIZE = 2     # o_g: [min(d_g / d_s, 1), alpha_g / pi]
SCAN_SLOT = 2     # per beam of o_scan: [d / d_max^scan, alpha / pi]
CAMERA_SLOT = 3   # per slot of o_cam and s_cam: [min(d / d_v, 1), alpha / pi, wrap(phi_i - phi_j) / pi]
CENTRE_SIZE = 3   # s_c: [min(d_c / d_v, 1), alpha_c / pi, wrap(phi_i - phi_bar) / pi]
# In 3-D (section 11) each piece gains an elevation, the camera and the centre also a climb difference.
SIZES_3D = {"goal": 3, "scan": 3, "camera": 5, "centre": 5}


def piece_sizes(cfg) -> dict[str, int]:
    """Numbers per piece (goal, scan slot, camera slot, centre) in ``cfg``'s dimension."""
    if cfg.dims == 3:
        return SIZES_3D
    return {"goal": GOAL_SIZE, "scan": SCAN_SLOT, "camera": CAMERA_SLOT, "centre": CENTRE_SIZE}


def observation_size(cfg) -> int:
    """Length of the actor's observation ``[o_g, o_scan, o_cam]`` for a scenario ``cfg`` (its
    ``n_scan`` beams and ``n_cam`` camera slots): 17 in the paper, 27 in 3-D (section 11)."""
    size = piece_sizes(cfg)
    return size["goal"] + size["scan"] * cfg.n_scan + size["camera"] * cfg.n_cam


def state_size(cfg) -> int:
    """Length of the critic's state ``[o_g, o_scan, s_cam, s_c]`` for a scenario ``cfg``: 20 in the paper, 32 in 3-D."""
    return observation_size(cfg) + piece_sizes(cfg)["centre"]


def planar_entries(cfg, critic: bool = False) -> list[int]:
    """Where a 3-D observation (``critic``: state) keeps the 2-D one's entries: the indices whose
    removal (the elevations and climb differences) leaves the 2-D layout (section 11, the special case)."""
    keep = [0, 1]
    at = 3
    for _ in range(cfg.n_scan):
        keep += [at, at + 1]
        at += 3
    for _ in range(cfg.n_cam):
        keep += [at, at + 1, at + 3]
        at += 5
    if critic:
        keep += [at, at + 1, at + 3]
    return keep


def elevation_of(dx: torch.Tensor, dy: torch.Tensor, dz: torch.Tensor) -> torch.Tensor:
    """Elevation of offsets ``(dx, dy, dz)`` above the horizontal plane, ``atan2(dz, |d_h|)``."""
    return torch.atan2(dz, torch.sqrt(dx * dx + dy * dy))


def off_axis(alpha: torch.Tensor, beta: torch.Tensor, climb: torch.Tensor) -> torch.Tensor:
    """Angle between a UAV's direction of flight (flight-path angle ``climb``) and a direction of
    azimuth ``alpha`` relative to its heading and elevation ``beta`` (section 11):
    ``atan2(|u x w|, u . w)``, and exactly ``|alpha|`` where both are level."""
    cb, sb, cg, sg = torch.cos(beta), torch.sin(beta), torch.cos(climb), torch.sin(climb)
    ca, sa = torch.cos(alpha), torch.sin(alpha)
    cross = torch.sqrt((sg * cb * sa) ** 2 + (sg * cb * ca - cg * sb) ** 2 + (cg * cb * sa) ** 2)
    theta = torch.atan2(cross, cg * cb * ca + sg * sb)
    return torch.where((beta == 0) & (climb == 0), alpha.abs(), theta)


def goal_polar(position: torch.Tensor, heading: torch.Tensor, goal: torch.Tensor, space: Space | None = None
               ) -> tuple[torch.Tensor, ...]:
    """The goal as each UAV sees it: distance ``d_g`` and angle ``alpha_g`` relative to the
    heading (Eq. 14-15 before normalising), each ``[B, N]``, for a ``goal [B, 2]``.

    In ``space`` (``goal [B, 3]``, the flight-path angles ``space.climb [B, N]``; section 11):
    ``(d_g, alpha_g, beta_g, theta_g)``, the 3-D distance, azimuth, elevation and off-axis angle
    (what the reward's angle term reads)."""
    to_goal = stored(goal[:, None, :] - position)
    if space is None:
        return torch.linalg.vector_norm(to_goal, dim=-1), relative_angle(to_goal, heading)
    alpha = relative_angle(to_goal, heading)
    beta = elevation_of(to_goal[..., 0], to_goal[..., 1], to_goal[..., 2])
    return length(to_goal, space), alpha, beta, off_axis(alpha, beta, space.climb)


def goal_observation(position: torch.Tensor, heading: torch.Tensor, goal: torch.Tensor, goal_scale: float,
                     polar: tuple[torch.Tensor, ...] | None = None, space: Space | None = None
                     ) -> torch.Tensor:
    """``o_g = [min(d_g / d_s, 1), alpha_g / pi]`` (Eq. 14-15, erratum: divide by d_s).

    Args:
        goal: ``[B, 2]``; polar: :func:`goal_polar` if already known. Returns ``[B, N, 2]``; in
        ``space`` (section 11) ``[min(d_g / d_s, 1), alpha_g / pi, beta_g / pi]``.
    """
    polar = polar if polar is not None else goal_polar(position, heading, goal, space)
    d, alpha = polar[0], polar[1]
    # Stacked outermost and viewed as [B, N, k] (here and in s_c): compiled, the loop computing
    # the pieces then writes each one whole; interleaved writes keep it from vectorising its atan2.
    parts = ((d / goal_scale).clamp_max(1.0), alpha / math.pi) + (() if space is None else (polar[2] / math.pi,))
    return torch.stack(parts, 0).movedim(0, -1)


@dataclass
class Neighbours:
    """What the camera measures of every other UAV, ``[B, N, N]`` (row i: seen by UAV i); with
    ``pair_dim = 0`` ``[N_j, N, B]`` (the UAV seen outermost, the worlds innermost: the compiled
    step's layout), and what reduces over the UAVs seen reduces over ``pair_dim``.

    ``distance``, ``bearing`` (relative to i's heading) and ``heading_difference``
    (``wrap(phi_i - phi_j)``) may carry S4 noise; ``visible`` never does. ``dx``, ``dy`` are
    the measured ``p_j - p_i`` in the world frame, one contiguous tensor per axis (pairwise
    work stays on plain ``[B, N, N]`` tensors: the swarm can grow to hundreds of UAVs).
    """

    distance: torch.Tensor
    bearing: torch.Tensor
    heading_difference: torch.Tensor
    visible: torch.Tensor
    dx: torch.Tensor
    dy: torch.Tensor
    valid: torch.Tensor | None = None  # packed (near_neighbours): which of the M entries hold a UAV
    space: Space | None = None  # measured in space (section 11): the entries below are then given
    # The vertical offset, the elevation, gamma_i - gamma_j, the off-axis angle.
    dz: torch.Tensor | None = None
    elevation: torch.Tensor | None = None
    climb_difference: torch.Tensor | None = None
    view_angle: torch.Tensor | None = None
    pair_dim: int = -1  # the axis of the UAV seen: -1 ([B, N, M]) or 0 ([M, N, B])

    def per_uav(self, values: torch.Tensor) -> torch.Tensor:
        """A per-UAV result of this layout (``[B, N, ...]``; ``[N, B, ...]`` with ``pair_dim = 0``) as ``[B, N, ...]``."""
        return values if self.pair_dim == -1 else values.transpose(0, 1)

    def against_pairs(self, per_uav: torch.Tensor) -> torch.Tensor:
        """A per-UAV ``[B, N]`` tensor shaped to broadcast against the pairs (UAV i's value)."""
        return per_uav[..., None] if self.pair_dim == -1 else worlds_last(per_uav)[None]

    @property
    def cone_angle(self) -> torch.Tensor:
        """The angle the field of view bounds: ``|bearing|`` in 2-D, the off-axis angle in 3-D."""
        return self.bearing if self.space is None else self.view_angle

    def offsets(self, heading: torch.Tensor | None = None) -> torch.Tensor:
        """Measured ``p_j - p_i`` in the world frame, ``[B, N, N, 2]`` (3-D: ``[B, N, N, 3]``)."""
        if self.space is not None:
            return torch.stack((self.dx, self.dy, self.dz), -1)
        return torch.stack((self.dx, self.dy), -1)

    def with_visibility(self, visible: torch.Tensor) -> "Neighbours":
        """The same measurements seen through another camera (e.g. the critic's all-round one)."""
        return dataclasses.replace(self, visible=visible)

    def nearest_distance(self) -> torch.Tensor:
        """``d_uav1``: distance to the nearest visible UAV, ``inf`` if none, ``[B, N]``."""
        return self.per_uav(torch.where(self.visible, self.distance,
                                        torch.full_like(self.distance, math.inf)).amin(self.pair_dim))


def visibility(distance: torch.Tensor, rel_bearing: torch.Tensor, camera_range: float, half_fov: float,
               others: torch.Tensor | None = None) -> torch.Tensor:
    """Camera visibility: ``|p_j - p_i| < d_v`` and ``|bearing| <= half_fov``, never oneself.

    ``half_fov`` is ``phi_v / 2`` under the reading ``literal`` and ``phi_v`` under ``paper_fit``
    (:attr:`~flock_torchrl.config.ScenarioConfig.half_fov`, section 9).

    Args:
        distance, rel_bearing: ``[B, N, N]``. Returns a bool ``[B, N, N]``.
        others: which entries are other UAVs (default: all but the diagonal); for packed
            neighbours (:func:`near_neighbours`) their ``valid`` mask.
    """
    if others is None:
        n = distance.shape[-1]
        others = ~torch.eye(n, dtype=torch.bool, device=distance.device)
    return (distance < camera_range) & (rel_bearing.abs() <= half_fov) & others


def measure_pairs(dx: torch.Tensor, dy: torch.Tensor, heading_i: torch.Tensor, heading_j: torch.Tensor,
                  space: Space | None = None, dz: torch.Tensor | None = None, climb_i: torch.Tensor | None = None,
                  climb_j: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """What UAV i's camera measures of UAV j at offset ``p_j - p_i = (dx, dy)`` (section 2, Eq. 17
    before normalising): ``distance``, ``bearing`` relative to i's heading and ``heading_difference``
    ``wrap(phi_i - phi_j)``, all broadcast to the offsets' shape. In ``space`` (with ``dz`` and the
    flight-path angles of i and j in the offsets' layout; section 11) the distance is 3-D, and the
    ``elevation``, ``climb_difference`` ``gamma_i - gamma_j`` and ``view_angle`` (the off-axis angle of j from i's direction of flight)
    join them; with ``dz = 0`` and level flight the first three are the plane's bit for bit."""
    bearing = wrap(torch.atan2(dy, dx) - heading_i)
    squared = dx * dx + dy * dy
    out = {"distance": torch.sqrt(squared if space is None else squared + dz * dz), "bearing": bearing,
           "heading_difference": wrap(heading_i - heading_j)}
    if space is not None:
        elevation = elevation_of(dx, dy, dz)
        out.update(elevation=elevation, climb_difference=climb_i - climb_j,
                   view_angle=off_axis(bearing, elevation, climb_i))
    return out


def measured(pairs: dict[str, torch.Tensor], dx: torch.Tensor, dy: torch.Tensor, dz: torch.Tensor | None,
             camera_range: float, half_fov: float, others: torch.Tensor | None, valid: torch.Tensor | None = None,
             pair_dim: int = -1, shape: tuple[int, ...] | None = None, space: Space | None = None) -> Neighbours:
    """The :class:`Neighbours` of :func:`measure_pairs`' ``pairs``, each visible as :func:`visibility`
    says of its cone angle (``others``: which entries are other UAVs); measured on rows, ``shape``
    views them as the layout's. ``valid``, ``pair_dim``: the layout's (:class:`Neighbours`)."""
    cone = pairs["bearing"] if space is None else pairs["view_angle"]
    visible = visibility(pairs["distance"], cone, camera_range, half_fov, others)
    if shape is not None:
        pairs, visible = {key: value.view(shape) for key, value in pairs.items()}, visible.view(shape)
    return Neighbours(visible=visible, dx=dx, dy=dy, dz=dz, valid=valid, pair_dim=pair_dim, space=space, **pairs)


def observe_neighbours(position: torch.Tensor, heading: torch.Tensor, camera_range: float, half_fov: float
                       ) -> Neighbours:
    """True camera measurements between all UAV pairs (no occlusion, section 2 decision)."""
    px, py = position[..., 0].contiguous(), position[..., 1].contiguous()
    dx = px[..., None, :] - px[..., :, None]  # [B, N, N]: p_j - p_i
    dy = py[..., None, :] - py[..., :, None]
    return measured(measure_pairs(dx, dy, heading[..., :, None], heading[..., None, :]), dx, dy, None, camera_range,
                    half_fov, None)


@dataclass
class NearPairs:
    """Where :func:`near_neighbours` packed the pairs within camera range: entry ``m`` of UAV
    ``i`` of world ``b`` is pair ``flat[b, i, m]`` of the flattened ``[B, N, N]`` tensors
    (padding points at the UAV itself), and holds a UAV where ``valid``. ``flat`` is ``None``
    when every pair was kept, in place (``M = N``)."""

    flat: torch.Tensor | None
    valid: torch.Tensor
    worlds_last: bool = False  # every pair kept, as [N_j, N, B]

    def take(self, pairs: torch.Tensor) -> torch.Tensor:
        """The packed ``[B, N, M]`` entries of a ``[B, N, N]`` tensor (e.g. S4 noise draws), in their layout."""
        if self.worlds_last:
            return pairs.permute(2, 1, 0)
        return pairs if self.flat is None else pairs.flatten().take(self.flat)


def near_neighbours(position: torch.Tensor, heading: torch.Tensor, camera_range: float, half_fov: float,
                    static_shapes: bool = False, space: Space | None = None, worlds_last: bool = False
                    ) -> tuple[Neighbours, NearPairs, torch.Tensor]:
    """:func:`observe_neighbours` for the pairs that can matter: only a UAV closer than
    ``camera_range`` can be seen or push back (the repulsion's ``r0`` is the camera's range).

    Squared distances come for every pair (three operations per axis); bearings, heading
    differences and visibility only for the pairs within range, packed per UAV in ascending
    ``j`` into ``[B, N, M]`` (``M``: the most any UAV has; the rest ``valid = False``). Every
    value is computed by the formula of :func:`observe_neighbours` and the order of ``j`` is
    kept, so the camera, the instinct and the nearest distance come out the same (up to the
    last bit of ``atan2``, which vectorised and scalar code round differently).
    In a spread swarm of 100 UAVs about one pair in ten is in range; where more than a quarter
    of the pairs are (small or dense swarms), packing would cost more than it saves and every
    pair is kept (``M = N``). With ``static_shapes`` every pair is kept, always: the packing
    has data-dependent shapes, which ``torch.compile(fullgraph=True)`` cannot trace.

    In ``space`` (``position [B, N, 3]``, ``space.climb [B, N]``; section 11) the distances are 3-D, the
    camera a cone about the direction of flight, and the neighbours carry their elevations and
    climb differences (:func:`measure_pairs`).

    ``worlds_last`` (with ``static_shapes``): every pair, laid out ``[N_j, N, B]`` (``pair_dim =
    0``), the compiled step's layout; the same formulas.

    Returns:
        ``(neighbours [B, N, M], where they came from, closest pair [B])`` (``inf`` for one UAV).
    """
    b, n = heading.shape
    dev = position.device
    if static_shapes and worlds_last:
        return _all_pairs_worlds_last(position, heading, camera_range, half_fov, space)
    px, py = position[..., 0].contiguous(), position[..., 1].contiguous()
    dx_all = px[..., None, :] - px[..., :, None]  # [B, N, N]: p_j - p_i
    dy_all = py[..., None, :] - py[..., :, None]
    squared = dx_all * dx_all + dy_all * dy_all
    dz_all = None
    if space is not None:
        pz = position[..., 2].contiguous()
        dz_all = pz[..., None, :] - pz[..., :, None]
        squared = squared + dz_all * dz_all
    squared.diagonal(dim1=-2, dim2=-1).fill_(math.inf)  # never oneself
    # sqrt is monotone and exactly rounded: the smallest distance is the root of the smallest square.
    closest = torch.sqrt(squared.flatten(-2).amin(-1))
    # A slightly wider net than "distance < camera_range" (the exact test is visibility's).
    near = squared < (camera_range * (1 + 1e-6)) ** 2
    if static_shapes or 4 * int(near.sum()) > near.numel():  # dense: keep every pair where it is
        valid = ~torch.eye(n, dtype=torch.bool, device=dev).expand(b, n, n)
        # Measured on rows of all N^2 pairs of a world, then viewed as [B, N, N]: the same values,
        # and one innermost dimension long enough for compiled code to vectorise (N alone is small).
        def rows(pairs: torch.Tensor) -> torch.Tensor:
            return pairs.reshape(b, n * n)

        def of_i(per_uav: torch.Tensor) -> torch.Tensor:  # per pair (i, j): UAV i's value
            return rows(per_uav[..., :, None].expand(b, n, n))

        def of_j(per_uav: torch.Tensor) -> torch.Tensor:  # per pair (i, j): UAV j's value
            return rows(per_uav[..., None, :].expand(b, n, n))

        others = valid[0].reshape(n * n)
        three = {} if space is None else dict(dz=rows(dz_all), climb_i=of_i(space.climb), climb_j=of_j(space.climb))
        # Oneself at distance 0, as measured (never valid; S4 noise keeps it finite).
        pairs = measure_pairs(rows(dx_all), rows(dy_all), of_i(heading), of_j(heading), space, **three)
        return (measured(pairs, dx_all, dy_all, dz_all, camera_range, half_fov, others, valid, shape=(b, n, n),
                         space=space), NearPairs(None, valid), closest)
    bi, ii, ji = near.nonzero(as_tuple=True)  # ordered by world, UAV, then j
    row = bi * n + ii
    counts = torch.bincount(row, minlength=b * n)
    width = max(int(counts.max()), 1) if row.numel() else 1
    at = row * width + torch.arange(row.numel(), device=dev) - (counts.cumsum(0) - counts)[row]
    rows = torch.arange(b * n, device=dev)
    flat = (rows * n + rows % n)[:, None].repeat(1, width)  # padding: the UAV itself
    flat.view(-1)[at] = row * n + ji
    flat = flat.view(b, n, width)
    valid = torch.arange(width, device=dev) < counts.view(b, n, 1)
    dx, dy = dx_all.flatten().take(flat), dy_all.flatten().take(flat)
    other = (rows - rows % n)[:, None].repeat(1, width)  # index of UAV j's heading; padding: world's first
    other.view(-1)[at] = bi * n + ji
    others = other.view(b, n, width)
    dz, three = None, {}
    if space is not None:
        dz = dz_all.flatten().take(flat)
        three = dict(dz=dz, climb_i=space.climb[..., None], climb_j=space.climb.flatten().take(others))
    pairs = measure_pairs(dx, dy, heading[..., None], heading.flatten().take(others), space, **three)
    return (measured(pairs, dx, dy, dz, camera_range, half_fov, valid, valid, space=space), NearPairs(flat, valid),
            closest)


def _all_pairs_worlds_last(position: torch.Tensor, heading: torch.Tensor, camera_range: float, half_fov: float,
                           space: Space | None) -> tuple[Neighbours, NearPairs, torch.Tensor]:
    """:func:`near_neighbours` of every pair, laid out ``[N_j, N_i, B]``: ``[j, i, b]`` is what UAV
    ``i`` of world ``b`` measures of UAV ``j``."""
    n, b = heading.shape[1], heading.shape[0]
    px, py, h = worlds_last(position[..., 0]), worlds_last(position[..., 1]), worlds_last(heading)  # [N, B]
    dx, dy = px[:, None] - px[None], py[:, None] - py[None]                       # [N_j, N_i, B]: p_j - p_i
    squared = dx * dx + dy * dy
    dz = None
    if space is not None:
        pz = worlds_last(position[..., 2])
        dz = pz[:, None] - pz[None]
        squared = squared + dz * dz
    others = ~torch.eye(n, dtype=torch.bool, device=position.device)[..., None]  # never oneself
    # sqrt is monotone and exactly rounded: the smallest distance is the root of the smallest square.
    closest = torch.sqrt(torch.where(others, squared, math.inf).amin(0).amin(0))
    valid = others.expand(n, n, b)
    g = None if space is None else worlds_last(space.climb)
    three = {} if space is None else dict(dz=dz, climb_i=g[None], climb_j=g[:, None])
    # Stored: the masks below are then compared afresh where read (a stored bool costs more than that).
    pairs = {key: stored(t) for key, t in measure_pairs(dx, dy, h[None], h[:, None], space, **three).items()}
    return (measured(pairs, dx, dy, dz, camera_range, half_fov, valid, valid, pair_dim=0, space=space),
            NearPairs(None, valid, worlds_last=True), closest)


def camera_observation(neighbours: Neighbours, n: int, camera_range: float) -> torch.Tensor:
    """``o_cam`` (Eq. 17): the ``n`` closest visible UAVs, ascending by measured distance.

    Each slot ``[min(d / d_v, 1), alpha / pi, wrap(phi_i - phi_j) / pi]``; missing slots
    ``[1, 0, 0]``.

    Returns:
        ``[B, N, 3 n]``; in 3-D ``[B, N, 5 n]``, slots ``[d, alpha, beta, dphi, dgamma]`` (missing
        ``[1, 0, 0, 0, 0]``).
    """
    key = torch.where(neighbours.visible, neighbours.distance, torch.full_like(neighbours.distance, math.inf))
    dim = neighbours.pair_dim
    first, order = smallest(key, min(n, key.shape[dim]), dim)

    def at_order(values: torch.Tensor) -> torch.Tensor:  # [B, N, m] in either layout
        return torch.gather(values, -1, order) if dim == -1 else pick(values, order).permute(2, 1, 0)

    present = torch.isfinite(first if dim == -1 else first.permute(2, 1, 0))
    parts = [(at_order(neighbours.distance) / camera_range).clamp(0.0, 1.0),
             at_order(neighbours.bearing) / math.pi]
    if neighbours.space is not None:  # 3-D (section 11): the elevation after the azimuth
        parts.append(at_order(neighbours.elevation) / math.pi)
    parts.append(at_order(neighbours.heading_difference) / math.pi)
    if neighbours.space is not None:
        parts.append(at_order(neighbours.climb_difference) / math.pi)
    slots = torch.stack(parts, -1)
    missing = constant([1.0] + [0.0] * (len(parts) - 1), slots)
    slots = torch.where(present[..., None], slots, missing)
    if slots.shape[-2] < n:  # fewer other UAVs than slots
        pad = missing.expand(*slots.shape[:-2], n - slots.shape[-2], len(parts))
        slots = torch.cat((slots, pad), -2)
    return slots.flatten(-2)


def swarm_centre_state(position: torch.Tensor, heading: torch.Tensor, camera_range: float,
                       space: Space | None = None) -> torch.Tensor:
    """``s_c = [min(d_c / d_v, 1), alpha_c / pi, wrap(phi_i - phi_bar) / pi]`` (specification section 2, Eq. 18 erratum).

    ``phi_bar`` is the circular mean heading. Returns ``[B, N, 3]``. In ``space`` (its ``climb``;
    section 11) ``[B, N, 5]``: ``[d_c, alpha_c, beta_c / pi, phi_i - phi_bar, (gamma_i - gamma_bar) / pi]``.
    """
    centre = position.mean(-2, keepdim=True)
    to_centre = stored(centre - position)
    d = length(to_centre, space)
    phi_bar = circular_mean(heading, -1, keepdim=True)
    parts = [(d / camera_range).clamp_max(1.0), relative_angle(to_centre, heading) / math.pi]
    if space is not None:
        parts.append(elevation_of(to_centre[..., 0], to_centre[..., 1], to_centre[..., 2]) / math.pi)
    parts.append(wrap(stored(heading - phi_bar)) / math.pi)
    if space is not None:
        parts.append((space.climb - space.climb.mean(-1, keepdim=True)) / math.pi)
    return torch.stack(parts, 0).movedim(0, -1)


def sensor_normals(n_worlds: int, n_uavs: int, n_beams: int, generator: torch.Generator | None = None,
                   device=None, dtype=torch.float32) -> dict[str, torch.Tensor]:
    """The standard normal draws of one step's S4 noise, in the order they are taken from
    ``generator``: ``scan [B, N, n_beams]``, then ``distance``, ``bearing`` and
    ``heading_difference``, each ``[B, N, N]``. Drawn outside the (compilable) step, so the
    step itself never touches a generator."""
    def draw(*shape: int) -> torch.Tensor:
        return torch.randn(shape, generator=generator, device=device, dtype=dtype)

    return {"scan": draw(n_worlds, n_uavs, n_beams), "distance": draw(n_worlds, n_uavs, n_uavs),
            "bearing": draw(n_worlds, n_uavs, n_uavs), "heading_difference": draw(n_worlds, n_uavs, n_uavs)}


def add_sensor_noise(beams: torch.Tensor, neighbours: Neighbours, *, scan_std: float, distance_std: float,
                     angle_std: float, max_range: float, generator: torch.Generator | None = None,
                     normals: dict[str, torch.Tensor] | None = None) -> tuple[torch.Tensor, Neighbours]:
    """S4 noise on raw measurements, before normalisation (specification section 2, "Noise").

    Beams ``+ scan_std N(0,1)`` clipped to ``[0, max_range]``; neighbour distance
    ``+ distance_std N(0,1)`` clipped at 0; bearing and heading difference
    ``+ angle_std N(0,1)``, wrapped. Visibility is the camera's detection and stays exact.

    Args:
        normals: the standard normals (:func:`sensor_normals`); drawn from ``generator`` if absent.
    """
    if normals is None:
        b, n = neighbours.distance.shape[:2]
        normals = sensor_normals(b, n, beams.shape[-1], generator, beams.device, beams.dtype)
    beams = (beams + scan_std * normals["scan"]).clamp(0.0, max_range)
    distance = (neighbours.distance + distance_std * normals["distance"]).clamp_min(0.0)
    bearing = wrap(neighbours.bearing + angle_std * normals["bearing"])
    heading_difference = wrap(neighbours.heading_difference + angle_std * normals["heading_difference"])
    # The measured offsets follow the measured distance and bearing (relative to the true heading).
    angle = bearing + torch.atan2(neighbours.dy, neighbours.dx) - neighbours.bearing
    if neighbours.space is None:
        noisy = dataclasses.replace(neighbours, distance=distance, bearing=bearing,
                                    heading_difference=heading_difference, dx=distance * torch.cos(angle),
                                    dy=distance * torch.sin(angle))
        return beams, noisy
    # 3-D (section 11): the elevation is measured exactly; the horizontal part follows the noisy distance.
    flat = distance * torch.cos(neighbours.elevation)
    noisy = dataclasses.replace(neighbours, distance=distance, bearing=bearing, heading_difference=heading_difference,
                                dx=flat * torch.cos(angle), dy=flat * torch.sin(angle),
                                dz=distance * torch.sin(neighbours.elevation))
    return beams, noisy


__all__ = ["CAMERA_SLOT", "CENTRE_SIZE", "GOAL_SIZE", "NearPairs", "Neighbours", "SCAN_SLOT", "SIZES_3D",
           "add_sensor_noise", "camera_observation", "elevation_of", "goal_observation", "goal_polar", "measure_pairs",
           "measured", "near_neighbours", "observation_size", "observe_neighbours", "off_axis", "piece_sizes",
           "planar_entries", "sensor_normals", "state_size", "swarm_centre_state", "visibility"]
