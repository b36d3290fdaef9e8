"""Obstacle fields drawn per episode (the forest; docs/specification.md section 6, decision).

A scenario may ask every episode to draw ``random_circles`` circles (radius uniform in
``random_circle_radius``) and ``random_rectangles`` axis-aligned rectangles (each side
uniform in ``random_rectangle_size``), each lying wholly inside ``random_region``. Every drawn
obstacle keeps ``random_clearance`` from the others, from the fixed obstacles, from the moving
circles' starts, from the goal disc (radius ``goal_radius``) and, at least
``max(random_clearance, spawn_clearance)``, from the spawn disc, so the starts drawn before
stay clear of it. They are drawn with the env's generator after everything else a reset draws,
so a scenario without them draws exactly the numbers it drew before they existed.

Placement, for all worlds at once: by rejection, one obstacle after the other
(:func:`place_by_rejection`); a world where that fails takes its whole field from a fixed grid of
cells (:func:`place_on_cells`), which :func:`check_forest` proves, when the config is built, can
always hold it: an accepted config never fails mid-run and the sampler never hangs.

Shapes are handled as axis-aligned *rounded boxes*, ``[..., 5]`` = ``(cx, cy, half_x, half_y,
rounding)``: a circle is ``(cx, cy, 0, 0, r)``, a rectangle ``(cx, cy, w/2, h/2, 0)``, a point
with a margin ``(x, y, 0, 0, margin)``. The gap between two of them (:func:`box_gap`) is exact
when they are apart, so every clearance test is one formula.
"""

from __future__ import annotations

import math

import torch

from ..config.scenario import ConfigError, ScenarioConfig
from .geometry import Obstacles


class SpawnError(RuntimeError):
    """No valid layout exists for a world: no room for the swarm (:mod:`.spawn`) or for the drawn
    obstacles (here); only possible for configs the checks refused."""


BOX = 5  # cx, cy, half_x, half_y, rounding
# Metres every blocker grows by in the config-time check (computed in float64), against the
# float32 round-off of the sampler's own test.
_ROUND_OFF = 1e-3


def drawn_count(cfg: ScenarioConfig) -> int:
    """How many obstacles each episode draws: circles, then rectangles."""
    return cfg.random_circles + cfg.random_rectangles


# ---------------------------------------------------------------------------- rounded boxes
def box_gap(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Gap between rounded boxes ``a [..., 5]`` and ``b [..., 5]`` (broadcast), ``[...]``.

    The distance between the shapes when they are apart (the distance from one centre to the
    other box grown by the first: half sizes and roundings add); zero or less when they touch
    or overlap."""
    q = (a[..., :2] - b[..., :2]).abs() - (a[..., 2:4] + b[..., 2:4])
    outside = torch.linalg.vector_norm(q.clamp_min(0.0), dim=-1)
    inside = q.amax(-1).clamp_max(0.0)
    return outside + inside - (a[..., 4] + b[..., 4])


def circle_boxes(circles: torch.Tensor) -> torch.Tensor:
    """Circles ``[..., 3]`` (cx, cy, r) as rounded boxes ``[..., 5]``."""
    zero = torch.zeros_like(circles[..., :2])
    return torch.cat((circles[..., :2], zero, circles[..., 2:]), -1)


def rectangle_boxes(rectangles: torch.Tensor) -> torch.Tensor:
    """Rectangles ``[..., 4]`` (cx, cy, width, height) as rounded boxes ``[..., 5]``."""
    return torch.cat((rectangles[..., :2], rectangles[..., 2:] / 2, torch.zeros_like(rectangles[..., :1])), -1)


def point_boxes(points: torch.Tensor, margin: float) -> torch.Tensor:
    """Points ``[..., 2]`` grown by ``margin`` (discs) as rounded boxes ``[..., 5]``."""
    return torch.cat((points, torch.zeros_like(points), torch.full_like(points[..., :1], margin)), -1)


def split_boxes(boxes: torch.Tensor, n_circles: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Drawn boxes ``[B, M, 5]`` (circles first) back as ``(circles [B, C, 3], rectangles [B, R, 4])``."""
    circles, rectangles = boxes[:, :n_circles], boxes[:, n_circles:]
    return (torch.cat((circles[..., :2], circles[..., 4:]), -1),
            torch.cat((rectangles[..., :2], 2 * rectangles[..., 2:4]), -1))


# ---------------------------------------------------------------------------- what is in the way
def disc_margin(cfg: ScenarioConfig) -> float:
    """The spawn disc as a blocker: its radius, plus what the starts need beyond the drawn
    obstacles' own clearance (every conflict test asks for a gap of ``random_clearance``)."""
    c = cfg.random_clearance
    return cfg.swarm_spawn_radius + max(c, cfg.spawn_clearance) - c


def blockers(cfg: ScenarioConfig, swarm_centre: torch.Tensor, goal: torch.Tensor, static: Obstacles,
             moving_position: torch.Tensor, pad: float = 0.0) -> torch.Tensor:
    """What every drawn obstacle must keep ``random_clearance`` from, ``[B, P, 5]``: the spawn
    disc, the goal disc (both grown by ``pad``), the fixed obstacles and the moving circles.

    Args:
        swarm_centre, goal: ``[B, 2]``; static: the fixed obstacles, batch 1;
        moving_position: ``[B, K, 2]`` moving circle centres.
    """
    b = swarm_centre.shape[0]
    parts = [point_boxes(swarm_centre[:, None], disc_margin(cfg) + pad),
             point_boxes(goal[:, None], cfg.goal_radius + pad),
             circle_boxes(static.circles.to(goal.dtype)).expand(b, -1, -1),
             rectangle_boxes(static.rectangles.to(goal.dtype)).expand(b, -1, -1),
             point_boxes(moving_position.to(goal.dtype), cfg.moving_radius)]
    return torch.cat(parts, 1)


def conflicts(box: torch.Tensor, others: torch.Tensor, clearance: float) -> torch.Tensor:
    """``[B]``: obstacle ``box [B, 5]`` is closer than ``clearance`` to one of ``others [B, P, 5]``."""
    if not others.shape[1]:
        return torch.zeros(box.shape[0], dtype=torch.bool, device=box.device)
    return (box_gap(box[:, None], others) < clearance).any(-1)


# ---------------------------------------------------------------------------- drawing
def uniform(shape, generator, device, low=0.0, high=1.0):
    """Draws uniform in ``[low, high)`` of ``shape`` (``low``, ``high``: numbers or tensors that broadcast)."""
    return low + (high - low) * torch.rand(shape, generator=generator, device=device)


def draw_shapes(cfg: ScenarioConfig, batch: int, generator: torch.Generator, device: torch.device) -> torch.Tensor:
    """Sizes of the drawn obstacles, centres still 0: ``[B, M, 5]`` rounded boxes, circles
    first (radius uniform in ``random_circle_radius``), then rectangles (width and height
    each uniform in ``random_rectangle_size``)."""
    radius = uniform((batch, cfg.random_circles, 1), generator, device, *cfg.random_circle_radius)
    sides = uniform((batch, cfg.random_rectangles, 2), generator, device, *cfg.random_rectangle_size)
    circles = circle_boxes(torch.cat((torch.zeros_like(radius).expand(-1, -1, 2), radius), -1))
    rectangles = rectangle_boxes(torch.cat((torch.zeros_like(sides), sides), -1))
    return torch.cat((circles, rectangles), 1)


def centre_bounds(cfg: ScenarioConfig, shapes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Where each centre may lie so that its obstacle stays wholly inside ``random_region``:
    ``(low, high)``, each ``[..., 2]`` for shapes ``[..., 5]``."""
    region = torch.tensor(cfg.random_region, dtype=shapes.dtype, device=shapes.device)
    extent = shapes[..., 2:4] + shapes[..., 4:]
    return region[:2] + extent, region[2:] - extent


def place_by_rejection(cfg: ScenarioConfig, shapes: torch.Tensor, fixed: torch.Tensor, generator: torch.Generator
                       ) -> tuple[torch.Tensor, torch.Tensor]:
    """Centres for ``shapes [B, M, 5]``, one obstacle after the other, every world at once.

    Each centre is drawn uniformly inside its bounds (:func:`centre_bounds`) and redrawn where
    it is closer than ``random_clearance`` to ``fixed [B, P, 5]`` or an obstacle placed before
    it, for at most ``spawn_max_tries`` rounds. A world whose obstacle is still in conflict is
    *stuck*; its later obstacles are not tried.

    Returns:
        ``(boxes [B, M, 5], stuck [B])``; a stuck world's boxes are meaningless.
    """
    batch, m = shapes.shape[:2]
    device, clearance = shapes.device, cfg.random_clearance
    low, high = centre_bounds(cfg, shapes)
    placed, stuck = fixed, torch.zeros(batch, dtype=torch.bool, device=device)
    for j in range(m):  # the drawn obstacles (a handful), each for every world at once
        box = torch.cat((uniform((batch, 2), generator, device, low[:, j], high[:, j]), shapes[:, j, 2:]), -1)
        bad = conflicts(box, placed, clearance) & ~stuck
        for _ in range(cfg.spawn_max_tries):
            if not bool(bad.any()):
                break
            fresh = torch.cat((uniform((batch, 2), generator, device, low[:, j], high[:, j]), shapes[:, j, 2:]), -1)
            box = torch.where(bad[:, None], fresh, box)
            bad = conflicts(box, placed, clearance) & ~stuck
        stuck = stuck | bad
        placed = torch.cat((placed, box[:, None]), 1)
    return placed[:, fixed.shape[1]:], stuck


def cell_grid(cfg: ScenarioConfig) -> tuple[int, int, float, float]:
    """The fallback's cells: ``(columns, rows, width, height)`` tiling ``random_region``, each at
    least the largest drawn obstacle's extent plus ``random_clearance`` on a side."""
    x0, y0, x1, y1 = cfg.random_region
    extent = max(cfg.random_circle_radius[1] if cfg.random_circles else 0.0,
                 cfg.random_rectangle_size[1] / 2 if cfg.random_rectangles else 0.0)
    side = 2 * extent + cfg.random_clearance
    columns, rows = int((x1 - x0) // side), int((y1 - y0) // side)
    if not columns or not rows:
        return 0, 0, 0.0, 0.0
    return columns, rows, (x1 - x0) / columns, (y1 - y0) / rows


def cell_boxes(cfg: ScenarioConfig, dtype=torch.float32, device=None) -> torch.Tensor:
    """The fallback's cells as boxes ``[G, 5]`` (no rounding), row by row; ``G = 0`` when the
    region cannot hold one."""
    columns, rows, width, height = cell_grid(cfg)
    x = cfg.random_region[0] + width * (torch.arange(columns, dtype=dtype, device=device) + 0.5)
    y = cfg.random_region[1] + height * (torch.arange(rows, dtype=dtype, device=device) + 0.5)
    yy, xx = torch.meshgrid(y, x, indexing="ij")
    half = torch.tensor([width / 2, height / 2, 0.0], dtype=dtype, device=device)
    return torch.cat((torch.stack((xx, yy), -1).reshape(-1, 2), half.expand(columns * rows, 3)), -1)


def free_cells(cfg: ScenarioConfig, cells: torch.Tensor, fixed: torch.Tensor) -> torch.Tensor:
    """``[B, G]``: cell ``g`` lies at least ``random_clearance / 2`` from every one of ``fixed
    [B, P, 5]``. An obstacle keeps ``random_clearance / 2`` from its cell's edges, and a box
    shrunk by ``h`` on every side is at least ``h`` farther from anything outside it, so the
    obstacle then keeps the whole clearance."""
    if not fixed.shape[1]:
        return torch.ones(fixed.shape[0], cells.shape[0], dtype=torch.bool, device=cells.device)
    return (box_gap(cells[None, :, None], fixed[:, None]) >= cfg.random_clearance / 2).all(-1)


def place_on_cells(cfg: ScenarioConfig, shapes: torch.Tensor, fixed: torch.Tensor, generator: torch.Generator
                   ) -> torch.Tensor:
    """Centres for ``shapes [W, M, 5]`` on the fallback's grid: ``M`` distinct free cells
    (:func:`free_cells`) drawn uniformly without replacement, each obstacle uniformly inside its
    cell and ``random_clearance / 2`` from the cell's edges, so obstacles in distinct cells are
    ``random_clearance`` apart and ``random_clearance`` from ``fixed``.

    Returns ``[W, M, 5]``; raises :class:`SpawnError` where fewer than ``M`` cells are free
    (only possible for a config :func:`check_forest` refused)."""
    w, m, device = shapes.shape[0], shapes.shape[1], shapes.device
    cells = cell_boxes(cfg, shapes.dtype, device)
    free = free_cells(cfg, cells, fixed)                                               # [W, G]
    if bool((free.sum(-1) < m).any()):
        raise SpawnError(f"fewer than {m} free cells for the drawn obstacles (a config check_forest should refuse)")
    score = torch.where(free, uniform(free.shape, generator, device), torch.full_like(free, 2.0, dtype=shapes.dtype))
    cell = cells[score.argsort(-1)[:, :m]]                                             # [W, M, 5]
    room = (cell[..., 2:4] - shapes[..., 2:4] - shapes[..., 4:] - cfg.random_clearance / 2).clamp_min(0.0)
    centre = cell[..., :2] + room * uniform((w, m, 2), generator, device, -1.0, 1.0)
    return torch.cat((centre, shapes[..., 2:]), -1)


def sample_forest(cfg: ScenarioConfig, swarm_centre: torch.Tensor, goal: torch.Tensor, static: Obstacles,
                  moving_position: torch.Tensor, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """The drawn obstacles of ``B`` new episodes: ``(circles [B, C, 3], rectangles [B, R, 4])``.

    Args:
        swarm_centre, goal: ``[B, 2]`` (Eq. 30); static: the fixed obstacles, batch 1;
        moving_position: ``[B, K, 2]``, the moving circles' starts.

    Draws nothing from ``generator`` when the scenario draws no obstacles.
    """
    batch, device = goal.shape[0], goal.device
    if not drawn_count(cfg):
        return goal.new_zeros(batch, 0, 3), goal.new_zeros(batch, 0, 4)
    shapes = draw_shapes(cfg, batch, generator, device)
    fixed = blockers(cfg, swarm_centre, goal, static, moving_position)
    boxes, stuck = place_by_rejection(cfg, shapes, fixed, generator)
    if bool(stuck.any()):
        boxes = boxes.clone()
        boxes[stuck] = place_on_cells(cfg, shapes[stuck], fixed[stuck], generator)
    return split_boxes(boxes, cfg.random_circles)


def lift_drawn(cfg: ScenarioConfig, circles: torch.Tensor, rectangles: torch.Tensor, generator: torch.Generator
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The drawn footprints of :func:`sample_forest` as 3-D solids (docs/specification.md section 11):
    ``(cylinders [B, C - S, 5], boxes [B, R, 6], spheres [B, S, 4])``. Every cylinder and box rises
    from the ground (``altitude[0]``) to a top uniform in ``random_heights``; the last
    ``random_spheres`` circles become spheres of their radius, centred at an altitude uniform in
    ``random_sphere_altitude``. Drawn in that order, after everything else; nothing when the
    scenario draws no obstacles."""
    batch, device = circles.shape[0], circles.device
    n_cyl, n_sph = cfg.drawn_cylinders, cfg.drawn_spheres
    ground = cfg.altitude[0]
    if not drawn_count(cfg):
        return circles.new_zeros(batch, 0, 5), circles.new_zeros(batch, 0, 6), circles.new_zeros(batch, 0, 4)
    top_c = uniform((batch, n_cyl, 1), generator, device, *cfg.random_heights)
    top_r = uniform((batch, rectangles.shape[1], 1), generator, device, *cfg.random_heights)
    sphere_z = uniform((batch, n_sph, 1), generator, device, *cfg.random_sphere_altitude)
    cylinders = torch.cat((circles[:, :n_cyl], torch.full_like(top_c, ground), top_c), -1)
    boxes = torch.cat((rectangles, torch.full_like(top_r, ground), top_r), -1)
    spheres = torch.cat((circles[:, n_cyl:, :2], sphere_z, circles[:, n_cyl:, 2:]), -1)
    return cylinders, boxes, spheres


# ---------------------------------------------------------------------------- config-time check
def cells_near_a_moving_circle(cfg: ScenarioConfig, steps: int = 32) -> int:
    """The most cells one moving circle can take from the fallback: those closer than
    ``moving_radius + random_clearance / 2`` to its centre (:func:`free_cells`). The grid
    repeats cell by cell, so the centre is tried at ``steps x steps`` points of one cell (of an
    unbounded grid: an upper bound), each reach grown by half the diagonal of the points'
    spacing, so that every centre between them is covered."""
    columns, rows, width, height = cell_grid(cfg)
    if not columns:
        return 0
    reach = cfg.moving_radius + cfg.random_clearance / 2 + math.hypot(width, height) / (2 * steps)
    kx, ky = math.ceil(reach / width) + 1, math.ceil(reach / height) + 1
    fraction = (torch.arange(steps, dtype=torch.float64) + 0.5) / steps
    px, py = torch.meshgrid(fraction * width, fraction * height, indexing="ij")
    points = point_boxes(torch.stack((px, py), -1).reshape(-1, 2), 0.0)                 # [S, 5]
    i, j = torch.meshgrid(torch.arange(-kx, kx + 1, dtype=torch.float64),
                          torch.arange(-ky, ky + 1, dtype=torch.float64), indexing="ij")
    centres = torch.stack(((i + 0.5) * width, (j + 0.5) * height), -1).reshape(-1, 2)
    cells = torch.cat((centres, torch.tensor([width / 2, height / 2, 0.0], dtype=torch.float64).expand(
        centres.shape[0], 3)), -1)                                                       # [G, 5]
    near = (box_gap(points[:, None], cells[None]) < reach).sum(-1)                       # [S]
    return min(int(near.max()), columns * rows)


def check_forest(cfg: ScenarioConfig, static: Obstacles, centre: torch.Tensor, pad: float) -> None:
    """Refuse (:class:`~flock_torchrl.config.ConfigError`) a field the fallback grid cannot
    always hold: for every swarm centre ``centre [A, 2]`` (the goal mirrored through
    ``area_center``; both grown by ``pad``, the distance to the nearest centre that is not on
    the list), the cells half the clearance from the spawn disc, the goal and the fixed
    obstacles (:func:`free_cells`), less what the moving circles can take in the worst case
    (:func:`cells_near_a_moving_circle`), must number at least the drawn obstacles. Rejection
    sampling needs no check: a world it cannot place takes the grid."""
    m = drawn_count(cfg)
    if not m:
        return
    area = torch.tensor(cfg.area_center, dtype=centre.dtype)
    goal = 2 * area - centre
    fixed = blockers(cfg, centre, goal, static, centre.new_zeros(centre.shape[0], 0, 2), pad)
    fixed[..., 4] += _ROUND_OFF  # the sampler decides in float32: a cell the check frees by less stays out
    room = free_cells(cfg, cell_boxes(cfg, centre.dtype), fixed).sum(-1)               # [A]
    room = room - cfg.n_moving * cells_near_a_moving_circle(cfg)
    worst = int(room.argmin())
    if int(room[worst]) < m:
        columns, rows, width, height = cell_grid(cfg)
        key = "scenario.random_circles" if cfg.random_circles else "scenario.random_rectangles"
        raise ConfigError(
            key, f"{cfg.random_circles} circles and {cfg.random_rectangles} rectangles {cfg.random_clearance:g} m "
                 f"apart cannot always be placed in random_region {list(cfg.random_region)}: its {columns} x {rows} "
                 f"cells of {width:.1f} m x {height:.1f} m (the largest obstacle plus the clearance) leave room for "
                 f"{max(int(room[worst]), 0)} near swarm centre ({centre[worst, 0]:.1f}, {centre[worst, 1]:.1f}); "
                 "lower random_circles / random_rectangles, the largest size or random_clearance, or enlarge "
                 "random_region",
            also=[f"scenario.{k}" for k in ("random_circles", "random_rectangles", "random_clearance", "random_region",
                                            "random_circle_radius", "random_rectangle_size")])


__all__ = ["SpawnError", "blockers", "box_gap", "cell_boxes", "cell_grid", "check_forest", "drawn_count", "lift_drawn",
           "place_by_rejection", "place_on_cells", "sample_forest"]
