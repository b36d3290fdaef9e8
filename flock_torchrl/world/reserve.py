"""A reserve of fresh worlds (``FlockingEnv(reset_pool=P)``): the done worlds take the next
unused ones with tensor operations only, no host read and no branch on a value; the reserve is
refilled on the host, at points that depend on the number of hand-outs alone."""

from __future__ import annotations

import functools
from typing import Any, Callable, Mapping

import torch
from tensordict import TensorDict

from ..capture import captured


def take_from_reserve(world: dict, reserve: dict, pointer: torch.Tensor, done: torch.Tensor,
                      pool: int) -> tuple[dict, torch.Tensor]:
    """``(world, pointer)`` after the done worlds took the next unused reserve worlds.

    ``world``: the worlds' entries (nested dicts of ``[K * B, ...]`` tensors), ``reserve`` the
    reserve's (``[K * pool, ...]``, group-major), ``pointer [K]`` each group's next unused
    reserve world, ``done [K, B]`` the done flags: world ``b`` of group ``k`` takes reserve world
    ``pointer[k] + (done worlds of k up to b) - 1`` (clamped into the group's reserve) when done.
    Tensor operations only: no host read, no branch on a value (with ``compile_step``, traced
    with the step as one function)."""
    groups = done.shape[0]
    taken = done.long().cumsum(-1)                                                       # [K, B]
    first = torch.arange(groups, device=done.device)[:, None] * pool
    slot = ((pointer[:, None] + taken - 1).clamp(0, pool - 1) + first).reshape(-1)      # never past the reserve
    mask = done.reshape(-1)

    def put(old: Any, new: Any) -> Any:
        if isinstance(old, dict):
            return {key: put(value, new[key]) for key, value in old.items()}
        return torch.where(mask.reshape(-1, *(1,) * (old.ndim - 1)), new[slot], old)

    return put(world, reserve), pointer + taken[:, -1]


def in_layout(old: dict, new: dict) -> dict:
    """``new``'s worlds in ``old``'s memory layout, entry by entry (a copy where a stride differs):
    the compiled step reads back what it wrote, as it wrote it."""
    return {key: in_layout(value, new[key]) if isinstance(value, dict)
            else new[key] if new[key].stride() == value.stride() else torch.empty_like(value).copy_(new[key])
            for key, value in old.items()}


class Reserve:
    """``pool`` fresh worlds for each of ``groups`` groups of ``per_group`` worlds (a population's
    members; one group otherwise): a group's done worlds take from its own part, in world order.

    One hand-out takes at most ``per_group`` worlds of a group, so ``pool // per_group`` hand-outs
    fit between refills: :meth:`count` refills before the one that could run the reserve dry
    (the used worlds' count read once on the host, the unused kept in order and as many new ones
    drawn after them). Until its first refill the reserve is empty (every world used).

    Args:
        worlds: the layout of ``groups * pool`` stored worlds (their values are never handed out
            before a refill replaces them).
        capture: record the hand-out as a CUDA graph on a GPU (``flock_torchrl.capture``).
    """

    def __init__(self, pool: int, groups: int, per_group: int, worlds: TensorDict, capture: bool = False) -> None:
        self.pool, self.groups, self.per_group = pool, groups, per_group
        self.worlds = worlds
        self.pointer = torch.zeros(groups, dtype=torch.long, device=worlds.device)
        self.calls = 0
        self._take = captured(functools.partial(take_from_reserve, pool=pool), worlds.device, capture)
        self.empty()

    @property
    def between_refills(self) -> int:
        """Hand-outs that fit between two refills."""
        return self.pool // self.per_group

    def empty(self) -> None:
        """Mark every world used: the next :meth:`count` draws the reserve anew."""
        self.pointer.fill_(self.pool)
        self.calls = self.between_refills

    def due(self) -> bool:
        """Whether the next hand-out could run the reserve dry (a refill comes first)."""
        return (self.calls + 1) * self.per_group > self.pool

    def count(self, draw: Callable[[torch.Tensor], TensorDict]) -> None:
        """One hand-out is about to happen: refill first (:meth:`refill`) if it is due."""
        if self.due():
            self.refill(draw)
        self.calls += 1

    def refill(self, draw: Callable[[torch.Tensor], TensorDict]) -> None:
        """Keep the unused worlds, in order, and draw as many new ones after them: ``draw(index)``
        gives fresh worlds for world indices ``index`` (a group's first world, repeated: the group
        it draws for is read off the index)."""
        pool, device = self.pool, self.worlds.device
        used = [int(n) for n in self.pointer.cpu()]  # the reserve's one read of the device
        if sum(used):
            index = torch.cat([torch.full((n,), k * self.per_group, dtype=torch.long) for k, n in enumerate(used) if n])
            fresh = draw(index.to(device))
            order, drawn = [], self.groups * pool
            for k, n in enumerate(used):  # groups, not worlds
                order += [torch.arange(k * pool + n, (k + 1) * pool), torch.arange(drawn, drawn + n)]
                drawn += n
            self.worlds = torch.cat([self.worlds, fresh])[torch.cat(order).to(device)]
        self.pointer.zero_()
        self.calls = 0

    def hand_out(self, world: dict, done: torch.Tensor) -> dict:
        """The worlds' entries (a nested dict) after their ``done [groups, per_group]`` worlds took
        the next unused reserve worlds."""
        new, self.pointer = self._take(world, self.worlds.to_dict(), self.pointer, done)
        return new

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        return {"worlds": self.worlds.to_dict(), "next": self.pointer.clone(), "calls": self.calls}

    def load_state_dict(self, state: Mapping[str, Any], worlds: Callable[[Any, int], TensorDict]) -> None:
        """Restore :meth:`state_dict`; ``worlds(saved, count)`` checks and converts its stored
        worlds. A state the calls since its refill cannot explain is a ``ValueError``."""
        if not isinstance(state, Mapping) or not {"worlds", "next", "calls"} <= state.keys():
            raise ValueError(f"env state: no 'reset_pool' entry with 'worlds', 'next' and 'calls' (saved with "
                             f"reset_pool=0?); this env keeps a reserve of {self.pool} worlds")
        count = self.groups * self.pool
        if not isinstance(state["worlds"], Mapping) and not isinstance(state["worlds"], TensorDict):
            raise ValueError("env state: 'reset_pool' has no mapping of worlds")
        stored = worlds(state["worlds"], count)
        pointer, calls = state["next"], state["calls"]
        if not (isinstance(pointer, torch.Tensor) and pointer.dtype == torch.long and pointer.shape == (self.groups,)
                and bool(((pointer >= 0) & (pointer <= self.pool)).all())):
            raise ValueError(f"env state: reset_pool 'next' must be an int64 tensor of shape [{self.groups}] in "
                             f"[0, {self.pool}], got {pointer!r}")
        if not isinstance(calls, int) or isinstance(calls, bool) or not 0 <= calls <= self.between_refills:
            raise ValueError(f"env state: reset_pool 'calls' must be an integer in [0, {self.between_refills}], "
                             f"got {calls!r}")
        if int(pointer.max()) + (self.between_refills - calls) * self.per_group > self.pool:
            raise ValueError(f"env state: reset_pool 'next' ({pointer.tolist()}) is more than {calls} call(s) since "
                             "the refill can have taken: the reserve would run dry")
        stored.batch_size = torch.Size([count])
        self.worlds, self.pointer, self.calls = stored, pointer.to(self.worlds.device).clone(), calls


__all__ = ["Reserve", "in_layout", "take_from_reserve"]
