"""UAV kinematics (Eq. 1) and the policy's action-to-command map (Eq. 19-20), in the plane or in
space (docs/specification.md section 11)."""

from __future__ import annotations

import math

import torch

from .space import Space


def action_to_command(action: torch.Tensor, heading: torch.Tensor, space: Space | None = None) -> torch.Tensor:
    """Velocity command from a policy action (Eq. 19-20).

    ``dphi = a0 pi/2``, ``V = a1 + 2``, command ``V (cos(phi + dphi), sin(phi + dphi))``. In
    ``space`` the action ``[a0, a1, a2]`` also commands the flight-path angle ``gamma_c = a2
    gamma_max`` (``space.climb_max``): ``V (cos gamma_c cos(phi + dphi), cos gamma_c sin(phi +
    dphi), sin gamma_c)`` (section 11; with ``gamma_max = 0`` the horizontal part is the 2-D
    command bit for bit).

    Args:
        action: ``[..., 2]`` (in space ``[..., 3]``) in ``[-1, 1]``.
        heading: ``[...]`` current heading ``phi``.

    Returns:
        ``[..., 2]`` (``[..., 3]``) velocity command (not yet clipped).
    """
    direction = heading + action[..., 0] * (math.pi / 2)
    speed = action[..., 1] + 2.0
    if space is None:
        return torch.stack((speed * torch.cos(direction), speed * torch.sin(direction)), -1)
    climb = action[..., 2] * space.climb_max
    horizontal = speed * torch.cos(climb)
    return torch.stack((horizontal * torch.cos(direction), horizontal * torch.sin(direction),
                        speed * torch.sin(climb)), -1)


def clip_command(command: torch.Tensor, v_max: float) -> torch.Tensor:
    """Clip a velocity command per axis to ``[-v_max, v_max]`` (specification section 1)."""
    return command.clamp(-v_max, v_max)


def first_order_step(position: torch.Tensor, velocity: torch.Tensor, command: torch.Tensor, dt: float, tau_v: float
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """One semi-implicit Euler step of Eq. 1.

    ``v <- v + dt/tau_v (v_cmd - v)``, then ``p <- p + dt v`` (the new velocity).

    Args:
        position, velocity, command: ``[..., 2]``; the command is used as given (clip first).

    Returns:
        ``(position, velocity)`` after the step.
    """
    velocity = velocity + (dt / tau_v) * (command - velocity)
    return position + dt * velocity, velocity


def update_heading(heading: torch.Tensor, velocity: torch.Tensor, threshold: float) -> torch.Tensor:
    """Heading follows the velocity where the speed exceeds ``threshold``, else is kept (specification section 1)."""
    speed = torch.linalg.vector_norm(velocity, dim=-1)
    return torch.where(speed > threshold, torch.atan2(velocity[..., 1], velocity[..., 0]), heading)


def update_attitude(heading: torch.Tensor, climb: torch.Tensor, velocity: torch.Tensor, threshold: float
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """3-D heading and flight-path angle (section 11): ``phi = atan2(v_y, v_x)`` where the
    horizontal speed exceeds ``threshold``, ``gamma = atan2(v_z, |v_h|)`` where the speed does;
    otherwise each is kept. Level flight updates ``phi`` as :func:`update_heading` does."""
    horizontal = torch.linalg.vector_norm(velocity[..., :2], dim=-1)
    # The speed as geometry.length gives it in space: a level velocity's is its horizontal speed, bit for bit.
    speed = torch.where(velocity[..., 2] == 0, horizontal, torch.linalg.vector_norm(velocity, dim=-1))
    heading = torch.where(horizontal > threshold, torch.atan2(velocity[..., 1], velocity[..., 0]), heading)
    climb = torch.where(speed > threshold, torch.atan2(velocity[..., 2], horizontal), climb)
    return heading, climb


def clamp_altitude(position: torch.Tensor, velocity: torch.Tensor, ground: float, ceiling: float
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """The autopilot's floor and ceiling (section 11): altitudes clamped into ``[ground, ceiling]``,
    the vertical velocity set to 0 where clamped. Positions and velocities ``[..., 3]``."""
    z = position[..., 2]
    held = (z < ground) | (z > ceiling)
    position = torch.cat((position[..., :2], z.clamp(ground, ceiling)[..., None]), -1)
    velocity = torch.cat((velocity[..., :2], torch.where(held, 0.0, velocity[..., 2])[..., None]), -1)
    return position, velocity


def reflect_in_box(position: torch.Tensor, velocity: torch.Tensor, low: float, high: float
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """Mirror points that left ``[low, high]`` per axis back inside, flipping that velocity axis (S5)."""
    below, above = position < low, position > high
    position = torch.where(below, 2 * low - position, torch.where(above, 2 * high - position, position))
    velocity = torch.where(below | above, -velocity, velocity)
    return position, velocity
