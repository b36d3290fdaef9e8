"""The three learners, wired from TorchRL parts only (no hand-written losses).

Each learner owns its networks, TorchRL loss module, optimisers and target updater, and
exposes the same small surface to the trainer:

* ``collector_policy`` — the module the collector runs (with exploration);
* ``actor`` — the policy to evaluate and ship (deterministic under
  ``ExplorationType.DETERMINISTIC``);
* ``off_policy`` — whether transitions go through a replay buffer;
* ``update(batch) -> dict`` — one gradient step (off-policy) or one PPO pass (on-policy);
* ``state_dict() / load_state_dict()`` — everything a checkpoint needs.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential
from torchrl.modules import AdditiveGaussianModule
from torchrl.objectives import ClipPPOLoss, DDPGLoss, SACLoss, SoftUpdate, ValueEstimators

from .models import ACTION, LOG_PROB, make_actor, make_qvalue, make_value
from ..config import DDPGConfig, PPOConfig, SACConfig

# PPO normalises advantages over all UAVs of the batch on purpose (one shared policy).
warnings.filterwarnings("ignore", message="You requested advantage normalization")

AGENT_KEYS = dict(reward=("agents", "reward"), done=("agents", "done"), terminated=("agents", "terminated"))


def _clip(params, max_norm: float) -> None:
    if max_norm > 0:
        torch.nn.utils.clip_grad_norm_(params, max_norm)


def _finite(losses: dict[str, torch.Tensor]) -> None:
    for name, value in losses.items():
        if not torch.isfinite(value).all():
            raise FloatingPointError(f"{name} is {value.item()}: training diverged")


class SACLearner:
    """SAC (paper Sec. III-C, Algorithm 1): twin Q, automatic temperature, soft targets."""

    off_policy = True

    def __init__(self, env, cfg: SACConfig, critic_input: str) -> None:
        self.cfg = cfg
        self.actor = make_actor(env, stochastic=True, hidden=cfg.hidden, depth=cfg.depth)
        self.qvalue = make_qvalue(env, critic_input, hidden=cfg.hidden, depth=cfg.depth)
        self.collector_policy = self.actor
        self.loss = SACLoss(
            actor_network=self.actor, qvalue_network=self.qvalue, num_qvalue_nets=cfg.num_qvalue_nets,
            loss_function=cfg.loss_function, alpha_init=cfg.alpha_init, target_entropy=cfg.target_entropy,
            action_spec=env.full_action_spec_unbatched[ACTION], delay_qvalue=True,
        )
        self.loss.set_keys(action=ACTION, state_action_value=("agents", "state_action_value"),
                           log_prob=LOG_PROB, **AGENT_KEYS)
        self.loss.make_value_estimator(ValueEstimators.TD0, gamma=cfg.gamma)
        self.target_updater = SoftUpdate(self.loss, tau=cfg.tau)
        self.actor_params = list(self.loss.actor_network_params.values(True, True))
        self.q_params = list(self.loss.qvalue_network_params.values(True, True))
        self.opt_actor = torch.optim.Adam(self.actor_params, lr=cfg.lr_actor)
        self.opt_q = torch.optim.Adam(self.q_params, lr=cfg.lr_critic)
        self.opt_alpha = torch.optim.Adam([self.loss.log_alpha], lr=cfg.lr_alpha)

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        losses = self.loss(batch)
        _finite({k: losses[k] for k in ("loss_actor", "loss_qvalue", "loss_alpha")})
        # One backward over the sum: the three losses touch disjoint parameter sets.
        self.opt_actor.zero_grad(set_to_none=True)
        self.opt_q.zero_grad(set_to_none=True)
        self.opt_alpha.zero_grad(set_to_none=True)
        (losses["loss_actor"] + losses["loss_qvalue"] + losses["loss_alpha"]).backward()
        _clip(self.actor_params, self.cfg.max_grad_norm)
        _clip(self.q_params, self.cfg.max_grad_norm)
        self.opt_q.step()
        self.opt_actor.step()
        self.opt_alpha.step()
        self.target_updater.step()
        return {"loss_actor": losses["loss_actor"].item(), "loss_qvalue": losses["loss_qvalue"].item(),
                "loss_alpha": losses["loss_alpha"].item(), "alpha": losses["alpha"].item(),
                "entropy": losses["entropy"].item()}

    def state_dict(self) -> dict[str, Any]:
        return {"loss": self.loss.state_dict(), "opt_actor": self.opt_actor.state_dict(),
                "opt_q": self.opt_q.state_dict(), "opt_alpha": self.opt_alpha.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.opt_actor.load_state_dict(state["opt_actor"])
        self.opt_q.load_state_dict(state["opt_q"])
        self.opt_alpha.load_state_dict(state["opt_alpha"])


class DDPGLearner:
    """DDPG (PolicyD-G): deterministic tanh actor, Q critic, target networks, Gaussian exploration."""

    off_policy = True

    def __init__(self, env, cfg: DDPGConfig, critic_input: str) -> None:
        self.cfg = cfg
        self.actor = make_actor(env, stochastic=False, hidden=cfg.hidden, depth=cfg.depth)
        self.qvalue = make_qvalue(env, critic_input, hidden=cfg.hidden, depth=cfg.depth)
        self.exploration = AdditiveGaussianModule(
            spec=env.full_action_spec_unbatched[ACTION], sigma_init=cfg.noise_sigma, sigma_end=cfg.noise_sigma_end,
            annealing_num_steps=max(cfg.noise_anneal_frames, 1), action_key=ACTION,
        )
        self.collector_policy = TensorDictSequential(self.actor, self.exploration)
        self.loss = DDPGLoss(actor_network=self.actor, value_network=self.qvalue, loss_function=cfg.loss_function,
                             delay_actor=True, delay_value=True)
        self.loss.set_keys(state_action_value=("agents", "state_action_value"), **AGENT_KEYS)
        self.loss.make_value_estimator(ValueEstimators.TD0, gamma=cfg.gamma)
        self.target_updater = SoftUpdate(self.loss, tau=cfg.tau)
        self.actor_params = list(self.loss.actor_network_params.values(True, True))
        self.q_params = list(self.loss.value_network_params.values(True, True))
        self.opt_actor = torch.optim.Adam(self.actor_params, lr=cfg.lr_actor)
        self.opt_q = torch.optim.Adam(self.q_params, lr=cfg.lr_critic)

    def on_frames(self, frames: int) -> None:
        """Anneal the exploration noise by the frames just collected."""
        self.exploration.step(frames)

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        losses = self.loss(batch)
        _finite({k: losses[k] for k in ("loss_actor", "loss_value")})
        self.opt_actor.zero_grad(set_to_none=True)
        self.opt_q.zero_grad(set_to_none=True)
        (losses["loss_actor"] + losses["loss_value"]).backward()
        _clip(self.actor_params, self.cfg.max_grad_norm)
        _clip(self.q_params, self.cfg.max_grad_norm)
        self.opt_q.step()
        self.opt_actor.step()
        self.target_updater.step()
        return {"loss_actor": losses["loss_actor"].item(), "loss_qvalue": losses["loss_value"].item(),
                "sigma": float(self.exploration.sigma)}

    def state_dict(self) -> dict[str, Any]:
        return {"loss": self.loss.state_dict(), "exploration": self.exploration.state_dict(),
                "opt_actor": self.opt_actor.state_dict(), "opt_q": self.opt_q.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.exploration.load_state_dict(state["exploration"])
        self.opt_actor.load_state_dict(state["opt_actor"])
        self.opt_q.load_state_dict(state["opt_q"])


class PPOLearner:
    """PPO (PolicyP-G): clipped objective, GAE on the per-UAV value ``V(x_i)``."""

    off_policy = False

    def __init__(self, env, cfg: PPOConfig, critic_input: str) -> None:
        self.cfg = cfg
        self.actor = make_actor(env, stochastic=True, hidden=cfg.hidden, depth=cfg.depth, return_log_prob=True)
        self.value = make_value(env, critic_input, hidden=cfg.hidden, depth=cfg.depth)
        self.collector_policy = self.actor
        self.loss = ClipPPOLoss(
            actor_network=self.actor, critic_network=self.value, clip_epsilon=cfg.clip_epsilon,
            entropy_coeff=cfg.entropy_coeff, critic_coeff=cfg.critic_coeff, loss_critic_type=cfg.loss_critic_type,
            normalize_advantage=cfg.normalize_advantage,
        )
        self.loss.set_keys(action=ACTION, sample_log_prob=LOG_PROB, value=("agents", "state_value"),
                           advantage=("agents", "advantage"), value_target=("agents", "value_target"),
                           **AGENT_KEYS)
        self.loss.make_value_estimator(ValueEstimators.GAE, gamma=cfg.gamma, lmbda=cfg.lmbda)
        self.params = list(self.loss.parameters())
        self.optimizer = torch.optim.Adam(self.params, lr=cfg.lr)

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        """``epochs`` passes of minibatch steps over one on-policy batch ``[E, T]``."""
        with torch.no_grad():
            self.loss.value_estimator(batch, params=self.loss.critic_network_params,
                                      target_params=self.loss.target_critic_network_params)
        flat = batch.reshape(-1)
        n = flat.shape[0]
        size = min(self.cfg.minibatch_size, n)
        stats: dict[str, float] = {}
        for _ in range(self.cfg.epochs):
            order = torch.randperm(n)
            for start in range(0, n - size + 1, size):
                losses = self.loss(flat[order[start:start + size]])
                total = losses["loss_objective"] + losses["loss_critic"] + losses.get("loss_entropy", 0.0)
                _finite({"loss_objective": losses["loss_objective"], "loss_critic": losses["loss_critic"]})
                self.optimizer.zero_grad(set_to_none=True)
                total.backward()
                _clip(self.params, self.cfg.max_grad_norm)
                self.optimizer.step()
                stats = {"loss_actor": losses["loss_objective"].item(), "loss_critic": losses["loss_critic"].item(),
                         "entropy": losses["entropy"].item() if "entropy" in losses.keys() else math.nan}
        return stats

    def state_dict(self) -> dict[str, Any]:
        return {"loss": self.loss.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizer"])


LEARNERS = {"sac": SACLearner, "ddpg": DDPGLearner, "ppo": PPOLearner}


def make_learner(env, algo_cfg, critic_input: str):
    return LEARNERS[algo_cfg.name](env, algo_cfg, critic_input)
