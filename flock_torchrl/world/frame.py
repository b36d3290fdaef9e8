"""Drawing one instant of the world: the frame ``FlockingEnv.render`` returns.

Matplotlib's object API on an Agg canvas (no pyplot, no display, no global state but a cache of
3-D layouts), so it runs headless and inside tests: obstacles (red), the goal circle (green), UAVs
as triangles along their heading (blue) and their camera wedges. Whole episodes and the paper's
figures are drawn by :mod:`flock_torchrl.report.figures`.

A 3-D world (docs/specification.md section 11) is drawn as a top view (obstacles by their
footprints) beside a side view (:func:`draw_side`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import torch
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Polygon, Rectangle, Wedge

OBSTACLE_COLOR = "#d62728"
MOVING_COLOR = "#ff7f0e"
GOAL_COLOR = "#2ca02c"
UAV_COLOR = "#1f77b4"
FOV_COLOR = "#1f77b4"
DPI = 100
SIDE_ASPECT = 0.75   # a 3-D frame's side view: its height over its width


# ---------------------------------------------------------------------------- world state
@dataclass
class WorldState:
    """One env at one instant, as numpy arrays: ``position [N, 2]``, ``heading [N]``,
    ``goal [2]``, ``moving [K, 2]`` (moving circle centres, ``K = 0`` without them), the
    episode's drawn obstacles ``circles [C, 3]`` and ``rectangles [R, 4]`` (none by default)."""

    position: np.ndarray
    heading: np.ndarray
    goal: np.ndarray
    moving: np.ndarray
    circles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    rectangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.float32))
    # 3-D only (section 11): the UAVs' and the goal's altitudes, the drawn spheres; then the drawn
    # circles and rectangles carry their height range ([C, 5], [R, 6]).
    altitude: np.ndarray | None = None
    goal_altitude: float | None = None
    spheres: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.float32))


def _np(x: torch.Tensor) -> np.ndarray:
    return x.detach().to("cpu", torch.float32).numpy()


def env_state(env: Any, env_index: int = 0) -> WorldState:
    """The current state of env ``env_index`` of a FlockingEnv."""
    world = env.world[env_index]
    position, goal = _np(world["position"]), _np(world["goal"])
    space = {} if env.cfg.dims != 3 else dict(altitude=position[:, 2], goal_altitude=float(goal[2]),
                                              spheres=_np(world["drawn_spheres"]))
    return WorldState(position[:, :2], _np(world["heading"]), goal[:2], _np(world["moving_position"]),
                      _np(world["drawn_circles"]), _np(world["drawn_rectangles"]), **space)


def rollout_states(rollout: Any, cfg: Any, env_index: int = 0) -> list[WorldState]:
    """The states of one env along a rollout TensorDict (``[B, T]`` or ``[T]``) of scenario ``cfg``,
    from the start to its first ``done``: ``T_done + 1`` states."""
    td = rollout[env_index] if rollout.batch_dims == 2 else rollout
    done = td["next", "done"].reshape(-1)
    last = int(done.nonzero()[0]) if bool(done.any()) else done.numel() - 1
    td = td[: last + 1]

    def track(key: tuple[str, ...]) -> torch.Tensor:
        return torch.cat((td[key][:1], td[("next", *key)]), 0)

    position, heading = track(("agents", "position")), track(("agents", "heading"))
    goal = td["goal"][0]
    keys = td.keys(include_nested=True)
    if ("obstacles", "position") in keys:
        moving = track(("obstacles", "position"))
    else:
        moving = torch.zeros(position.shape[0], 0, 2)
    # Drawn obstacles stay put for the episode: its first step's.
    drawn = {name: _np(td["obstacles", f"drawn_{name}"][0]) for name in ("circles", "rectangles", "spheres")
             if ("obstacles", f"drawn_{name}") in keys}
    space = cfg.dims == 3  # the top view's positions, and the altitudes apart
    return [WorldState(_np(position[t, :, :2]), _np(heading[t]), _np(goal[:2]), _np(moving[t]), **drawn,
                       altitude=_np(position[t, :, 2]) if space else None,
                       goal_altitude=float(goal[2]) if space else None)
            for t in range(position.shape[0])]


def world_extent(cfg: Any, states: Sequence[WorldState], margin: float = 4.0) -> tuple[float, float, float, float]:
    """A square ``(x0, x1, y0, y1)`` holding the nominal area, the obstacles, the goal and every
    UAV position of ``states``."""
    cx, cy = cfg.area_center
    half = cfg.area_size / 2
    xs = [cx - half, cx + half]
    ys = [cy - half, cy + half]
    for s in states:
        pts = np.concatenate((s.position.reshape(-1, 2), s.goal.reshape(1, 2)), 0)
        xs += [float(pts[:, 0].min()), float(pts[:, 0].max())]
        ys += [float(pts[:, 1].min()), float(pts[:, 1].max())]
    x0, x1, y0, y1 = min(xs) - margin, max(xs) + margin, min(ys) - margin, max(ys) + margin
    side = max(x1 - x0, y1 - y0)
    mx, my = (x0 + x1) / 2, (y0 + y1) / 2
    return mx - side / 2, mx + side / 2, my - side / 2, my + side / 2


# ---------------------------------------------------------------------------- drawing
def draw_obstacles(ax: Any, circles: Any, rectangles: Any) -> None:
    """Circles ``[C, 3]`` (cx, cy, r) and axis-aligned rectangles ``[R, 4]`` (cx, cy, w, h), red
    (3-D cylinders ``[C, 5]`` and boxes ``[R, 6]``: their footprints)."""
    circles, rectangles = np.asarray(circles, dtype=float), np.asarray(rectangles, dtype=float)
    for cx, cy, r in (circles[:, :3] if circles.ndim == 2 else circles.reshape(-1, 3)):
        ax.add_patch(Circle((cx, cy), r, facecolor=OBSTACLE_COLOR, edgecolor="none", alpha=0.85, zorder=1))
    for cx, cy, w, h in (rectangles[:, :4] if rectangles.ndim == 2 else rectangles.reshape(-1, 4)):
        ax.add_patch(Rectangle((cx - w / 2, cy - h / 2), w, h, facecolor=OBSTACLE_COLOR, edgecolor="none",
                               alpha=0.85, zorder=1))


def draw_static(ax: Any, cfg: Any, goal: np.ndarray) -> None:
    """The scenario's fixed circles and rectangles (red) and the goal circle (green)."""
    draw_obstacles(ax, cfg.circles, cfg.rectangles)
    ax.add_patch(Circle(tuple(goal), cfg.goal_radius, facecolor=GOAL_COLOR, edgecolor=GOAL_COLOR, alpha=0.5,
                        zorder=2))
    ax.add_patch(Circle(tuple(goal), cfg.goal_radius, fill=False, edgecolor=GOAL_COLOR, lw=1.5, zorder=2))


def draw_moving(ax: Any, cfg: Any, centres: np.ndarray, alpha: float = 0.6, label: str | None = None) -> None:
    """Moving circles of radius ``cfg.moving_radius`` at ``centres [K, 2]``."""
    for c in centres.reshape(-1, 2):
        ax.add_patch(Circle(tuple(c), cfg.moving_radius, facecolor=MOVING_COLOR, edgecolor=OBSTACLE_COLOR,
                            alpha=alpha, hatch="//", zorder=1))
        if label:
            ax.annotate(label, tuple(c), ha="center", va="center", fontsize=6, zorder=5)


def draw_uavs(ax: Any, position: np.ndarray, heading: np.ndarray, length: float) -> None:
    """UAVs as isosceles triangles of ``length`` pointing along their heading."""
    for (x, y), h in zip(position.reshape(-1, 2), heading.reshape(-1)):
        tip = (x + length * math.cos(h), y + length * math.sin(h))
        back = [(x + 0.6 * length * math.cos(h + s * 2.5), y + 0.6 * length * math.sin(h + s * 2.5)) for s in (1, -1)]
        ax.add_patch(Polygon([tip, *back], closed=True, facecolor=UAV_COLOR, edgecolor="black", lw=0.4, zorder=4))


def draw_fov(ax: Any, position: np.ndarray, heading: np.ndarray, radius: float, half_fov: float) -> None:
    """Camera fields of view: wedges of ``radius`` reaching ``half_fov`` either side of each heading."""
    for (x, y), h in zip(position.reshape(-1, 2), heading.reshape(-1)):
        if half_fov >= math.pi - 1e-6:
            patch: Any = Circle((x, y), radius)
        else:
            patch = Wedge((x, y), radius, math.degrees(h - half_fov), math.degrees(h + half_fov))
        patch.set(facecolor=FOV_COLOR, edgecolor=FOV_COLOR, alpha=0.12, lw=0.5, zorder=3)
        ax.add_patch(patch)


def style_axes(ax: Any, extent: tuple[float, float, float, float], title: str | None, axes: bool = True) -> None:
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    if title:
        ax.set_title(title, fontsize=9)
    if axes:
        ax.set_xlabel("x (m)", fontsize=7)
        ax.set_ylabel("y (m)", fontsize=7)
        ax.tick_params(labelsize=6)
    else:
        ax.set_axis_off()


def draw_world(ax: Any, cfg: Any, state: WorldState, extent: tuple[float, float, float, float],
               show_fov: bool = True) -> None:
    """One instant of the world into ``ax``: obstacles (the world's drawn ones too), goal, fields
    of view, UAVs."""
    draw_static(ax, cfg, state.goal)
    draw_obstacles(ax, state.circles, state.rectangles)
    spheres = [*cfg.spheres] if cfg.dims == 3 else []
    for cx, cy, _, r in [*spheres, *np.asarray(state.spheres, dtype=float).reshape(-1, 4)]:
        ax.add_patch(Circle((cx, cy), r, facecolor=OBSTACLE_COLOR, edgecolor="black", lw=0.3, alpha=0.5, zorder=1))
    if state.moving.size:
        draw_moving(ax, cfg, state.moving)
    if show_fov:
        draw_fov(ax, state.position, state.heading, cfg.camera_range, cfg.half_fov)
    draw_uavs(ax, state.position, state.heading, length=(extent[1] - extent[0]) / 60)
    style_axes(ax, extent, None, axes=False)


def image_size(size: int | tuple[int, int]) -> tuple[int, int]:
    h, w = (size, size) if isinstance(size, int) else size
    if h < 16 or w < 16:
        raise ValueError(f"size must be at least 16 pixels per side, got {size!r}")
    return int(h), int(w)


def _figure(height: int, width: int, constrained: bool = False) -> tuple[Figure, FigureCanvasAgg]:
    fig = Figure(figsize=(width / DPI, height / DPI), dpi=DPI)
    if constrained:  # matplotlib makes room for the labels (a few pixels of padding around them)
        fig.set_layout_engine("constrained", w_pad=2 / DPI, h_pad=2 / DPI, wspace=0.04)
    return fig, FigureCanvasAgg(fig)


def _to_rgb(canvas: FigureCanvasAgg, height: int, width: int) -> np.ndarray:
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    rgb = np.ascontiguousarray(rgba[..., :3])
    if rgb.shape[:2] != (height, width):  # float rounding of figsize * dpi: pad or crop to size
        out = np.full((height, width, 3), 255, dtype=np.uint8)
        h, w = min(height, rgb.shape[0]), min(width, rgb.shape[1])
        out[:h, :w] = rgb[:h, :w]
        rgb = out
    return rgb


def side_axis(cfg: Any, state: WorldState) -> np.ndarray:
    """The side view's horizontal direction: from the area's centre towards the goal (unit, ``[2]``)."""
    direction = np.asarray(state.goal, dtype=float) - np.asarray(cfg.area_center, dtype=float)
    norm = float(np.hypot(*direction))
    return direction / norm if norm > 1e-9 else np.array([1.0, 0.0])


def _box_section(centre: np.ndarray, u: np.ndarray, box: Sequence[float]) -> tuple[float, float] | None:
    """Where the line ``centre + s u`` crosses the footprint of ``box`` (cx, cy, w, h, ...): ``(s_in,
    s_out)``, or ``None`` if it misses."""
    low, high = -math.inf, math.inf
    for axis in (0, 1):
        lo = box[axis] - box[axis + 2] / 2 - centre[axis]
        hi = box[axis] + box[axis + 2] / 2 - centre[axis]
        if abs(u[axis]) < 1e-12:
            if not lo <= 0 <= hi:
                return None
            continue
        a, b = sorted((lo / u[axis], hi / u[axis]))
        low, high = max(low, a), min(high, b)
    return (low, high) if low <= high else None


def draw_side(ax: Any, cfg: Any, state: WorldState, extent: tuple[float, float, float, float]) -> None:
    """The side view of a 3-D world (section 11): altitude against ``s``, the distance from the
    area's centre along :func:`side_axis`, in the vertical plane through that line. Obstacles
    appear as their sections by the plane (solid red); cylinders and spheres within the laser's
    range of the plane but not cut by it as faded silhouettes. The ground and the ceiling are grey
    lines, the goal green, the UAVs (projected onto the plane) blue dots."""
    u = side_axis(cfg, state)
    centre = np.asarray(cfg.area_center, dtype=float)
    ground, ceiling = cfg.altitude
    half_range = (extent[1] - extent[0]) / 2

    def along(xy: Any) -> tuple[float, float]:
        offset = np.asarray(xy, dtype=float)[:2] - centre
        return float(offset @ u), float(abs(offset[0] * u[1] - offset[1] * u[0]))

    def block(s0: float, s1: float, z0: float, z1: float, alpha: float = 0.85) -> None:
        s0, s1 = max(s0, -half_range - 1.0), min(s1, half_range + 1.0)
        z0, z1 = max(z0, ground - 2.0), min(z1, ceiling + 2.0)
        if s1 > s0 and z1 > z0:
            ax.add_patch(Rectangle((s0, z0), s1 - s0, z1 - z0, facecolor=OBSTACLE_COLOR, edgecolor="none",
                                   alpha=alpha, zorder=1))

    cylinders = [*np.asarray(cfg.circles, dtype=float).reshape(-1, 5), *np.asarray(state.circles, float).reshape(-1, 5),
                 *[[*c, cfg.moving_radius, -1e6, 1e6] for c in np.asarray(state.moving, float).reshape(-1, 2)]]
    for cx, cy, r, z0, z1 in cylinders:
        s, lateral = along((cx, cy))
        if lateral < r:
            chord = math.sqrt(r * r - lateral * lateral)
            block(s - chord, s + chord, z0, z1)
        elif lateral < r + cfg.laser_range:
            block(s - r, s + r, z0, z1, alpha=0.15)
    boxes = [*np.asarray(cfg.rectangles, dtype=float).reshape(-1, 6), *np.asarray(state.rectangles, float)
             .reshape(-1, 6)]
    for box in boxes:
        section = _box_section(centre, u, box)
        if section is not None:
            block(section[0], section[1], box[4], box[5])
    for cx, cy, cz, r in [*np.asarray(cfg.spheres, dtype=float).reshape(-1, 4), *np.asarray(state.spheres, float)
                          .reshape(-1, 4)]:
        s, lateral = along((cx, cy))
        if lateral < r + cfg.laser_range:
            cut = lateral < r
            ax.add_patch(Circle((s, cz), math.sqrt(r * r - lateral * lateral) if cut else r,
                                facecolor=OBSTACLE_COLOR, edgecolor="none", alpha=0.85 if cut else 0.15, zorder=1))
    for z in (ground, ceiling):
        ax.axhline(z, color="0.5", lw=1.0, zorder=0)
    s_goal, _ = along(state.goal)
    ax.add_patch(Circle((s_goal, state.goal_altitude), cfg.goal_radius, facecolor=GOAL_COLOR, alpha=0.5, zorder=2))
    s_uav = (np.asarray(state.position, dtype=float) - centre) @ u
    ax.scatter(s_uav, state.altitude, s=8, color=UAV_COLOR, edgecolors="black", linewidths=0.3, zorder=4)
    ax.set_xlim(-half_range, half_range)
    ax.set_ylim(ground - 2.0, ceiling + 2.0)
    ax.set_xlabel("along the centre-to-goal line (m)", fontsize=6)
    ax.set_ylabel("altitude (m)", fontsize=6)
    ax.tick_params(labelsize=5)


# Where a 3-D frame's two views go, by what decides it (the pixels, the extent, the altitudes):
# matplotlib's constrained layout works it out for the first frame of a size; a GIF's other frames,
# whose axes and labels are the same, take its positions as they are (the last LAYOUTS_KEPT kept).
_LAYOUTS: dict[tuple, tuple[tuple[float, ...], tuple[float, ...]]] = {}
LAYOUTS_KEPT = 32


def frame_figure(cfg: Any, state: WorldState, extent: tuple[float, float, float, float], height: int, width: int,
                 show_fov: bool, title: str | None) -> Figure:
    """The frame as a figure of ``height x width`` pixels on an Agg canvas (:func:`frame_image`
    draws it and reads its pixels).

    2-D: the world fills it, no axes. 3-D: the top view (left, with its axes) and the side view
    (right), laid out by matplotlib's constrained layout, so that every axis label and tick label
    lies inside the picture at the sizes it is drawn at (``env.render``'s 512 x 512, a GIF's 400 x
    400 or 300 x 600)."""
    space = state.altitude is not None
    if not space:
        fig, canvas = _figure(height, width)
        ax = fig.add_axes((0, 0, 1, 1))
        draw_world(ax, cfg, state, extent, show_fov=show_fov)
    else:
        key = (height, width, tuple(float(e) for e in extent), tuple(float(a) for a in cfg.altitude))
        known = _LAYOUTS.get(key)
        fig, canvas = _figure(height, width, constrained=known is None)
        if known is None:
            ax, side = fig.subplots(1, 2, width_ratios=(1.0, 1.0))
        else:
            ax, side = fig.add_axes(known[0]), fig.add_axes(known[1])
        draw_side(side, cfg, state, extent)
        side.set_box_aspect(SIDE_ASPECT)
        draw_world(ax, cfg, state, extent, show_fov=show_fov)
        ax.set_axis_on()
        style_axes(ax, extent, None, axes=True)
        if known is None:
            canvas.draw()  # the layout engine places the views
            _LAYOUTS[key] = (ax.get_position(original=True).bounds, side.get_position(original=True).bounds)
            while len(_LAYOUTS) > LAYOUTS_KEPT:
                del _LAYOUTS[next(iter(_LAYOUTS))]
            fig.set_layout_engine("none")
    if title:
        ax.text(0.02, 0.98, title, transform=ax.transAxes, ha="left", va="top", fontsize=8)
    return fig


def frame_image(cfg: Any, state: WorldState, extent: tuple[float, float, float, float], height: int, width: int,
                show_fov: bool, title: str | None) -> np.ndarray:
    return _to_rgb(frame_figure(cfg, state, extent, height, width, show_fov, title).canvas, height, width)


# render_env(): the frame's options, and VMAS's display options TorchRL's scripts pass (ignored).
FRAME_OPTIONS = frozenset({"size", "extent", "show_fov", "title"})
VMAS_RENDER_OPTIONS = frozenset({"visualize_when_possible", "plot_position_function", "plot_position_function_range",
                                 "plot_position_function_cmap_range", "plot_position_function_cmap_alpha",
                                 "plot_position_function_precision", "plot_position_function_cmap_name"})


def render_env(env: Any, mode: str = "rgb_array", env_index: int = 0, agent_index_focus: int | None = None,
               **kwargs: Any) -> np.ndarray:
    """``FlockingEnv.render``: an RGB frame ``[H, W, 3]`` (uint8) of world ``env_index``: obstacles, goal,
    UAVs, headings, fields of view (``size``, ``extent``, ``show_fov``, ``title``: :func:`render_frame`).

    Takes the call TorchRL's multi-agent scripts make for VMAS,
    ``render(mode="rgb_array", agent_index_focus=None, visualize_when_possible=True)``:
    ``agent_index_focus`` centres a 20 m view on that UAV (``None``: the whole world); VMAS's other
    display options (:data:`VMAS_RENDER_OPTIONS`) have no meaning here and are ignored."""
    if mode != "rgb_array":
        raise ValueError(f"render mode {mode!r} is not supported; use 'rgb_array'")
    unknown = sorted(set(kwargs) - FRAME_OPTIONS - VMAS_RENDER_OPTIONS)
    if unknown:
        raise TypeError(f"render: unknown option(s) {unknown}; known: {sorted(FRAME_OPTIONS)} (and VMAS's "
                        f"{sorted(VMAS_RENDER_OPTIONS)}, ignored)")
    options = {k: v for k, v in kwargs.items() if k in FRAME_OPTIONS}
    if agent_index_focus is not None and "extent" not in options:
        x, y = env.world["position"][env_index, int(agent_index_focus), :2].tolist()
        options["extent"] = (x - 10.0, x + 10.0, y - 10.0, y + 10.0)
    return render_frame(env, env_index=env_index, **options)


def render_frame(env: Any, env_index: int = 0, size: int | tuple[int, int] = 512,
                 extent: tuple[float, float, float, float] | None = None, show_fov: bool = True,
                 title: str | None = None) -> np.ndarray:
    """The current state of env ``env_index`` as an RGB image.

    Args:
        env: a FlockingEnv (after ``reset``).
        size: pixels, ``S`` for ``S x S`` or ``(height, width)``.
        extent: ``(x0, x1, y0, y1)`` in metres (default: area, goal and UAVs, square).
        show_fov: draw the camera wedges.

    Returns:
        ``np.ndarray [H, W, 3]`` of ``uint8``.
    """
    if not 0 <= env_index < env.num_envs:
        raise IndexError(f"env_index {env_index} out of range for {env.num_envs} envs")
    height, width = image_size(size)
    state = env_state(env, env_index)
    return frame_image(env.cfg, state, extent or world_extent(env.cfg, [state]), height, width, show_fov, title)
