"""The worlds of a population: K members' worlds stepped as one batch, each member drawing its
episodes from its own generator.

A population (``flock_torchrl.policies.population``) trains K independent members. Stepping
their worlds is pure tensor work over ``[K * B]`` worlds, so one :class:`FlockingEnv` step
serves them all; only the random draws must stay apart: a member's worlds end when its own
policy makes them end, so with one shared generator a member's resets would change what every
other member's spawns draw. Here member k (worlds ``k * B .. k * B + B - 1``) has its own
generator, seeded ``seeds[k]``: a member's worlds are exactly those of a solo env seeded so.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping, Sequence

import torch

from .env import FlockingEnv
from .spawn import sample_layout
from .step import noise_draws


class PopulationEnv(FlockingEnv):
    """``members`` blocks of ``worlds_per_member`` worlds (member-major), one generator each.

    Args:
        scenario: as :class:`FlockingEnv`'s.
        members, worlds_per_member: K and B; the env holds ``K * B`` worlds.
        seeds: one generator seed per member.
        **kwargs: the other :class:`FlockingEnv` arguments (``device``, ``compile_step``, ...).
    """

    def __init__(self, scenario: Any, members: int, worlds_per_member: int, seeds: Sequence[int],
                 **kwargs: Any) -> None:
        if len(seeds) != members:
            raise ValueError(f"PopulationEnv: {members} members need {members} seeds, got {len(seeds)}")
        self.members, self.worlds_per_member = int(members), int(worlds_per_member)
        self._member_seeds = [int(s) for s in seeds]
        kwargs.pop("seed", None)
        super().__init__(scenario, num_envs=self.members * self.worlds_per_member, seed=None, **kwargs)
        self._generators = [torch.Generator(device=self.device) for _ in seeds]
        for generator, seed in zip(self._generators, self._member_seeds):
            generator.manual_seed(seed)

    def _reserve_groups(self) -> tuple[int, int]:
        # reset_pool: a reserve per member, drawn from its generator (its resets stay its own).
        return self.members, self.worlds_per_member

    def _groups(self, index: torch.Tensor | None) -> list[tuple[int, int]]:
        """``(member, count)`` for each member with worlds in ``index`` (ascending), in order."""
        if index is None:
            return [(k, self.worlds_per_member) for k in range(self.members)]
        counts = torch.bincount(index // self.worlds_per_member, minlength=self.members).tolist()
        return [(k, c) for k, c in enumerate(counts) if c]

    def _draw_layout(self, index: torch.Tensor | None):
        parts = [sample_layout(self.cfg, count, self._static, self._generators[k], self.device)
                 for k, count in self._groups(index)]  # members with resetting worlds: a few per step
        if len(parts) == 1:
            return parts[0]
        return type(parts[0])(**{f.name: torch.cat([getattr(p, f.name) for p in parts])
                                 for f in dataclasses.fields(parts[0])})

    def _draw_noise(self, index: torch.Tensor | None):
        if not self.cfg.noise:
            return None
        parts = [noise_draws(self.cfg, count, self._generators[k], self.device) for k, count in self._groups(index)]
        return {key: torch.cat([p[key] for p in parts]) for key in parts[0]}

    def get_state(self) -> dict:
        state = super().get_state()
        state["member_generators"] = [g.get_state() for g in self._generators]
        return state

    def set_state(self, state: Mapping[str, Any]) -> None:
        generators = state.get("member_generators") if isinstance(state, Mapping) else None
        if not isinstance(generators, (list, tuple)) or len(generators) != self.members:
            raise ValueError(f"env state: expected 'member_generators' with {self.members} entries (a population's "
                             "get_state())")
        super().set_state(state)
        for generator, saved in zip(self._generators, generators):
            generator.set_state(saved)

    def member_of(self, world: torch.Tensor) -> torch.Tensor:
        """The member each world index belongs to."""
        return world // self.worlds_per_member


__all__ = ["PopulationEnv"]
