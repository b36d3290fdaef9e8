"""Rendering: env frames, trajectory plots, GIFs and the Fig. 4 reward curves."""

from __future__ import annotations

import math

import imageio.v2 as imageio
import numpy as np
import pytest
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from flock_torchrl import FlockingEnv, app_config
from flock_torchrl.report.figures import (binned_mean_ci, first_block_reaching, make_figures, plot_trajectory, save_animation,
                                          training_curve, trajectory_grid)
from flock_torchrl.policies.scripted import goal_seeking_policy
from flock_torchrl.world.frame import render_frame, rollout_states


def _red(img: np.ndarray) -> np.ndarray:
    r, g, b = (img[..., i].astype(int) for i in range(3))
    return (r > 180) & (g < 120) & (b < 120)


@pytest.fixture(scope="module")
def s5_rollout():
    """Two S5 envs (static and moving obstacles) for 12 steps of the scripted policy."""
    env = FlockingEnv("s5", num_envs=2, seed=0, extras="physics")
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(12, goal_seeking_policy(), break_when_any_done=False)
    return rollout, env


def test_render_frame_is_an_rgb_image_of_the_requested_size():
    env = FlockingEnv("train", num_envs=2, seed=0)
    env.reset()
    img = env.render("rgb_array", env_index=1)
    assert img.shape == (512, 512, 3) and img.dtype == np.uint8
    assert _red(img).any()  # the red obstacles are drawn
    small = render_frame(env, 0, size=(120, 200))
    assert small.shape == (120, 200, 3) and small.dtype == np.uint8
    with pytest.raises(IndexError):
        render_frame(env, env_index=2)
    with pytest.raises(ValueError, match="human"):
        env.render("human")


def test_field_of_view_wedges_follow_the_config():
    narrow = FlockingEnv("s1", num_envs=1, seed=0, reading="literal", fov=0.5 * math.pi)
    half = FlockingEnv("s1", num_envs=1, seed=0, reading="paper_fit", fov=0.5 * math.pi)
    wide = FlockingEnv("s1", num_envs=1, seed=0, reading="literal", fov=2 * math.pi)
    position = [[[10.0, 10.0], [20.0, 20.0], [30.0, 30.0], [40.0, 10.0], [10.0, 40.0]]]
    for env in (narrow, half, wide):
        env.place(position, [[0.0, 1.0, 2.0, 3.0, -1.0]], [[70.0, 70.0]])
    a, h, b = (render_frame(e, size=200) for e in (narrow, half, wide))
    bare = render_frame(narrow, size=200, show_fov=False)
    tinted = [int((img.astype(int).sum(-1) < 3 * 250).sum()) for img in (bare, a, h, b)]
    # 90 degree wedges < half discs (paper_fit's half-angle) < full discs.
    assert tinted[0] < tinted[1] < tinted[2] < tinted[3]


def test_rollout_states_stop_at_the_first_done():
    env = FlockingEnv("s1", num_envs=1, seed=0, max_steps=5, extras="physics")
    with torch.no_grad():
        rollout = env.rollout(20, goal_seeking_policy(), break_when_any_done=False)
    states = rollout_states(rollout, env.cfg, 0)
    assert len(states) == 6  # the start and five steps, truncated at max_steps = 5
    assert np.allclose(states[1].position, rollout["next", "agents", "position"][0, 0].numpy())


def test_trajectory_plot_and_animation_files(tmp_path, s5_rollout):
    rollout, env = s5_rollout
    fig = plot_trajectory(rollout, env, env_index=1, path=tmp_path / "traj.png", title="S5")
    assert fig.axes and (tmp_path / "traj.png").is_file()
    img = imageio.imread(tmp_path / "traj.png")
    assert img.ndim == 3 and img.shape[0] > 100
    gif = save_animation(rollout, env, tmp_path / "anim.gif", env_index=0, size=96, stride=4)
    frames = imageio.mimread(gif)
    assert len(frames) == 4 and frames[0].shape[:2] == (96, 96)  # states 0, 4, 8, 12
    grid = trajectory_grid([("a", rollout, env), ("b", None, "no checkpoint")], ncols=2, path=tmp_path / "g.png")
    assert len(grid.axes) == 2 and (tmp_path / "g.png").is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # atomic writes


def test_reward_curves_from_checkpoints(tmp_path):
    from flock_torchrl.policies.checkpoint import save_checkpoint
    from flock_torchrl.run.batches import EPISODE_COLUMNS

    root = tmp_path / "checkpoints"
    for seed, offset in ((0, 0.0), (1, 2.0)):
        curve = torch.zeros(200, len(EPISODE_COLUMNS), dtype=torch.float64)
        curve[:, 0] = torch.arange(1, 201)
        curve[:, EPISODE_COLUMNS.index("reward")] = offset + torch.arange(1, 201) / 100
        if seed == 0:  # success: 85 of episodes 1-100, all of 101-200; seed 1 never succeeds
            curve[:85, EPISODE_COLUMNS.index("success")] = 1.0
            curve[100:, EPISODE_COLUMNS.index("success")] = 1.0
        meta = {"policy": "Policy3-G", "policy_id": "policy3_g", "reading": "literal", "scenario": {},
                "policy_scenario": {}, "stochastic": True, "hidden": 128, "depth": 2}
        actor = {"weight": torch.zeros(2, 2)}   # a curve's reader never builds the network
        save_checkpoint({"meta": meta, "actor": actor, "curve": curve}, root / "literal" / "policy3_g" / f"seed{seed}.pt",
                        kind="policy")
    e, r = training_curve(root / "literal" / "policy3_g" / "seed0.pt")
    assert e.shape == (200,) and r[0] == pytest.approx(0.01)
    # One run, episodes 1..100 -> block 0 with mean (1 + ... + 100) / 100 / 100 = 0.505.
    x, mean, half = binned_mean_ci(e, r, 100)
    assert list(x) == [100.0, 200.0] and mean[0] == pytest.approx(0.505) and (half > 0).all()
    written = make_figures(app_config("figures", reading="literal", figs=[4], checkpoints_dir=root), tmp_path / "figures",
                           log=lambda m: None)
    assert written == [tmp_path / "figures" / f for f in ("fig4_rewards.png", "fig4_convergence.md")]
    assert all(p.is_file() for p in written)
    # Convergence: seed 0's first block (1-100) has mean success 0.85 < 0.9, its second 1.0, so
    # episode 200; seed 1 never (—). Success over the last 100 episodes: 100 %, 0 %.
    e, s = training_curve(root / "literal" / "policy3_g" / "seed0.pt", "success")
    assert first_block_reaching(e, s, 0.9) == 200.0 and first_block_reaching(e, s, 0.8) == 100.0
    assert math.isnan(first_block_reaching(e, 0 * s, 0.9))
    table = written[1].read_text().splitlines()
    assert "| Policy3-G | seed0 | 200 | 200 | 100.0 % |" in table and "| Policy3-G | seed1 | 200 | — | 0.0 % |" in table
    with pytest.raises(ValueError, match="column must be one of"):
        training_curve(root / "literal" / "policy3_g" / "seed0.pt", "successes")
    assert make_figures(app_config("figures", reading="paper_fit", figs=[4], checkpoints_dir=root),
                        tmp_path / "figures2", log=lambda m: None) == []


def labels_outside(fig) -> list[str]:
    """Every axis label and tick label (of the ticks within the view) of ``fig`` (drawn) that does
    not lie inside the picture."""
    renderer = fig.canvas.get_renderer()
    width, height = fig.bbox.width, fig.bbox.height
    outside = []
    for i, ax in enumerate(fig.axes):
        shown = [tick.label1 for axis in (ax.xaxis, ax.yaxis) for tick in axis.get_major_ticks()
                 if min(axis.get_view_interval()) <= tick.get_loc() <= max(axis.get_view_interval())]
        for text in (ax.xaxis.label, ax.yaxis.label, *shown):
            if not text.get_visible() or not text.get_text():
                continue
            box = text.get_window_extent(renderer)
            if box.x0 < 0 or box.y0 < 0 or box.x1 > width or box.y1 > height:
                outside.append(f"axes {i} {text.get_text()!r} at {[round(v) for v in box.extents]} in "
                               f"{width:.0f} x {height:.0f}")
    return outside


def test_a_3d_frames_axis_labels_lie_inside_the_picture(tmp_path, monkeypatch):
    """A 3-D frame's top view and side view keep their axis and tick labels inside the picture
    at the sizes it is drawn at: env.render's 512 x 512 (its y label was clipped), a GIF's default
    400 x 400 (the top view's y label and the side view's x label were lost), the published
    300 x 600 GIFs and 360 x 720 frames; each GIF frame as its first."""
    from flock_torchrl.world import frame

    drawn = []
    figure = frame.frame_figure

    def keep(*args, **kwargs):
        drawn.append(figure(*args, **kwargs))
        return drawn[-1]

    monkeypatch.setattr(frame, "frame_figure", keep)
    monkeypatch.setattr(frame, "_LAYOUTS", {})
    env = FlockingEnv("wall3d", num_envs=1, seed=0, extras="physics")
    with torch.no_grad():
        rollout = env.rollout(6, break_when_any_done=False)
    env.reset()
    assert env.render("rgb_array").shape == (512, 512, 3)
    for size in ((300, 600), (360, 720)):
        render_frame(env, 0, size=size)
    save_animation(rollout, env, tmp_path / "space.gif", stride=3)
    assert len(drawn) == 6 and [f.bbox.height for f in drawn] == [512, 300, 360, 400, 400, 400]
    for fig in drawn:
        assert len(fig.axes) == 2 and all(ax.get_xlabel() and ax.get_ylabel() for ax in fig.axes)
        assert labels_outside(fig) == []
    first, later = drawn[3], drawn[5]   # a GIF's later frames take the first one's layout
    assert [ax.get_position().bounds for ax in first.axes] == [ax.get_position().bounds for ax in later.axes]


def test_the_label_check_sees_a_clipped_label():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4, 4), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.0, 0.3, 0.5, 0.5))   # no room left of it
    ax.set_ylabel("y (m)")
    fig.canvas.draw()
    assert any("'y (m)'" in line for line in labels_outside(fig))
