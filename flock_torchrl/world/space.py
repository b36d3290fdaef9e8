"""The third dimension as sensing and the step read it (docs/specification.md section 11).

One small object built from the scenario, :class:`Space`, ``None`` in the plane. Every function
on the step path whose formula differs in space takes ``space: Space | None`` and asks ``space is
None``; none of them tells the dimension from a tensor's width or from another optional input.
Configuration-level code, which holds the scenario, reads its ``dims`` and builds the object
(:func:`space_of`). With a zero vertical part every formula in space gives the plane's values bit
for bit (the special case, tests/test_threed.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..config.scenario import Laser


@dataclass(frozen=True)
class Space:
    """What space adds to a batch of worlds. A function reads the fields its formula needs; a
    test may build one with only those."""

    climb: torch.Tensor | None = None  # [B, N]: the UAVs' flight-path angles gamma_i (rad)
    laser: Laser | None = None         # the laser's rings and vertical pair
    climb_max: float = 0.0             # rad, gamma_max: the action's third entry's full scale


def space_of(cfg, climb: torch.Tensor | None = None) -> Space | None:
    """The :class:`Space` of scenario ``cfg`` with the flight-path angles ``climb``; ``None`` in the plane."""
    if cfg.dims != 3:
        return None
    return Space(climb, cfg.laser, cfg.climb_max)


__all__ = ["Space", "space_of"]
