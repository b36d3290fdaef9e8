"""Geometry on batched tensors: angles, ray casting, distances to obstacles, in the plane or
in space (docs/specification.md section 11).

Obstacles come in two batched tensors in 2-D, three in 3-D (see :class:`Obstacles`):

* circles ``[B, C, 3]`` holding ``(cx, cy, radius)``; in 3-D vertical cylinders ``[B, C, 5]``
  ``(cx, cy, radius, z_low, z_high)``;
* axis-aligned rectangles ``[B, R, 4]`` holding ``(cx, cy, width_x, height_y)``; in 3-D boxes
  ``[B, R, 6]`` ``(cx, cy, width_x, height_y, z_low, z_high)``;
* in 3-D only, spheres ``[B, S, 4]`` ``(cx, cy, cz, radius)``.

Every 3-D formula evaluates its horizontal part with the 2-D formula's own operations and adds
the vertical part so that a zero vertical part changes no bit (section 11, the special case).

Everything here is a pure function over leading batch dimensions; nothing loops over
environments, UAVs, beams or obstacles.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Sequence

import torch

from .space import Space

_PI = math.pi
_TWO_PI = 2.0 * math.pi


def constant(values: Sequence[float], like: torch.Tensor) -> torch.Tensor:
    """The numbers ``values`` as a 1-D tensor of ``like``'s dtype and device, made once per
    values, dtype and device and then reused (read-only): a step copies nothing from the host,
    which on a GPU waits for the device and cannot be recorded in a CUDA graph. Compiled code
    gets them as constants of its graph."""
    if torch.compiler.is_compiling():
        return torch.tensor(list(values), dtype=like.dtype, device=like.device)
    return _constant(tuple(values), like.dtype, like.device)


@functools.lru_cache(maxsize=None)
def _constant(values: tuple[float, ...], dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    return torch.tensor(values, dtype=dtype, device=device)


def stored(x: torch.Tensor) -> torch.Tensor:
    """``x`` itself, held in memory of its own by compiled code (eagerly a view of the same
    strides, nothing changes). Compiled code otherwise computes an elementwise result inside
    every loop that reads it; where such a loop also reads a per-world value (the goal, the
    swarm's mean heading) it runs one UAV at a time, five to a world, and its ``atan2``, ``sin``
    or ``fmod`` go scalar. Stored, ``x`` is computed by a loop of its own, vectorised along all
    UAVs of all worlds."""
    return x.as_strided(x.shape, x.stride())


def wrap(angle: torch.Tensor) -> torch.Tensor:
    """Map angles to ``[-pi, pi)`` (specification, "Conventions")."""
    wrapped = torch.remainder(angle + _PI, _TWO_PI) - _PI
    # Angles already in range pass unchanged: the round trip through ``remainder`` costs an
    # ulp, enough to push a UAV exactly on the camera's edge (+-phi_v/2) out of view.
    return torch.where((angle >= -_PI) & (angle < _PI), angle, wrapped)


def bearing(vec: torch.Tensor) -> torch.Tensor:
    """Angle of ``vec[..., 2]`` with the x axis, ``atan2(y, x)``."""
    return torch.atan2(vec[..., 1], vec[..., 0])


def relative_angle(vec: torch.Tensor, heading: torch.Tensor) -> torch.Tensor:
    """``wrap(angle(vec) - heading)``: where ``vec`` points, seen from a UAV facing ``heading``."""
    return wrap(bearing(vec) - heading)


def length(vec: torch.Tensor, space: Space | None = None) -> torch.Tensor:
    """Euclidean length over the last dimension. In ``space`` (3-vectors) a vector with a zero
    vertical component gets exactly the length of its horizontal part, as the plane computes it."""
    if space is None:
        return torch.linalg.vector_norm(vec, dim=-1)
    return torch.where(vec[..., 2] == 0, torch.linalg.vector_norm(vec[..., :2], dim=-1),
                       torch.linalg.vector_norm(vec, dim=-1))


def circular_mean(angles: torch.Tensor, dim: int = -1, keepdim: bool = False) -> torch.Tensor:
    """``atan2(sum sin, sum cos)`` along ``dim`` (docs/specification.md section 2, erratum to Eq. 18)."""
    return torch.atan2(stored(torch.sin(angles)).sum(dim, keepdim=keepdim),
                       stored(torch.cos(angles)).sum(dim, keepdim=keepdim))


@dataclass
class Obstacles:
    """Obstacles of a batch of worlds.

    Attributes:
        circles: ``[B, C, 3]`` centre x, centre y, radius (fixed, then moving, then drawn ones).
        rectangles: ``[B, R, 4]`` centre x, centre y, width along x, height along y (fixed, then drawn).
    """

    circles: torch.Tensor
    rectangles: torch.Tensor
    spheres: torch.Tensor | None = None  # 3-D only (``None``: a 2-D world)

    def tensors(self) -> list[torch.Tensor]:
        """The obstacle tensors held, in the laser's index order."""
        return [t for t in (self.circles, self.rectangles, self.spheres) if t is not None]

    @property
    def count(self) -> int:
        return sum(t.shape[-2] for t in self.tensors())

    def __getitem__(self, index) -> "Obstacles":
        """The obstacles of the worlds ``index`` (batch dimension first)."""
        return Obstacles(*(t[index] for t in self.tensors()))

    def footprints(self) -> "Obstacles":
        """The 2-D obstacles that cover these from above: a cylinder's or a sphere's circle, a box's
        rectangle (circles first, spheres after the cylinders). For obstacles in space only."""
        spheres = torch.cat((self.spheres[..., :2], self.spheres[..., 3:]), -1)
        return Obstacles(torch.cat((self.circles[..., :3], spheres), -2), self.rectangles[..., :4])


def _ray_circle(origin: torch.Tensor, direction: torch.Tensor, circles: torch.Tensor) -> torch.Tensor:
    """Distance along unit rays to circles.

    Args:
        origin: ``[..., 1, 2]``; direction: ``[..., K, 2]`` (unit); circles: ``[..., 1, 3]`` (one circle
            per row); leading dimensions broadcast.

    Returns:
        ``[..., K]``: the smallest ``t >= 0`` with ``origin + t direction`` on the circle, 0 when
        the origin is inside (or on) the circle, ``inf`` for a miss (:func:`ray_circle_hit`).
    """
    centre, radius = circles[..., :2], circles[..., 2]
    f = origin - centre
    c = (f * f).sum(-1) - radius * radius
    return ray_circle_hit(f[..., 0], f[..., 1], direction[..., 0], direction[..., 1], c)


def ray_circle_hit(fx: torch.Tensor, fy: torch.Tensor, dx: torch.Tensor, dy: torch.Tensor, c: torch.Tensor
                   ) -> torch.Tensor:
    """The ray-circle hit on components, the one home of its formula: rays from origins at
    ``(fx, fy)`` from the centre along unit ``(dx, dy)``, ``c = |f|^2 - r^2``; all broadcast, in
    any layout (the compiled step's keeps the worlds innermost). The smallest ``t >= 0`` on the
    circle, 0 inside (or on) it, ``inf`` for a miss."""
    b = fx * dx + fy * dy
    disc = b * b - c
    t_near = -b - torch.sqrt(disc.clamp_min(0.0))
    hit = (disc >= 0) & (t_near >= 0)
    t = torch.where(hit, t_near, torch.full_like(t_near, math.inf))
    return torch.where(c <= 0, torch.zeros_like(t), t)


def _ray_rectangle(origin: torch.Tensor, direction: torch.Tensor, rects: torch.Tensor) -> torch.Tensor:
    """Distance along unit rays to axis-aligned rectangles (slab test, :func:`ray_rectangle_hit`).

    Shapes as in :func:`_ray_circle` with ``rects`` ``[P, 1, 4]``.
    """
    half = rects[..., 2:] / 2
    lo = rects[..., :2] - half - origin  # [P, 1, 2] offsets of the slab lines
    hi = rects[..., :2] + half - origin
    return ray_rectangle_hit(lo[..., 0], hi[..., 0], lo[..., 1], hi[..., 1], direction[..., 0], direction[..., 1])


def ray_rectangle_hit(lo_x: torch.Tensor, hi_x: torch.Tensor, lo_y: torch.Tensor, hi_y: torch.Tensor,
                      dx: torch.Tensor, dy: torch.Tensor) -> torch.Tensor:
    """The slab test on components, the one home of its formula: the rectangle's sides lie at
    ``lo_x, hi_x, lo_y, hi_y`` from the rays' origins, the rays run along unit ``(dx, dy)``; all
    broadcast, in any layout. The smallest ``t >= 0`` in the rectangle, 0 inside, ``inf`` a miss.

    The slabs are solved one axis at a time. A direction component below 1e-12 is replaced by
    +1e-12: the slab interval then becomes about +-1e13 m, i.e. "all of the line" when the
    origin lies between the slab's two lines (on them included) and "beyond any range"
    otherwise, which is the exact parallel-ray answer once beams are capped at their range.
    """
    inside = (lo_x <= 0) & (hi_x >= 0) & (lo_y <= 0) & (hi_y >= 0)
    # Edges are part of the rectangle: an origin exactly on a slab line counts as between the
    # lines, also for a ray running along that line.
    lo_x, lo_y = torch.where(lo_x == 0, -1e-6, lo_x), torch.where(lo_y == 0, -1e-6, lo_y)
    hi_x, hi_y = torch.where(hi_x == 0, 1e-6, hi_x), torch.where(hi_y == 0, 1e-6, hi_y)
    tiny = 1e-12
    inv_x = 1.0 / torch.where(dx.abs() < tiny, torch.full_like(dx, tiny), dx)
    inv_y = 1.0 / torch.where(dy.abs() < tiny, torch.full_like(dy, tiny), dy)
    tx1, tx2 = lo_x * inv_x, hi_x * inv_x
    ty1, ty2 = lo_y * inv_y, hi_y * inv_y
    t_near = torch.maximum(torch.minimum(tx1, tx2), torch.minimum(ty1, ty2))
    t_far = torch.minimum(torch.maximum(tx1, tx2), torch.maximum(ty1, ty2))
    hit = (t_far >= t_near) & (t_far >= 0)
    t = torch.where(hit, t_near.clamp_min(0.0), math.inf)
    return torch.where(inside, 0.0, t)


def cast_rays(origin: torch.Tensor, angles: torch.Tensor, obstacles: Obstacles, max_range: float
              ) -> tuple[torch.Tensor, torch.Tensor]:
    """Exact ray casting against circles and rectangles (docs/specification.md section 2, "Laser").

    Args:
        origin: ``[B, N, 2]`` ray origins (UAV positions).
        angles: ``[B, N, K]`` absolute beam headings.
        obstacles: the worlds' obstacles.
        max_range: beams are capped at this distance.

    Returns:
        ``(distance [B, N, K], obstacle [B, N, K])``: ``min(hit, max_range)`` (0 inside an
        obstacle) and the index of the obstacle hit (circles first, then rectangles), -1 for
        none within range.
    """
    direction = torch.stack((torch.cos(angles), torch.sin(angles)), -1)
    return cast_rays_along(origin, direction, obstacles, max_range)


def cast_rays_along(origin: torch.Tensor, directions: torch.Tensor, obstacles: Obstacles,
                    max_range: float) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`cast_rays` for rays of unit ``directions [B, N, K, 2]`` from ``origin [B, N, 2]``.

    A beam's hit is no closer than the obstacle's surface, so an obstacle farther than
    ``max_range`` returns a distance the cap removes anyway. Eager code therefore casts only the
    (UAV, obstacle) pairs within range, gathered into one batch per obstacle shape (the work
    follows how many obstacles are near, not B x N x all of them). The compiled step, which
    needs shapes that do not depend on the data, casts every pair with
    :func:`cast_rays_worlds_last`; both give the same distances and indices.
    """
    shapes = ((obstacles.circles, _ray_circle, distance_to_circles),
              (obstacles.rectangles, _ray_rectangle, distance_to_rectangles))
    return _cast_near(origin, directions, (), shapes, obstacles.count, max_range)


def _cast_near(origin: torch.Tensor, directions: torch.Tensor, extra: tuple, shapes: tuple, count: int,
               max_range: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The eager cast of :func:`cast_rays_along` and :func:`cast_rays_3d`: ``cast(origin, direction,
    *extra, obstacle)`` of each ``(tensors, cast, distance)`` of ``shapes`` on the (UAV, obstacle)
    pairs within range only; ``(distance [B, N, K], obstacle [B, N, K])``."""
    b, n, k = directions.shape[:3]
    if count == 0:
        return (origin.new_full((b, n, k), max_range),
                torch.full((b, n, k), -1, dtype=torch.long, device=origin.device))
    t = origin.new_full((b, n, count, k), math.inf)
    offset = 0
    for tensors, cast, distance in shapes:  # the obstacle shapes, not a loop over worlds or UAVs
        m = tensors.shape[-2]
        if m:
            near = distance(origin, tensors) < max_range                     # [B, N, M]
            bi, ni, mi = near.nonzero(as_tuple=True)
            if bi.numel():
                t[bi, ni, offset + mi] = cast(origin[bi, ni, None], directions[bi, ni], *extra,
                                              tensors[bi, mi, None])
        offset += m
    return _within_range(t, max_range)


def _within_range(t: torch.Tensor, max_range: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The nearest hit over the obstacles of ``t [B, N, M, K]`` and its index; ``max_range`` and -1 beyond range."""
    t_min, idx = t.min(-2)
    in_range = t_min < max_range
    return torch.where(in_range, t_min, torch.full_like(t_min, max_range)), torch.where(
        in_range, idx, torch.full_like(idx, -1))


def _nearer(t: torch.Tensor, m: int, best: torch.Tensor | None, index: torch.Tensor | None
            ) -> tuple[torch.Tensor, torch.Tensor]:
    """Fold obstacle ``m``'s hits ``t`` into the running nearest ``(best, index)``; a tie keeps the earlier obstacle."""
    if best is None:
        return t, torch.zeros_like(t, dtype=torch.long)
    closer = t < best
    return torch.where(closer, t, best), torch.where(closer, m, index)


def cast_rays_worlds_last(px: torch.Tensor, py: torch.Tensor, dx: torch.Tensor, dy: torch.Tensor,
                          obstacles: Obstacles, max_range: float) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`cast_rays_along` with the worlds innermost, every beam cast at every obstacle (no
    shape depends on the data): rays from ``(px, py) [N, B]`` along unit ``(dx, dy) [K, N, B]``.

    The compiled step's layout: each obstacle's numbers ``[B]`` broadcast against the beams, so
    compiled loops run along the worlds (a world's 36 beams or 5 UAVs are too few to fill a
    vector). The formulas are :func:`ray_circle_hit` and :func:`ray_rectangle_hit`, as eager
    casting uses them; the obstacles are folded in one at a time (a loop over the scenario's
    obstacles, never over worlds or UAVs).

    Returns:
        ``(distance [K, N, B], obstacle [K, N, B])`` as :func:`cast_rays_along` gives them.
    """
    best = index = None
    m = 0
    # One obstacle at a time, a running minimum (ties keep the earlier obstacle): compiled, every
    # obstacle's cast fuses into one pass over the beams, with nothing per beam stored between.
    for circle in obstacles.circles.unbind(1):                  # [B, 3] each
        fx, fy = px - circle[:, 0], py - circle[:, 1]           # [N, B]
        best, index = _nearer(ray_circle_hit(fx, fy, dx, dy, (fx * fx + fy * fy) - circle[:, 2] * circle[:, 2]),
                              m, best, index)
        m += 1
    for rect in obstacles.rectangles.unbind(1):                 # [B, 4] each
        half_w, half_h = rect[:, 2] / 2, rect[:, 3] / 2
        best, index = _nearer(ray_rectangle_hit((rect[:, 0] - half_w) - px, (rect[:, 0] + half_w) - px,
                                                (rect[:, 1] - half_h) - py, (rect[:, 1] + half_h) - py, dx, dy),
                              m, best, index)
        m += 1
    if best is None:
        return (px.new_full(dx.shape, max_range), torch.full(dx.shape, -1, dtype=torch.long, device=px.device))
    in_range = best < max_range
    return torch.where(in_range, best, max_range), torch.where(in_range, index, -1)


def _slab_z(oz: torch.Tensor, dz: torch.Tensor, low: torch.Tensor, high: torch.Tensor
            ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The vertical slab ``low <= z <= high`` along rays ``oz + t dz`` (the rectangle's slab test of
    :func:`_ray_rectangle` on one axis): ``(t_enter, t_exit, origin inside)``, broadcast."""
    lo, hi = low - oz, high - oz
    inside = (lo <= 0) & (hi >= 0)
    lo = torch.where(lo == 0, -1e-6, lo)
    hi = torch.where(hi == 0, 1e-6, hi)
    tiny = 1e-12
    inv = 1.0 / torch.where(dz.abs() < tiny, torch.full_like(dz, tiny), dz)
    t1, t2 = lo * inv, hi * inv
    return torch.minimum(t1, t2), torch.maximum(t1, t2), inside


def _ray_cylinder(origin: torch.Tensor, horizontal: torch.Tensor, cos_e: torch.Tensor, sin_e: torch.Tensor,
                  cylinders: torch.Tensor) -> torch.Tensor:
    """Distance along 3-D rays to vertical cylinders of finite height (section 11).

    Args:
        origin: ``[..., 1, 3]``; horizontal: ``[..., K, 2]`` unit horizontal directions; cos_e, sin_e:
            ``[K]`` the rays' elevations (direction ``(cos_e horizontal, sin_e)``); cylinders
            ``[..., 1, 5]``. Returns ``[..., K]`` as :func:`_ray_circle` (0 inside, ``inf`` a miss).

    The side is :func:`_ray_circle`'s quadratic in the horizontal distance ``s`` (``t = s / cos_e``),
    the caps the vertical slab; for a level ray within the height it is :func:`_ray_circle` bit for bit.
    """
    centre, radius = cylinders[..., :2], cylinders[..., 2]
    f = origin[..., :2] - centre
    b = (f * horizontal).sum(-1)
    c = (f * f).sum(-1) - radius * radius
    disc = b * b - c
    root = torch.sqrt(disc.clamp_min(0.0))
    s_near, s_far = -b - root, -b + root
    inside_xy = c <= 0
    valid = inside_xy | ((disc >= 0) & (s_near >= 0))
    z_in, z_out, _ = _slab_z(origin[..., 2], sin_e, cylinders[..., 3], cylinders[..., 4])
    enter = torch.maximum(torch.where(inside_xy, -math.inf, s_near / cos_e), z_in)
    exit_ = torch.minimum(s_far / cos_e, z_out)
    hit = valid & (enter <= exit_) & (exit_ >= 0)
    return torch.where(hit, enter.clamp_min(0.0), math.inf)


def _ray_box(origin: torch.Tensor, horizontal: torch.Tensor, cos_e: torch.Tensor, sin_e: torch.Tensor,
             boxes: torch.Tensor) -> torch.Tensor:
    """Distance along 3-D rays to axis-aligned boxes ``[..., 1, 6]`` (shapes as :func:`_ray_cylinder`):
    :func:`_ray_rectangle`'s slab test in the horizontal distance, plus the vertical slab."""
    half = boxes[..., 2:4] / 2
    lo = boxes[..., :2] - half - origin[..., :2]
    hi = boxes[..., :2] + half - origin[..., :2]
    inside = ((lo <= 0) & (hi >= 0)).all(-1)
    lo = torch.where(lo == 0, -1e-6, lo)
    hi = torch.where(hi == 0, 1e-6, hi)
    tiny = 1e-12
    inv = 1.0 / torch.where(horizontal.abs() < tiny, torch.full_like(horizontal, tiny), horizontal)
    tx1, tx2 = lo[..., 0] * inv[..., 0], hi[..., 0] * inv[..., 0]
    ty1, ty2 = lo[..., 1] * inv[..., 1], hi[..., 1] * inv[..., 1]
    z_in, z_out, inside_z = _slab_z(origin[..., 2], sin_e, boxes[..., 4], boxes[..., 5])
    t_near = torch.maximum(torch.maximum(torch.minimum(tx1, tx2), torch.minimum(ty1, ty2)) / cos_e, z_in)
    t_far = torch.minimum(torch.minimum(torch.maximum(tx1, tx2), torch.maximum(ty1, ty2)) / cos_e, z_out)
    hit = (t_far >= t_near) & (t_far >= 0)
    t = torch.where(hit, t_near.clamp_min(0.0), math.inf)
    return torch.where(inside & inside_z, 0.0, t)


def _ray_sphere(origin: torch.Tensor, horizontal: torch.Tensor, cos_e: torch.Tensor, sin_e: torch.Tensor,
                spheres: torch.Tensor) -> torch.Tensor:
    """Distance along 3-D rays to spheres ``[..., 1, 4]`` (shapes as :func:`_ray_cylinder`)."""
    direction = torch.cat((horizontal * cos_e[..., None], sin_e[..., None].expand(*horizontal.shape[:-1], 1)), -1)
    f = origin - spheres[..., :3]
    b = (f * direction).sum(-1)
    c = (f * f).sum(-1) - spheres[..., 3] * spheres[..., 3]
    disc = b * b - c
    t_near = -b - torch.sqrt(disc.clamp_min(0.0))
    hit = (disc >= 0) & (t_near >= 0)
    t = torch.where(hit, t_near, torch.full_like(t_near, math.inf))
    return torch.where(c <= 0, torch.zeros_like(t), t)


def cast_rays_3d(origin: torch.Tensor, horizontal: torch.Tensor, cos_e: torch.Tensor, sin_e: torch.Tensor,
                 obstacles: Obstacles, max_range: float, static_shapes: bool = False
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`cast_rays_along` in space: rays from ``origin [B, N, 3]`` along ``(cos_e horizontal,
    sin_e)``, ``horizontal [B, N, K, 2]`` unit, ``cos_e, sin_e [K]`` (section 11, laser rings),
    against cylinders, boxes and spheres (index order: cylinders, boxes, spheres). Eager code casts
    only the (UAV, obstacle) pairs within range, ``static_shapes`` every pair; the same values."""
    shapes = ((obstacles.circles, _ray_cylinder, distance_to_cylinders),
              (obstacles.rectangles, _ray_box, distance_to_boxes),
              (obstacles.spheres, _ray_sphere, distance_to_spheres))
    if static_shapes and obstacles.count:
        return _within_range(torch.cat([cast(origin[:, :, None, None], horizontal[:, :, None], cos_e, sin_e,
                                             tensors[:, None, :, None])
                                        for tensors, cast, _ in shapes if tensors.shape[-2]], -2), max_range)
    return _cast_near(origin, horizontal, (cos_e, sin_e), shapes, obstacles.count, max_range)


def _vertical_excess(points: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """How far points ``[B, N, 3]`` lie above or below the height ranges ``[B, M]`` (negative
    inside), ``[B, N, M]``."""
    return (points[:, :, None, 2] - (low + high)[:, None] / 2).abs() - (high - low)[:, None] / 2


def distance_to_cylinders(points: torch.Tensor, cylinders: torch.Tensor) -> torch.Tensor:
    """Signed distance from points ``[B, N, 3]`` to the surfaces of cylinders ``[B, C, 5]`` -> ``[B, N, C]``;
    within the cylinder's height it is :func:`distance_to_circles` bit for bit."""
    q_r = distance_to_circles(points[..., :2], cylinders[..., :3])
    q_z = _vertical_excess(points, cylinders[..., 3], cylinders[..., 4])
    out = q_r.clamp_min(0.0)
    outside = torch.where(q_z > 0, torch.hypot(out, q_z), out)
    return outside + torch.maximum(q_r, q_z).clamp_max(0.0)


def distance_to_boxes(points: torch.Tensor, boxes: torch.Tensor) -> torch.Tensor:
    """Signed distance from points ``[B, N, 3]`` to the surfaces of boxes ``[B, R, 6]`` -> ``[B, N, R]``;
    within the box's height it is :func:`distance_to_rectangles` bit for bit."""
    q = (points[:, :, None, :2] - boxes[:, None, :, :2]).abs() - boxes[:, None, :, 2:4] / 2
    q_z = _vertical_excess(points, boxes[..., 4], boxes[..., 5])
    flat = torch.linalg.vector_norm(q.clamp_min(0.0), dim=-1)
    outside = torch.where(q_z > 0, torch.hypot(flat, q_z), flat)
    return outside + torch.maximum(q.amax(-1), q_z).clamp_max(0.0)


def distance_to_spheres(points: torch.Tensor, spheres: torch.Tensor) -> torch.Tensor:
    """Signed distance from points ``[B, N, 3]`` to sphere surfaces ``[B, S, 4]`` -> ``[B, N, S]``."""
    return torch.linalg.vector_norm(points[:, :, None] - spheres[:, None, :, :3], dim=-1) - spheres[:, None, :, 3]


def distance_to_circles(points: torch.Tensor, circles: torch.Tensor) -> torch.Tensor:
    """Signed distance from points ``[B, N, 2]`` to circle surfaces ``[B, C, 3]`` -> ``[B, N, C]``."""
    return torch.linalg.vector_norm(points[:, :, None] - circles[:, None, :, :2], dim=-1) - circles[:, None, :, 2]


def distance_to_rectangles(points: torch.Tensor, rects: torch.Tensor) -> torch.Tensor:
    """Signed distance from points ``[B, N, 2]`` to rectangle surfaces ``[B, R, 4]`` -> ``[B, N, R]``.

    Positive outside (Euclidean distance to the boundary), negative inside.
    """
    q = (points[:, :, None] - rects[:, None, :, :2]).abs() - rects[:, None, :, 2:] / 2
    outside = torch.linalg.vector_norm(q.clamp_min(0.0), dim=-1)
    inside = q.amax(-1).clamp_max(0.0)
    return outside + inside


def distance_to_obstacles(points: torch.Tensor, obstacles: Obstacles, space: Space | None = None) -> torch.Tensor:
    """Signed distance to every obstacle surface, ``[B, N, C + R]`` (circles first; in ``space``
    ``[B, N, C + R + S]``, cylinders, boxes, spheres)."""
    shapes = ((obstacles.circles, distance_to_circles), (obstacles.rectangles, distance_to_rectangles))
    if space is not None:
        shapes = ((obstacles.circles, distance_to_cylinders), (obstacles.rectangles, distance_to_boxes),
                  (obstacles.spheres, distance_to_spheres))
    parts = [distance(points, tensors) for tensors, distance in shapes if tensors.shape[-2] > 0]
    if not parts:
        return points.new_empty(points.shape[:-1] + (0,))
    return torch.cat(parts, -1)


def nearest_obstacle_distance(points: torch.Tensor, obstacles: Obstacles, space: Space | None = None
                              ) -> torch.Tensor:
    """True distance from each point to the nearest obstacle surface, ``[B, N]`` (``inf`` if none)."""
    d = distance_to_obstacles(points, obstacles, space)
    if d.shape[-1] == 0:
        return torch.full(points.shape[:-1], math.inf, dtype=points.dtype, device=points.device)
    return d.amin(-1)


def pairwise(positions: torch.Tensor, space: Space | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Pairwise offsets and distances between UAVs.

    Args:
        positions: ``[B, N, 2]`` (in ``space`` ``[B, N, 3]``).

    Returns:
        ``(offset [B, N, N, d], distance [B, N, N])`` with ``offset[b, i, j] = p_j - p_i``.
    """
    offset = positions[:, None, :, :] - positions[:, :, None, :]
    return offset, length(offset, space)
