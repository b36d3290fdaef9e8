"""Episode generator: swarm starts, goals (Eq. 30), moving obstacles (S5) and drawn obstacles
(the forest, :mod:`.forest`), vectorised.

Starts follow docs/specification.md sections 1 and 9: each UAV uniform in a disc around the
swarm centre (radius :attr:`ScenarioConfig.swarm_spawn_radius`, which grows with the swarm
as the reading says), at least ``spawn_separation`` from the others and ``spawn_clearance``
from obstacle surfaces. Rejection sampling redraws only the offending UAVs; a world whose swarm
is still not placed takes its starts from a hexagonal lattice (:func:`lattice_starts`), which
:func:`check_spawn_feasible` proves at config time to have room, so an accepted config never
fails to spawn mid-run. The drawn obstacles come last (:mod:`.forest`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..config.scenario import ConfigError, ScenarioConfig
from .forest import SpawnError, uniform, check_forest, lift_drawn, sample_forest
from .geometry import Obstacles, distance_to_obstacles, pairwise

# Angular resolution of the config-time check over swarm centres (Eq. 30's chi); the check
# pads obstacle distances by the discretisation error. The fallback's lattices: fixed
# rotations and shifts, so that the check can count their free points exactly.
_CHECK_ANGLES = 360
_CHECK_GRID = 96
LATTICES = 16
# Rejection rounds without fewer offending UAVs after which the lattice takes over.
_STALLED_ROUNDS = 10
# Above this packing fraction of the separation discs in the spawn disc, rejection sampling
# (parallel random sequential adsorption, which jams near 0.55) barely converges: the starts
# come from the lattice at once.
_DENSE = 0.4


def packing_fraction(cfg: ScenarioConfig) -> float:
    """Area of the N discs of radius ``spawn_separation / 2`` over the spawn disc's (grown by that radius)."""
    half = cfg.spawn_separation / 2
    return cfg.n_uavs * half * half / (cfg.swarm_spawn_radius + half) ** 2
# Moving circles (S5) are placed by rejection with up to spawn_max_tries draws each; the
# config check asks for at least this free fraction of their start box in the worst case,
# so a failure would need spawn_max_tries misses in a row (probability <= 0.8 ** 200).
_MIN_MOVING_FREE_FRACTION = 0.2


@dataclass
class Layout:
    """Episode starts of ``B`` worlds: ``goal [B, 2]``, ``position [B, N, 2]``, ``heading [B, N]``,
    moving circles ``moving_position [B, K, 2]`` and ``moving_velocity [B, K, 2]``, drawn
    obstacles ``drawn_circles [B, C, 3]`` and ``drawn_rectangles [B, R, 4]``. In 3-D (section 11)
    goal and positions are 3-D, the drawn obstacles cylinders ``[B, C, 5]``, boxes ``[B, R, 6]`` and
    ``drawn_spheres [B, S, 4]`` (2-D: ``[B, 0, 4]``)."""

    goal: torch.Tensor
    position: torch.Tensor
    heading: torch.Tensor
    moving_position: torch.Tensor
    moving_velocity: torch.Tensor
    drawn_circles: torch.Tensor
    drawn_rectangles: torch.Tensor
    drawn_spheres: torch.Tensor


def static_obstacles(cfg: ScenarioConfig, device=None, dtype=torch.float32) -> Obstacles:
    """The scenario's fixed obstacles, batch 1: circles and rectangles, in 3-D (section 11)
    cylinders ``[1, C, 5]``, boxes ``[1, R, 6]`` and spheres ``[1, S, 4]``."""
    circles = torch.tensor(cfg.circles, dtype=dtype, device=device).reshape(1, -1, cfg.circle_size)
    rectangles = torch.tensor(cfg.rectangles, dtype=dtype, device=device).reshape(1, -1, cfg.rectangle_size)
    spheres = torch.tensor(cfg.spheres, dtype=dtype, device=device).reshape(1, -1, 4) if cfg.dims == 3 else None
    return Obstacles(circles, rectangles, spheres)


def chi_grid(cfg: ScenarioConfig, steps: int, dtype=torch.float64) -> torch.Tensor:
    """``steps`` values of Eq. 30's chi covering ``chi_range`` (the full circle: ``k 2 pi / steps``),
    spaced at most ``2 pi / steps`` apart."""
    low, high = cfg.chi_range
    if high - low >= 2 * math.pi - 1e-9:
        return torch.arange(steps, dtype=dtype) * (2 * math.pi / steps)
    return low + torch.arange(steps, dtype=dtype) * ((high - low) / (steps - 1))


def _drawn(shape, generator, device, low: float, high: float) -> torch.Tensor:
    """Uniform in ``[low, high)``; a range of zero width is its value and draws nothing (section 11:
    a fixed altitude leaves the generator as the plane leaves it)."""
    if low == high:
        return torch.full(shape, float(low), device=device)
    return uniform(shape, generator, device, low, high)


def _angle(shape, generator, device):
    return uniform(shape, generator, device, -math.pi, math.pi)


def _in_disc(shape, radius, generator, device):
    r = radius * torch.sqrt(uniform(shape, generator, device))
    theta = _angle(shape, generator, device)
    return torch.stack((r * torch.cos(theta), r * torch.sin(theta)), -1)


def _first_of_close_pairs(position: torch.Tensor, separation: float) -> torch.Tensor:
    """``[B, N]``: UAV j is closer than ``separation`` to some UAV i < j."""
    _, dist = pairwise(position)
    n = position.shape[-2]
    earlier = torch.ones(n, n, dtype=torch.bool, device=position.device).tril(-1)  # [j, i]: i < j
    return ((dist < separation) & earlier).any(-1)


def _hex_lattice(radius: float, spacing: float, device=None, dtype=torch.float32) -> torch.Tensor:
    """Points of a hexagonal lattice of ``spacing`` covering a disc of ``radius`` plus two cells,
    centred on the origin, ``[P, 2]``."""
    rows = int(math.ceil((radius + 2 * spacing) / (spacing * math.sqrt(3) / 2)))
    cols = int(math.ceil((radius + 2 * spacing) / spacing))
    j = torch.arange(-rows, rows + 1, device=device, dtype=dtype)
    i = torch.arange(-cols, cols + 1, device=device, dtype=dtype)
    jj, ii = torch.meshgrid(j, i, indexing="ij")
    x = spacing * (ii + 0.5 * torch.remainder(jj, 2))
    y = spacing * (math.sqrt(3) / 2) * jj
    return torch.stack((x, y), -1).reshape(-1, 2)


def lattice_offsets(cfg: ScenarioConfig, device=None, dtype=torch.float32) -> torch.Tensor:
    """The fallback's candidate starts relative to the swarm centre: :data:`LATTICES` fixed
    rotations and shifts of a hexagonal lattice of spacing ``spawn_separation`` (times
    1 + 1e-4, against float32 round-off), each cut to the spawn disc, ``[L, P, 2]`` (NaN pads)."""
    radius = cfg.swarm_spawn_radius
    spacing = max(cfg.spawn_separation, 1e-3) * (1 + 1e-4)
    points = _hex_lattice(radius, spacing, device, torch.float64)
    k = torch.arange(LATTICES, dtype=torch.float64, device=device)
    angle = k * (math.pi / 3) / LATTICES
    # A fixed, well spread set of shifts inside one cell (golden-ratio sequence).
    shift = torch.stack((torch.remainder(k * 0.6180339887498949, 1.0),
                         torch.remainder(k * 0.7548776662466927, 1.0)), -1) * spacing
    shifted = points[None] + shift[:, None]
    cos, sin = torch.cos(angle)[:, None], torch.sin(angle)[:, None]
    rotated = torch.stack((cos * shifted[..., 0] - sin * shifted[..., 1],
                           sin * shifted[..., 0] + cos * shifted[..., 1]), -1)
    inside = torch.linalg.vector_norm(rotated, dim=-1) <= radius
    return torch.where(inside[..., None], rotated, torch.full_like(rotated, math.nan)).to(dtype)


def _free(points: torch.Tensor, static: Obstacles, clearance: float) -> torch.Tensor:
    """``[M, ...]``: the points ``[M, ..., 2]`` (NaN: none) are at least ``clearance`` from every
    obstacle surface."""
    m = points.shape[0]
    free = ~torch.isnan(points[..., 0])
    if static.count:
        batch_static = Obstacles(static.circles.to(points.dtype).expand(m, -1, -1),
                                 static.rectangles.to(points.dtype).expand(m, -1, -1))
        flat = torch.nan_to_num(points, nan=1e9).reshape(m, -1, 2)
        clear = distance_to_obstacles(flat, batch_static).amin(-1) >= clearance
        free &= clear.reshape(free.shape)
    return free


def lattice_starts(centre: torch.Tensor, cfg: ScenarioConfig, static: Obstacles, generator: torch.Generator
                   ) -> torch.Tensor:
    """Starts on a hexagonal lattice, for worlds rejection sampling could not place.

    Per world, the lattices of :func:`lattice_offsets` are tried from a uniformly drawn one on
    (in a fixed cyclic order) until one has at least ``N`` free points; ``N`` of them are then
    drawn uniformly without replacement, so pairs are ``spawn_separation`` apart by
    construction. :func:`check_spawn_feasible` has proved that such a lattice exists for every
    swarm centre the scenario can draw.

    Args:
        centre: ``[M, 2]`` swarm centres. Returns ``[M, N, 2]``.
    """
    m, n, device = centre.shape[0], cfg.n_uavs, centre.device
    offsets = lattice_offsets(cfg, device)                                             # [L, P, 2]
    first = (uniform((m,), generator, device) * LATTICES).long().clamp_max(LATTICES - 1)
    lattice = first.clone()
    free = torch.zeros(m, offsets.shape[1], dtype=torch.bool, device=device)
    todo = torch.arange(m, device=device)
    for shift in range(LATTICES):  # the fixed set of lattices, not worlds or UAVs
        lattice[todo] = (first[todo] + shift) % LATTICES
        room = _free(centre[todo][:, None] + offsets[lattice[todo]], static, cfg.spawn_clearance)   # [W, P]
        free[todo] = room
        todo = todo[room.sum(-1) < n]
        if not todo.numel():
            break
    else:
        raise SpawnError(f"no spawn lattice has {n} free points (a config check_spawn_feasible should refuse)")
    score = torch.where(free, uniform(free.shape, generator, device), torch.full_like(free, 2.0, dtype=torch.float32))
    chosen = score.argsort(-1)[:, :n]                                                  # [M, N]
    candidates = centre[:, None] + offsets[lattice]                                    # [M, P, 2]
    return torch.gather(candidates, 1, chosen[..., None].expand(-1, -1, 2))


def sample_layout(cfg: ScenarioConfig, batch: int, static: Obstacles, generator: torch.Generator,
                  device: torch.device) -> Layout:
    """Draw ``batch`` episode starts (sections 1, 6 and 9) among ``static``, the fixed obstacles (batch 1)."""
    n = cfg.n_uavs
    cx, cy = cfg.area_center
    three_d = cfg.dims == 3
    static = static.footprints() if three_d else static  # in 3-D the starts are placed on footprints
    chi = uniform((batch,), generator, device, *cfg.chi_range)
    unit = torch.stack((torch.cos(chi), torch.sin(chi)), -1)
    area_center = torch.tensor([cx, cy], device=device)
    swarm_centre = area_center + cfg.d_env * unit
    goal = area_center - cfg.d_env * unit  # angle chi + pi
    static_b = Obstacles(static.circles.expand(batch, -1, -1), static.rectangles.expand(batch, -1, -1))
    radius = cfg.swarm_spawn_radius

    def offending(worlds: torch.Tensor) -> torch.Tensor:
        """``[W, N]``: UAVs of these worlds too close to an earlier one or to an obstacle."""
        bad = _first_of_close_pairs(position[worlds], cfg.spawn_separation)
        if static_b.count:
            bad |= distance_to_obstacles(position[worlds], static_b[worlds]).amin(-1) < cfg.spawn_clearance
        return bad

    position = swarm_centre[:, None] + _in_disc((batch, n), radius, generator, device)
    bad = offending(torch.arange(batch, device=device))
    fewest, stalled = batch * n + 1, 0
    for _ in range(cfg.spawn_max_tries if packing_fraction(cfg) <= _DENSE else 0):
        count = int(bad.sum())
        if not count:
            break
        # A dense swarm stops converging long before the round limit: hand it to the lattice.
        fewest, stalled = (count, 0) if count < fewest else (fewest, stalled + 1)
        if stalled >= _STALLED_ROUNDS:
            break
        fresh = swarm_centre[:, None] + _in_disc((batch, n), radius, generator, device)
        position = torch.where(bad[..., None], fresh, position)
        # Only worlds that had an offending UAV changed: only they need checking again.
        worlds = bad.any(-1).nonzero().squeeze(-1)
        bad = torch.zeros_like(bad)
        bad[worlds] = offending(worlds)
    count = int(bad.sum())
    if count:
        stuck = bad.any(-1)
        position = position.clone()
        position[stuck] = lattice_starts(swarm_centre[stuck], cfg, static, generator)
    heading = _angle((batch, n), generator, device)

    k = cfg.n_moving
    moving_position = torch.zeros(batch, k, 2, device=device)
    moving_velocity = torch.zeros(batch, k, 2, device=device)
    if k:
        low, high = cfg.moving_box
        moving_position = uniform((batch, k, 2), generator, device, low, high)
        for _ in range(cfg.spawn_max_tries):
            bad = _moving_conflicts(moving_position, cfg, static_b, position, goal)
            if not bad.any():
                break
            fresh = uniform((batch, k, 2), generator, device, low, high)
            moving_position = torch.where(bad[..., None], fresh, moving_position)
        else:
            raise SpawnError(
                f"could not place {k} moving circles clear of the static obstacles and "
                f"{cfg.moving_clearance} m from the swarm and goal within {cfg.spawn_max_tries} draws "
                "(fields n_moving, moving_radius, moving_clearance, moving_box)")
        direction = _angle((batch, k), generator, device)
        moving_velocity = cfg.moving_speed * torch.stack((torch.cos(direction), torch.sin(direction)), -1)
    drawn_circles, drawn_rectangles = sample_forest(cfg, swarm_centre, goal, static, moving_position, generator)
    if not three_d:
        return Layout(goal, position, heading, moving_position, moving_velocity, drawn_circles, drawn_rectangles,
                      goal.new_zeros(batch, 0, 4))
    # 3-D (section 11): the altitudes, after every draw the plane makes.
    centre_z = _drawn((batch,), generator, device, *cfg.spawn_altitude)
    goal_z = _drawn((batch,), generator, device, *cfg.goal_altitude)
    spread = _drawn((batch, n), generator, device, -cfg.spawn_height / 2, cfg.spawn_height / 2)
    position = torch.cat((position, (centre_z[:, None] + spread)[..., None]), -1)
    goal = torch.cat((goal, goal_z[:, None]), -1)
    drawn_circles, drawn_rectangles, drawn_spheres = lift_drawn(cfg, drawn_circles, drawn_rectangles, generator)
    return Layout(goal, position, heading, moving_position, moving_velocity, drawn_circles, drawn_rectangles,
                  drawn_spheres)


def _moving_conflicts(centres: torch.Tensor, cfg: ScenarioConfig, static: Obstacles, uavs: torch.Tensor,
                      goal: torch.Tensor) -> torch.Tensor:
    """``[B, K]``: a moving circle overlaps a static obstacle or is too near the swarm or goal."""
    bad = torch.zeros(centres.shape[:-1], dtype=torch.bool, device=centres.device)
    if static.count:
        bad |= distance_to_obstacles(centres, static).amin(-1) < cfg.moving_radius
    points = torch.cat((uavs, goal[:, None]), 1)  # [B, N+1, 2]
    gap = torch.linalg.vector_norm(centres[:, :, None] - points[:, None], dim=-1) - cfg.moving_radius
    return bad | (gap < cfg.moving_clearance).any(-1)


# ---------------------------------------------------------------------------- config-time check
_FEASIBLE: set[tuple] = set()  # the scenarios checked already (:func:`_feasibility_key`)


def _feasibility_key(cfg: ScenarioConfig) -> tuple:
    return (cfg.n_uavs, cfg.swarm_spawn_radius, cfg.spawn_separation, cfg.spawn_clearance, cfg.d_env,
            tuple(cfg.area_center), tuple(map(tuple, cfg.circles)), tuple(map(tuple, cfg.rectangles)),
            cfg.n_moving, cfg.moving_radius, cfg.moving_clearance, tuple(cfg.moving_box), cfg.goal_radius,
            cfg.random_circles, tuple(cfg.random_circle_radius), cfg.random_rectangles,
            tuple(cfg.random_rectangle_size), tuple(cfg.random_region), cfg.random_clearance, tuple(cfg.chi_range),
            cfg.dims, tuple(map(tuple, cfg.spheres)) if cfg.dims == 3 else ())


def check_spawn_feasible(cfg: ScenarioConfig) -> None:
    """Refuse (with :class:`ConfigError`) a scenario whose starts cannot always be placed.

    For every swarm centre Eq. 30 can draw (``chi`` on a 360-step grid; obstacle clearances
    padded by half the grid's chord, so centres between grid points are covered too), one of
    the fallback's lattices (:func:`lattice_offsets`) must have at least ``n_uavs`` points in
    the spawn disc and clear of the obstacles. Moving circles (S5) need at least 20 % of their
    start box free of the swarm's, the goal's and the static obstacles' exclusion zones. Drawn
    obstacles must always fit the fallback grid of :func:`.forest.check_forest`.
    """
    from .memory import check_scenario_memory

    key = _feasibility_key(cfg)
    if key in _FEASIBLE:
        return
    check_scenario_memory(cfg)  # before the lattices and the forest grid are allocated
    n, s = cfg.n_uavs, cfg.spawn_separation
    static = static_obstacles(cfg, dtype=torch.float64)
    static = static.footprints() if cfg.dims == 3 else static  # 3-D: footprints (section 11)
    chi = chi_grid(cfg, _CHECK_ANGLES)
    centre = torch.tensor(cfg.area_center, dtype=torch.float64) + cfg.d_env * torch.stack(
        (torch.cos(chi), torch.sin(chi)), -1)                                         # [A, 2]
    chord = 2 * cfg.d_env * math.sin(math.pi / _CHECK_ANGLES)  # a centre off the grid is this close to one
    if n > 1 and s > 0:
        offsets = lattice_offsets(cfg, dtype=torch.float64)
        free = _free(centre[:, None, None] + offsets[None], static, cfg.spawn_clearance + chord / 2)  # [A, L, P]
        room = free.sum(-1).amax(-1)                                                   # [A]
        worst = int(room.argmin())
        if int(room[worst]) < n:
            where = f" near swarm centre ({centre[worst, 0]:.1f}, {centre[worst, 1]:.1f})" if static.count else ""
            raise ConfigError(
                "scenario.n_uavs",
                f"{n} UAVs at least {s} m apart and {cfg.spawn_clearance} m from obstacles cannot always be placed "
                f"in a spawn disc of radius {cfg.swarm_spawn_radius:.2f} m{where} (room for {int(room[worst])}); "
                "raise spawn_radius or d_env, or lower n_uavs / spawn_separation")
    elif static.count:
        # One UAV (or no separation): some point of the disc must be clear of the obstacles.
        free = _free(centre[:, None], static, cfg.spawn_clearance + chord / 2)                # [A, 1]
        if not bool(free.any(-1).all()):
            raise ConfigError("scenario.spawn_clearance", "the swarm centre can fall inside an obstacle's clearance")
    if cfg.n_moving:
        _check_moving(cfg, static, centre, chi, chord)
    check_forest(cfg, static, centre, chord / 2)
    _FEASIBLE.add(key)


def _check_moving(cfg: ScenarioConfig, static: Obstacles, centre: torch.Tensor, chi: torch.Tensor,
                  chord: float) -> None:
    low, high = cfg.moving_box
    grid = torch.linspace(low, high, _CHECK_GRID, dtype=torch.float64)
    gx, gy = torch.meshgrid(grid, grid, indexing="ij")
    points = torch.stack((gx, gy), -1).reshape(1, -1, 2)                              # [1, G, 2]
    free = torch.ones(points.shape[1], dtype=torch.bool)
    if static.count:
        free &= distance_to_obstacles(points, static)[0].amin(-1) >= cfg.moving_radius
    goal = torch.tensor(cfg.area_center, dtype=torch.float64) - (centre - torch.tensor(cfg.area_center,
                                                                                       dtype=torch.float64))
    reach = cfg.moving_radius + cfg.moving_clearance + chord / 2
    near_swarm = torch.cdist(points[0], centre) <= reach + cfg.swarm_spawn_radius     # [G, A]
    near_goal = torch.cdist(points[0], goal) <= reach
    fraction = (free[:, None] & ~near_swarm & ~near_goal).double().mean(0)            # [A]
    if float(fraction.min()) < _MIN_MOVING_FREE_FRACTION:
        raise ConfigError("scenario.n_moving", f"moving circles have only {100 * float(fraction.min()):.0f} % of "
                          f"their start box free in the worst case (need {100 * _MIN_MOVING_FREE_FRACTION:.0f} %); "
                          "change moving_box, moving_radius or moving_clearance")
