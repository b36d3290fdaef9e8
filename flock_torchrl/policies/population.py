"""A population: K independent members of one off-policy learner, trained as one.

Each member has its own networks, target networks, entropy temperature (SAC), optimiser
state and replay buffer; their parameters are stacked along a leading member dimension and
TorchRL's own loss module (``SACLoss``, ``DDPGLoss``) is called once per update under
``torch.vmap`` over that dimension, so the members' fixed per-call costs are paid once. Members
share no value: a member's gradients come from its own loss alone, one Adam steps every member
elementwise (what K Adams would do), the target update is elementwise. What they share is the
order of the draws from torch's generator: every draw has a fixed shape (``[K, ...]``, one slice
per member, ``randomness="different"``), so no member's data or weights change what another
member draws (``tests/test_population.py`` perturbs one member and checks the others).

Initial weights: member 0 draws from torch's global generator exactly as a solo run of
``seeds[0]`` does (the trainer seeds it); member k from a generator seeded ``seeds[k]``, so
its initial networks are those of a solo run with that seed. Later draws are shared (above),
so member k > 0 trains as a seed of its own, not as the solo run of ``seeds[k]``.
"""

from __future__ import annotations

from typing import Any, Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.data.replay_buffers.samplers import Sampler

from ..capture import captured
from .learners import FiniteLosses, adam, make_learner
from .models import SamplingActor

# The trainable parameters and the soft-updated targets of each learner, as SoftUpdate pairs
# them (``target_<name>_params`` follows ``<name>_params``).
_TRAINED = {"sac": ("actor_network_params", "qvalue_network_params", "log_alpha"),
            "ddpg": ("actor_network_params", "value_network_params")}
_TARGETS = {"sac": ("qvalue_network",), "ddpg": ("actor_network", "value_network")}
_TERMS = {"sac": {"loss_actor": "loss_actor", "loss_qvalue": "loss_qvalue", "loss_alpha": "loss_alpha"},
          "ddpg": {"loss_actor": "loss_actor", "loss_qvalue": "loss_value"}}
_STATS = {"sac": ("alpha", "entropy"), "ddpg": ()}


class PopulationError(ValueError):
    """A population that cannot be built (a learner or setting it does not support)."""


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


class PopulationPolicy(TensorDictModuleBase):
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

        self._vmapped = torch.vmap(one, (0, 0), randomness="different") if members > 1 else _unbatched(one, 0)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        k = self.members
        batch = tensordict.batch_size
        grouped = tensordict.select(*self.in_keys, strict=False).reshape(k, batch[0] // k, *batch[1:])
        out = self._vmapped(self.params, grouped).reshape(batch)
        tensordict.update(out.select(*self.actor.out_keys, strict=False))
        if self.after is not None:
            tensordict = self.after(tensordict)
        return tensordict


class PopulationLearner:
    """K members of SAC or DDPG (``make_learner``'s), stacked and updated as one.

    ``update(batch)`` takes ``[batch, K]`` swarm transitions (member k's in column k) and
    returns per-member statistics ``[K]``. ``actor_state(k)`` is member k's actor
    ``state_dict`` (what a solo run's checkpoint holds), ``collector_policy`` the
    :class:`PopulationPolicy` over all members' worlds.
    """

    off_policy = True

    def __init__(self, env, algo_cfg, critic_input: str, seeds: Sequence[int], compile: bool = False,
                 cudagraphs: bool = False) -> None:
        name = algo_cfg.name
        if name not in _TRAINED:
            raise PopulationError(f"a population trains sac or ddpg, not {name}")
        if compile:
            raise PopulationError("a population's update runs eagerly (torch.vmap); use compile=false or step")
        self.cfg, self.name, self.members = algo_cfg, name, len(seeds)
        # Member 0 from the global generator (as a solo run), the others from their own seeds.
        solos = [make_learner(env, algo_cfg, critic_input)]
        for seed in seeds[1:]:
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(int(seed))
                solos.append(make_learner(env, algo_cfg, critic_input))
        self.template = solos[0]
        self.loss = self.template.loss
        self.actor = self.template.actor
        stacked = torch.stack([TensorDict.from_module(s.loss).detach() for s in solos]).clone()
        trained = _TRAINED[name]
        leaves: dict[str, list[torch.Tensor]] = {}
        for key in trained:
            sub = stacked.get(key)
            if isinstance(sub, torch.Tensor):
                param = nn.Parameter(sub)
                stacked.set(key, param)
                leaves[key] = [param]
            else:
                sub = sub.apply(nn.Parameter)
                stacked.set(key, sub)
                leaves[key] = list(sub.values(True, True))
        self.params = stacked
        lrs = {"actor_network_params": algo_cfg.lr_actor, "qvalue_network_params": algo_cfg.lr_critic,
               "value_network_params": algo_cfg.lr_critic, "log_alpha": getattr(algo_cfg, "lr_alpha", None)}
        self.optimizer = adam([{"params": leaves[k], "lr": lrs[k]} for k in trained], env.device,
                              capturable=cudagraphs)
        self._clip_groups = [leaves[k] for k in trained if k != "log_alpha"]
        # SoftUpdate's own arithmetic: target.lerp_(source, 1 - eps), eps = 1 - tau.
        self._target_weight = 1 - (1 - algo_cfg.tau)
        self._target_pairs = [(stacked.get(f"{n}_params"), stacked.get(f"target_{n}_params")) for n in _TARGETS[name]]
        self.exploration = getattr(self.template, "exploration", None)
        acting = self.template.collector_policy if isinstance(self.template.collector_policy, SamplingActor) else None
        self.collector_policy = PopulationPolicy(self.actor, stacked.get("actor_network_params"), self.members,
                                                 after=self.exploration, acting=acting)
        terms, stats = _TERMS[name], _STATS[name]

        def member_losses(p: TensorDictBase, batch: TensorDictBase) -> dict[str, torch.Tensor]:
            with p.to_module(self.loss):
                out = self.loss(batch)
            return {**{ours: out[theirs] for ours, theirs in terms.items()}, **{k: out[k] for k in stats}}

        if self.members > 1:
            self._losses = torch.vmap(member_losses, (0, 1), randomness="different")
        else:  # one member: the same loss called directly (vmap's batched kernels would round differently)
            self._losses = _unbatched(member_losses, 1)
        # Captured (flock_torchrl.capture): the whole step is one function without a host read.
        self.cudagraphs = bool(cudagraphs)
        self.finite = FiniteLosses(tuple(_TERMS[name]), env.device, self.members)
        self._update = captured(self._captured_step, env.device, self.cudagraphs)

    # ------------------------------------------------------------------ training
    def on_frames(self, frames: int) -> None:
        """DDPG: anneal the exploration noise by the frames each member collected."""
        if self.exploration is not None:
            self.exploration.step(frames)

    def update(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """One gradient step of every member on its column of ``batch [batch, K]``."""
        if self.cudagraphs:
            return self._update(batch)
        out = self._losses(self.params, batch)
        terms = {k: out[k] for k in _TERMS[self.name]}
        values = torch.stack([v.detach() for v in terms.values()])
        if not bool(torch.isfinite(values).all()):
            name, member = next((k, int((~torch.isfinite(v)).nonzero()[0, 0])) for k, v in terms.items()
                                if not torch.isfinite(v).all())
            raise FloatingPointError(f"{name} of member {member} is {terms[name][member].item()}: training diverged")
        return self._step(out, terms)

    def check(self) -> None:
        """Raise ``FloatingPointError`` if a captured update met a non-finite loss."""
        self.finite.check()

    def _captured_step(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """One whole update without a host synchronisation (what ``CudaGraphModule`` records)."""
        out = self._losses(self.params, batch)
        terms = {k: out[k] for k in _TERMS[self.name]}
        self.finite.record(terms)
        return self._step(out, terms)

    def _step(self, out: dict[str, torch.Tensor], terms: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        self.optimizer.zero_grad(set_to_none=True)
        sum(terms.values()).sum().backward()
        if self.cfg.max_grad_norm > 0:
            for group in self._clip_groups:
                _clip_per_member(group, self.cfg.max_grad_norm)
        self.optimizer.step()
        with torch.no_grad():
            for source, target in self._target_pairs:
                for s, t in zip(source.values(True, True), target.values(True, True)):
                    t.lerp_(s, self._target_weight)
        stats = {k: v.detach() for k, v in terms.items()}
        stats.update({k: out[k].detach() for k in _STATS[self.name]})
        if self.exploration is not None:
            stats["sigma"] = self.exploration.sigma.detach().clone().expand(self.members)
        return stats

    # ------------------------------------------------------------------ members
    def actor_state(self, member: int) -> dict[str, torch.Tensor]:
        """Member ``member``'s actor ``state_dict`` (loadable into ``make_actor``'s module)."""
        with self.params.get("actor_network_params")[member].to_module(self.actor):
            return {k: v.detach().clone() for k, v in self.actor.state_dict().items()}

    def state_dict(self) -> dict[str, Any]:
        state = {"params": self.params.detach().clone().to_dict(), "optimizer": self.optimizer.state_dict()}
        if self.exploration is not None:
            state["exploration"] = self.exploration.state_dict()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        saved = TensorDict(state["params"], batch_size=[self.members])
        if saved.batch_size != self.params.batch_size:
            raise ValueError("the saved population has another number of members")
        with torch.no_grad():
            for key, value in saved.items(True, True):
                self.params.get(key).copy_(value)
        self.optimizer.load_state_dict(state["optimizer"])
        if self.exploration is not None:
            self.exploration.load_state_dict(state["exploration"])


def _unbatched(fn, batch_dim: int):
    """``fn`` over a population of one, called as ``torch.vmap(fn, (0, batch_dim))`` would be,
    without vmap: a population of one then computes exactly what the solo learner computes."""

    def call(params: TensorDictBase, data: TensorDictBase):
        out = fn(params[0], data.squeeze(batch_dim))
        if isinstance(out, dict):
            return {k: v.unsqueeze(0) for k, v in out.items()}
        return out.unsqueeze(0)

    return call


def _clip_per_member(params: list[torch.Tensor], max_norm: float) -> None:
    """``clip_grad_norm_`` for each member alone: the norm of member k's slice of every gradient."""
    grads = [p.grad for p in params if p.grad is not None]
    if not grads:
        return
    norms = torch.stack([g.reshape(g.shape[0], -1).norm(dim=1) for g in grads], 1).norm(dim=1)
    scale = (max_norm / (norms + 1e-6)).clamp(max=1.0)
    for g in grads:
        g.mul_(scale.reshape(-1, *([1] * (g.ndim - 1))))


__all__ = ["MemberSampler", "PopulationError", "PopulationLearner", "PopulationPolicy"]
