"""Why learned flocks crash at 20-50 UAVs: crash forensics and evaluation-time ablations.

Two tools, both on the evaluation protocol (seeded batched episodes, deterministic actions):

* :func:`run_cell` evaluates one policy in one world under one *variant* and, for every episode
  that ends in an obstacle crash, keeps the last ``window`` steps (1 s at ``dt = 0.2``) of the
  UAV that hit: what its laser and camera saw, how many UAVs were packed around it, what the
  repulsion instinct would command (split into its UAV and obstacle parts) and what the policy
  itself asked for, each projected on the obstacle's outward normal (:func:`crash_forensics`).
* The variants (:data:`.variants.VARIANTS`, each described there) separate the causes at evaluation
  time, without retraining and without touching the world: the paper's instinct, off, or without its
  tangential term (Eq. 28, as Policy5-G's); the actor fed the critic's all-round camera slots; and
  instincts that hold in a crowd, applied by a wrapper (:class:`.variants.InstinctWrapper`), the
  paper's one re-applied as a control (it must give the built-in instinct's episodes).

Rates come with exact (Clopper-Pearson) binomial 95 % intervals (:func:`binomial_ci`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from ..config import EVAL_SEED, ScenarioConfig
from ..policies.registry import PolicyHandle
from ..run.rollout import policy_env
from ..world.dynamics import action_to_command, clip_command
from ..world.geometry import Obstacles, nearest_obstacle_distance
from ..world.laser import beam_return_offset
from ..world.sensors import near_neighbours
from ..world.step import obstacles_of
from .variants import ACTION, VARIANTS, AllRoundCamera, InstinctWrapper, crowd_instinct

UAV_RADIUS = 0.25  # m: half the collision distance, the body a laser that saw UAVs would hit


def binomial_ci(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper-Pearson) interval of a rate ``k / n`` (``scipy.stats.binomtest``)."""
    from scipy.stats import binomtest

    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=level, method="exact")
    return float(ci.low), float(ci.high)


# ---------------------------------------------------------------------------- forensics
def outward_normal(points: torch.Tensor, obstacles: Obstacles, h: float = 1e-3) -> torch.Tensor:
    """Unit gradient of the distance to the nearest obstacle surface at ``points [B, N, 2]``
    (central differences): the direction that leads away from it, ``[B, N, 2]``."""
    ex = points.new_tensor([h, 0.0])
    ey = points.new_tensor([0.0, h])
    gx = nearest_obstacle_distance(points + ex, obstacles) - nearest_obstacle_distance(points - ex, obstacles)
    gy = nearest_obstacle_distance(points + ey, obstacles) - nearest_obstacle_distance(points - ey, obstacles)
    g = torch.stack((gx, gy), -1)
    return g / torch.linalg.vector_norm(g, dim=-1, keepdim=True).clamp_min(1e-12)


def along(vec: torch.Tensor, normal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Component of ``vec [..., 2]`` along the unit ``normal`` (m/s, > 0: away from the obstacle)
    and the cosine of their angle (``nan`` for a zero vector)."""
    comp = (vec * normal).sum(-1)
    norm = torch.linalg.vector_norm(vec, dim=-1)
    return comp, torch.where(norm > 0, comp / norm.clamp_min(1e-12), torch.full_like(norm, math.nan))


@dataclass
class CellResult:
    """One policy x world x variant: per-episode flags and, for obstacle crashes, the forensics."""

    label: str
    n_uavs: int
    scenario: str
    variant: str
    episodes: dict[str, torch.Tensor]
    crashes: dict[str, torch.Tensor] = field(default_factory=dict)
    seconds: float = 0.0

    def rates(self) -> dict[str, tuple[int, int, float, float, float]]:
        """``name -> (k, n, rate, low, high)`` for success, safe success, obstacle crash and UAV contact."""
        flags = {"success": self.episodes["success"], "safe_success": self.episodes["safe_success"],
                 "obstacle_crash": self.episodes["crashed"], "uav_contact": self.episodes["uav_contact"]}
        out = {}
        for name, f in flags.items():
            k, n = int(f.sum()), int(f.numel())
            out[name] = (k, n, k / n, *binomial_ci(k, n))
        return out


def crash_forensics(steps: Mapping[str, torch.Tensor], crash_position: torch.Tensor, obstacles: Obstacles,
                    cfg: ScenarioConfig) -> dict[str, torch.Tensor]:
    """What the UAV that hit saw and did in its last ``W`` steps, for ``E`` crashed episodes.

    Args:
        steps: per episode and step before the crash, oldest first: ``position [E, W, N, 2]``,
            ``heading [E, W, N]``, ``scan [E, W, N, K]``, ``action [E, W, N, 2]`` (the actor's, in
            [-1, 1]), ``instinct [E, W, N]`` (the world's flag for that step), ``goal [E, 2]``,
            and ``valid [E, W]`` (False where the episode is younger than ``W`` steps).
        crash_position: ``[E, N, 2]`` after the crash step (the crasher is the UAV nearest an obstacle).
        obstacles: each episode's obstacles (``[E, ...]``).

    Returns:
        ``[E]`` tensors at the last step before the crash (``*_last``) and over the window
        (``*_window``): distances, counts and m/s components along the outward normal.
    """
    e, w, n = steps["heading"].shape
    crasher = nearest_obstacle_distance(crash_position, obstacles).argmin(-1)  # [E]
    flat = lambda t: t.reshape(e * w, *t.shape[2:])  # noqa: E731 (steps as a batch of E * W worlds)
    position, heading, scan = flat(steps["position"]), flat(steps["heading"]), flat(steps["scan"])
    goal = steps["goal"].repeat_interleave(w, 0)
    rep = lambda t: t.repeat_interleave(w, 0)  # noqa: E731
    obs_ew = Obstacles(rep(obstacles.circles), rep(obstacles.rectangles))
    who = crasher.repeat_interleave(w)
    rows = torch.arange(e * w)
    neighbours = near_neighbours(position, heading, cfg.camera_range, cfg.half_fov)[0]
    instinct = dict(gain=cfg.rep_gain, r0=cfg.rep_range, safe_distance=cfg.safe_distance, mode="paper")
    _, command, uav, wall = crowd_instinct(position, heading, goal, scan, neighbours, tangential=cfg.tangential,
                                          **instinct)
    radial = crowd_instinct(position, heading, goal, scan, neighbours, tangential=False, **instinct)[2]  # Eq. 26 alone
    own = action_to_command(flat(steps["action"]), heading)
    me = position[rows, who]  # [E W, 2]
    normal = outward_normal(me[:, None], obs_ew)[:, 0]
    d_true = nearest_obstacle_distance(me[:, None], obs_ew)[:, 0]
    offsets = position - me[:, None]
    dist = torch.linalg.vector_norm(offsets, dim=-1)
    dist[rows, who] = math.inf
    visible = neighbours.visible[rows, who]
    # Would other UAVs hide the obstacle from a laser that saw them? Count those within
    # ``UAV_RADIUS`` of the crasher's shortest beam, between it and the return point.
    d1, beam_vec = beam_return_offset(scan[rows, who][:, None], heading[rows, who][:, None])
    unit = beam_vec[:, 0] / d1.clamp_min(1e-12)
    ahead = (offsets * unit[:, None]).sum(-1)
    across = (offsets[..., 0] * unit[:, None, 1] - offsets[..., 1] * unit[:, None, 0]).abs()
    on_beam = (ahead > 0) & (ahead < d1) & (across < UAV_RADIUS) & torch.isfinite(dist)
    out = {
        "d_obstacle": d_true,
        "d_scan1": scan[rows, who].amin(-1),
        "nearest_uav": dist.amin(-1),
        "uavs_within_2m": (dist < 2.0).sum(-1).float(),
        "uavs_within_r0": (dist < cfg.rep_range).sum(-1).float(),
        "visible_uavs": visible.sum(-1).float(),
        "uavs_on_shortest_beam": on_beam.sum(-1).float(),
        "camera_slots_filled": visible.sum(-1).clamp_max(cfg.n_cam).float(),
        "heading_cos": torch.cos(heading[rows, who]) * normal[:, 0] + torch.sin(heading[rows, who]) * normal[:, 1],
        "instinct_on": flat(steps["instinct"]).float()[rows, who],
        "instinct_speed": torch.linalg.vector_norm(command[rows, who], dim=-1),
        "instinct_uav_speed": torch.linalg.vector_norm(uav[rows, who], dim=-1),
        "instinct_obstacle_speed": torch.linalg.vector_norm(wall[rows, who], dim=-1),
    }
    for name, vec in (("instinct", clip_command(command[rows, who], cfg.v_max)), ("instinct_uav", uav[rows, who]),
                      ("instinct_uav_radial", radial[rows, who]), ("instinct_obstacle", wall[rows, who]),
                      ("policy", own[rows, who])):
        comp, cos = along(vec, normal)
        out[f"{name}_outward"], out[f"{name}_cos"] = comp, cos
    valid = steps["valid"].reshape(e * w).float()
    result = {}
    for key, value in out.items():
        v = value.reshape(e, w)
        result[f"{key}_last"] = v[:, -1]
        ok = valid.reshape(e, w) * torch.isfinite(v).float()
        result[f"{key}_window"] = (torch.nan_to_num(v) * ok).sum(-1) / ok.sum(-1).clamp_min(1.0)
    result["crasher"] = crasher
    return result


def run_cell(handle: PolicyHandle, scenario: str, reading: str, n_uavs: int, variant: str = "paper",
             n_episodes: int = 100, seed: int = EVAL_SEED, window: int = 5, device: str = "cpu",
             label: str | None = None) -> CellResult:
    """Evaluate ``handle`` on ``n_episodes`` seeded episodes of ``scenario`` with ``n_uavs``
    UAVs under ``variant`` (:data:`VARIANTS`), keeping the last ``window`` steps of every world
    (a ring buffer, by world), and the :func:`crash_forensics` of the obstacle crashes."""
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {', '.join(VARIANTS)}; got {variant!r}")
    overrides, view, mode, instinct_view = VARIANTS[variant]
    start = time.perf_counter()
    env = policy_env(handle, scenario, reading, n_episodes, seed, device, {"n_uavs": n_uavs, **overrides},
                     extras=("physics", "laser", "command"))
    cfg = env.cfg
    module = handle.build(env)
    if view == "allround":
        module = AllRoundCamera(module)
    if mode is not None:
        module = InstinctWrapper(module, cfg, mode, math.pi if instinct_view == "allround" else None)
    static = Obstacles(torch.tensor(cfg.circles, dtype=torch.float32).reshape(1, -1, 3),
                       torch.tensor(cfg.rectangles, dtype=torch.float32).reshape(1, -1, 4))
    b, n, k = n_episodes, cfg.n_uavs, cfg.n_beams
    ring = {"position": torch.zeros(b, window, n, 2), "heading": torch.zeros(b, window, n),
            "scan": torch.zeros(b, window, n, k), "action": torch.zeros(b, window, n, 2),
            "instinct": torch.zeros(b, window, n, dtype=torch.bool)}
    final_position = torch.zeros(b, n, 2)
    goal = torch.zeros(b, 2)
    circles = torch.zeros(b, cfg.random_circles, 3)
    rectangles = torch.zeros(b, cfg.random_rectangles, 4)
    moving = torch.zeros(b, cfg.n_moving, 2)
    ended_at = torch.zeros(b, dtype=torch.long)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.reset()
        records = td["episode"].clone()
        rows = torch.arange(b)
        goal[:] = td["goal"]
        if cfg.random_circles:
            circles[:] = td["obstacles", "drawn_circles"]
        if cfg.random_rectangles:
            rectangles[:] = td["obstacles", "drawn_rectangles"]
        step = 0
        while rows.numel():
            slot = step % window
            ring["position"][rows, slot] = td["agents", "position"]
            ring["heading"][rows, slot] = td["agents", "heading"]
            ring["scan"][rows, slot] = td["agents", "scan"]
            out = module(td)
            # the actor's own action (a wrapper's output is the executed command)
            action = module.last_action if mode is not None else out[ACTION]
            ring["action"][rows, slot] = action
            nxt = env.step(out)["next"]
            ring["instinct"][rows, slot] = nxt["agents", "instinct"] if mode is None else torch.zeros_like(
                nxt["agents", "instinct"])
            if cfg.n_moving:
                moving[rows] = nxt["obstacles", "position"]
            step += 1
            done = nxt["done"].reshape(-1)
            if bool(done.any()):
                records[rows[done]] = nxt["episode"][done]
                final_position[rows[done]] = nxt["agents", "position"][done]
                ended_at[rows[done]] = step
                keep = (~done).nonzero().squeeze(-1)
                if keep.numel():
                    env, nxt = env.subset(keep), nxt[keep]
                rows = rows[keep]
            td = nxt
    episodes = {key: records[key].clone() for key in ("success", "safe_success", "crashed", "reached", "steps",
                                                       "d_min_uav")}
    episodes["uav_contact"] = records["d_min_uav"] < cfg.collision_distance
    result = CellResult(label or handle.name, n_uavs, cfg.name, variant, episodes)
    crashed = episodes["crashed"].nonzero().squeeze(-1)
    if crashed.numel() and mode is None:
        # the ring in time order, oldest first: slot of the step before the crash is (end - 1) % window
        order = (ended_at[crashed, None] - window + torch.arange(window)) % window
        steps_kept = {key: value[crashed[:, None], order] for key, value in ring.items()}
        steps_kept["goal"] = goal[crashed]
        steps_kept["valid"] = (ended_at[crashed, None] - window + torch.arange(window)) >= 0
        obstacles = obstacles_of(static, moving[crashed], cfg.moving_radius, circles[crashed], rectangles[crashed])
        result.crashes = crash_forensics(steps_kept, final_position[crashed], obstacles, cfg)
        result.crashes["crash_time"] = ended_at[crashed].float() * cfg.dt
    result.seconds = time.perf_counter() - start
    return result


def summarise_crashes(crashes: Mapping[str, torch.Tensor]) -> dict[str, float]:
    """Means (and a few shares) over the crashed episodes of :attr:`CellResult.crashes`."""
    if not crashes:
        return {}
    out = {key: float(torch.nanmean(value.float())) for key, value in crashes.items() if key != "crasher"}
    out["share_instinct_on_last"] = float((crashes["instinct_on_last"] > 0).float().mean())
    out["share_instinct_pushes_in_last"] = float(
        ((crashes["instinct_on_last"] > 0) & (crashes["instinct_outward_last"] < 0)).float().mean())
    out["share_uav_part_pushes_in_last"] = float((crashes["instinct_uav_outward_last"] < 0).float().mean())
    out["share_policy_pushes_in_last"] = float((crashes["policy_outward_last"] < 0).float().mean())
    out["share_beam_hidden_by_uav_last"] = float((crashes["uavs_on_shortest_beam_last"] > 0).float().mean())
    out["share_crash_first_10s"] = float((crashes["crash_time"] <= 10.0).float().mean())
    out["n_crashes"] = float(crashes["crash_time"].numel())
    return out


# ---------------------------------------------------------------------------- the grid
CRASH_COLUMNS = ("n_crashes", "crash_time", "share_crash_first_10s", "d_scan1_last", "nearest_uav_last",
                 "uavs_within_2m_last", "uavs_within_r0_last", "visible_uavs_last", "camera_slots_filled_last",
                 "share_beam_hidden_by_uav_last", "heading_cos_last", "instinct_on_window", "instinct_speed_last",
                 "instinct_uav_speed_last", "instinct_obstacle_speed_last", "instinct_outward_last",
                 "instinct_cos_last", "instinct_uav_outward_last", "instinct_uav_radial_outward_last",
                 "instinct_obstacle_outward_last",
                 "share_instinct_pushes_in_last", "share_uav_part_pushes_in_last", "policy_outward_last",
                 "policy_cos_last", "share_policy_pushes_in_last")


def pooled(cells: Sequence[CellResult]) -> CellResult:
    """Several cells (e.g. one per training seed) as one: episodes and crashes concatenated."""
    first = cells[0]
    episodes = {k: torch.cat([c.episodes[k] for c in cells]) for k in first.episodes}
    keys = set.intersection(*(set(c.crashes) for c in cells if c.crashes)) if any(c.crashes for c in cells) else set()
    crashes = {k: torch.cat([c.crashes[k] for c in cells if c.crashes]) for k in keys}
    return CellResult(first.label, first.n_uavs, first.scenario, first.variant, episodes, crashes,
                      sum(c.seconds for c in cells))


def diagnose(policies: Mapping[str, Sequence[str]], scenarios: Sequence[str] = ("train", "forest"),
             sizes: Sequence[int] = (20, 50), variants: Sequence[str] = tuple(VARIANTS), episodes: int = 50,
             reading: str = "paper_fit", seed: int = EVAL_SEED, device: str = "cpu",
             log: Callable[[str], None] = print) -> list[CellResult]:
    """:func:`run_cell` over ``policies`` (label -> checkpoint files, pooled) x ``scenarios`` x
    ``sizes`` x ``variants``, ``episodes`` per checkpoint and cell."""
    from ..policies.registry import resolve

    handles = {label: [resolve(p, reading, device=device)[0] for p in paths] for label, paths in policies.items()}
    cells = []
    for label, hs in handles.items():
        for scenario in scenarios:
            for n in sizes:
                for variant in variants:
                    cell = pooled([run_cell(h, scenario, reading, n, variant, episodes, seed, device=device,
                                            label=label) for h in hs])
                    cells.append(cell)
                    r = cell.rates()
                    log(f"[{len(cells)}] {label} {scenario} N={n} {variant}: success {r['success'][2]:.3f} "
                        f"safe {r['safe_success'][2]:.3f} obstacle {r['obstacle_crash'][2]:.3f} "
                        f"uav {r['uav_contact'][2]:.3f} ({cell.seconds:.1f} s)")
    return cells


def rate_rows(cells: Sequence[CellResult]) -> list[dict]:
    """One row per cell: the four rates with their 95 % intervals and the wall time."""
    rows = []
    for c in cells:
        row = {"policy": c.label, "scenario": c.scenario, "n_uavs": c.n_uavs, "variant": c.variant,
               "episodes": int(c.episodes["success"].numel())}
        for name, (k, n, rate, low, high) in c.rates().items():
            row.update({name: rate, f"{name}_low": low, f"{name}_high": high})
        row["seconds"] = round(c.seconds, 1)
        rows.append(row)
    return rows


def crash_rows(cells: Sequence[CellResult]) -> list[dict]:
    """One row per cell with crashes: :func:`summarise_crashes`' :data:`CRASH_COLUMNS`."""
    rows = []
    for c in cells:
        s = summarise_crashes(c.crashes)
        if s:
            rows.append({"policy": c.label, "scenario": c.scenario, "n_uavs": c.n_uavs, "variant": c.variant,
                         **{k: s[k] for k in CRASH_COLUMNS}})
    return rows


def rate_table(rows: Sequence[dict]) -> list[str]:
    """Markdown: success, safe success, obstacle crash and UAV contact in %, with 95 % intervals."""
    pct = lambda r, m: f"{100 * r[m]:.1f} [{100 * r[m + '_low']:.0f}, {100 * r[m + '_high']:.0f}]"  # noqa: E731
    lines = ["| policy | scenario | N | variant | episodes | success % | safe success % | obstacle crash % | "
             "UAV contact % |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['policy']} | {r['scenario']} | {r['n_uavs']} | {r['variant']} | {r['episodes']} | "
                     f"{pct(r, 'success')} | {pct(r, 'safe_success')} | {pct(r, 'obstacle_crash')} | "
                     f"{pct(r, 'uav_contact')} |")
    return lines


def crash_table(rows: Sequence[dict]) -> list[str]:
    """Markdown: the crash forensics of the cells with the paper's instinct."""
    head = ("policy", "scenario", "N", "crashes", "crash t (s)", "<= 10 s", "d_scan1 (m)", "nearest UAV (m)",
            "UAVs < 2 m", "UAVs < r0", "visible", "beam hidden", "heading . n", "instinct on (1 s)", "v_rep (m/s)",
            "UAV part (m/s)", "obstacle part (m/s)", "v_rep . n (m/s)", "UAV part . n", "its radial (Eq. 26) . n", "obstacle part . n",
            "v_rep into obstacle", "policy cmd . n (m/s)", "policy into obstacle")
    keys = [k for k in CRASH_COLUMNS if k not in ("camera_slots_filled_last", "instinct_cos_last",
                                                    "share_uav_part_pushes_in_last", "policy_cos_last")]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["policy"], r["scenario"], str(r["n_uavs"])]
        for k in keys:
            v = r[k]
            share = k.startswith("share_") or k == "instinct_on_window"
            cells.append(f"{int(v)}" if k == "n_crashes" else f"{100 * v:.0f} %" if share else f"{v:.2f}")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


# ---------------------------------------------------------------------------- the app
def diagnosed_checkpoints(cfg: Any) -> dict[str, list[Path]]:
    """Label -> the shipped checkpoints it pools, of the catalogue's ``cfg.policies``
    (``<checkpoints_dir>/<reading>/<folder>/seed<k>.pt``: found from any working folder)."""
    root = Path(cfg.checkpoints_dir) / cfg.scenario.reading
    return {cfg.catalogue[key]["label"]: [root / cfg.catalogue[key]["folder"] / f"seed{k}.pt"
                                          for k in range(int(cfg.catalogue[key]["seeds"]))] for key in cfg.policies}


def cell_bytes(scenario: ScenarioConfig, episodes: int, window: int = 5) -> int:
    """What :func:`run_cell` holds for ``episodes`` worlds: the worlds themselves and the ring of
    their last ``window`` steps (positions, headings, scans, actions, instinct flags)."""
    from ..world.memory import world_bytes

    ring = window * scenario.n_uavs * (4 * (2 + 1 + scenario.n_beams + 2) + 1)
    return episodes * (world_bytes(scenario) + ring)


def check_diagnosis(cfg: Any) -> None:
    """Everything that can refuse a diagnosis before its first episode, each in one line: an
    unknown variant, a swarm that cannot be spawned, more episodes than memory holds, a shipped
    checkpoint that is missing, broken or of another reading."""
    from ..config import ConfigError, scenario_config
    from ..policies.registry import resolve
    from ..world.memory import check_memory
    from ..world.spawn import check_spawn_feasible

    for name in cfg.variants:
        if name not in VARIANTS:
            raise ConfigError("variants", f"must be among {', '.join(VARIANTS)}; got {name!r}")
    largest = 0
    for name in cfg.scenarios:
        for n in sorted(set(cfg.sizes)):
            scenario = scenario_config(name, reading=cfg.scenario.reading, n_uavs=n)
            check_spawn_feasible(scenario)
            largest = max(largest, cell_bytes(scenario, cfg.episodes))
    check_memory({"episodes": largest}, f"diagnosing {cfg.episodes} episodes at once")
    for paths in diagnosed_checkpoints(cfg).values():
        for path in paths:
            resolve(path, cfg.scenario.reading, device=cfg.device)


def diagnose_app(cfg: Any, out_dir: str | Path, log: Callable[[str], None] = print) -> list[CellResult]:
    """``conf/diagnose.yaml``'s app: :func:`diagnose` of the catalogue's ``cfg.policies``; writes
    ``rates.csv``, ``crashes.csv`` and ``diagnosis.md`` into ``out_dir``."""
    from ..io import write_csv, write_text

    out = Path(out_dir)
    start = time.perf_counter()
    cells = diagnose(diagnosed_checkpoints(cfg), cfg.scenarios, cfg.sizes, cfg.variants, cfg.episodes,
                     reading=cfg.scenario.reading, seed=cfg.seed, device=cfg.device, log=log)
    rates, crashes = rate_rows(cells), crash_rows(cells)
    write_csv(out / "rates.csv", list(rates[0]), rates)
    write_csv(out / "crashes.csv", ["policy", "scenario", "n_uavs", "variant", *CRASH_COLUMNS], crashes)
    text = ["# Crash forensics and ablations (scripts/diagnose.py)", "",
            f"Reading {cfg.scenario.reading}, evaluation seed {cfg.seed}, {cfg.episodes} episodes per checkpoint "
            f"and cell, {time.perf_counter() - start:.0f} s.", "", *rate_table(rates), "",
            "Crashed episodes, the UAV that hit, at its last step before the crash (n: outward normal of the "
            "obstacle; negative = toward it):", "", *crash_table([r for r in crashes if r["variant"] == "paper"]), ""]
    write_text(out / "diagnosis.md", "\n".join(text))
    log("\n".join(text))
    return cells


__all__ = ["CRASH_COLUMNS", "CellResult", "along", "binomial_ci", "cell_bytes", "check_diagnosis", "crash_forensics",
           "crash_rows", "crash_table", "diagnose", "diagnose_app", "diagnosed_checkpoints", "outward_normal", "pooled",
           "rate_rows", "rate_table", "run_cell", "summarise_crashes"]
