"""Pictures of the flocking world: env frames, trajectory plots (paper Fig. 5-6), GIFs, Fig. 4.

Everything draws with matplotlib's object API on an Agg canvas (no pyplot, no display, no
global state), so it runs headless and inside tests.

* :func:`render_frame` — one env now, as an RGB array (``FlockingEnv.render`` calls it):
  static and moving obstacles (red), the goal circle (green, radius ``goal_radius``), UAVs as
  triangles along their heading (blue) and their camera fields of view (wedges of radius
  ``camera_range`` and angle ``fov``).
* :func:`plot_trajectory` — one episode like the paper's Fig. 5: every UAV's path, the swarm
  as triangles at a few times, obstacles (moving ones at those times), goal.
* :func:`save_animation` — one episode as a GIF.
* :func:`plot_reward_curves` — training reward per policy, mean and 95 % band every 100
  episodes (paper Fig. 4), from CSV logs with columns ``episode,reward``.
* :func:`make_figures` — Fig. 4, 5 and 6 into ``figures/`` (``scripts/figures.py``).
"""

from __future__ import annotations

import csv
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

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
    ``goal [2]``, ``moving [K, 2]`` (moving circle centres, ``K = 0`` without them)."""

    position: np.ndarray
    heading: np.ndarray
    goal: np.ndarray
    moving: np.ndarray


def _np(x: torch.Tensor) -> np.ndarray:
    return x.detach().to("cpu", torch.float32).numpy()


def env_state(env: Any, env_index: int = 0) -> WorldState:
    """The current state of env ``env_index`` of a FlockingEnv."""
    moving = env.moving_position[env_index] if env.cfg.n_moving else torch.zeros(0, 2)
    return WorldState(_np(env.position[env_index]), _np(env.heading[env_index]), _np(env.goal[env_index]),
                      _np(moving))


def rollout_states(rollout: Any, env_index: int = 0) -> list[WorldState]:
    """The states of one env along a rollout TensorDict (``[B, T]`` or ``[T]``), from the start
    to its first ``done``: ``T_done + 1`` states."""
    td = rollout[env_index] if rollout.batch_dims == 2 else rollout
    done = td["next", "done"].reshape(-1)
    last = int(done.nonzero()[0]) if bool(done.any()) else done.numel() - 1
    td = td[: last + 1]

    def track(key: tuple[str, ...]) -> torch.Tensor:
        return torch.cat((td[key][:1], td["next", *key]), 0)

    position, heading = track(("agents", "position")), track(("agents", "heading"))
    goal = td["goal"][0]
    if ("obstacles", "position") in td.keys(include_nested=True):
        moving = track(("obstacles", "position"))
    else:
        moving = torch.zeros(position.shape[0], 0, 2)
    return [WorldState(_np(position[t]), _np(heading[t]), _np(goal), _np(moving[t])) for t in range(position.shape[0])]


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
def draw_static(ax: Any, cfg: Any, goal: np.ndarray) -> None:
    """Static circles and rectangles (red) and the goal circle (green)."""
    for cx, cy, r in cfg.circles:
        ax.add_patch(Circle((cx, cy), r, facecolor=OBSTACLE_COLOR, edgecolor="none", alpha=0.85, zorder=1))
    for cx, cy, w, h in cfg.rectangles:
        ax.add_patch(Rectangle((cx - w / 2, cy - h / 2), w, h, facecolor=OBSTACLE_COLOR, edgecolor="none",
                               alpha=0.85, zorder=1))
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


def draw_fov(ax: Any, position: np.ndarray, heading: np.ndarray, radius: float, fov: float) -> None:
    """Camera fields of view: wedges of ``radius`` and opening angle ``fov`` about each heading."""
    for (x, y), h in zip(position.reshape(-1, 2), heading.reshape(-1)):
        if fov >= 2 * math.pi - 1e-6:
            patch: Any = Circle((x, y), radius)
        else:
            patch = Wedge((x, y), radius, math.degrees(h - fov / 2), math.degrees(h + fov / 2))
        patch.set(facecolor=FOV_COLOR, edgecolor=FOV_COLOR, alpha=0.12, lw=0.5, zorder=3)
        ax.add_patch(patch)


def _style(ax: Any, extent: tuple[float, float, float, float], title: str | None, axes: bool = True) -> None:
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
    """One instant of the world into ``ax``: obstacles, goal, fields of view, UAVs."""
    draw_static(ax, cfg, state.goal)
    if state.moving.size:
        draw_moving(ax, cfg, state.moving)
    if show_fov:
        draw_fov(ax, state.position, state.heading, cfg.camera_range, cfg.fov)
    draw_uavs(ax, state.position, state.heading, length=(extent[1] - extent[0]) / 60)
    _style(ax, extent, title, axes=False)


def _hw(size: int | tuple[int, int]) -> tuple[int, int]:
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


def _frame(cfg: Any, state: WorldState, extent: tuple[float, float, float, float], height: int, width: int,
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
    height, width = _hw(size)
    state = env_state(env, env_index)
    return _frame(env.cfg, state, extent or world_extent(env.cfg, [state]), height, width, show_fov, title)


# ---------------------------------------------------------------------------- saving
def _save_figure(fig: Figure, path: str | os.PathLike) -> Path:
    """``fig.savefig`` through a temporary file and ``os.replace`` (never a half-written file)."""
    from .evaluation import replace_atomic

    FigureCanvasAgg(fig)
    path = Path(path)
    return replace_atomic(path, lambda tmp: fig.savefig(tmp, dpi=fig.dpi, bbox_inches="tight",
                                                       format=(path.suffix or ".png")[1:]))


def plot_trajectory(rollout_td: Any, env: Any, env_index: int = 0, path: str | os.PathLike | None = None,
                    title: str | None = None, ax: Any = None, n_snapshots: int = 5,
                    extent: tuple[float, float, float, float] | None = None) -> Figure:
    """One episode like the paper's Fig. 5: every UAV's path, the swarm as triangles at
    ``n_snapshots`` evenly spaced times (labelled ``t = ... s``), static obstacles, moving
    obstacles at those same times, the goal.

    Args:
        rollout_td: a rollout TensorDict (``[B, T]`` or ``[T]``, e.g. ``env.rollout(...)`` or
            :func:`~flock_torchrl.evaluation.rollout_episode`), cut at the env's first done.
        env: the env that produced it (for its config).
        path: save a PNG there (atomically) when given.
        ax: draw into this axes (a panel of a grid) instead of a new figure.

    Returns:
        the figure.
    """
    cfg = env.cfg
    states = rollout_states(rollout_td, env_index)
    extent = extent or world_extent(cfg, states)
    if ax is None:
        fig = Figure(figsize=(5, 5), dpi=DPI)
        ax = fig.add_subplot(1, 1, 1)
    else:
        fig = ax.figure
    draw_static(ax, cfg, states[0].goal)
    times = sorted({int(round(t)) for t in np.linspace(0, len(states) - 1, max(2, n_snapshots))})
    if states[0].moving.size:
        for i, t in enumerate(times):
            draw_moving(ax, cfg, states[t].moving, alpha=0.15 + 0.5 * i / max(1, len(times) - 1),
                        label=f"{t * cfg.dt:.0f}s")
    tracks = np.stack([s.position for s in states])  # [T+1, N, 2]
    colors = [f"C{i % 10}" for i in range(tracks.shape[1])]
    for i in range(tracks.shape[1]):
        ax.plot(tracks[:, i, 0], tracks[:, i, 1], color=colors[i], lw=0.8, alpha=0.8, zorder=3)
    length = (extent[1] - extent[0]) / 50
    for t in times:
        s = states[t]
        draw_uavs(ax, s.position, s.heading, length)
        centre = s.position.mean(0)
        ax.annotate(f"t={t * cfg.dt:.0f}s", (centre[0], centre[1] + 2.2 * length), ha="center", fontsize=6, zorder=5)
    _style(ax, extent, title)
    if path is not None:
        _save_figure(fig, path)
    return fig


def save_animation(rollout_td: Any, env: Any, path: str | os.PathLike, env_index: int = 0, fps: float | None = None,
                   size: int | tuple[int, int] = 400, stride: int = 1, show_fov: bool = True) -> Path:
    """One episode of a rollout as a GIF (one frame per ``stride`` steps, fixed extent)."""
    import imageio.v2 as imageio

    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    height, width = _hw(size)
    states = rollout_states(rollout_td, env_index)
    extent = world_extent(env.cfg, states)
    idx = list(range(0, len(states), stride))
    if idx[-1] != len(states) - 1:
        idx.append(len(states) - 1)
    frames = [_frame(env.cfg, states[t], extent, height, width, show_fov, f"t = {t * env.cfg.dt:.1f} s") for t in idx]
    fps = fps or env.metadata.get("render_fps", 5) * stride
    from .evaluation import replace_atomic

    return replace_atomic(path, lambda tmp: imageio.mimsave(tmp, frames, format="GIF", duration=1000.0 / fps,
                                                            loop=0))


# ---------------------------------------------------------------------------- grids
def trajectory_grid(panels: Sequence[tuple[str, Any, Any] | tuple[str, None, str]], ncols: int,
                    path: str | os.PathLike | None = None, suptitle: str | None = None,
                    panel_size: float = 3.2) -> Figure:
    """A grid of :func:`plot_trajectory` panels.

    Args:
        panels: ``(title, rollout_td, env)`` per panel, or ``(title, None, reason)`` for a panel
            with nothing to show (the reason is written in it).
    """
    import textwrap

    nrows = max(1, math.ceil(len(panels) / ncols))
    fig = Figure(figsize=(panel_size * ncols, panel_size * nrows), dpi=DPI, layout="constrained")
    for i, (title, rollout, env) in enumerate(panels):
        ax = fig.add_subplot(nrows, ncols, i + 1)
        if rollout is None:
            ax.text(0.5, 0.5, textwrap.fill(str(env), 30), ha="center", va="center", fontsize=7,
                    transform=ax.transAxes)
            ax.set_title(title, fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_box_aspect(1)
        else:
            plot_trajectory(rollout, env, ax=ax, title=title)
    if suptitle:
        fig.suptitle(suptitle)
    if path is not None:
        _save_figure(fig, path)
    return fig


# ---------------------------------------------------------------------------- Fig. 4
def read_reward_log(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """``(episode, reward)`` arrays from a CSV with (at least) columns ``episode,reward``."""
    episodes, rewards = [], []
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        if not reader.fieldnames or not {"episode", "reward"} <= set(reader.fieldnames):
            raise ValueError(f"{path}: expected columns episode,reward, got {reader.fieldnames}")
        for row in reader:
            try:
                e, r = float(row["episode"]), float(row["reward"])
            except (TypeError, ValueError):
                continue
            if math.isfinite(e) and math.isfinite(r):
                episodes.append(e)
                rewards.append(r)
    return np.asarray(episodes), np.asarray(rewards)


def binned_mean_ci(episodes: np.ndarray, rewards: np.ndarray, bin_size: int = 100,
                   z: float = 1.959963984540054) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean reward per block of ``bin_size`` episodes and its 95 % normal confidence half-width
    (``z * std / sqrt(n)``; 0 for a block of one): ``(block end episode, mean, half_width)``."""
    if episodes.size == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    block = np.floor((episodes - 1).clip(min=0) / bin_size).astype(int)  # episodes 1..100 -> block 0
    ends, means, halves = [], [], []
    for b in np.unique(block):
        r = rewards[block == b]
        ends.append((b + 1) * bin_size)
        means.append(r.mean())
        halves.append(z * r.std(ddof=1) / math.sqrt(r.size) if r.size > 1 else 0.0)
    return np.asarray(ends, float), np.asarray(means), np.asarray(halves)


def plot_reward_curves(curves: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]],
                       path: str | os.PathLike | None = None, bin_size: int = 100,
                       title: str | None = "Training reward (mean and 95 % CI per 100 episodes)") -> Figure:
    """Paper Fig. 4: per policy, the reward of all its runs pooled in blocks of ``bin_size``
    episodes, mean line and 95 % band.

    Args:
        curves: policy name -> ``[(episode, reward), ...]``, one pair of arrays per run (seed).
    """
    fig = Figure(figsize=(7, 4.5), dpi=DPI, layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    for i, (name, runs) in enumerate(curves.items()):
        if not runs:
            continue
        episodes = np.concatenate([e for e, _ in runs])
        rewards = np.concatenate([r for _, r in runs])
        x, mean, half = binned_mean_ci(episodes, rewards, bin_size)
        label = f"{name} ({len(runs)} run{'s' if len(runs) > 1 else ''})"
        ax.plot(x, mean, color=f"C{i % 10}", lw=1.2, label=label, marker="o" if x.size < 3 else None, ms=3)
        ax.fill_between(x, mean - half, mean + half, color=f"C{i % 10}", alpha=0.2, lw=0)
    ax.set_xlabel("episode")
    ax.set_ylabel("episode reward")
    if title:
        ax.set_title(title, fontsize=10)
    if ax.lines:
        ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    if path is not None:
        _save_figure(fig, path)
    return fig


def find_reward_logs(runs_dir: str | os.PathLike, experiment: str | None = None) -> dict[str, list[Path]]:
    """Training logs under ``runs_dir`` (``runs/<experiment>/<policy>/seed<k>/...``): every CSV
    with columns ``episode`` and ``reward``, grouped by the policy folder in its path (paper
    names). Only ``experiment``'s runs when given; when runs of several experiments are found,
    each group is labelled ``"<policy> (<experiment>)"`` so that they are not pooled."""
    from .evaluation import available_policies, load_policy_config

    stems = set(available_policies())
    root = Path(runs_dir)
    if not root.is_dir():
        return {}
    groups: dict[tuple[str, str], list[Path]] = {}
    for p in sorted(root.rglob("*.csv")):
        parts = p.relative_to(root).parts[:-1]
        at = next((i for i, part in enumerate(parts) if part in stems), None)
        if at is None:
            continue
        exp = parts[at - 1] if at > 0 else ""
        if experiment is not None and exp != experiment:
            continue
        try:
            with open(p, newline="") as fh:
                header = next(csv.reader(fh), [])
        except OSError:
            continue
        if {"episode", "reward"} <= set(header):
            groups.setdefault((load_policy_config(parts[at])["name"], exp), []).append(p)
    several = len({exp for _, exp in groups}) > 1
    return {(f"{name} ({exp})" if several else name): paths for (name, exp), paths in groups.items()}


# ---------------------------------------------------------------------------- the figures
FIG6_SCENARIOS = ("s1", "s2", "s3", "s4", "s5")
FIG6_POLICIES = ("Policy3-G", "PolicyD-G", "PolicyP-G", "Policy-MA", "Policy-OP")


def _first_run(name: str, checkpoint_dir: Any, overrides: Mapping[str, Any] | None) -> tuple[Any, str]:
    from .evaluation import policy_runs

    runs, note = policy_runs(name, checkpoint_dir, overrides)
    return (runs[0][1], runs[0][0]) if runs else (None, note)


def _panel(title: str, name: str, scenario: str, seed: int, device: str, checkpoint_dir: Any,
           overrides: Mapping[str, Any] | None, log: Callable[[str], None]) -> tuple[str, Any, Any]:
    from .evaluation import load_policy_config, policy_source, rollout_episode

    policy, label = _first_run(name, checkpoint_dir, overrides)
    if policy is None:
        log(f"  {title}: {label}")
        return title, None, label.replace("skipped: ", "").split(" (train it")[0]
    try:
        source = policy_source(policy, device=device, checkpoint_dir=checkpoint_dir)
        try:
            source.env = {**load_policy_config(name)["env"], **source.env}
        except Exception:
            pass
        rollout, env = rollout_episode(source, scenario, seed=seed, device=device, checkpoint_dir=checkpoint_dir)
    except Exception as exc:  # one broken policy should not cost the whole figure
        log(f"  {title}: failed: {exc}")
        return title, None, f"failed: {exc}"
    ep = rollout["next", "episode"][0, -1]
    outcome = "reached" if bool(ep["success"]) else "crashed" if bool(ep["crashed"]) else "timeout"
    log(f"  {title}: {label}, {rollout.shape[-1]} steps, {outcome}")
    return f"{title} ({outcome})", rollout, env


def make_figures(figs: Sequence[int] = (4, 5, 6), runs_dir: str | os.PathLike = "runs",
                 checkpoint_dir: str | os.PathLike = "checkpoints", out_dir: str | os.PathLike = "figures",
                 seed: int | None = None, device: str = "cpu", policies: Mapping[str, Any] | None = None,
                 experiment: str | None = None, log: Callable[[str], None] = print) -> list[Path]:
    """Write the paper's figures that the available runs and checkpoints allow.

    * ``fig4_rewards.png``: training reward curves (CSV logs under ``runs_dir``, only those of
      ``experiment`` if given).
    * ``fig5_trajectories.png``: one seeded training-scenario episode per policy (3 x 4 grid).
    * ``fig6_generalization.png``: one seeded episode per scenario S1-S5 (rows) and policy
      (Policy3-G, PolicyD-G, PolicyP-G, Policy-MA, Policy-OP; columns).

    Missing checkpoints, baselines or logs are skipped with a message (an empty panel says
    why). Learned policies use their lowest-seed checkpoint. Returns the files written.
    """
    from .evaluation import EVAL_SEED
    from .tables import table_entries

    seed = EVAL_SEED if seed is None else seed
    out = Path(out_dir)
    written: list[Path] = []
    if 4 in figs:
        logs = find_reward_logs(runs_dir, experiment)
        if not logs:
            log(f"Fig. 4: skipped, no CSV with columns episode,reward under "
                f"{runs_dir}/{experiment or '<experiment>'}/<policy>/seed<k>/")
        else:
            curves: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
            for name, paths in logs.items():
                runs = []
                for p in paths:
                    try:
                        episodes, rewards = read_reward_log(p)
                    except (OSError, ValueError) as exc:
                        log(f"Fig. 4: skipping {p}: {exc}")
                        continue
                    if episodes.size == 0:
                        log(f"Fig. 4: skipping {p}: no finished episode logged yet")
                        continue
                    runs.append((episodes, rewards))
                if runs:
                    curves[name] = runs
                    log(f"Fig. 4: {name}: {len(runs)} run(s), {sum(e.size for e, _ in runs)} episodes")
            if curves:
                plot_reward_curves(curves, out / "fig4_rewards.png")
                written.append(out / "fig4_rewards.png")
            else:
                log("Fig. 4: skipped, the logs hold no finished episode")
    if 5 in figs:
        log("Fig. 5: one training-scenario episode per policy")
        names = [e.policy for e in table_entries(3)]
        panels = [_panel(n, n, "train", seed, device, checkpoint_dir, policies, log) for n in names]
        if any(p[1] is not None for p in panels):
            trajectory_grid(panels, ncols=4, path=out / "fig5_trajectories.png",
                            suptitle=f"Training scenario, seed {seed}")
            written.append(out / "fig5_trajectories.png")
        else:
            log("Fig. 5: skipped, no policy available")
    if 6 in figs:
        log("Fig. 6: one episode per scenario and policy")
        panels = [_panel(f"S{s[-1]} {n}", n, s, seed, device, checkpoint_dir, policies, log)
                  for s in FIG6_SCENARIOS for n in FIG6_POLICIES]
        if any(p[1] is not None for p in panels):
            trajectory_grid(panels, ncols=len(FIG6_POLICIES), path=out / "fig6_generalization.png",
                            suptitle=f"Generalisation scenarios S1-S5, seed {seed}")
            written.append(out / "fig6_generalization.png")
        else:
            log("Fig. 6: skipped, no policy available")
    for p in written:
        log(f"wrote {p}")
    return written


def figures_main(argv: Sequence[str]) -> int:
    """``scripts/figures.py``: ``key=value`` arguments (figs, runs, checkpoints, out, seed, device,
    threads) -> :func:`make_figures`; returns the exit status (2 for bad arguments)."""
    from .evaluation import EVAL_SEED

    options = {"figs": "4,5,6", "runs": "runs", "experiment": "", "checkpoints": "checkpoints", "out": "figures",
               "seed": str(EVAL_SEED), "device": "cpu", "threads": "1"}
    if any(a in ("-h", "--help", "help") for a in argv):
        print("keys: " + ", ".join(f"{k}={v}" for k, v in options.items()))
        return 0
    try:
        for arg in argv:
            key, sep, value = arg.lstrip("-").partition("=")
            if not sep or key not in options:
                raise ValueError(f"expected key=value with key in {sorted(options)}, got {arg!r}")
            options[key] = value
        figs = [int(f) for f in options["figs"].split(",") if f.strip()]
        if not figs or any(f not in (4, 5, 6) for f in figs):
            raise ValueError(f"figs: a comma-separated list of 4, 5, 6, got {options['figs']!r}")
        seed, threads = int(options["seed"]), int(options["threads"])
    except ValueError as exc:
        print(f"figures.py: {exc}", file=sys.stderr)
        return 2
    if threads > 0:
        torch.set_num_threads(threads)
    make_figures(figs, runs_dir=options["runs"], checkpoint_dir=options["checkpoints"], out_dir=options["out"],
                 seed=seed, device=options["device"], experiment=options["experiment"] or None,
                 log=lambda m: print(m, flush=True))
    return 0
