"""Networks (paper Fig. 3), built from the env's specs with TorchRL's modules.

One actor is shared by all UAVs and reads only its own UAV's observation; the critic is per
UAV and shared too, reading ``("agents", critic_input)`` and, for Q networks, the action.
Shared, decentralised networks are one TorchRL ``MLP`` applied along the last dimension of
``[..., N, features]``: what ``MultiAgentMLP(share_params=True, centralized=False)`` computes,
without its per-call functional machinery (1.5-2x faster updates here, and compilable). The
parameters do not depend on N, so a policy trained with 5 UAVs runs S2's 9 as it is.
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictModuleBase
from torch import distributions as D
from torch import nn
from torchrl.envs.utils import ExplorationType, exploration_type
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator

_TorchRLTanhNormal = TanhNormal

OBS = ("agents", "observation")
ACTION = ("agents", "action")
LOG_PROB = ("agents", "action_log_prob")
LOC, SCALE = ("agents", "loc"), ("agents", "scale")


class _Normal(D.Normal):
    """``torch.distributions.Normal`` whose reparameterised draw is ``torch.randn_like(loc)``.

    Torch's own draws into a fresh unbatched tensor (``empty(shape).normal_()``), which
    ``torch.vmap(..., randomness="different")`` refuses; ``randn_like`` of the (batched) mean
    draws one independent stream per vmapped member. Without vmap both draw the same numbers
    from the same generator in the same order, so a solo run samples exactly what it did."""

    def rsample(self, sample_shape: torch.Size = torch.Size()) -> torch.Tensor:
        shape = self._extended_shape(sample_shape)
        return self.loc + torch.randn_like(self.loc.expand(shape)) * self.scale


class TanhNormal(TanhNormal):
    """TorchRL's ``TanhNormal`` on :class:`_Normal`: the same distribution, and usable inside
    ``torch.vmap`` over a population's members (:mod:`.population`)."""

    def update(self, loc: torch.Tensor, scale: torch.Tensor) -> None:
        super().update(loc, scale)
        root = self.root_dist
        if type(root) is D.Normal:  # just built by TorchRL: the same Normal, built as a _Normal
            # (a new object rather than a __class__ assignment, which torch.compile cannot trace:
            # it broke the compiled losses into pieces, each run eagerly)
            base = _Normal(root.loc, root.scale)
            if self._event_dims > 0:
                base = D.Independent(base, self._event_dims)
            super(_TorchRLTanhNormal, self).__init__(base, self._t)


def shared_mlp(n_in: int, n_out: int, hidden: int, depth: int, device=None) -> MLP:
    """The network every UAV shares: ``depth`` hidden layers of ``hidden`` ReLU units (Fig. 3)."""
    return MLP(in_features=n_in, out_features=n_out, depth=depth, num_cells=hidden, activation_class=nn.ReLU,
               device=device)


def action_bounds(env) -> tuple[torch.Tensor, torch.Tensor]:
    """The per-UAV action box ``(low [2], high [2])`` (every UAV has the same one)."""
    space = env.full_action_spec_unbatched[ACTION].space
    low, high = space.low.reshape(-1, space.low.shape[-1]), space.high.reshape(-1, space.high.shape[-1])
    if not (torch.equal(low, low[:1].expand_as(low)) and torch.equal(high, high[:1].expand_as(high))):
        raise ValueError("the shared actor needs the same action box for every UAV")
    return low[0], high[0]


def make_actor(env, *, stochastic: bool = True, hidden: int = 128, depth: int = 2,
               return_log_prob: bool = False) -> TensorDictModule:
    """The shared policy ``pi(a | o)``.

    Stochastic: ``MLP -> (loc, scale)`` and a tanh-squashed Gaussian on ``[-1, 1]^2`` (its
    deterministic mode is the tanh of the mean). Deterministic (DDPG): ``tanh(MLP(o))``.
    Sizes come from ``env``'s specs; the module runs with any number of UAVs.
    """
    low, high = action_bounds(env)
    return actor_of_sizes(env.full_observation_spec_unbatched[OBS].shape[-1], low, high, device=env.device,
                          stochastic=stochastic, hidden=hidden, depth=depth, return_log_prob=return_log_prob)


def actor_of_sizes(n_obs: int, low: torch.Tensor, high: torch.Tensor, *, device: Any = None, stochastic: bool = True,
                   hidden: int = 128, depth: int = 2, return_log_prob: bool = False) -> TensorDictModule:
    """:func:`make_actor` for an observation of ``n_obs`` numbers and the action box
    ``low, high [n_act]`` (a checkpoint's stored sizes: no env needed)."""
    n_act = low.shape[-1]
    if not stochastic:
        net = nn.Sequential(shared_mlp(n_obs, n_act, hidden, depth, device), nn.Tanh())
        return TensorDictModule(net, in_keys=[OBS], out_keys=[ACTION])
    net = nn.Sequential(shared_mlp(n_obs, 2 * n_act, hidden, depth, device),
                        NormalParamExtractor(scale_mapping="biased_softplus_1.0", scale_lb=1e-4))
    module = TensorDictModule(net, in_keys=[OBS], out_keys=[LOC, SCALE])
    return ProbabilisticActor(module=module, in_keys=[LOC, SCALE], out_keys=[ACTION], distribution_class=TanhNormal,
                              distribution_kwargs={"low": low, "high": high}, return_log_prob=return_log_prob,
                              log_prob_key=LOG_PROB)


class SamplingActor(TensorDictModuleBase):
    """A stochastic actor (:func:`make_actor`) as a collector runs it: under
    ``ExplorationType.RANDOM`` the actor's own network and the draw its ``ProbabilisticActor``
    makes, written as that module writes it (``loc``, ``scale``, ``action``), without a
    distribution object and tensordict dispatch per call (two thirds of the actor's time on the
    paper recipe's one world). Every other exploration type runs the actor itself.

    The draw is the tanh-squashed Gaussian's ``rsample``: ``loc + randn_like(loc) * scale``
    (:class:`_Normal`); TorchRL's safe tanh (``SafeTanhTransform``: the tanh clamped to
    ``+-(1 - eps)``, ``eps`` the dtype's resolution), here without the ``autograd.Function`` it
    runs through there (whose call costs four times its two ops); and the box's affine map
    ``(high + low) / 2 + (high - low) / 2 * y`` only where the box is not ``[-1, 1]`` (as
    TorchRL's ``TanhNormal`` composes it): the same operations in the same order, so the same
    numbers from the same generator, bit for bit (tests/test_sampling_actor.py). It is for acting
    (the losses differentiate the actor itself): where the clamp bites, its gradient would be
    zero, not the safe tanh's."""

    def __init__(self, actor: ProbabilisticActor) -> None:
        super().__init__()
        head = actor.module[1]
        if head.return_log_prob or head.distribution_class is not TanhNormal:
            raise ValueError("SamplingActor: expected make_actor(stochastic=True)'s TanhNormal actor without "
                             f"return_log_prob, got return_log_prob={head.return_log_prob} and "
                             f"{head.distribution_class.__name__}")
        self.actor = actor
        # MLP -> NormalParamExtractor: (loc, scale); in a tuple, its parameters are registered once (the actor's)
        self._net = (actor.module[0].module,)
        low, high = head.distribution_kwargs["low"], head.distribution_kwargs["high"]
        trivial = not bool((high != 1.0).any()) and not bool((low != -1.0).any())
        self.box = None if trivial else ((high + low) / 2, (high - low) / 2)
        self.in_keys, self.out_keys = [OBS], [LOC, SCALE, ACTION]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if exploration_type() is not ExplorationType.RANDOM:
            return self.actor(tensordict)
        loc, scale = self._net[0](tensordict.get(OBS))
        lim = 1.0 - torch.finfo(loc.dtype).resolution
        action = (loc + torch.randn_like(loc) * scale).tanh().clamp(-lim, lim)
        if self.box is not None:
            action = self.box[0] + self.box[1] * action
        tensordict.set(LOC, loc)
        tensordict.set(SCALE, scale)
        tensordict.set(ACTION, action)
        return tensordict


def make_qvalue(env, critic_input: str, *, hidden: int = 128, depth: int = 2) -> ValueOperator:
    """Per-UAV ``Q(x_i, a_i)`` with ``x`` the observation or the centralised state."""
    key = ("agents", critic_input)
    n_in = env.full_observation_spec_unbatched[key].shape[-1] + env.full_action_spec_unbatched[ACTION].shape[-1]
    net = shared_mlp(n_in, 1, hidden, depth, env.device)
    return ValueOperator(module=net, in_keys=[key, ACTION], out_keys=[("agents", "state_action_value")])


def make_value(env, critic_input: str, *, hidden: int = 128, depth: int = 2) -> ValueOperator:
    """Per-UAV ``V(x_i)`` (PPO)."""
    key = ("agents", critic_input)
    n_in = env.full_observation_spec_unbatched[key].shape[-1]
    net = shared_mlp(n_in, 1, hidden, depth, env.device)
    return ValueOperator(module=net, in_keys=[key], out_keys=[("agents", "state_value")])


__all__ = ["ACTION", "LOG_PROB", "OBS", "SamplingActor", "action_bounds", "actor_of_sizes", "make_actor", "make_qvalue",
           "make_value", "shared_mlp"]
