"""Policy-MA: Olfati-Saber 2006 flocking, Algorithm 3 (alpha-, beta- and gamma-agents).

R. Olfati-Saber, "Flocking for multi-agent dynamic systems: algorithms and theory",
IEEE TAC 51(3), 2006. Each helper's docstring states the paper's formula (as collected in
docs/baselines.md, "Policy-MA — Olfati-Saber Algorithm 3"): sigma-norm and its gradient, the bump function, the action
functions phi, phi_alpha, phi_beta, the beta-agents of walls and circles, and the protocol of
Algorithm 3, ``u = alpha terms + beta terms + gamma term``.

Each UAV is a double integrator for the protocol: ``u_i`` is an acceleration. This world's
UAVs take a velocity command through a first-order lag (Eq. 1 of Bai et al.,
``dv/dt = (v_cmd - v) / tau_v``), so the command ``v_cmd = v + tau_v u`` realises ``u`` exactly
until it saturates; it is norm-capped at ``v_max`` (docs/baselines.md, the parameter table of "Policy-MA").

Sensing is limited as for the learned policies (section 7): alpha-neighbours are the UAVs the
camera sees (:func:`~flock_torchrl.policies.baselines.sensing.neighbour_view`); beta-agents sit at the
nearest laser hit on each obstacle, the surface taken locally as the wall through that point
with normal towards the UAV (:func:`beta_agents_from_scan`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .params import check_params, raise_param
from .sensing import Percept, RuleBasedPolicy, cap_norm

# --------------------------------------------------------------------------- helpers


def sigma_norm(z: torch.Tensor, eps: float) -> torch.Tensor:
    """Sigma-norm ``||z||_s = (sqrt(1 + eps ||z||^2) - 1) / eps``.

    Args:
        z: vectors ``[..., 2]``. Returns ``[...]``.
    """
    return sigma_norm_of_length(torch.linalg.vector_norm(z, dim=-1), eps)


def sigma_norm_of_length(length: torch.Tensor | float, eps: float) -> torch.Tensor | float:
    """Sigma-norm of a vector of Euclidean length ``length``, elementwise."""
    if isinstance(length, torch.Tensor):
        return (torch.sqrt(1.0 + eps * length * length) - 1.0) / eps
    return (math.sqrt(1.0 + eps * length * length) - 1.0) / eps


def sigma_gradient(z: torch.Tensor, eps: float) -> torch.Tensor:
    """Gradient of the sigma-norm, ``sigma_eps(z) = z / sqrt(1 + eps ||z||^2)``.

    ``n_ij = sigma_eps(q_j - q_i)`` is the direction of the pair force; note it
    vanishes as two agents touch. ``z`` ``[..., 2]`` -> ``[..., 2]``.
    """
    return z / torch.sqrt(1.0 + eps * (z * z).sum(-1, keepdim=True))


def sigma_1(z: torch.Tensor) -> torch.Tensor:
    """Scalar ``sigma_1(z) = z / sqrt(1 + z^2)``, elementwise."""
    return z / torch.sqrt(1.0 + z * z)


def sigma_1_vector(z: torch.Tensor) -> torch.Tensor:
    """Vector ``sigma_1(z) = z / sqrt(1 + ||z||^2)`` ``[..., 2]`` (gamma-agent term of Algorithm 3)."""
    return z / torch.sqrt(1.0 + (z * z).sum(-1, keepdim=True))


def bump(z: torch.Tensor, h: float) -> torch.Tensor:
    """Bump function ``rho_h``, elementwise.

    1 on ``[0, h)``; ``0.5 (1 + cos(pi (z - h) / (1 - h)))`` on ``[h, 1]``; 0 beyond.
    """
    ramp = 0.5 * (1.0 + torch.cos(math.pi * (z - h) / (1.0 - h)))
    return torch.where(z < h, torch.ones_like(z), torch.where(z <= 1.0, ramp, torch.zeros_like(z)))


def action_phi(z: torch.Tensor, a: float, b: float) -> torch.Tensor:
    """Uneven sigmoid ``phi(z) = 0.5 ((a + b) sigma_1(z + c) + (a - b))``, ``c = |a - b| / sqrt(4ab)``.

    ``0 < a <= b`` makes ``phi(0) = 0``.
    """
    c = abs(a - b) / math.sqrt(4.0 * a * b)
    return 0.5 * ((a + b) * sigma_1(z + c) + (a - b))


def phi_alpha(z: torch.Tensor, r_alpha: float, d_alpha: float, h: float, a: float, b: float) -> torch.Tensor:
    """Pair action function ``phi_alpha(z) = rho_h(z / r_a) phi(z - d_a)``, sigma-norm units.

    Negative (repulsive) below ``d_a = ||d||_s``, 0 at it, positive (attractive) up to
    ``r_a = ||r||_s``, 0 beyond.
    """
    return bump(z / r_alpha, h) * action_phi(z - d_alpha, a, b)


def phi_beta(z: torch.Tensor, d_beta: float, h: float) -> torch.Tensor:
    """Obstacle action function ``phi_beta(z) = rho_h(z / d_b) (sigma_1(z - d_b) - 1)``.

    Purely repulsive (``<= 0``), 0 beyond ``d_b = ||d'||_s``.
    """
    return bump(z / d_beta, h) * (sigma_1(z - d_beta) - 1.0)


# --------------------------------------------------------------------------- beta-agents


def beta_agent_wall(position: torch.Tensor, velocity: torch.Tensor, normal: torch.Tensor,
                    point: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Beta-agent of a wall (hyperplane obstacle): the agent's projection on the line through ``point``.

    ``P = I - a a^T``; ``qh = P q + (I - P) y``; ``ph = P p``.

    Args:
        position, velocity: ``[..., 2]``; normal: unit normal ``a`` ``[..., 2]``; point: ``y`` ``[..., 2]``.

    Returns:
        ``(qh, ph)``, each ``[..., 2]``.
    """
    along = lambda v: (v * normal).sum(-1, keepdim=True) * normal  # noqa: E731  (I - P) v
    return position - along(position) + along(point), velocity - along(velocity)


def beta_agent_circle(position: torch.Tensor, velocity: torch.Tensor, centre: torch.Tensor,
                      radius: torch.Tensor | float) -> tuple[torch.Tensor, torch.Tensor]:
    """Beta-agent of a circular (spherical) obstacle, the agent outside it.

    ``mu = R / ||q - y||``, ``a = (q - y) / ||q - y||``, ``P = I - a a^T``;
    ``qh = mu q + (1 - mu) y``; ``ph = mu P p``.

    Args:
        position, velocity, centre: ``[..., 2]``; radius: ``[...]`` or a float.

    Returns:
        ``(qh, ph)``, each ``[..., 2]``.
    """
    offset = position - centre
    dist = torch.linalg.vector_norm(offset, dim=-1, keepdim=True)
    mu = torch.as_tensor(radius, dtype=position.dtype, device=position.device)
    mu = (mu[..., None] if mu.dim() else mu) / dist
    a = offset / dist
    tangential = velocity - (velocity * a).sum(-1, keepdim=True) * a
    return mu * position + (1.0 - mu) * centre, mu * tangential


def beta_agents_from_scan(hit_offset: torch.Tensor, hit_normal: torch.Tensor,
                          velocity: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Beta-agents seen by the laser: the wall rule at each obstacle's nearest hit.

    The nearest hit approximates the agent's projection on the obstacle and the surface there
    is taken as a wall with unit normal ``hit_normal`` (hit -> UAV). So ``qh - q = hit_offset``
    and ``ph = P p``. For a circle this gives the circle rule's ``qh`` exactly (up to beam
    resolution) and its ``ph`` without the factor ``mu = R / (R + d) < 1``, which the
    laser cannot measure.

    Args:
        hit_offset: ``qh - q`` ``[B, N, M, 2]``; hit_normal: ``[B, N, M, 2]``; velocity: ``[B, N, 2]``.

    Returns:
        ``(qh - q [B, N, M, 2], ph [B, N, M, 2])``.
    """
    p = velocity[:, :, None, :]
    return hit_offset, p - (p * hit_normal).sum(-1, keepdim=True) * hit_normal


# --------------------------------------------------------------------------- the three terms of Algorithm 3


def alpha_terms(offset: torch.Tensor, relative_velocity: torch.Tensor, visible: torch.Tensor, *, eps: float,
                r: float, d: float, h: float, a: float, b: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Alpha-agent (UAV-UAV) gradient and consensus sums of Algorithm 3 (Algorithm 1's protocol), unscaled.

    ``sum_j phi_alpha(||q_j - q_i||_s) n_ij`` and ``sum_j a_ij (p_j - p_i)`` with
    ``a_ij = rho_h(||q_j - q_i||_s / r_a)``, over the neighbours ``j`` that ``i`` sees.

    Args:
        offset: ``q_j - q_i`` ``[B, N, N, 2]``; relative_velocity: ``p_j - p_i`` ``[B, N, N, 2]``;
        visible: ``[B, N, N]``; eps, r, d, h, a, b: Olfati-Saber's constants (``r``, ``d`` in metres).

    Returns:
        ``(gradient [B, N, 2], consensus [B, N, 2])``.
    """
    z = sigma_norm(offset, eps)
    r_a, d_a = sigma_norm_of_length(r, eps), sigma_norm_of_length(d, eps)
    mask = visible.to(offset.dtype)
    force = phi_alpha(z, r_a, d_a, h, a, b) * mask
    gradient = (force[..., None] * sigma_gradient(offset, eps)).sum(-2)
    adjacency = bump(z / r_a, h) * mask
    consensus = (adjacency[..., None] * relative_velocity).sum(-2)
    return gradient, consensus


def beta_terms(beta_offset: torch.Tensor, beta_velocity: torch.Tensor, velocity: torch.Tensor, seen: torch.Tensor,
               *, eps: float, d_beta: float, r_beta: float, h: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Beta-agent (obstacle) gradient and consensus sums of Algorithm 3, unscaled.

    ``sum_k phi_beta(||qh_k - q_i||_s) nh_ik`` with ``nh_ik = sigma_eps(qh_k - q_i)`` and
    ``sum_k b_ik (ph_k - p_i)`` with ``b_ik = rho_h(||qh_k - q_i||_s / d_b)``, over the
    beta-agents within ``r'`` (``r_beta``) of the UAV.

    Args:
        beta_offset: ``qh_k - q_i`` ``[B, N, M, 2]``; beta_velocity: ``ph_k`` ``[B, N, M, 2]``;
        velocity: ``p_i`` ``[B, N, 2]``; seen: ``[B, N, M]``.

    Returns:
        ``(gradient [B, N, 2], consensus [B, N, 2])``.
    """
    dist = torch.linalg.vector_norm(beta_offset, dim=-1)
    mask = (seen & (dist < r_beta)).to(beta_offset.dtype)
    z = sigma_norm_of_length(dist, eps)
    d_b = sigma_norm_of_length(d_beta, eps)
    force = phi_beta(z, d_b, h) * mask
    gradient = (force[..., None] * sigma_gradient(beta_offset, eps)).sum(-2)
    weight = bump(z / d_b, h) * mask
    consensus = (weight[..., None] * (beta_velocity - velocity[:, :, None, :])).sum(-2)
    return gradient, consensus


def gamma_term(to_goal: torch.Tensor, velocity: torch.Tensor, c1: float, c2: float) -> torch.Tensor:
    """Gamma-agent navigational feedback of Algorithm 3 for a static goal (``p_r = 0``).

    ``-c1 sigma_1(q_i - q_r) - c2 (p_i - p_r) = c1 sigma_1(q_r - q_i) - c2 p_i``. Far from the
    goal the attraction saturates at ``c1``, so the cruise speed is about ``c1 / c2``.

    Args:
        to_goal: ``q_r - q_i`` ``[B, N, 2]``; velocity: ``p_i`` ``[B, N, 2]``. Returns ``[B, N, 2]``.
    """
    return c1 * sigma_1_vector(to_goal) - c2 * velocity


def acceleration_to_command(velocity: torch.Tensor, acceleration: torch.Tensor, tau_v: float,
                            v_max: float) -> torch.Tensor:
    """Velocity command realising ``acceleration`` through Eq. 1's lag: ``cap(v + tau_v u, v_max)``.

    ``[B, N, 2]`` -> ``[B, N, 2]``; the norm cap keeps the direction (the env's per-axis clip
    would bend it).
    """
    return cap_norm(velocity + tau_v * acceleration, v_max)


# --------------------------------------------------------------------------- parameters and policy


@dataclass
class OlfatiSaberParams:
    """Algorithm 3's constants; their values (the paper's, rescaled to this world) live in ``conf/policy/policy_ma.yaml``."""

    eps: float             # sigma-norm parameter
    a: float               # phi's repulsive / attractive plateaus (0 < a <= b)
    b: float
    h_alpha: float         # bump parameters
    h_beta: float
    d: float               # desired UAV spacing (m)
    r: float               # UAV interaction range (m), 1.2 d
    d_beta: float          # desired obstacle distance d' (m)
    r_beta: float          # obstacle interaction range r' (m), 1.2 d'
    c1_alpha: float
    c2_alpha: float
    c1_beta: float
    c2_beta: float
    c1_gamma: float
    c2_gamma: float

    def __post_init__(self) -> None:
        check_params(self, positive=("eps", "a", "b", "d", "r", "d_beta", "r_beta"),
                     non_negative=("c1_alpha", "c2_alpha", "c1_beta", "c2_beta", "c1_gamma", "c2_gamma"),
                     unit_interval=("h_alpha", "h_beta"))
        if self.a > self.b:
            raise_param(self, "a", f"must not exceed b={self.b} (phi(0) = 0 needs 0 < a <= b), got {self.a}")
        if self.r <= self.d:
            raise_param(self, "r", f"the interaction range must exceed the spacing d={self.d}, got {self.r}")


class OlfatiSaberPolicy(RuleBasedPolicy):
    """Policy-MA as a :class:`RuleBasedPolicy` (its arguments; ``params``: :class:`OlfatiSaberParams`).

    Example:
        >>> from flock_torchrl import FlockingEnv, make_policy
        >>> env = FlockingEnv("s1", num_envs=2, seed=0, policy_id="policy_ma", extras=("physics", "laser"))
        >>> td = env.rollout(3, policy=make_policy("policy_ma", env))
        >>> td["agents", "action"].shape
        torch.Size([2, 3, 5, 2])
    """

    params: OlfatiSaberParams

    def acceleration(self, percept: Percept) -> torch.Tensor:
        """``u_i`` of Algorithm 3, ``[B, N, 2]``."""
        p, view, hits, velocity = self.params, percept.neighbours, percept.obstacles, percept.velocity
        grad_a, cons_a = alpha_terms(view.offset, view.relative_velocity, view.visible, eps=p.eps, r=p.r, d=p.d,
                                     h=p.h_alpha, a=p.a, b=p.b)
        beta_offset, beta_velocity = beta_agents_from_scan(hits.offset, hits.normal, velocity)
        grad_b, cons_b = beta_terms(beta_offset, beta_velocity, velocity, hits.seen, eps=p.eps, d_beta=p.d_beta,
                                    r_beta=p.r_beta, h=p.h_beta)
        return (p.c1_alpha * grad_a + p.c2_alpha * cons_a + p.c1_beta * grad_b + p.c2_beta * cons_b
                + gamma_term(percept.to_goal, velocity, p.c1_gamma, p.c2_gamma))

    def command(self, percept: Percept) -> torch.Tensor:
        return acceleration_to_command(percept.velocity, self.acceleration(percept), self.env_cfg.tau_v,
                                       self.env_cfg.v_max)


__all__ = [
    "OlfatiSaberParams", "OlfatiSaberPolicy", "acceleration_to_command", "action_phi", "alpha_terms",
    "beta_agent_circle", "beta_agent_wall", "beta_agents_from_scan", "beta_terms", "bump", "gamma_term",
    "phi_alpha", "phi_beta", "sigma_1", "sigma_1_vector", "sigma_gradient", "sigma_norm", "sigma_norm_of_length",
]
