"""Policy-OP: Vasarhelyi et al. 2018 flocking, with self-propulsion towards the goal.

G. Vasarhelyi, Cs. Viragh, G. Somorjai, T. Nepusz, A. E. Eiben, T. Vicsek, "Optimized
flocking of autonomous drones in confined environments", Science Robotics 3(20), 2018.
Each term's docstring states its formula (Materials and Methods, as collected in docs/baselines.md,
"Policy-OP — Vasarhelyi et al. 2018"); the desired velocity is their sum with a speed cap.

The controller outputs a desired velocity, which is exactly this world's command (Eq. 1 of
Bai et al. has the same first-order robot model as the paper's simulator). The original has
no goal: its self-propulsion keeps the current direction. Here it points at the goal
(docs/baselines.md, "Policy-OP"). Sensing is limited as for the learned policies (section 7): neighbours are the
UAVs the camera sees, with their relative velocities; a shill agent sits at each obstacle's
nearest laser hit and moves away from the surface along the normal hit -> UAV.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .params import check_params
from .sensing import Percept, RuleBasedPolicy, cap_norm, unit


def braking_curve(r: torch.Tensor, a: float, p: float) -> torch.Tensor:
    """Optimal braking curve ``D(r, a, p)``, elementwise.

    0 for ``r <= 0``; ``r p`` for ``0 < r < a / p^2``; ``sqrt(2 a r - a^2 / p^2)`` beyond: the
    largest speed from which one can stop within ``r`` at deceleration ``a`` (with a linear
    part of gain ``p`` near the stop).
    """
    r = r.clamp_min(0.0)
    linear = r * p
    sqrt_part = torch.sqrt((2.0 * a * r - a * a / (p * p)).clamp_min(0.0))
    return torch.where(r < a / (p * p), linear, sqrt_part)


def self_propulsion(to_goal: torch.Tensor, v_flock: float) -> torch.Tensor:
    """Self-propulsion at the preferred speed ``v_flock`` towards the goal, ``[B, N, 2]``.

    Replaces the original's ``v_flock v_i / |v_i|`` (no goal there) by the unit vector to the
    goal. ``to_goal``: ``q_goal - q_i`` ``[B, N, 2]``.
    """
    return v_flock * unit(to_goal)


def repulsion(offset: torch.Tensor, distance: torch.Tensor, visible: torch.Tensor, p_rep: float,
              r0_rep: float) -> torch.Tensor:
    """Linear short-range repulsion: ``sum_j p_rep (r0 - r_ij) (q_i - q_j) / r_ij`` for ``r_ij < r0``.

    Args:
        offset: ``q_j - q_i`` ``[B, N, N, 2]``; distance: ``r_ij`` ``[B, N, N]``; visible: ``[B, N, N]``.

    Returns:
        ``[B, N, 2]``.
    """
    active = visible & (distance < r0_rep) & (distance > 0)
    gain = torch.where(active, p_rep * (r0_rep - distance) / distance.clamp_min(1e-9), torch.zeros_like(distance))
    return -(gain[..., None] * offset).sum(-2)


def friction(relative_velocity: torch.Tensor, distance: torch.Tensor, visible: torch.Tensor, *, c_frict: float,
             v_frict: float, r0_frict: float, a_frict: float, p_frict: float) -> torch.Tensor:
    """Velocity alignment as viscous friction.

    ``v_ij = |v_j - v_i|``, ``v_ij^max = max(v_frict, D(r_ij - r0_frict, a_frict, p_frict))``;
    ``sum_j C_frict (v_ij - v_ij^max) (v_j - v_i) / v_ij`` where ``v_ij > v_ij^max``: velocity
    differences up to the slack ``v_frict`` (nearby) or the braking curve (far) are tolerated.

    Args:
        relative_velocity: ``v_j - v_i`` ``[B, N, N, 2]``; distance: ``[B, N, N]``; visible: ``[B, N, N]``.

    Returns:
        ``[B, N, 2]``.
    """
    speed = torch.linalg.vector_norm(relative_velocity, dim=-1)
    allowed = braking_curve(distance - r0_frict, a_frict, p_frict).clamp_min(v_frict)
    excess = torch.where(visible & (speed > allowed), c_frict * (speed - allowed), torch.zeros_like(speed))
    return (excess[..., None] * relative_velocity / speed.clamp_min(1e-9)[..., None]).sum(-2)


def shill(hit_distance: torch.Tensor, hit_normal: torch.Tensor, seen: torch.Tensor, velocity: torch.Tensor, *,
          v_shill: float, r0_shill: float, a_shill: float, p_shill: float) -> torch.Tensor:
    """Obstacle avoidance by shill agents, one per obstacle at its nearest laser hit.

    The shill agent moves at ``v_s = v_shill n`` (``n`` the surface normal, hit -> UAV);
    ``v_is = |v_s - v_i|``; the UAV aligns with it when ``v_is`` exceeds the braking curve
    ``D(r_is - r0_shill, a_shill, p_shill)``: ``(v_is - D) (v_s - v_i) / v_is``.

    Args:
        hit_distance: ``r_is`` ``[B, N, M]``; hit_normal: ``[B, N, M, 2]``; seen: ``[B, N, M]``;
        velocity: ``v_i`` ``[B, N, 2]``.

    Returns:
        ``[B, N, 2]``.
    """
    difference = v_shill * hit_normal - velocity[:, :, None, :]                # v_s - v_i
    speed = torch.linalg.vector_norm(difference, dim=-1)
    allowed = braking_curve(torch.where(seen, hit_distance, torch.zeros_like(hit_distance)) - r0_shill,
                            a_shill, p_shill)
    excess = torch.where(seen & (speed > allowed), speed - allowed, torch.zeros_like(speed))
    return (excess[..., None] * difference / speed.clamp_min(1e-9)[..., None]).sum(-2)


@dataclass
class VasarhelyiParams:
    """The 2018 paper's parameters; their values (rescaled to this world) live in ``conf/policy/policy_op.yaml``."""

    v_flock: float         # preferred speed (m/s)
    v_max: float           # speed cap on the desired velocity (m/s)
    r0_rep: float          # repulsion range (m)
    p_rep: float           # repulsion gain (1/s)
    r0_frict: float        # friction: distance where the braking-curve slack starts (m)
    c_frict: float         # friction coefficient
    v_frict: float         # friction slack: tolerated velocity difference (m/s)
    p_frict: float         # braking curve gain (1/s)
    a_frict: float        # braking curve deceleration (m/s^2)
    r0_shill: float        # shill: stopping point in front of the obstacle (m)
    v_shill: float         # shill agents' speed (m/s)
    p_shill: float        # shill braking gain (1/s)
    a_shill: float        # shill braking deceleration (m/s^2)

    def __post_init__(self) -> None:
        check_params(self, positive=("v_flock", "v_max", "r0_rep", "p_frict", "a_frict", "v_shill", "p_shill",
                                     "a_shill"),
                     non_negative=("p_rep", "r0_frict", "c_frict", "v_frict", "r0_shill"))


class VasarhelyiPolicy(RuleBasedPolicy):
    """Policy-OP as a :class:`RuleBasedPolicy` (its arguments; ``params``: :class:`VasarhelyiParams`).

    Example:
        >>> from flock_torchrl import FlockingEnv, make_policy
        >>> env = FlockingEnv("s1", num_envs=2, seed=0, policy_id="policy_op", extras=("physics", "laser"))
        >>> td = env.rollout(3, policy=make_policy("policy_op", env))
        >>> td["agents", "action"].shape
        torch.Size([2, 3, 5, 2])
    """

    params: VasarhelyiParams

    def command(self, percept: Percept) -> torch.Tensor:
        """``v_d`` (sum of the terms) ``[B, N, 2]``, capped at ``min(v_max, scenario v_max)``."""
        p, view, hits = self.params, percept.neighbours, percept.obstacles
        desired = (self_propulsion(percept.to_goal, p.v_flock)
                   + repulsion(view.offset, view.distance, view.visible, p.p_rep, p.r0_rep)
                   + friction(view.relative_velocity, view.distance, view.visible, c_frict=p.c_frict,
                              v_frict=p.v_frict, r0_frict=p.r0_frict, a_frict=p.a_frict, p_frict=p.p_frict)
                   + shill(hits.distance, hits.normal, hits.seen, percept.velocity, v_shill=p.v_shill,
                           r0_shill=p.r0_shill, a_shill=p.a_shill, p_shill=p.p_shill))
        return cap_norm(desired, min(p.v_max, self.env_cfg.v_max))


__all__ = ["VasarhelyiParams", "VasarhelyiPolicy", "braking_curve", "friction", "repulsion", "self_propulsion",
           "shill"]
