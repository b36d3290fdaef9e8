"""The world's step with the worlds innermost, the layout compiled code runs fastest.

:mod:`.step` lays tensors out as ``[B, N, ...]``, natural for eager PyTorch, where each
operation is one kernel over all its elements. Compiled (inductor's C++ backend), a step is a
few loop nests vectorised along each tensor's innermost dimension; for beams ``[B, N, 36]``
or pairs ``[B, N, N]`` that dimension is short (36 or 5 values: the tail of every 16-float
vector wasted, the shortest beam and the nearest neighbour reduced one UAV at a time). Here
every tensor puts the worlds last: per UAV ``[N, B]``, per beam ``[K, N, B]``, per pair
``[N_j, N_i, B]`` (``j`` the UAV seen, ``i`` the one seeing). Vectorised loops then run along
the batch, and every reduction (the shortest beams, the nearest neighbours, the repulsion
sums, the nearest obstacle) runs over the outermost dimension, a vector of worlds at a time.

:func:`sense` and :func:`advance` return what :func:`~.step.sense` and :func:`~.step.advance`
return, in their layout, by the same formulas; those hand over to them under
``torch.compile``. They run eagerly too, which is how the tests compare the two, key by key,
in every scenario.
"""

from __future__ import annotations

import math
from typing import Mapping

import torch

from ..config import ScenarioConfig
from .dynamics import reflect_in_box
from .geometry import Obstacles, circular_mean, wrap
from .instinct import repulsion_xy
from .metrics import update_episode
from .reward import collision_reward, flocking_reward, goal_reward
from .sensors import CAMERA_SLOT, beam_unit_table
from .state import world_state

Tensors = Mapping[str, torch.Tensor]


def _stored(x: torch.Tensor) -> torch.Tensor:
    """``x``, kept in memory by compiled code: inductor otherwise inlines an elementwise result
    into every consumer, recomputing (say) each beam's ray cast in every pass of the shortest-
    beam selection. ``as_strided`` on itself makes it store ``x`` once; eagerly a no-op."""
    return x.as_strided(x.shape, x.stride()) if torch.compiler.is_compiling() else x


def _worlds_last(x: torch.Tensor) -> torch.Tensor:
    """``[B, N, ...]`` -> ``[..., N, B]`` (a view)."""
    return x.permute(*range(x.dim() - 1, 1, -1), 1, 0)


def _batch_first(x: torch.Tensor) -> torch.Tensor:
    """``[N, B, ...]`` -> contiguous ``[B, N, ...]``."""
    return x.transpose(0, 1).contiguous()


def smallest(values: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`~.sensors.smallest` along the first dimension: the ``k`` smallest entries,
    ascending, ties by the lowest index; ``(value [k, ...], index [k, ...])``, the index in
    the values' dtype (:func:`pick` reads other tensors there without a gather).

    Each pass takes the minimum and the first index holding it (a minimum over indices where
    the value equals it), then masks that index with ``inf``: two plain reductions over the
    outer dimension, vectorised along the inner ones. Indices are counted in the values'
    float dtype (exact up to 2^24) and clamped into range, so a NaN row (an action nobody
    checked) still indexes safely.
    """
    n = values.shape[0]
    index = torch.arange(n, device=values.device, dtype=values.dtype).view(n, *([1] * (values.dim() - 1)))
    picks, indices = [], []
    for _ in range(k):
        low = values.amin(0)
        at = torch.where(values == low, index, n).amin(0).clamp_max(n - 1)
        picks.append(low)
        indices.append(at)
        values = torch.where(index == at, math.inf, values)
    return torch.stack(picks), torch.stack(indices)


def pick(values: torch.Tensor, at: torch.Tensor) -> torch.Tensor:
    """``values[at]`` along the first dimension for float indices ``at`` (from :func:`smallest`):
    a masked sum over that dimension, vectorised like the selection itself (a gather would
    convert, bounds-check and load every index one by one)."""
    index = torch.arange(values.shape[0], device=values.device, dtype=at.dtype).view(-1, *([1] * at.dim()))
    return torch.where(index == at, values, 0.0).sum(0)


def beam_angle(at: torch.Tensor, n_beams: int) -> torch.Tensor:
    """The offset ``k * 2 pi / n_beams`` of beams ``at`` (float indices), wrapped to ``[-pi, pi)``:
    wrapped in index space (``k - n_beams`` from the half turn on), so the beam at exactly pi
    goes to -pi whatever the float rounding of its angle."""
    return torch.where(at < n_beams / 2, at, at - n_beams) * (2 * math.pi / n_beams)


def _running_min(t: torch.Tensor, m: int, best: torch.Tensor | None, index: torch.Tensor | None):
    """Fold candidate ``t`` (obstacle ``m``) into the running minimum; ties keep the earlier one."""
    if best is None:
        return t, torch.zeros_like(t, dtype=torch.long)
    closer = t < best
    return torch.where(closer, t, best), torch.where(closer, m, index)


def laser_scan(px: torch.Tensor, py: torch.Tensor, heading: torch.Tensor, obstacles: Obstacles, n_beams: int,
               max_range: float) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`~.sensors.laser_scan` for positions ``px, py`` and headings ``[N, B]``:
    ``(distance [K, N, B], obstacle index [K, N, B])``, the formulas of
    :func:`~.geometry.cast_rays_along`, every (beam, obstacle) pair cast."""
    cos_o, sin_o = (torch.tensor(v, dtype=px.dtype, device=px.device).view(-1, 1, 1)
                    for v in beam_unit_table(n_beams))
    cos_h, sin_h = _stored(torch.stack((torch.cos(heading), torch.sin(heading))))
    dx, dy = cos_h * cos_o - sin_h * sin_o, sin_h * cos_o + cos_h * sin_o  # beam directions [K, N, B]
    best = index = None
    m = 0
    for circle in obstacles.circles.unbind(1):  # [B, 3] each
        fx, fy = px - circle[:, 0], py - circle[:, 1]  # origin - centre, [N, B]
        fx, fy, c = _stored(torch.stack((fx, fy, (fx * fx + fy * fy) - circle[:, 2] * circle[:, 2])))
        b = fx * dx + fy * dy
        disc = b * b - c
        t_near = -b - torch.sqrt(disc.clamp_min(0.0))
        t = torch.where((disc >= 0) & (t_near >= 0), t_near, math.inf)
        best, index = _running_min(torch.where(c <= 0, 0.0, t), m, best, index)
        m += 1
    if obstacles.rectangles.shape[1]:
        tiny = 1e-12
        inv_x = 1.0 / torch.where(dx.abs() < tiny, tiny, dx)
        inv_y = 1.0 / torch.where(dy.abs() < tiny, tiny, dy)
    for rect in obstacles.rectangles.unbind(1):  # [B, 4] each
        half_w, half_h = rect[:, 2] / 2, rect[:, 3] / 2
        lo_x, hi_x = (rect[:, 0] - half_w) - px, (rect[:, 0] + half_w) - px
        lo_y, hi_y = (rect[:, 1] - half_h) - py, (rect[:, 1] + half_h) - py
        inside = (lo_x <= 0) & (hi_x >= 0) & (lo_y <= 0) & (hi_y >= 0)
        lo_x, lo_y = torch.where(lo_x == 0, -1e-6, lo_x), torch.where(lo_y == 0, -1e-6, lo_y)
        hi_x, hi_y = torch.where(hi_x == 0, 1e-6, hi_x), torch.where(hi_y == 0, 1e-6, hi_y)
        lo_x, hi_x, lo_y, hi_y = _stored(torch.stack((lo_x, hi_x, lo_y, hi_y)))  # per UAV, not per beam
        inside = _stored(inside)
        tx1, tx2, ty1, ty2 = lo_x * inv_x, hi_x * inv_x, lo_y * inv_y, hi_y * inv_y
        t_near = torch.maximum(torch.minimum(tx1, tx2), torch.minimum(ty1, ty2))
        t_far = torch.minimum(torch.maximum(tx1, tx2), torch.maximum(ty1, ty2))
        t = torch.where((t_far >= t_near) & (t_far >= 0), t_near.clamp_min(0.0), math.inf)
        best, index = _running_min(torch.where(inside, 0.0, t), m, best, index)
        m += 1
    shape = (n_beams, *px.shape)
    if best is None:
        return px.new_full(shape, max_range), torch.full(shape, -1, dtype=torch.long, device=px.device)
    in_range = best < max_range
    return _stored(torch.where(in_range, best, max_range)), _stored(torch.where(in_range, index, -1))


def nearest_obstacle_distance(px: torch.Tensor, py: torch.Tensor, obstacles: Obstacles) -> torch.Tensor:
    """:func:`~.geometry.nearest_obstacle_distance` for points ``[N, B]`` (``inf`` without obstacles)."""
    best = None
    for circle in obstacles.circles.unbind(1):
        ox, oy = px - circle[:, 0], py - circle[:, 1]
        d = torch.sqrt(ox * ox + oy * oy) - circle[:, 2]
        best = d if best is None else torch.minimum(best, d)
    for rect in obstacles.rectangles.unbind(1):
        qx, qy = (px - rect[:, 0]).abs() - rect[:, 2] / 2, (py - rect[:, 1]).abs() - rect[:, 3] / 2
        ox, oy = qx.clamp_min(0.0), qy.clamp_min(0.0)
        d = torch.sqrt(ox * ox + oy * oy) + torch.maximum(qx, qy).clamp_max(0.0)
        best = d if best is None else torch.minimum(best, d)
    return torch.full_like(px, math.inf) if best is None else best


def scan_observation(shortest: tuple[torch.Tensor, torch.Tensor], n: int, n_beams: int, max_range: float
                     ) -> torch.Tensor:
    """``o_scan`` (:func:`~.sensors.scan_observation`) from the shortest beams ``[>= n, N, B]``: ``[N, B, 2 n]``."""
    dist, idx = shortest[0][:n], shortest[1][:n]
    slots = torch.stack((dist.clamp(0.0, max_range) / max_range, beam_angle(idx, n_beams) / math.pi), -1)
    return slots.permute(1, 2, 0, 3).flatten(-2)


def camera_observation(distance: torch.Tensor, bearing: torch.Tensor, heading_difference: torch.Tensor,
                       visible: torch.Tensor, n: int, camera_range: float
                       ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """``o_cam`` (:func:`~.sensors.camera_observation`) from pair tensors ``[N_j, N_i, B]``:
    ``([N, B, 3 n], distance to the nearest visible UAV [N, B] or None when n = 0)``."""
    key = torch.where(visible, distance, math.inf)
    m = min(n, key.shape[0])
    first, order = smallest(key, m)  # [m, N, B]; where present, first is the distance at order
    present = torch.isfinite(first)
    slots = torch.stack(
        ((first / camera_range).clamp(0.0, 1.0),
         torch.stack([pick(bearing, at) for at in order]) / math.pi,
         torch.stack([pick(heading_difference, at) for at in order]) / math.pi), -1)  # [m, N, B, 3]
    missing = slots.new_tensor([1.0, 0.0, 0.0])
    slots = torch.where(present[..., None], slots, missing)
    if m < n:  # fewer other UAVs than slots
        slots = torch.cat((slots, missing.expand(n - m, *slots.shape[1:-1], CAMERA_SLOT)), 0)
    return slots.permute(1, 2, 0, 3).flatten(-2), (first[0] if m else None)


def _sense(px: torch.Tensor, py: torch.Tensor, h: torch.Tensor, goal: torch.Tensor, obstacles: Obstacles,
           cfg: ScenarioConfig, normals: Tensors | None) -> dict[str, torch.Tensor]:
    """:func:`~.step.sense` from positions and headings ``[N, B]``: every quantity worlds
    innermost (``[N, B, ...]`` per UAV, ``[K, N, B]`` beams), ``closest_pair`` ``[B]``."""
    gx, gy = goal[:, 0], goal[:, 1]        # [B]
    n_uavs, n_beams = h.shape[0], cfg.n_beams

    # Laser, true and (S4) sensed.
    beams, beam_obstacle = laser_scan(px, py, h, obstacles, n_beams, cfg.laser_range)  # [K, N, B]
    # Camera: every pair (j seen by i), [N_j, N_i, B].
    dx, dy = px[:, None] - px[None, :], py[:, None] - py[None, :]
    distance = _stored(torch.sqrt(dx * dx + dy * dy))
    world_bearing = torch.atan2(dy, dx)
    bearing = _stored(wrap(world_bearing - h[None]))
    heading_difference = wrap(h[None] - h[:, None])
    others = ~torch.eye(n_uavs, dtype=torch.bool, device=h.device)[..., None]
    in_range = (distance < cfg.camera_range) & others
    visible = in_range & (bearing.abs() <= cfg.half_fov)
    all_round = in_range & (bearing.abs() <= math.pi)  # the critic's camera

    sensed_beams, s_distance, s_bearing, s_heading_difference, s_dx, s_dy = (
        beams, distance, bearing, heading_difference, dx, dy)
    if cfg.noise:
        if normals is None:
            raise ValueError("sense: the scenario has sensor noise; pass its normals (sensors.sensor_normals)")
        sensed_beams = (beams + cfg.noise_scan * _worlds_last(normals["scan"])).clamp(0.0, cfg.laser_range)
        s_distance = (distance + cfg.noise_distance * _worlds_last(normals["distance"])).clamp_min(0.0)
        s_bearing = wrap(bearing + cfg.noise_angle * _worlds_last(normals["bearing"]))
        s_heading_difference = wrap(heading_difference + cfg.noise_angle * _worlds_last(normals["heading_difference"]))
        angle = s_bearing + world_bearing - bearing
        s_dx, s_dy = s_distance * torch.cos(angle), s_distance * torch.sin(angle)

    k = max(cfg.n_scan, 1)
    sensed_shortest = smallest(sensed_beams, k)
    true_shortest = smallest(beams, k) if cfg.noise else sensed_shortest

    # o_g and s_c.
    tx, ty = gx - px, gy - py
    d_goal = torch.sqrt(tx * tx + ty * ty)
    alpha_goal = wrap(torch.atan2(ty, tx) - h)
    o_g = torch.stack(((d_goal / cfg.goal_scale).clamp_max(1.0), alpha_goal / math.pi), -1)  # [N, B, 2]
    cx, cy = px.mean(0) - px, py.mean(0) - py
    d_c = torch.sqrt(cx * cx + cy * cy)
    s_c = torch.stack(((d_c / cfg.camera_range).clamp_max(1.0), wrap(torch.atan2(cy, cx) - h) / math.pi,
                       wrap(h - circular_mean(h, 0, keepdim=True)) / math.pi), -1)

    o_cam, nearest_seen = camera_observation(s_distance, s_bearing, s_heading_difference, visible, cfg.n_cam,
                                             cfg.camera_range)
    s_cam, _ = camera_observation(distance, bearing, heading_difference, all_round, cfg.n_cam, cfg.camera_range)
    observation = torch.cat((o_g, scan_observation(sensed_shortest, cfg.n_scan, n_beams, cfg.laser_range), o_cam), -1)
    critic_state = torch.cat((o_g, scan_observation(true_shortest, cfg.n_scan, n_beams, cfg.laser_range), s_cam,
                              s_c), -1)

    # The instinct (section 3): visible UAVs and one virtual UAV at the shortest beam's return.
    if nearest_seen is None:
        nearest_seen = torch.where(visible, s_distance, math.inf).amin(0)
    d_scan1 = sensed_shortest[0][0]
    angle = h + sensed_shortest[1][0] * (2 * math.pi / n_beams)
    to_goal = torch.stack((tx, ty), -1)  # [N, B, 2]
    ux, uy = repulsion_xy(s_dx, s_dy, s_distance, visible, to_goal, cfg.rep_gain, cfg.rep_range, cfg.tangential,
                          dim=0)
    wx, wy = repulsion_xy((d_scan1 * torch.cos(angle))[None], (d_scan1 * torch.sin(angle))[None], d_scan1[None],
                          torch.ones_like(visible[:1]), to_goal, cfg.rep_gain, cfg.rep_range, cfg.tangential, dim=0)
    triggered = torch.minimum(nearest_seen, d_scan1) <= cfg.safe_distance

    return {
        "observation": observation, "state": critic_state, "scan": sensed_beams, "scan_obstacle": beam_obstacle,
        "instinct_triggered": triggered, "instinct_command": torch.stack((ux + wx, uy + wy), -1),
        "d_scan1": true_shortest[0][0],
        "d_uav1": nearest_seen if not cfg.noise else torch.where(visible, distance, math.inf).amin(0),
        "d_goal": d_goal, "alpha_goal": alpha_goal,
        "obstacle_distance": nearest_obstacle_distance(px, py, obstacles),
        "closest_pair": torch.where(others, distance, math.inf).amin(0).amin(0),  # [B]
    }


def _sensed_batch_first(sensed: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """:func:`_sense`'s quantities in :func:`~.step.sense`'s layout."""
    out = {key: _batch_first(value) for key, value in sensed.items() if key not in ("scan", "scan_obstacle",
                                                                                   "closest_pair")}
    # Views of the beam-major tensors (strides [1, B, N B]): a contiguous copy would cost a
    # transpose of every beam, for keys only the "laser" extras show.
    out["scan"] = sensed["scan"].permute(2, 1, 0)
    out["scan_obstacle"] = sensed["scan_obstacle"].permute(2, 1, 0)
    out["closest_pair"] = sensed["closest_pair"]
    return {key: out[key] for key in sensed}


def _planar(x: torch.Tensor) -> torch.Tensor:
    """``[B, N, ...]`` stored worlds innermost, ``[..., N, B]`` (contiguous, computed once)."""
    return _stored(_worlds_last(x).contiguous())


def sense(state: Tensors, static: Obstacles, cfg: ScenarioConfig, normals: Tensors | None = None
          ) -> dict[str, torch.Tensor]:
    """:func:`~.step.sense`, computed with the worlds innermost; same keys, shapes and layout."""
    from .step import world_obstacles  # step imports this module

    obstacles = world_obstacles(state, static, cfg)
    px, py = _planar(state["position"])
    return _sensed_batch_first(_sense(px, py, _planar(state["heading"]), state["goal"], obstacles, cfg, normals))


def advance(state: Tensors, sensed: Tensors, episode: Tensors, action: torch.Tensor, static: Obstacles,
            cfg: ScenarioConfig, normals: Tensors | None = None
            ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor], dict[str, torch.Tensor], torch.Tensor]:
    """:func:`~.step.advance`, computed with the worlds innermost; same results and layout.

    The kinematics, reward and metrics run per axis on ``[N, B]`` tensors: atan2, sin and cos
    then vectorise along the batch (on interleaved ``[B, N, 2]`` tensors inductor falls back
    to scalar loops), and the sums and means over the swarm reduce the outer dimension.
    """
    from .step import obstacles_of

    h = _planar(state["heading"])
    px, py = _planar(state["position"])
    vx, vy = _planar(state["velocity"])
    ax, ay = _planar(action)
    if cfg.action_mode == "policy":  # Eq. 19-20
        direction, speed = h + ax * (math.pi / 2), ay + 2.0
        cx, cy = speed * torch.cos(direction), speed * torch.sin(direction)
    else:  # the action is the velocity command (rule-based controllers)
        cx, cy = ax, ay
    use = sensed["instinct_triggered"].transpose(0, 1)
    if cfg.instinct:
        rx, ry = _planar(sensed["instinct_command"])
        cx, cy = torch.where(use, rx, cx), torch.where(use, ry, cy)
    else:
        use = torch.zeros_like(use)
    cx, cy = cx.clamp(-cfg.v_max, cfg.v_max), cy.clamp(-cfg.v_max, cfg.v_max)
    rate = cfg.dt / cfg.tau_v  # Eq. 1, semi-implicit Euler
    vx, vy = vx + rate * (cx - vx), vy + rate * (cy - vy)
    px, py = px + cfg.dt * vx, py + cfg.dt * vy
    speed = torch.sqrt(vx * vx + vy * vy)
    h = torch.where(speed > cfg.heading_speed_threshold, torch.atan2(vy, vx), h)
    moving_position, moving_velocity = state["moving_position"], state["moving_velocity"]
    if cfg.n_moving:
        moving_position, moving_velocity = reflect_in_box(
            moving_position + cfg.dt * moving_velocity, moving_velocity, 0.0, cfg.area_size)
    obstacles = obstacles_of(static, moving_position, cfg.moving_radius, state["drawn_circles"],
                             state["drawn_rectangles"])
    now = _sense(px, py, h, state["goal"], obstacles, cfg, normals)

    has_prev = state["has_prev_action"]
    prev_x, prev_y = (torch.where(has_prev, p, a) for p, a in zip(_planar(state["prev_action"]), (ax, ay)))
    d_collision = now["d_scan1"]
    if cfg.collision_reward_source == "min_uav_scan":
        d_collision = torch.minimum(now["d_uav1"], d_collision)
    ox, oy = px - px.mean(0), py - py.mean(0)
    d_centre = torch.sqrt(ox * ox + oy * oy)
    deviation = wrap(h - circular_mean(h, 0, keepdim=True))
    reward = (goal_reward(now["d_goal"], sensed["d_goal"].transpose(0, 1), now["alpha_goal"], cfg.goal_radius)
              + collision_reward(d_collision) + flocking_reward(deviation, d_centre)
              - 0.02 * ((prev_x - ax).abs() + (prev_y - ay).abs()))  # r_v, Eq. 25
    reached = (now["d_goal"] < cfg.goal_radius).any(0)
    crashed = (now["obstacle_distance"] < cfg.collision_distance).any(0)
    swarm_x, swarm_y = vx.mean(0), vy.mean(0)
    v_c = torch.sqrt(swarm_x * swarm_x + swarm_y * swarm_y)
    stats = {  # metrics.step_statistics
        "obs": now["obstacle_distance"].amin(0).clamp_min(0.0), "uav": now["closest_pair"],
        "d_c": d_centre.mean(0), "v_error": (speed - v_c).abs().mean(0), "phi_error": deviation.abs().mean(0),
        "speed": v_c,
    }
    terminated = reached | crashed
    if cfg.uav_collision_terminates:
        terminated = terminated | (stats["uav"] < cfg.collision_distance)
    episode = update_episode(dict(episode), stats, reached, crashed, cfg.dt, reward.mean(0))
    new = world_state(
        position=_batch_first(torch.stack((px, py), -1)), velocity=_batch_first(torch.stack((vx, vy), -1)),
        heading=_batch_first(h), goal=state["goal"], moving_position=moving_position, moving_velocity=moving_velocity,
        drawn_circles=state["drawn_circles"], drawn_rectangles=state["drawn_rectangles"],
        command=_batch_first(torch.stack((cx, cy), -1)), instinct=_batch_first(use), prev_action=action,
        has_prev_action=torch.ones_like(has_prev), terminated=terminated[:, None],
        truncated=(episode["steps"] >= cfg.max_steps)[:, None] & ~terminated[:, None])
    return new, _sensed_batch_first(now), episode, _batch_first(reward)


__all__ = ["advance", "beam_angle", "camera_observation", "laser_scan", "nearest_obstacle_distance", "pick",
           "scan_observation", "sense", "smallest"]
