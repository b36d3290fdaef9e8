"""A controller of your own, as a row of the paper's tables: fly at the goal, turn away from the
nearest obstacle and the nearest UAV when they come close.

    python scripts/reproduce.py table=3 episodes=100 only=[Policy3-G] \
        'contenders=[examples/goal_separation.py:make]'          # from a clone
    flock-evaluate contender=flock_torchrl.examples.goal_separation.make scenario=s2 episodes=100   # anywhere

A contender is any factory ``make(env, **kwargs)`` that returns a TensorDict module writing
``("agents", "action")``. It flies in the scenario's own world (field of view 0.5 pi, the
instinct off) through every door, unless it declares other policy fields (a ``scenario``
mapping on the factory, or in the contender's config). This one reads only the actor's
observation (docs/specification.md section 2): ``o_g = [d_g / d_s, alpha_g / pi]``, then the ``n_scan`` shortest beams
``[d / d_max^scan, alpha / pi]`` and the ``n_cam`` nearest visible UAVs
``[d / d_v, alpha / pi, dphi / pi]``, nearest first (missing ones read as range 1).
Actions are ``[turn, speed]`` in ``[-1, 1]``: the heading changes by ``turn * pi / 2`` per step.
"""

import torch
from tensordict.nn import TensorDictModule


class GoalSeparation(torch.nn.Module):
    def __init__(self, n_scan: int, n_cam: int, near: float, avoid: float, separate: float):
        super().__init__()
        self.n_scan, self.n_cam = n_scan, n_cam
        self.near, self.avoid, self.separate = near, avoid, separate

    def away(self, distance: torch.Tensor, bearing: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """How close a thing at ``bearing`` (/pi) is (0 beyond ``near``, 1 touching), and the turn
        away from it (harder the more ahead it is; one dead ahead is passed on the right)."""
        closeness = ((self.near - distance) / self.near).clamp(0.0, 1.0)
        side = torch.where(bearing >= 0, -1.0, 1.0)
        return closeness, side * closeness * (1.0 - bearing.abs())

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        beams = observation[..., 2:2 + 2 * self.n_scan].unflatten(-1, (self.n_scan, 2))
        uavs = observation[..., 2 + 2 * self.n_scan:].unflatten(-1, (self.n_cam, 3))
        obstacle, dodge = self.away(beams[..., 0, 0], beams[..., 0, 1])
        _, separation = self.away(uavs[..., 0, 0], uavs[..., 0, 1])
        turn = (1.0 - obstacle) * 2.0 * observation[..., 1] + self.avoid * dodge + self.separate * separation
        return torch.stack((turn.clamp(-1.0, 1.0), torch.zeros_like(turn)), -1)


def make(env, near: float = 0.6, avoid: float = 2.0, separate: float = 1.5) -> TensorDictModule:
    """The controller for ``env`` (its scenario gives the observation's layout)."""
    net = GoalSeparation(env.cfg.n_scan, env.cfg.n_cam, near, avoid, separate)
    return TensorDictModule(net, in_keys=[("agents", "observation")], out_keys=[("agents", "action")])
