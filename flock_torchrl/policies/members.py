"""The pieces of K members trained as one (:class:`~.learners.OffPolicyLearner`; K = 1 a solo run):
the replay buffer's sampler of each member's own rows, the members' actors as one collector
policy, a function of one member called for K of them, and gradient clipping per member."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.data.replay_buffers.samplers import Sampler


class MemberSampler(Sampler):
    """Uniform sampling of each member's own transitions from a storage whose items are
    population rows ``[K]`` (one transition per member, written together).

    ``sample`` returns ``(rows [batch, K], members [batch, K])``: member k's column draws its
    rows independently of the others' (one ``randint`` of shape ``[batch, K]``; with ``K = 1``
    the same numbers TorchRL's ``RandomSampler`` draws)."""

    def __init__(self, members: int) -> None:
        super().__init__()
        self.members = members

    def sample(self, storage, batch_size: int) -> tuple[tuple[torch.Tensor, torch.Tensor], dict]:
        if len(storage) == 0:
            raise RuntimeError("the replay buffer is empty")
        device = getattr(storage, "device", None)
        rows = torch.randint(0, len(storage), (batch_size, self.members), generator=storage._rng, device=device)
        members = torch.arange(self.members, device=rows.device).expand(batch_size, self.members)
        return (rows, members), {}

    def _empty(self) -> None:
        pass

    def dumps(self, path) -> None:
        pass

    def loads(self, path) -> None:
        pass

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        return None


class MemberPolicy(TensorDictModuleBase):
    """The members' actors as one module over the population's worlds ``[K * B]`` (member-major:
    world ``k * B + b`` is member k's): member k's weights act on member k's worlds.

    ``after``: a module applied to the whole batch afterwards (DDPG's exploration noise);
    ``acting``: what acts with the member's weights put into ``actor`` (by default the actor
    itself; a SAC actor's :class:`~.models.SamplingActor`, as a solo run's collector acts)."""

    def __init__(self, actor: TensorDictModuleBase, params: TensorDictBase, members: int,
                 after: TensorDictModuleBase | None = None, acting: TensorDictModuleBase | None = None) -> None:
        super().__init__()
        self.actor, self.members, self.after = actor, members, after
        self._acting = (actor if acting is None else acting,)  # in a tuple: the actor's parameters registered once
        self.params = params
        self.in_keys = list(actor.in_keys)
        self.out_keys = list(actor.out_keys) + ([k for k in after.out_keys if k not in actor.out_keys]
                                                if after is not None else [])

        def one(p: TensorDictBase, td: TensorDictBase) -> TensorDictBase:
            with p.to_module(self.actor):
                return self._acting[0](td)

        self._vmapped = for_members(one, members, 0)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        k = self.members
        batch = tensordict.batch_size
        grouped = tensordict.select(*self.in_keys, strict=False).reshape(k, batch[0] // k, *batch[1:])
        out = self._vmapped(self.params, grouped).reshape(batch)
        tensordict.update(out.select(*self.actor.out_keys, strict=False))
        if self.after is not None:
            tensordict = self.after(tensordict)
        return tensordict


def for_members(fn, members: int, batch_dim: int):
    """``fn(params, data)`` of one member, called for every member: ``torch.vmap(fn, (0, batch_dim))``
    (each member's draws its own slice of one draw, ``randomness="different"``), or, for one member,
    ``fn`` itself on the member's slices: one member then computes exactly what a learner of one
    network set computes (vmap's batched kernels would round differently)."""
    if members > 1:
        return torch.vmap(fn, (0, batch_dim), randomness="different")

    def call(params: TensorDictBase, data: TensorDictBase):
        out = fn(params[0], data.squeeze(batch_dim))
        if isinstance(out, dict):
            return {k: v.unsqueeze(0) for k, v in out.items()}
        return out.unsqueeze(0)

    return call


def clip_per_member(params: list[torch.Tensor], max_norm: float) -> None:
    """``clip_grad_norm_`` for each member alone: the norm of member k's slice of every gradient."""
    grads = [p.grad for p in params if p.grad is not None]
    if not grads:
        return
    norms = torch.stack([g.reshape(g.shape[0], -1).norm(dim=1) for g in grads], 1).norm(dim=1)
    scale = (max_norm / (norms + 1e-6)).clamp(max=1.0)
    for g in grads:
        g.mul_(scale.reshape(-1, *([1] * (g.ndim - 1))))


__all__ = ["MemberPolicy", "MemberSampler", "clip_per_member", "for_members"]
