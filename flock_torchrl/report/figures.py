"""The paper's figures: trajectory plots (Fig. 5-6), training curves (Fig. 4), animations.

Drawing one instant lives in :mod:`flock_torchrl.world.frame`; this module draws whole
episodes and grids of them, with matplotlib's object API (headless, no global state).

:func:`plot_trajectory` draws one episode as Fig. 5 does, :func:`save_animation` one as a GIF,
:func:`plot_reward_curves` the training reward of Fig. 4 (from the curves the checkpoints carry),
and :func:`make_figures` Fig. 4, 5 and 6 of one reading into a folder (``scripts/figures.py``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..io import atomic_write, write_text
from ..policies.checkpoint import load_checkpoint
from ..policies.registry import shipped_checkpoints
from ..config import FiguresConfig
from ..run.rollout import rollout_episode
from ..run.batches import EPISODE_COLUMNS
from ..world.frame import (DPI, draw_moving, draw_obstacles, draw_static, draw_uavs, frame_image, image_size, rollout_states,
                           style_axes, world_extent)
from .reference import PAPER_RECIPE_ROW, table_entries


def save_figure(fig: Figure, path: str | os.PathLike) -> Path:
    """``fig.savefig`` atomically (never a half-written file)."""
    FigureCanvasAgg(fig)
    path = Path(path)
    return atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=fig.dpi, bbox_inches="tight",
                                                     format=(path.suffix or ".png")[1:]))


def plot_trajectory(rollout_td: Any, env: Any, env_index: int = 0, path: str | os.PathLike | None = None,
                    title: str | None = None, ax: Any = None, n_snapshots: int = 5) -> Figure:
    """One episode like the paper's Fig. 5: every UAV's path, the swarm as triangles at
    ``n_snapshots`` evenly spaced times (labelled ``t = ... s``), static obstacles, moving
    obstacles at those same times, the goal.

    Args:
        rollout_td: a rollout TensorDict (``[B, T]`` or ``[T]``, e.g. ``env.rollout(...)`` or
            :func:`~flock_torchrl.run.evaluation.rollout_episode`), cut at the env's first done.
        env: the env that produced it (for its config).
        path: save a PNG there (atomically) when given.
        ax: draw into this axes (a panel of a grid) instead of a new figure (returned either way).
    """
    cfg = env.cfg
    states = rollout_states(rollout_td, env.cfg, env_index)
    extent = world_extent(cfg, states)
    if ax is None:
        fig = Figure(figsize=(5, 5), dpi=DPI)
        ax = fig.add_subplot(1, 1, 1)
    else:
        fig = ax.figure
    draw_static(ax, cfg, states[0].goal)
    draw_obstacles(ax, states[0].circles, states[0].rectangles)  # the episode's drawn obstacles (forest)
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
    style_axes(ax, extent, title)
    if path is not None:
        save_figure(fig, path)
    return fig


def save_animation(rollout_td: Any, env: Any, path: str | os.PathLike, env_index: int = 0,
                   size: int | tuple[int, int] = 400, stride: int = 1) -> Path:
    """One episode of a rollout as a GIF (one frame per ``stride`` steps, fixed extent)."""
    import imageio.v2 as imageio

    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    height, width = image_size(size)
    states = rollout_states(rollout_td, env.cfg, env_index)
    extent = world_extent(env.cfg, states)
    idx = list(range(0, len(states), stride))
    if idx[-1] != len(states) - 1:
        idx.append(len(states) - 1)
    frames = [frame_image(env.cfg, states[t], extent, height, width, True, f"t = {t * env.cfg.dt:.1f} s") for t in idx]
    fps = env.metadata.get("render_fps", 5) * stride
    return atomic_write(path, lambda tmp: imageio.mimsave(tmp, frames, format="GIF", duration=1000.0 / fps,
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
        save_figure(fig, path)
    return fig


# ---------------------------------------------------------------------------- Fig. 4
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
                       title: str | None = "Training reward (mean and 95 % CI per 100 episodes)",
                       highlight: Sequence[str] = ()) -> Figure:
    """Paper Fig. 4: per policy, the reward of all its runs pooled in blocks of ``bin_size``
    episodes, mean line and 95 % band.

    Args:
        curves: policy name -> ``[(episode, reward), ...]``, one pair of arrays per run (seed).
        highlight: names drawn black and dashed (e.g. the paper recipe's run beside the others).
            When a curve runs ten times longer than the shortest, the episode axis is
            logarithmic, so that both stay readable.
    """
    fig = Figure(figsize=(7, 4.5), dpi=DPI, layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    lengths = []
    for i, (name, runs) in enumerate(curves.items()):
        if not runs:
            continue
        episodes = np.concatenate([e for e, _ in runs])
        rewards = np.concatenate([r for _, r in runs])
        x, mean, half = binned_mean_ci(episodes, rewards, bin_size)
        lengths.append(x.max())
        label = f"{name} ({len(runs)} run{'s' if len(runs) > 1 else ''})"
        color, style, band = ("k", "--", 0.1) if name in highlight else (f"C{i % 10}", "-", 0.2)
        ax.plot(x, mean, color=color, ls=style, lw=1.2, label=label, marker="o" if x.size < 3 else None, ms=3)
        ax.fill_between(x, mean - half, mean + half, color=color, alpha=band, lw=0)
    if lengths and max(lengths) >= 10 * min(lengths):
        ax.set_xscale("log")
    ax.set_xlabel("episode")
    ax.set_ylabel("episode reward")
    if title:
        ax.set_title(title, fontsize=10)
    if ax.lines:
        ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    if path is not None:
        save_figure(fig, path)
    return fig


def training_curve(path: str | os.PathLike, column: str = "reward") -> tuple[np.ndarray, np.ndarray]:
    """``(episode, column)`` of a checkpoint's training curve (one row per finished episode;
    ``column`` one of the trainer's ``EPISODE_COLUMNS``, e.g. ``success``)."""
    if column not in EPISODE_COLUMNS:
        raise ValueError(f"training_curve: column must be one of {EPISODE_COLUMNS}, got {column!r}")
    curve = load_checkpoint(path).get("curve")
    if curve is None or curve.numel() == 0:
        return np.zeros(0), np.zeros(0)
    curve = curve.numpy()
    return curve[:, EPISODE_COLUMNS.index("episode")], curve[:, EPISODE_COLUMNS.index(column)]


# How Fig. 4's table measures convergence: the first block of 100 training episodes whose
# success rate reaches 90 % (the paper: Policy4-G "has a slower convergence rate").
CONVERGENCE_BLOCK = 100
CONVERGENCE_SUCCESS = 0.9


def first_block_reaching(episodes: np.ndarray, values: np.ndarray, threshold: float,
                         bin_size: int = CONVERGENCE_BLOCK) -> float:
    """The last episode of the first block of ``bin_size`` episodes (as :func:`binned_mean_ci`
    blocks them) whose mean value reaches ``threshold``; ``nan`` if none does."""
    ends, means, _ = binned_mean_ci(episodes, values, bin_size)
    hit = np.flatnonzero(means >= threshold)
    return float(ends[hit[0]]) if hit.size else math.nan


def convergence_markdown(collections: Mapping[str, Mapping[str, Sequence[Path]]]) -> str:
    """Fig. 4's convergence table: per collection (title -> policy -> checkpoints), per run,
    the episodes trained, the first block of 100 whose training success reaches 90 %, and the
    success over its last 100 training episodes."""
    lines = ["# Fig. 4: convergence of the training runs", "",
             f"Per run, from the training curve its checkpoint carries: the last episode of the first block of "
             f"{CONVERGENCE_BLOCK} training episodes whose success rate reaches {CONVERGENCE_SUCCESS:.0%} "
             f"(— where none does), and the success rate over its last {CONVERGENCE_BLOCK}. Training "
             f"episodes explore (stochastic actions); the tables evaluate deterministic ones."]
    for title, runs in collections.items():
        lines += ["", f"**{title}**", "", f"| policy | run | episodes | success >= {CONVERGENCE_SUCCESS:.0%} from "
                  f"episode | success, last {CONVERGENCE_BLOCK} |", "|---|---|---|---|---|"]
        for name, paths in runs.items():
            for path in paths:
                episodes, success = training_curve(path, "success")
                if not episodes.size:
                    continue
                first = first_block_reaching(episodes, success, CONVERGENCE_SUCCESS)
                reached = "—" if math.isnan(first) else f"{first:.0f}"
                lines.append(f"| {name} | {Path(path).stem} | {episodes.size} | {reached} | "
                             f"{100 * success[-CONVERGENCE_BLOCK:].mean():.1f} % |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- the figures
FIG6_SCENARIOS = ("s1", "s2", "s3", "s4", "s5")
FIG6_POLICIES = ("Policy3-G", "PolicyD-G", "PolicyP-G", "Policy-MA", "Policy-OP")


def _panel(title: str, name: str, scenario: str, reading: str, seed: int, device: str, checkpoints_dir: Any,
           log: Callable[[str], None]) -> tuple[str, Any, Any]:
    try:
        rollout, env = rollout_episode(name, scenario, reading, seed=seed, device=device,
                                       checkpoints_dir=checkpoints_dir)
    except Exception as exc:  # one missing or broken policy must not cost the whole figure
        log(f"  {title}: skipped: {exc}")
        return title, None, f"not available: {str(exc).split(';')[0]}"
    ep = rollout["next", "episode"][0, -1]
    outcome = "reached" if bool(ep["success"]) else "crashed" if bool(ep["crashed"]) else "timeout"
    log(f"  {title}: {rollout.shape[-1]} steps, {outcome}")
    return f"{title} ({outcome})", rollout, env


def check_figure_inputs(reading: str, figs: Sequence[int], checkpoints_dir: str | os.PathLike) -> None:
    """Every shipped checkpoint the figures read, opened and digest-checked before anything is drawn."""
    folder = Path(checkpoints_dir) / reading
    for name in dict.fromkeys(e.policy for e in table_entries(3)):
        for path in shipped_checkpoints(name, folder):
            load_checkpoint(path)


def _curves(names: Sequence[str], folder: Path) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """Training curves (episode, reward) of each policy's checkpoints in a collection folder."""
    curves = {}
    for name in names:
        runs = [training_curve(p) for p in shipped_checkpoints(name, folder)]
        runs = [r for r in runs if r[0].size]
        if runs:
            curves[name] = runs
    return curves


def make_figures(cfg: FiguresConfig, out_dir: str | os.PathLike, log: Callable[[str], None] = print) -> list[Path]:
    """``conf/figures.yaml``'s app: the paper's figures ``cfg.figs`` of the reading
    ``cfg.scenario.reading`` into ``out_dir``, from ``cfg.checkpoints_dir`` (and
    ``cfg.paper_recipe_dir``), episodes seeded ``cfg.seed``. Build ``cfg`` with
    :func:`flock_torchrl.config.app_config`, e.g. ``app_config("figures", reading="literal", figs=[4])``.

    * ``fig4_rewards.png``: training reward per learned policy, all its shipped seeds pooled
      (the checkpoints carry their training curves), the paper recipe's Policy3-G dashed beside
      them; ``fig4_paper_recipe.png``: the same for every policy trained with the paper's recipe
      (the recipe of the paper's own Fig. 4); ``fig4_convergence.md``: per run of both, the
      first block of 100 training episodes at 90 % success (:func:`convergence_markdown`).
    * ``fig5_trajectories.png``: one seeded training-scenario episode per policy (3 x 4 grid),
      and Policy3-G's as an animation, ``policy3_g_train.gif``.
    * ``fig6_generalization.png``: one seeded episode per scenario S1-S5 (rows) and policy
      (Policy3-G, PolicyD-G, PolicyP-G, Policy-MA, Policy-OP; columns).

    Missing checkpoints are skipped with a message (an empty panel says why).
    """
    reading, figs, seed, device = cfg.scenario.reading, list(cfg.figs), cfg.seed, cfg.device
    checkpoints_dir, paper_recipe_dir = cfg.checkpoints_dir, cfg.paper_recipe_dir
    out = Path(out_dir)
    written: list[Path] = []
    names = [e.policy for e in table_entries(3)]
    paper = _curves(names, Path(paper_recipe_dir)) if paper_recipe_dir is not None else {}
    if 4 in figs:
        collections = {f"{reading}, shipped (`fast`) checkpoints": Path(checkpoints_dir) / reading}
        if paper:
            collections[f"{reading}, the paper's recipe"] = Path(paper_recipe_dir)
        convergence = {title: {n: shipped_checkpoints(n, folder) for n in dict.fromkeys(names)}
                       for title, folder in collections.items()}
        curves = _curves(names, Path(checkpoints_dir) / reading)
        if "Policy3-G" in paper:
            curves[PAPER_RECIPE_ROW] = paper["Policy3-G"]
        if curves:
            for name, runs in curves.items():
                log(f"Fig. 4: {name}: {len(runs)} run(s), {sum(e.size for e, _ in runs)} episodes")
            plot_reward_curves(curves, out / "fig4_rewards.png", highlight=[PAPER_RECIPE_ROW],
                               title=f"Training reward ({reading}; mean and 95 % CI per 100 episodes)")
            written.append(out / "fig4_rewards.png")
        else:
            log(f"Fig. 4: skipped, no checkpoint under {checkpoints_dir}/{reading}/ carries a training curve")
        if paper:
            for name, runs in paper.items():
                log(f"Fig. 4, paper recipe: {name}: {len(runs)} run(s), {sum(e.size for e, _ in runs)} episodes")
            plot_reward_curves(paper, out / "fig4_paper_recipe.png",
                               title=f"Training reward, the paper's recipe ({reading}; mean and 95 % CI per 100 "
                                     "episodes)")
            written.append(out / "fig4_paper_recipe.png")
        if curves or paper:
            written.append(write_text(out / "fig4_convergence.md", convergence_markdown(convergence)))
    if 5 in figs:
        log("Fig. 5: one training-scenario episode per policy")
        panels = [_panel(n, n, "train", reading, seed, device, checkpoints_dir, log) for n in names]
        if any(p[1] is not None for p in panels):
            trajectory_grid(panels, ncols=4, path=out / "fig5_trajectories.png",
                            suptitle=f"Training scenario ({reading}), seed {seed}")
            written.append(out / "fig5_trajectories.png")
        method = next((p for p in panels if p[0].startswith("Policy3-G") and p[1] is not None), None)
        if method is not None:  # the paper's method, one episode as an animation
            written.append(save_animation(method[1], method[2], out / "policy3_g_train.gif", size=360, stride=2))
    if 6 in figs:
        log("Fig. 6: one episode per scenario and policy")
        panels = [_panel(f"S{s[-1]} {n}", n, s, reading, seed, device, checkpoints_dir, log)
                  for s in FIG6_SCENARIOS for n in FIG6_POLICIES]
        if any(p[1] is not None for p in panels):
            trajectory_grid(panels, ncols=len(FIG6_POLICIES), path=out / "fig6_generalization.png",
                            suptitle=f"Generalisation scenarios S1-S5 ({reading}), seed {seed}")
            written.append(out / "fig6_generalization.png")
    for path in written:
        log(f"wrote {path}")
    return written


__all__ = ["CONVERGENCE_BLOCK", "CONVERGENCE_SUCCESS", "FIG6_POLICIES", "FIG6_SCENARIOS", "binned_mean_ci",
           "check_figure_inputs", "convergence_markdown", "first_block_reaching", "make_figures", "plot_reward_curves",
           "plot_trajectory", "save_animation", "save_figure", "training_curve", "trajectory_grid"]
