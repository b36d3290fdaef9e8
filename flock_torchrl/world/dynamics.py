"""UAV kinematics (Eq. 1) and the policy's action-to-command map (Eq. 19-20)."""

from __future__ import annotations

import math

import torch


def action_to_command(action: torch.Tensor, heading: torch.Tensor) -> torch.Tensor:
    """Velocity command from a policy action (Eq. 19-20).

    ``dphi = a0 pi/2``, ``V = a1 + 2``, command ``V (cos(phi + dphi), sin(phi + dphi))``.

    Args:
        action: ``[..., 2]`` in ``[-1, 1]``.
        heading: ``[...]`` current heading ``phi``.

    Returns:
        ``[..., 2]`` velocity command (not yet clipped).
    """
    direction = heading + action[..., 0] * (math.pi / 2)
    speed = action[..., 1] + 2.0
    return torch.stack((speed * torch.cos(direction), speed * torch.sin(direction)), -1)


def clip_command(command: torch.Tensor, v_max: float) -> torch.Tensor:
    """Clip a velocity command per axis to ``[-v_max, v_max]`` (specification section 1)."""
    return command.clamp(-v_max, v_max)


def first_order_step(
    position: torch.Tensor, velocity: torch.Tensor, command: torch.Tensor, dt: float, tau_v: float
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


def reflect_in_box(position: torch.Tensor, velocity: torch.Tensor, low: float, high: float
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """Mirror points that left ``[low, high]`` per axis back inside, flipping that velocity axis (S5)."""
    below, above = position < low, position > high
    position = torch.where(below, 2 * low - position, torch.where(above, 2 * high - position, position))
    velocity = torch.where(below | above, -velocity, velocity)
    return position, velocity
