"""Per-UAV reward (docs/specification.md section 4; paper Eq. 21-25), in raw units."""

from __future__ import annotations

import math

import torch

from ..config.scenario import COHESION_RANGES, COLLISION_SHAPES


def goal_reward(d_goal: torch.Tensor, d_goal_prev: torch.Tensor, alpha_goal: torch.Tensor,
                goal_radius: float) -> torch.Tensor:
    """``r_g`` (Eq. 22): 20 inside the goal, else ``0.2 (d_prev - d) + 0.02 (pi/2 - |alpha_g|) - 0.02``."""
    shaping = 0.2 * (d_goal_prev - d_goal) + 0.02 * (math.pi / 2 - alpha_goal.abs()) - 0.02
    return torch.where(d_goal < goal_radius, torch.full_like(shaping, 20.0), shaping)


def collision_reward(d: torch.Tensor, shape: str = "paper") -> torch.Tensor:
    """``r_c`` (Eq. 23): -0.2 on (2, 3], -0.5 on (0.5, 2], -1 on [0, 0.5], else 0.

    ``shape="ramp"`` (beyond the paper): -1 on [0, 0.5], then ``-(3 - d) / 2.5`` up to 0 at 3 m,
    the same end points with a slope, so that more spacing always pays inside 3 m.
    """
    if shape == "ramp":
        return -((3.0 - d) / 2.5).clamp(0.0, 1.0)
    if shape != "paper":
        raise ValueError(f"collision_shape must be one of {', '.join(COLLISION_SHAPES)}; got {shape!r}")
    # Levels built in d's dtype: scalar branches of torch.where would be float32 (-0.2 -> -0.200000003).
    zero = torch.zeros_like(d)
    return torch.where(d <= 0.5, zero - 1.0, torch.where(d <= 2.0, zero - 0.5, torch.where(d <= 3.0, zero - 0.2, zero)))


def cohesion_range(mode: str, n_uavs: int) -> float:
    """The range (m) of ``r_f``'s cohesion term: 3 m (Eq. 24, ``paper``), or ``3 sqrt(N / 5)`` m
    (``sqrt_n``, beyond the paper: the radius that grows with a swarm of N UAVs at the density of
    five, so that a large swarm is not rewarded for packing denser than a small one)."""
    if mode == "paper":
        return 3.0
    if mode == "sqrt_n":
        return 3.0 * math.sqrt(n_uavs / 5.0)
    raise ValueError(f"cohesion_range must be one of {', '.join(COHESION_RANGES)}; got {mode!r}")


def flocking_reward(heading_deviation: torch.Tensor, d_centre: torch.Tensor, reach: float = 3.0) -> torch.Tensor:
    """``r_f`` (Eq. 24): ``0.05 (1 - |wrap(phi_i - phi_bar)| / pi) + 0.05 (1 - d_c,i / 3)``.

    Args:
        heading_deviation: ``wrap(phi_i - phi_bar)``; d_centre: distance to the swarm centre.
        reach: the cohesion term's range, Eq. 24's 3 m unless :func:`cohesion_range` says otherwise.
    """
    return 0.05 * (1 - heading_deviation.abs() / math.pi) + 0.05 * (1 - d_centre / reach)


def smoothness_reward(action: torch.Tensor, prev_action: torch.Tensor) -> torch.Tensor:
    """``r_v`` (Eq. 25): ``-0.02 ||a_{t-1} - a_t||_1`` over the action's last dimension."""
    return -0.02 * (prev_action - action).abs().sum(-1)


def total_reward(*, d_goal, d_goal_prev, alpha_goal, goal_radius, d_collision, heading_deviation,
                 d_centre, action, prev_action, reach: float = 3.0, shape: str = "paper") -> torch.Tensor:
    """``r = r_g + r_c + r_f + r_v`` (Eq. 21), all ``[B, N]``."""
    return (goal_reward(d_goal, d_goal_prev, alpha_goal, goal_radius) + collision_reward(d_collision, shape)
            + flocking_reward(heading_deviation, d_centre, reach) + smoothness_reward(action, prev_action))
