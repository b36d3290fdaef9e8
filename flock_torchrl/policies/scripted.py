"""A scripted policy with a known answer, :func:`goal_seeking_policy` (also a template for a
controller of your own)."""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule

from .models import ACTION, OBS


class _GoalSeeking(torch.nn.Module):
    def __init__(self, speed_action: float) -> None:
        super().__init__()
        self.speed_action = speed_action

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        # o_g = [d_g / d_s, alpha_g / pi]: turn by alpha_g (dphi = a0 pi/2, so a0 = 2 alpha_g / pi).
        turn = (2.0 * observation[..., 1:2]).clamp(-1.0, 1.0)
        return torch.cat((turn, torch.full_like(turn, self.speed_action)), -1)


def goal_seeking_policy(speed_action: float = 0.0) -> TensorDictModule:
    """A scripted policy that steers every UAV straight at the goal at ``V = 2 + speed_action``.

    It reads only ``o_g`` of ``("agents", "observation")`` and ignores obstacles and
    neighbours, so its episodes have a known answer in S1 (tests, timing, sanity checks).
    """
    module = TensorDictModule(_GoalSeeking(speed_action), in_keys=[OBS], out_keys=[ACTION])
    module.flock_meta = {"policy": "GoalSeeking"}
    return module


__all__ = ["goal_seeking_policy"]
