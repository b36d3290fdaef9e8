"""Networks (paper Fig. 3), built from the env's specs with TorchRL's multi-agent modules.

One actor is shared by all UAVs (``MultiAgentMLP(share_params=True, centralized=False)``);
the critic is per UAV and shared too, reading ``("agents", critic_input)`` and, for Q
networks, the action. Shared parameters do not depend on N, so a policy trained with 5 UAVs
runs with 9 (S2): :func:`make_actor` is simply rebuilt for the other N and loaded.
"""

from __future__ import annotations

import copy
from typing import Any

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal, ValueOperator

OBS = ("agents", "observation")
ACTION = ("agents", "action")
LOG_PROB = ("agents", "action_log_prob")


def _mlp(n_in: int, n_out: int, n_agents: int, hidden: int, depth: int, device) -> MultiAgentMLP:
    return MultiAgentMLP(
        n_agent_inputs=n_in, n_agent_outputs=n_out, n_agents=n_agents, centralized=False, share_params=True,
        device=device, depth=depth, num_cells=hidden, activation_class=nn.ReLU,
    )


def action_bounds(env) -> tuple[torch.Tensor, torch.Tensor]:
    spec = env.full_action_spec_unbatched[ACTION]
    return spec.space.low, spec.space.high


def make_actor(env, *, stochastic: bool = True, hidden: int = 128, depth: int = 2,
               return_log_prob: bool = False) -> TensorDictModule:
    """The shared policy ``pi(a | o)``.

    Stochastic: ``MultiAgentMLP -> (loc, scale)`` and a tanh-squashed Gaussian on ``[-1, 1]^2``
    (its deterministic mode is the tanh of the mean). Deterministic (DDPG): ``tanh(MLP(o))``.
    Sizes come from ``env``'s specs.
    """
    n_obs = env.full_observation_spec_unbatched[OBS].shape[-1]
    n_act = env.full_action_spec_unbatched[ACTION].shape[-1]
    low, high = action_bounds(env)
    device = env.device
    if not stochastic:
        net = nn.Sequential(_mlp(n_obs, n_act, env.n_agents, hidden, depth, device), nn.Tanh())
        return TensorDictModule(net, in_keys=[OBS], out_keys=[ACTION])
    net = nn.Sequential(_mlp(n_obs, 2 * n_act, env.n_agents, hidden, depth, device),
                        NormalParamExtractor(scale_mapping="biased_softplus_1.0", scale_lb=1e-4))
    module = TensorDictModule(net, in_keys=[OBS], out_keys=[("agents", "loc"), ("agents", "scale")])
    return ProbabilisticActor(
        module=module,
        in_keys=[("agents", "loc"), ("agents", "scale")],
        out_keys=[ACTION],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": low, "high": high},
        return_log_prob=return_log_prob,
        log_prob_key=LOG_PROB,
    )


def make_qvalue(env, critic_input: str, *, hidden: int = 128, depth: int = 2) -> ValueOperator:
    """Per-UAV ``Q(x_i, a_i)`` with ``x`` the observation or the centralised state."""
    key = ("agents", critic_input)
    n_in = env.full_observation_spec_unbatched[key].shape[-1] + env.full_action_spec_unbatched[ACTION].shape[-1]
    net = _mlp(n_in, 1, env.n_agents, hidden, depth, env.device)
    return ValueOperator(module=net, in_keys=[key, ACTION], out_keys=[("agents", "state_action_value")])


def make_value(env, critic_input: str, *, hidden: int = 128, depth: int = 2) -> ValueOperator:
    """Per-UAV ``V(x_i)`` (PPO)."""
    key = ("agents", critic_input)
    n_in = env.full_observation_spec_unbatched[key].shape[-1]
    net = _mlp(n_in, 1, env.n_agents, hidden, depth, env.device)
    return ValueOperator(module=net, in_keys=[key], out_keys=[("agents", "state_value")])


def adapt_n_agents(module: Any, n_agents: int) -> Any:
    """A copy of ``module`` whose shared, decentralised ``MultiAgentMLP`` s take ``n_agents`` UAVs.

    Shared parameters do not depend on N (section 7), so a policy trained with five UAVs runs S2's
    nine; torchrl's MultiAgentMLP only checks its stored ``n_agents``. Returns ``module`` itself
    when nothing needs changing; raises for per-agent or centralised networks.
    """
    if not isinstance(module, torch.nn.Module) or callable(getattr(module, "actor_for", None)):
        return module  # not a network, or one that rebuilds itself per N (checkpoint.SharedPolicy)
    mismatched = [m for m in module.modules() if isinstance(m, MultiAgentMLP) and m.n_agents != n_agents]
    if not mismatched:
        return module
    bad = [m for m in mismatched if not m.share_params or m.centralized]
    if bad:
        raise ValueError(f"the policy's MultiAgentMLP was built for {bad[0].n_agents} agents with "
                         f"share_params={bad[0].share_params}, centralized={bad[0].centralized}; "
                         f"it cannot run {n_agents} UAVs")
    module = copy.deepcopy(module)
    for m in module.modules():
        if isinstance(m, MultiAgentMLP):
            m.n_agents = n_agents
    return module


__all__ = ["adapt_n_agents", "make_actor", "make_qvalue", "make_value"]
