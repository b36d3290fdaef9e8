"""Episode generator: swarm starts, goals (Eq. 30) and moving obstacles (S5), vectorised.

Rejection sampling redraws only the offending samples, with a bounded number of rounds; a
layout that still fails raises :class:`SpawnError` instead of hanging. Densities that make
this likely are refused earlier, by :func:`flock_torchrl.config.validate_scenario`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .config import ScenarioConfig
from .geometry import Obstacles, distance_to_obstacles, pairwise


class SpawnError(RuntimeError):
    """No valid layout was found within ``spawn_max_tries`` rounds."""


@dataclass
class Layout:
    """One episode's start, per env: ``goal [B, 2]``, ``position [B, N, 2]``, ``heading [B, N]``,
    moving circles ``moving_position [B, K, 2]`` and ``moving_velocity [B, K, 2]``."""

    goal: torch.Tensor
    position: torch.Tensor
    heading: torch.Tensor
    moving_position: torch.Tensor
    moving_velocity: torch.Tensor


def _uniform(shape, generator, device, low=0.0, high=1.0):
    return low + (high - low) * torch.rand(shape, generator=generator, device=device)


def _angle(shape, generator, device):
    return _uniform(shape, generator, device, -math.pi, math.pi)


def _in_disc(shape, radius, generator, device):
    r = radius * torch.sqrt(_uniform(shape, generator, device))
    theta = _angle(shape, generator, device)
    return torch.stack((r * torch.cos(theta), r * torch.sin(theta)), -1)


def _first_of_close_pairs(position: torch.Tensor, separation: float) -> torch.Tensor:
    """``[B, N]``: UAV j is closer than ``separation`` to some UAV i < j."""
    _, dist = pairwise(position)
    n = position.shape[-2]
    earlier = torch.ones(n, n, dtype=torch.bool, device=position.device).tril(-1)  # [j, i]: i < j
    return ((dist < separation) & earlier).any(-1)


def sample_layout(cfg: ScenarioConfig, batch: int, static: Obstacles, generator: torch.Generator,
                  device: torch.device) -> Layout:
    """Draw ``batch`` episode starts (SPEC 1 "Starts and goals", SPEC 6 "S5").

    Args:
        static: the scenario's static obstacles, batch dimension of size 1 or ``batch``.
    """
    n = cfg.n_uavs
    cx, cy = cfg.area_center
    chi = _angle((batch,), generator, device)
    unit = torch.stack((torch.cos(chi), torch.sin(chi)), -1)
    area_center = torch.tensor([cx, cy], device=device)
    swarm_centre = area_center + cfg.d_env * unit
    goal = area_center - cfg.d_env * unit  # angle chi + pi
    static_b = Obstacles(static.circles.expand(batch, -1, -1), static.rectangles.expand(batch, -1, -1))

    position = swarm_centre[:, None] + _in_disc((batch, n), cfg.spawn_radius, generator, device)
    for _ in range(cfg.spawn_max_tries):
        bad = _first_of_close_pairs(position, cfg.spawn_separation)
        if static_b.count:
            bad |= distance_to_obstacles(position, static_b).amin(-1) < cfg.spawn_clearance
        if not bad.any():
            break
        fresh = swarm_centre[:, None] + _in_disc((batch, n), cfg.spawn_radius, generator, device)
        position = torch.where(bad[..., None], fresh, position)
    else:
        raise SpawnError(
            f"could not place {n} UAVs {cfg.spawn_separation} m apart and {cfg.spawn_clearance} m from "
            f"obstacles within {cfg.spawn_max_tries} rounds (fields n_uavs, spawn_radius, d_env, "
            "circles, rectangles)"
        )
    heading = _angle((batch, n), generator, device)

    k = cfg.n_moving
    moving_position = torch.zeros(batch, k, 2, device=device)
    moving_velocity = torch.zeros(batch, k, 2, device=device)
    if k:
        low, high = cfg.moving_box
        moving_position = _uniform((batch, k, 2), generator, device, low, high)
        for _ in range(cfg.spawn_max_tries):
            bad = _moving_conflicts(moving_position, cfg, static_b, position, goal)
            if not bad.any():
                break
            fresh = _uniform((batch, k, 2), generator, device, low, high)
            moving_position = torch.where(bad[..., None], fresh, moving_position)
        else:
            raise SpawnError(
                f"could not place {k} moving circles clear of the static obstacles and "
                f"{cfg.moving_clearance} m from the swarm and goal within {cfg.spawn_max_tries} rounds "
                "(fields n_moving, moving_radius, moving_clearance, moving_box)"
            )
        direction = _angle((batch, k), generator, device)
        moving_velocity = cfg.moving_speed * torch.stack((torch.cos(direction), torch.sin(direction)), -1)
    return Layout(goal, position, heading, moving_position, moving_velocity)


def _moving_conflicts(centres: torch.Tensor, cfg: ScenarioConfig, static: Obstacles, uavs: torch.Tensor,
                      goal: torch.Tensor) -> torch.Tensor:
    """``[B, K]``: a moving circle overlaps a static obstacle or is too near the swarm or goal."""
    bad = torch.zeros(centres.shape[:-1], dtype=torch.bool, device=centres.device)
    if static.count:
        bad |= distance_to_obstacles(centres, static).amin(-1) < cfg.moving_radius
    points = torch.cat((uavs, goal[:, None]), 1)  # [B, N+1, 2]
    gap = torch.linalg.vector_norm(centres[:, :, None] - points[:, None], dim=-1) - cfg.moving_radius
    return bad | (gap < cfg.moving_clearance).any(-1)
