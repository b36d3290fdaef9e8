"""What a rule-based UAV knows (docs/specification.md section 7): its camera's neighbours and its laser's obstacles.

In 3-D (section 11) the same views hold 3-vectors: the controllers' equations are dimension-free.

Both baselines read only onboard, sensor-limited information: the neighbours its camera sees
(range ``d_v``, field of view ``phi_v``) with their relative velocities, the laser returns,
its own velocity and heading, and the goal. This module turns the env's tensordict entries
into those two views; the controllers never see other UAVs' or obstacles' true state.

Everything is batched over ``[B, N]`` (pairs ``[B, N, N]``, obstacles ``[B, N, M]``); there
is no Python loop over environments, UAVs, beams or obstacles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from ...world.laser import beam_azimuths, beam_offsets, ring_tables
from ...world.sensors import add_sensor_noise, near_neighbours, observe_neighbours
from ...world.space import Space, space_of


@dataclass
class NeighbourView:
    """What UAV ``i`` (row) measures of UAV ``j`` (column), ``[B, N, N, ...]``.

    Attributes:
        offset: measured ``q_j - q_i`` in the world frame ``[B, N, N, 2]`` (0 where not visible).
        distance: measured ``|q_j - q_i|`` ``[B, N, N]``.
        relative_velocity: ``p_j - p_i`` ``[B, N, N, 2]`` (0 where not visible).
        visible: camera detection ``[B, N, N]`` (never oneself).
    """

    offset: torch.Tensor
    distance: torch.Tensor
    relative_velocity: torch.Tensor
    visible: torch.Tensor


def neighbour_view(position: torch.Tensor, velocity: torch.Tensor, heading: torch.Tensor, camera_range: float,
                   half_fov: float, noise: tuple[float, float] | None = None,
                   generator: torch.Generator | None = None, space: Space | None = None) -> NeighbourView:
    """The camera's view of the other UAVs plus their relative velocities (specification section 2 camera, specification section 7).

    Args:
        position, velocity: ``[B, N, 2]``; heading: ``[B, N]``.
        camera_range, half_fov: ``d_v`` and the largest visible bearing (``ScenarioConfig.half_fov``).
        noise: ``(distance_std, angle_std)`` of the S4 camera noise, or ``None``; the bearing
            and distance a UAV measures then carry it, as they do in the env's observation.
        generator: source of that noise.
        space: docs/specification.md section 11, with the flight-path angles ``climb [B, N]``; positions
            and velocities are then ``[B, N, 3]`` and the camera is the cone about the direction of flight.

    Returns:
        A :class:`NeighbourView`; entries of invisible pairs are zeroed.
    """
    if space is None:
        seen = observe_neighbours(position, heading, camera_range, half_fov)
    else:  # every pair, measured as the world's camera measures it
        seen = near_neighbours(position, heading, camera_range, half_fov, static_shapes=True, space=space)[0]
    if noise is not None:
        dummy_beams = position.new_zeros(position.shape[:-1] + (1,))
        _, seen = add_sensor_noise(dummy_beams, seen, scan_std=0.0, distance_std=noise[0], angle_std=noise[1],
                                   max_range=1.0, generator=generator)
    visible = seen.visible
    offset = seen.offsets(heading) * visible[..., None]
    relative_velocity = (velocity[:, None, :, :] - velocity[:, :, None, :]) * visible[..., None]
    return NeighbourView(offset, seen.distance * visible, relative_velocity, visible)


@dataclass
class ObstacleView:
    """The nearest laser return on each obstacle, ``[B, N, M, ...]`` (``M`` obstacles).

    One obstacle counts once however many beams hit it (a wall is one beta-agent / one
    shill agent, not 36).

    Attributes:
        distance: length of the shortest beam that hit obstacle ``m`` ``[B, N, M]`` (``inf`` if none).
        offset: hit point minus the UAV's position ``[B, N, M, 2]`` (0 where not seen).
        normal: unit vector from the hit point to the UAV ``[B, N, M, 2]`` (the estimated
            outward surface normal; 0 where not seen).
        seen: some beam hit obstacle ``m`` within range ``[B, N, M]``.
    """

    distance: torch.Tensor
    offset: torch.Tensor
    normal: torch.Tensor
    seen: torch.Tensor


def nearest_hits(scan: torch.Tensor, scan_obstacle: torch.Tensor, heading: torch.Tensor,
                 n_obstacles: int, space: Space | None = None) -> ObstacleView:
    """Nearest laser hit per obstacle (docs/baselines.md, "What a baseline UAV senses").

    Beam ``k`` points at ``heading + k * 2 pi / K``. For each obstacle the shortest beam that hit
    it gives the hit point; the estimated surface normal points from that point back to the
    UAV (minus the beam's direction). With 10 deg beams the direction error is at most 5 deg.

    Args:
        scan: sensed beam lengths ``[B, N, K]``; scan_obstacle: obstacle index per beam
            ``[B, N, K]`` (-1: none); heading: ``[B, N]``; n_obstacles: ``M``.
        space: section 11, its ``laser``'s beams (:class:`~flock_torchrl.config.scenario.Laser`);
            offsets and normals are then ``[B, N, M, 3]``.

    Returns:
        An :class:`ObstacleView` over ``M`` obstacles (``M = 0`` gives empty tensors).
    """
    ids = torch.arange(n_obstacles, device=scan.device)
    hits = scan_obstacle[..., None] == ids                                  # [B, N, K, M]
    lengths = torch.where(hits, scan[..., None], torch.full_like(scan[..., None], math.inf))
    if n_obstacles == 0:
        distance = scan.new_zeros(scan.shape[:-1] + (0,))
        beam = torch.zeros_like(distance, dtype=torch.long)
    else:
        distance, beam = lengths.min(-2)                                    # [B, N, M]
    seen = torch.isfinite(distance)
    if space is None:
        angle = heading[..., None] + beam_offsets(scan.shape[-1], scan.device, scan.dtype)[beam]
        direction = torch.stack((torch.cos(angle), torch.sin(angle)), -1)   # UAV -> hit, [B, N, M, 2]
    else:
        angle = heading[..., None] + beam_azimuths(space.laser, beam, scan)
        cos_e, sin_e = (t[beam] for t in ring_tables(space.laser, scan))
        direction = torch.stack((cos_e * torch.cos(angle), cos_e * torch.sin(angle), sin_e), -1)
    mask = seen[..., None]
    offset = torch.where(mask, distance.clamp_max(1e9)[..., None] * direction, torch.zeros_like(direction))
    return ObstacleView(distance, offset, torch.where(mask, -direction, torch.zeros_like(direction)), seen)


def obstacle_count(env_cfg) -> int:
    """Obstacles a scenario's laser can tell apart: fixed, moving and drawn circles, fixed and
    drawn rectangles."""
    return env_cfg.n_obstacles


def cap_norm(vector: torch.Tensor, max_norm: float) -> torch.Tensor:
    """Scale ``vector[..., 2]`` down to norm ``max_norm`` where it is longer."""
    norm = torch.linalg.vector_norm(vector, dim=-1, keepdim=True)
    return vector * (max_norm / norm.clamp_min(max_norm))


def unit(vector: torch.Tensor, eps: float = 1e-9) -> torch.Tensor:
    """``vector / |vector|`` (0 for the zero vector), ``[..., 2]``."""
    return vector / torch.linalg.vector_norm(vector, dim=-1, keepdim=True).clamp_min(eps)


@dataclass
class Percept:
    """Everything a rule-based UAV knows at one step, batched ``[B, N, ...]``."""

    velocity: torch.Tensor      # own velocity p_i [B, N, 2]
    to_goal: torch.Tensor       # q_goal - q_i [B, N, 2]
    neighbours: NeighbourView   # the camera's view [B, N, N]
    obstacles: ObstacleView     # nearest laser hit per obstacle [B, N, M]


class RuleBasedPolicy(TensorDictModuleBase):
    """Base of the baselines' modules: reads the env's raw sensing, writes the velocity command.

    Subclasses implement :meth:`command` on a :class:`Percept`. The env must run with
    ``action_mode="velocity"``. Works on the inputs' device.

    Args:
        params: the controller's parameter dataclass.
        env_cfg: the scenario (:class:`~flock_torchrl.config.ScenarioConfig`): camera range and
            field of view, ``tau_v``, ``v_max``, obstacle count, S4 noise.
        seed: seed of the S4 camera-noise generator (the env does not expose its noisy camera
            measurements, so the module draws the same noise model itself).
    """

    def __init__(self, params: Any, env_cfg: Any, seed: int = 0) -> None:
        super().__init__()
        self.in_keys = [("agents", "position"), ("agents", "velocity"), ("agents", "heading"),
                        ("agents", "scan"), ("agents", "scan_obstacle"), "goal"]
        if env_cfg.dims == 3:  # the flight-path angle (section 11)
            self.in_keys.append(("agents", "climb"))
        self.out_keys = [("agents", "action")]
        self.params, self.env_cfg, self.seed = params, env_cfg, seed
        self.n_obstacles = obstacle_count(env_cfg)
        self._generator: torch.Generator | None = None

    def _camera_noise(self, device: torch.device):
        if not self.env_cfg.noise:
            return None, None
        if self._generator is None or self._generator.device != device:
            self._generator = torch.Generator(device=device)
            self._generator.manual_seed(self.seed)
        return (self.env_cfg.noise_distance, self.env_cfg.noise_angle), self._generator

    def perceive(self, tensordict: TensorDictBase) -> Percept:
        """The sensor-limited view of every UAV from the env's tensordict."""
        cfg = self.env_cfg
        position, velocity = tensordict["agents", "position"], tensordict["agents", "velocity"]
        heading = tensordict["agents", "heading"]
        noise, generator = self._camera_noise(position.device)
        space = space_of(cfg, tensordict.get(("agents", "climb"), None))  # None in the plane
        return Percept(
            velocity=velocity,
            to_goal=tensordict["goal"][:, None, :] - position,
            neighbours=neighbour_view(position, velocity, heading, cfg.camera_range, cfg.half_fov, noise, generator,
                                      space),
            obstacles=nearest_hits(tensordict["agents", "scan"], tensordict["agents", "scan_obstacle"], heading,
                                   self.n_obstacles, space),
        )

    def command(self, percept: Percept) -> torch.Tensor:
        """Velocity command ``[B, N, 2]``."""
        raise NotImplementedError

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        tensordict.set(("agents", "action"), self.command(self.perceive(tensordict)))
        return tensordict


__all__ = ["NeighbourView", "ObstacleView", "Percept", "RuleBasedPolicy", "cap_norm", "nearest_hits",
           "neighbour_view", "obstacle_count", "unit"]
