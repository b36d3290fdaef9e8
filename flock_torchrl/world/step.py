"""One time step of B worlds as pure tensor functions: sense, act, move, score.

:func:`sense` turns the physical state into everything a step needs (observation, critic
state, laser, instinct, the distances the reward, termination and metrics read), computing
the pairwise UAV quantities once. :func:`advance` applies a batch of actions: the instinct
(Eq. 26-29), kinematics (Eq. 1, 19-20), moving obstacles, sensing of the new state, reward
(Eq. 21-25), termination and the episode metrics (Eq. 31-36). Neither touches a Python
object per world or per UAV; the env (:mod:`.env`) owns the state and calls them.

The state is a flat mapping of tensors with leading batch dimension ``B``, the keys, shapes
and dtypes of :data:`~.state.WORLD_STATE`; the metrics accumulator is a separate mapping
(:mod:`.metrics`).
"""

from __future__ import annotations

import functools
import math
from typing import Any, Mapping, Sequence

import torch

from ..capture import captured
from ..config import ScenarioConfig
from ..config.scenario import FULL_HEIGHT
from .dynamics import (action_to_command, clamp_altitude, clip_command, first_order_step, reflect_in_box,
                       update_attitude, update_heading)
from .geometry import Obstacles, circular_mean, constant, length, nearest_obstacle_distance, stored, wrap
from .instinct import instinct_command
from .metrics import step_statistics, summary_values, update_episode
from .reward import cohesion_range, total_reward
from .laser import laser_scan, scan_observation, shortest_beams
from .sensors import (add_sensor_noise, camera_observation, goal_observation, goal_polar, near_neighbours,
                      sensor_normals, swarm_centre_state, visibility)
from .space import Space, space_of
from .state import world_state

Tensors = Mapping[str, torch.Tensor]


# Inductor's CPU code for the compiled step: the step's innermost dimensions are tiny (5 UAVs, 3
# obstacles, 2 coordinates, 36 beams against 16-lane AVX-512 vectors), and inductor's defaults
# vectorise them anyway, with masked loads and stores for each loop's remainder and 16 x 16 tiles
# of which 5 rows hold data. Scalar remainders and no 2-D tiling measured 4.2x the eager step at
# B = 1024 where the defaults gave 2.1x (one process, alternated; docs/throughput.md). CUDA
# kernels (Triton) ignore both settings.
STEP_COMPILE_OPTIONS = {"cpp.enable_loop_tail_vec": False, "cpp.enable_tiling_heuristics": False}
# Calls of a whole compiled step and reset (compile_step with reset_pool) that run eagerly first
# (TorchRL's compile warm-up): the tensordict's layout after a step is settled before tracing.
WHOLE_WARMUP = 2


def whole_step_guards(entries: Sequence[Any]) -> list[bool]:
    """Dynamo's guards for the whole compiled step, less those on tensordict's memo of which
    classes are tensorclasses: the traced step reads that memo, so dynamo guarded its length, and
    any class checked anywhere later in the process (a learner's first update) recompiled the
    step. The memo caches a class attribute: its other entries cannot change what the step does."""
    return ["_TENSORCLASS_MEMO" not in entry.name for entry in entries]


def obstacles_of(static: Obstacles, moving_position: torch.Tensor, moving_radius: float,
                 drawn_circles: torch.Tensor, drawn_rectangles: torch.Tensor,
                 drawn_spheres: torch.Tensor | None = None, space: Space | None = None) -> Obstacles:
    """Every world's obstacles, in the laser's index order: the fixed circles, the moving circles
    of ``moving_radius`` at ``moving_position [B, K, 2]``, the episode's ``drawn_circles
    [B, C, 3]``; then the fixed rectangles and the ``drawn_rectangles [B, R, 4]``. In ``space``
    (section 11) circles are cylinders ``[.., 5]`` (the moving ones
    unbounded in height), rectangles boxes ``[.., 6]``, then the fixed and ``drawn_spheres [B, S, 4]``."""
    b = moving_position.shape[0]
    circles = static.circles.expand(b, -1, -1)
    if moving_position.shape[1]:
        moving = torch.cat((moving_position, torch.full_like(moving_position[..., :1], moving_radius)), -1)
        if space is not None:
            moving = torch.cat((moving, torch.full_like(moving[..., :2], FULL_HEIGHT) * constant((-1.0, 1.0), moving)),
                               -1)
        circles = torch.cat((circles, moving), 1)
    if drawn_circles.shape[1]:
        circles = torch.cat((circles, drawn_circles), 1)
    rectangles = static.rectangles.expand(b, -1, -1)
    if drawn_rectangles.shape[1]:
        rectangles = torch.cat((rectangles, drawn_rectangles), 1)
    if space is None:
        return Obstacles(circles, rectangles)
    spheres = static.spheres.expand(b, -1, -1)
    if drawn_spheres.shape[1]:
        spheres = torch.cat((spheres, drawn_spheres), 1)
    return Obstacles(circles, rectangles, spheres)


def world_obstacles(state: Tensors, static: Obstacles, cfg: ScenarioConfig) -> Obstacles:
    """:func:`obstacles_of` the physical ``state`` (its ``moving_position``, ``drawn_circles``
    and ``drawn_rectangles``)."""
    return obstacles_of(static, state["moving_position"], cfg.moving_radius, state["drawn_circles"],
                        state["drawn_rectangles"], state.get("drawn_spheres"), space_of(cfg))


def noise_draws(cfg: ScenarioConfig, n_worlds: int, generator: torch.Generator | None,
                device: torch.device | str | None = None) -> dict[str, torch.Tensor] | None:
    """The S4 noise of one sensing of ``n_worlds`` worlds (``None`` without noise)."""
    if not cfg.noise:
        return None
    return sensor_normals(n_worlds, cfg.n_uavs, cfg.n_laser, generator, device)


def sense(state: Tensors, static: Obstacles, cfg: ScenarioConfig,
          normals: Tensors | None = None, static_shapes: bool = False) -> dict[str, torch.Tensor]:
    """Everything a step reads from the physical ``state``, for all worlds at once.

    ``normals``: the S4 noise's standard normal draws (:func:`~.sensors.sensor_normals`),
    required when ``cfg.noise``; drawn by the caller so that this function stays free of
    random state (and compiles whole).

    Returns:
        ``observation [B, N, 17]`` (section 2, noisy in S4), ``state [B, N, 20]`` (the critic's,
        never noisy), ``scan [B, N, n_beams]`` (as sensed), ``scan_obstacle`` (index hit, -1
        none), ``instinct_triggered [B, N]`` and ``instinct_command [B, N, 2]`` (section 3,
        from the sensed readings), ``d_scan1``, ``d_uav1`` (true), ``d_goal``, ``alpha_goal``,
        ``obstacle_distance`` (true distance to the nearest surface), all ``[B, N]``; and the
        ``closest_pair`` of UAVs ``[B]`` (true), for the metrics.

    ``static_shapes``: no shape depends on the data (every UAV pair, every beam against every
    obstacle), which ``torch.compile(fullgraph=True)`` needs; otherwise only the pairs and the
    obstacles within range are measured (eager; what pays in large swarms and forests). The
    same formulas either way, so the same values up to float round-off. With ``static_shapes``
    the beams and the UAV pairs are also held with the worlds innermost (``[K, N, B]``,
    ``[N_j, N, B]``), so compiled loops run along the worlds and the shortest beams and nearest
    neighbours reduce over the outermost dimension; the keys returned have the same shapes.
    """
    position, heading, goal = state["position"], state["heading"], state["goal"]
    space = space_of(cfg, state["climb"])  # None in the plane (section 11)
    obstacles = world_obstacles(state, static, cfg)
    beams, beam_obstacle = laser_scan(position, heading, obstacles, cfg.n_beams, cfg.laser_range, static_shapes,
                                      space)
    # Only UAVs within camera range can be seen or push back: the pairs are packed per UAV.
    true_neighbours, pairs, closest = near_neighbours(position, heading, cfg.camera_range, cfg.half_fov,
                                                      static_shapes, space, worlds_last=static_shapes)
    # The critic's camera sees all round: the same measurements, wider visibility.
    all_round = true_neighbours.with_visibility(
        visibility(true_neighbours.distance, true_neighbours.cone_angle, cfg.camera_range, math.pi, pairs.valid))
    sensed_beams, neighbours = beams, true_neighbours
    if cfg.noise:
        if normals is None:
            raise ValueError("sense: the scenario has sensor noise; pass its normals (sensors.sensor_normals)")
        packed = {"scan": normals["scan"],
                  **{k: pairs.take(normals[k]) for k in ("distance", "bearing", "heading_difference")}}
        sensed_beams, neighbours = add_sensor_noise(
            beams, true_neighbours, scan_std=cfg.noise_scan, distance_std=cfg.noise_distance,
            angle_std=cfg.noise_angle, max_range=cfg.laser_range, normals=packed)
    # The shortest beams, selected once: the observation, the instinct and (without noise) the
    # critic's state all read them.
    sensed_shortest = shortest_beams(sensed_beams, max(cfg.n_scan, 1), static_shapes)
    true_shortest = shortest_beams(beams, max(cfg.n_scan, 1), static_shapes) if cfg.noise else sensed_shortest
    polar = goal_polar(position, heading, goal, space)
    d_goal, alpha_goal = polar[0], polar[-1]  # 3-D: the off-axis angle, what r_g reads
    o_g = goal_observation(position, heading, goal, cfg.goal_scale, polar, space)
    # The actor's slots: the camera's field of view (the paper), or all round (``actor_camera``),
    # the same (noisy) measurements either way; the instinct below keeps the field of view.
    actor_view = neighbours if cfg.actor_camera == "paper" else neighbours.with_visibility(all_round.visible)
    observation = torch.cat(
        (o_g, scan_observation(sensed_beams, cfg.n_scan, cfg.laser_range, sensed_shortest, space),
         camera_observation(actor_view, cfg.n_cam, cfg.camera_range)), -1)
    critic_state = torch.cat(
        (o_g, scan_observation(beams, cfg.n_scan, cfg.laser_range, true_shortest, space),
         camera_observation(all_round, cfg.n_cam, cfg.camera_range),
         swarm_centre_state(position, heading, cfg.camera_range, space)), -1)
    triggered, repulsion_command = instinct_command(
        position, heading, goal, sensed_beams, neighbours, gain=cfg.rep_gain, r0=cfg.rep_range,
        safe_distance=cfg.safe_distance, tangential=cfg.tangential, shortest=sensed_shortest,
        mode=cfg.instinct_mode, space=space, taper=cfg.tangential_taper)
    out = {
        "observation": observation,
        "state": critic_state,
        "scan": sensed_beams,
        "scan_obstacle": beam_obstacle,
        "instinct_triggered": triggered,
        "instinct_command": repulsion_command,
        "d_scan1": true_shortest[0][..., 0],
        "d_uav1": true_neighbours.nearest_distance(),
        "d_goal": d_goal,
        "alpha_goal": alpha_goal,
        "obstacle_distance": nearest_obstacle_distance(position, obstacles, space),
        "closest_pair": closest,
    }
    if static_shapes:  # per-UAV results of the worlds-last layout are transposed views: stored [B, N, ...],
        # as eager sensing gives them (the step reads some back: inputs of other strides would recompile it).
        # With its standard strides even where a dimension of 1 leaves `contiguous()` a view (B = 1), as
        # compiled code stores it.
        out = {key: value if key in ("scan", "scan_obstacle") else value.clone(memory_format=torch.contiguous_format)
               for key, value in out.items()}
    return out


def advance(state: Tensors, sensed: Tensors, episode: Tensors, action: torch.Tensor, static: Obstacles,
            cfg: ScenarioConfig, normals: Tensors | None = None, static_shapes: bool = False
            ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor], dict[str, torch.Tensor], torch.Tensor]:
    """One step of every world under ``action [B, N, 2]`` (already checked and clipped).

    Returns ``(state, sensed, episode, reward [B, N])`` after the step; ``state`` holds the
    keys of :data:`~.state.WORLD_STATE`, among them the executed ``command``, the ``instinct``
    flags and ``terminated`` / ``truncated`` ``[B, 1]``. Nothing is modified in place.
    ``normals``: the S4 noise of the new state, ``static_shapes`` how it is sensed (:func:`sense`).
    With ``static_shapes`` there is no host synchronisation and no data-dependent shape: it
    compiles whole (``torch.compile(advance, fullgraph=True)``), and run eagerly it is the
    compiled step's twin.
    """
    space = space_of(cfg, state["climb"])  # None in the plane (section 11)
    # In the "velocity" action mode the action is the velocity command (rule-based controllers).
    command = action_to_command(action, state["heading"], space) if cfg.action_mode == "policy" else action
    if cfg.instinct:
        use = sensed["instinct_triggered"]
        command = torch.where(use[..., None], sensed["instinct_command"], command)
    else:
        use = torch.zeros_like(sensed["instinct_triggered"])
    command = clip_command(command, cfg.v_max)
    position, velocity = first_order_step(state["position"], state["velocity"], command, cfg.dt, cfg.tau_v)
    climb = state["climb"]
    if space is not None:  # the ground and ceiling, and the flight-path angle (section 11)
        position, velocity = clamp_altitude(position, velocity, *cfg.altitude)
        heading, climb = update_attitude(state["heading"], climb, velocity, cfg.heading_speed_threshold)
    else:
        heading = update_heading(state["heading"], velocity, cfg.heading_speed_threshold)
    moving_position, moving_velocity = state["moving_position"], state["moving_velocity"]
    if cfg.n_moving:
        moving_position, moving_velocity = reflect_in_box(
            moving_position + cfg.dt * moving_velocity, moving_velocity, 0.0, cfg.area_size)
    physical = {"position": position, "heading": heading, "climb": climb, "goal": state["goal"],
                "moving_position": moving_position, "drawn_circles": state["drawn_circles"],
                "drawn_rectangles": state["drawn_rectangles"], "drawn_spheres": state["drawn_spheres"]}
    now = sense(physical, static, cfg, normals, static_shapes)
    prev_action = torch.where(state["has_prev_action"][:, None, None], state["prev_action"], action)
    d_collision = now["d_scan1"]
    if cfg.collision_reward_source == "min_uav_scan":
        d_collision = torch.minimum(now["d_uav1"], d_collision)
    centre = position.mean(-2, keepdim=True)
    reward = total_reward(
        d_goal=now["d_goal"], d_goal_prev=sensed["d_goal"], alpha_goal=now["alpha_goal"],
        goal_radius=cfg.goal_radius, d_collision=d_collision,
        heading_deviation=wrap(stored(heading - circular_mean(heading, -1, keepdim=True))),
        d_centre=length(position - centre, space),
        action=action, prev_action=prev_action, reach=cohesion_range(cfg.cohesion_range, position.shape[-2]),
        shape=cfg.collision_shape)
    reached = (now["d_goal"] < cfg.goal_radius).any(-1)
    crashed = (now["obstacle_distance"] < cfg.collision_distance).any(-1)
    stats = step_statistics(position, velocity, heading, now["obstacle_distance"], now["closest_pair"], space)
    terminated = reached | crashed
    if cfg.uav_collision_terminates:
        terminated = terminated | (stats["uav"] < cfg.collision_distance)
    episode = update_episode(dict(episode), stats, reached, crashed, cfg.dt, reward.mean(-1))
    new = world_state(
        position=position, velocity=velocity, heading=heading, climb=climb, goal=state["goal"],
        moving_position=moving_position, moving_velocity=moving_velocity, drawn_circles=state["drawn_circles"],
        drawn_rectangles=state["drawn_rectangles"], drawn_spheres=state["drawn_spheres"], command=command,
        instinct=use, prev_action=action,
        has_prev_action=torch.ones_like(state["has_prev_action"]), terminated=terminated[:, None],
        truncated=(episode["steps"] >= cfg.max_steps)[:, None] & ~terminated[:, None])
    return new, now, episode, reward


def step_function(static: Obstacles, cfg: ScenarioConfig, device: torch.device, compile_step: bool = False,
                  capture_step: bool = False):
    """The env's step, :func:`transition` with its obstacles and scenario bound: compiled or captured
    (on a GPU, a CUDA graph: ``flock_torchrl.capture``), it measures every UAV pair and every (beam,
    obstacle) pair (static shapes). Called ``(state, sensed, episode, action, normals=...)``: what
    changes, all tensors (what a captured function is given each call is copied into its graph's
    inputs); the obstacles and the scenario are bound (a graph holds them as they are)."""
    step = functools.partial(transition, static_shapes=compile_step or capture_step)
    if compile_step:
        step = torch.compile(step, dynamic=False, fullgraph=True, options=STEP_COMPILE_OPTIONS)
    return captured(functools.partial(step, static=static, cfg=cfg), device, capture_step)


def transition(state: Tensors, sensed: Tensors, episode: Tensors, action: torch.Tensor, static: Obstacles,
               cfg: ScenarioConfig, normals: Tensors | None = None, static_shapes: bool = False
               ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor], dict[str, torch.Tensor], torch.Tensor,
                          dict[str, torch.Tensor]]:
    """:func:`advance`, plus the episode summary the env returns with it
    (:func:`~.metrics.summary_values`): the function the env runs (and compiles) per step."""
    state, sensed, episode, reward = advance(state, sensed, episode, action, static, cfg, normals, static_shapes)
    return state, sensed, episode, reward, summary_values(episode, cfg.collision_distance)
