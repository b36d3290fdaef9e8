"""Drawing one instant of the world: the frame ``FlockingEnv.render`` returns.

Matplotlib's object API on an Agg canvas (no pyplot, no display, no global state), so it runs
headless and inside tests: fixed, moving and drawn obstacles (red; each world's own), the goal circle (green, radius
``goal_radius``), UAVs as triangles along their heading (blue) and their camera fields of view
(wedges of radius ``camera_range`` reaching ``half_fov`` either side of the heading). Whole
episodes and the paper's figures are drawn by :mod:`flock_torchrl.report.figures`.
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


def _np(x: torch.Tensor) -> np.ndarray:
    return x.detach().to("cpu", torch.float32).numpy()


def env_state(env: Any, env_index: int = 0) -> WorldState:
    """The current state of env ``env_index`` of a FlockingEnv."""
    world = env.world[env_index]
    return WorldState(_np(world["position"]), _np(world["heading"]), _np(world["goal"]),
                      _np(world["moving_position"]), _np(world["drawn_circles"]), _np(world["drawn_rectangles"]))


def rollout_states(rollout: Any, env_index: int = 0) -> list[WorldState]:
    """The states of one env along a rollout TensorDict (``[B, T]`` or ``[T]``), from the start
    to its first ``done``: ``T_done + 1`` states."""
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
    drawn = {name: _np(td["obstacles", f"drawn_{name}"][0]) for name in ("circles", "rectangles")
             if ("obstacles", f"drawn_{name}") in keys}
    return [WorldState(_np(position[t]), _np(heading[t]), _np(goal), _np(moving[t]), **drawn)
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
    """Circles ``[C, 3]`` (cx, cy, r) and axis-aligned rectangles ``[R, 4]`` (cx, cy, w, h), red."""
    for cx, cy, r in np.asarray(circles, dtype=float).reshape(-1, 3):
        ax.add_patch(Circle((cx, cy), r, facecolor=OBSTACLE_COLOR, edgecolor="none", alpha=0.85, zorder=1))
    for cx, cy, w, h in np.asarray(rectangles, dtype=float).reshape(-1, 4):
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


def draw_uavs(ax: Any, position: np.ndarray, heading: np.ndarray, length: float, color: str = UAV_COLOR,
              alpha: float = 1.0) -> None:
    """UAVs as isosceles triangles of ``length`` pointing along their heading."""
    for (x, y), h in zip(position.reshape(-1, 2), heading.reshape(-1)):
        tip = (x + length * math.cos(h), y + length * math.sin(h))
        back = [(x + 0.6 * length * math.cos(h + s * 2.5), y + 0.6 * length * math.sin(h + s * 2.5)) for s in (1, -1)]
        ax.add_patch(Polygon([tip, *back], closed=True, facecolor=color, edgecolor="black", lw=0.4, alpha=alpha,
                             zorder=4))


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
               show_fov: bool = True, title: str | None = None) -> None:
    """One instant of the world into ``ax``: obstacles (the world's drawn ones too), goal, fields
    of view, UAVs."""
    draw_static(ax, cfg, state.goal)
    draw_obstacles(ax, state.circles, state.rectangles)
    if state.moving.size:
        draw_moving(ax, cfg, state.moving)
    if show_fov:
        draw_fov(ax, state.position, state.heading, cfg.camera_range, cfg.half_fov)
    draw_uavs(ax, state.position, state.heading, length=(extent[1] - extent[0]) / 60)
    style_axes(ax, extent, title, axes=False)


def image_size(size: int | tuple[int, int]) -> tuple[int, int]:
    h, w = (size, size) if isinstance(size, int) else size
    if h < 16 or w < 16:
        raise ValueError(f"size must be at least 16 pixels per side, got {size!r}")
    return int(h), int(w)


def _figure(height: int, width: int) -> tuple[Figure, FigureCanvasAgg]:
    fig = Figure(figsize=(width / DPI, height / DPI), dpi=DPI)
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


def frame_image(cfg: Any, state: WorldState, extent: tuple[float, float, float, float], height: int, width: int,
           show_fov: bool, title: str | None) -> np.ndarray:
    fig, canvas = _figure(height, width)
    ax = fig.add_axes((0, 0, 1, 1))
    draw_world(ax, cfg, state, extent, show_fov=show_fov)
    if title:
        ax.text(0.02, 0.98, title, transform=ax.transAxes, ha="left", va="top", fontsize=8)
    return _to_rgb(canvas, height, width)


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
