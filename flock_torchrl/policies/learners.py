"""The three learners, wired from TorchRL parts only (no hand-written losses).

Each learner owns its networks, TorchRL loss module, optimiser and target updater, and
exposes the same small surface to the trainer:

* ``collector_policy`` — the module the collector runs (with exploration);
* ``actor`` — the policy to evaluate and ship (deterministic under
  ``ExplorationType.DETERMINISTIC``);
* ``off_policy`` — whether transitions go through a replay buffer;
* ``update(batch) -> dict[str, Tensor]`` — one gradient step (off-policy) or one PPO pass
  (on-policy); the statistics stay tensors, so an update never waits on a ``.item()``;
* ``state_dict() / load_state_dict()`` — everything a checkpoint needs.

Speed: one Adam per learner with a parameter group per network (each its own learning rate,
as Table I), fused where the device supports it (one kernel for every parameter); with
``compile=True`` the loss module's forward (and, through AOTAutograd, its backward) is
``torch.compile`` d. ``compile=False`` is the eager twin: the same loss, module and optimiser.

Captured (``cudagraphs=True``, SAC and DDPG): the whole gradient step (loss, backward, clipping,
Adam, target update) is one function that never reads a tensor on the host, wrapped in
tensordict's ``CudaGraphModule``: on a GPU it is recorded once as a CUDA graph and replayed, its
Adam ``capturable`` (its step counts on the device). Whether a loss was finite is then kept on
the device and read by :meth:`check` (at logging time and before every checkpoint) instead of
after every update. On a CPU ``CudaGraphModule`` calls the function as it is: the same code path,
eager, which the tests compare against the uncaptured learner.
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

from ..capture import captured
from ..config import DDPGConfig, PPOConfig, SACConfig
from .models import ACTION, LOG_PROB, SamplingActor, make_actor, make_qvalue, make_value

# PPO normalises advantages over all UAVs of the batch on purpose (one shared policy): TorchRL's
# warning about it is held back around our own loss calls only (PPOLearner.update).
ADVANTAGE_NORMALIZATION = "You requested advantage normalization"

AGENT_KEYS = dict(reward=("agents", "reward"), done=("agents", "done"), terminated=("agents", "terminated"))


def adam(groups: list[dict[str, Any]], device: torch.device, capturable: bool = False) -> torch.optim.Adam:
    """One Adam over parameter groups (each with its ``lr``), fused on CPU and CUDA;
    ``capturable`` on CUDA (its step counts on the device, so a CUDA graph can hold its step)."""
    fused = device.type in ("cpu", "cuda")
    extra = {"capturable": True} if capturable and device.type == "cuda" else {}
    return torch.optim.Adam(groups, fused=fused or None, foreach=None if fused else True, **extra)


class FiniteLosses:
    """Whether every loss of every update so far was finite, kept on the device (a captured
    update never reads it on the host): ``record`` inside the update, ``check`` outside it."""

    def __init__(self, names: tuple[str, ...], device: torch.device, members: int | None = None) -> None:
        self.names = names
        shape = (len(names),) if members is None else (len(names), members)
        self.flags = torch.ones(shape, dtype=torch.bool, device=device)

    def record(self, terms: dict[str, torch.Tensor]) -> None:
        self.flags.logical_and_(torch.stack([torch.isfinite(terms[k].detach()).reshape(self.flags.shape[1:])
                                             for k in self.names]))

    def check(self) -> None:
        """``FloatingPointError`` naming the first loss (and member) that was not finite."""
        if bool(self.flags.all()):
            return
        bad = (~self.flags).nonzero()[0].tolist()
        member = f" of member {bad[1]}" if len(bad) > 1 else ""
        raise FloatingPointError(f"{self.names[bad[0]]}{member} was not finite: training diverged")


# Inductor's CPU kernels for the losses are built scalar (``cpp.simdlen = 1``): at these sizes
# (128-wide layers, 130-1280 rows) its vectorised kernels spend their time storing the ReLU masks
# the backward reads, one byte at a time, and measured slower than scalar ones here (a paper-recipe
# update 5.2 -> 4.1 ms, a batch-1280 one 35 -> 23 ms; `make benchmark`'s SAC-update rows). CUDA
# kernels (Triton) ignore the setting.
LOSS_COMPILE_OPTIONS = {"cpp.simdlen": 1}


def compiled(loss: torch.nn.Module, compile: bool, options: dict[str, Any] | None = None):
    """The loss module itself, or its ``torch.compile`` d forward (inductor ``options``, default
    :data:`LOSS_COMPILE_OPTIONS`). Compiled code draws its random numbers (SAC's
    reparameterised actions) from torch's own generator, as eager code does
    (``fallback_random``), so a seeded run samples the same actions either way."""
    if not compile:
        return loss
    import torch._inductor.config as inductor_config

    inductor_config.fallback_random = True
    options = LOSS_COMPILE_OPTIONS if options is None else options
    # Dynamo's full guards and static shapes: a second learner of another size in the same process
    # (a sweep's worker, the tests) must recompile for its own shapes. Skipping the guards on
    # module attributes (as this did before) let it run the first learner's graph; left dynamic,
    # dynamo retraces TorchRL's vmapped twin Q with a symbolic hidden size and fails. The guards
    # cost no measurable time per update here.
    return torch.compile(loss, dynamic=False, options=options)


def _clip(params, max_norm: float) -> None:
    if max_norm > 0:
        torch.nn.utils.clip_grad_norm_(params, max_norm)


def check_finite(losses: dict[str, torch.Tensor]) -> None:
    """Stop a diverged run: a non-finite loss raises ``FloatingPointError`` naming it."""
    values = torch.stack([v.detach().reshape(()) for v in losses.values()])
    if not bool(torch.isfinite(values).all()):
        name, value = next((k, v) for k, v in losses.items() if not torch.isfinite(v).all())
        raise FloatingPointError(f"{name} is {value.item()}: training diverged")


class _OffPolicy:
    """What SAC and DDPG share: one gradient step over the summed losses (they touch disjoint
    parameter sets), gradient clipping per network, then the soft target update.

    Uncaptured, a non-finite loss stops the update before the optimiser steps; captured, the
    step runs whole and :meth:`check` reports it later (the run then stops before its next
    checkpoint, so the last good checkpoint is kept either way)."""

    off_policy = True
    cfg: Any
    actor_params: list
    q_params: list
    optimizer: torch.optim.Optimizer
    target_updater: SoftUpdate
    cudagraphs: bool = False

    def on_frames(self, frames: int) -> None:
        """Called with the frames of every collected batch; SAC has nothing to anneal (DDPG does)."""

    def _terms(self, losses: TensorDictBase) -> dict[str, torch.Tensor]:
        raise NotImplementedError

    def _stats(self, losses: TensorDictBase, terms: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        raise NotImplementedError

    def _setup_update(self, device: torch.device, cudagraphs: bool) -> None:
        self.cudagraphs = bool(cudagraphs)
        self.finite = FiniteLosses(tuple(self._term_names), device)
        self._update = captured(self._captured_step, device, self.cudagraphs)

    def update(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        if self.cudagraphs:
            return self._update(batch)
        losses = self.loss_fn(batch)
        terms = self._terms(losses)
        check_finite(terms)
        self._gradient_step(terms)
        return self._stats(losses, terms)

    def check(self) -> None:
        """Raise ``FloatingPointError`` if a captured update met a non-finite loss."""
        self.finite.check()

    def _captured_step(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """One whole update without a host synchronisation (what ``CudaGraphModule`` records)."""
        losses = self.loss_fn(batch)
        terms = self._terms(losses)
        self.finite.record(terms)
        self._gradient_step(terms)
        return self._stats(losses, terms)

    def _gradient_step(self, terms: dict[str, torch.Tensor]) -> None:
        self.optimizer.zero_grad(set_to_none=True)
        sum(terms.values()).backward()
        _clip(self.actor_params, self.cfg.max_grad_norm)
        _clip(self.q_params, self.cfg.max_grad_norm)
        self.optimizer.step()
        self.target_updater.step()


class SACLearner(_OffPolicy):
    """SAC (paper Sec. III-C, Algorithm 1): twin Q, automatic temperature, soft targets."""

    _term_names = ("loss_actor", "loss_qvalue", "loss_alpha")

    def __init__(self, env, cfg: SACConfig, critic_input: str, compile: bool = False,
                 cudagraphs: bool = False) -> None:
        self.cfg = cfg
        self.actor = make_actor(env, stochastic=True, hidden=cfg.hidden, depth=cfg.depth)
        self.qvalue = make_qvalue(env, critic_input, hidden=cfg.hidden, depth=cfg.depth)
        self.collector_policy = SamplingActor(self.actor)  # the actor's draws, without its per-step overhead
        self.loss = SACLoss(
            actor_network=self.actor, qvalue_network=self.qvalue, num_qvalue_nets=cfg.num_qvalue_nets,
            loss_function=cfg.loss_function, alpha_init=cfg.alpha_init, target_entropy=cfg.target_entropy,
            action_spec=env.full_action_spec_unbatched[ACTION], delay_qvalue=True,
        )
        self.loss.set_keys(action=ACTION, state_action_value=("agents", "state_action_value"),
                           log_prob=LOG_PROB, **AGENT_KEYS)
        # The estimator's discount on the env's device: moved lazily inside the update, it would be a
        # host-to-device copy that a CUDA graph cannot record (and a functional call would undo).
        self.loss.make_value_estimator(ValueEstimators.TD0, gamma=cfg.gamma, device=env.device)
        self.target_updater = SoftUpdate(self.loss, tau=cfg.tau)
        self.actor_params = list(self.loss.actor_network_params.values(True, True))
        self.q_params = list(self.loss.qvalue_network_params.values(True, True))
        self.optimizer = adam([{"params": self.actor_params, "lr": cfg.lr_actor},
                               {"params": self.q_params, "lr": cfg.lr_critic},
                               {"params": [self.loss.log_alpha], "lr": cfg.lr_alpha}], env.device,
                              capturable=cudagraphs)
        # SACLoss turns its target entropy into a buffer on first use; do it here, outside any
        # compiled region (traced, the conversion is lost and state_dict() fails later).
        self.loss.target_entropy  # noqa: B018
        self.loss_fn = compiled(self.loss, compile)
        self._setup_update(env.device, cudagraphs)

    def _terms(self, losses: TensorDictBase) -> dict[str, torch.Tensor]:
        return {k: losses[k] for k in self._term_names}

    def _stats(self, losses: TensorDictBase, terms: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return {**{k: v.detach() for k, v in terms.items()}, "alpha": losses["alpha"].detach(),
                "entropy": losses["entropy"].detach()}

    def state_dict(self) -> dict[str, Any]:
        return {"loss": self.loss.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizer"])


class DDPGLearner(_OffPolicy):
    """DDPG (PolicyD-G): deterministic tanh actor, Q critic, target networks, Gaussian exploration."""

    _term_names = ("loss_actor", "loss_qvalue")

    def __init__(self, env, cfg: DDPGConfig, critic_input: str, compile: bool = False,
                 cudagraphs: bool = False) -> None:
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
        self.loss.make_value_estimator(ValueEstimators.TD0, gamma=cfg.gamma, device=env.device)
        self.target_updater = SoftUpdate(self.loss, tau=cfg.tau)
        self.actor_params = list(self.loss.actor_network_params.values(True, True))
        self.q_params = list(self.loss.value_network_params.values(True, True))
        self.optimizer = adam([{"params": self.actor_params, "lr": cfg.lr_actor},
                               {"params": self.q_params, "lr": cfg.lr_critic}], env.device, capturable=cudagraphs)
        self.loss_fn = compiled(self.loss, compile)
        self._setup_update(env.device, cudagraphs)

    def on_frames(self, frames: int) -> None:
        """Anneal the exploration noise by the frames just collected."""
        self.exploration.step(frames)

    def _terms(self, losses: TensorDictBase) -> dict[str, torch.Tensor]:
        return {"loss_actor": losses["loss_actor"], "loss_qvalue": losses["loss_value"]}

    def _stats(self, losses: TensorDictBase, terms: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return {**{k: v.detach() for k, v in terms.items()}, "sigma": self.exploration.sigma.detach().clone()}

    def state_dict(self) -> dict[str, Any]:
        return {"loss": self.loss.state_dict(), "exploration": self.exploration.state_dict(),
                "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.exploration.load_state_dict(state["exploration"])
        self.optimizer.load_state_dict(state["optimizer"])


class PPOLearner:
    """PPO (PolicyP-G): clipped objective, GAE on the per-UAV value ``V(x_i)``."""

    off_policy = False

    def on_frames(self, frames: int) -> None:
        """Called with the frames of every collected batch: nothing to anneal."""

    def __init__(self, env, cfg: PPOConfig, critic_input: str, compile: bool = False,
                 cudagraphs: bool = False) -> None:
        if cudagraphs:
            raise ValueError("cudagraphs: the captured update is SAC's and DDPG's; PPO's epochs run as they are")
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
        self.loss.make_value_estimator(ValueEstimators.GAE, gamma=cfg.gamma, lmbda=cfg.lmbda, device=env.device)
        self.params = list(self.loss.parameters())
        self.optimizer = adam([{"params": self.params, "lr": cfg.lr}], env.device)
        self.loss_fn = compiled(self.loss, compile)

    def update(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """``epochs`` passes of minibatch steps over one on-policy batch ``[E, T]``."""
        with torch.no_grad():
            self.loss.value_estimator(batch, params=self.loss.critic_network_params,
                                      target_params=self.loss.target_critic_network_params)
        flat = batch.reshape(-1)
        n = flat.shape[0]
        size = min(self.cfg.minibatch_size, n)
        stats: dict[str, torch.Tensor] = {}
        for _ in range(self.cfg.epochs):
            order = torch.randperm(n, device=flat.device)
            for start in range(0, n - size + 1, size):  # minibatches of one batch: PPO's epochs
                with warnings.catch_warnings():
                    warnings.filterwarnings("ignore", message=ADVANTAGE_NORMALIZATION)
                    losses = self.loss_fn(flat[order[start:start + size]])
                terms = {"loss_objective": losses["loss_objective"], "loss_critic": losses["loss_critic"]}
                check_finite(terms)
                total = terms["loss_objective"] + terms["loss_critic"] + losses.get("loss_entropy", 0.0)
                self.optimizer.zero_grad(set_to_none=True)
                total.backward()
                _clip(self.params, self.cfg.max_grad_norm)
                self.optimizer.step()
                stats = {"loss_actor": terms["loss_objective"].detach(), "loss_critic": terms["loss_critic"].detach(),
                         "entropy": losses["entropy"].detach() if "entropy" in losses.keys()
                         else torch.tensor(math.nan)}
        return stats

    def check(self) -> None:
        """Every PPO update checks its losses itself."""

    def state_dict(self) -> dict[str, Any]:
        return {"loss": self.loss.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizer"])


LEARNERS = {"sac": SACLearner, "ddpg": DDPGLearner, "ppo": PPOLearner}


def make_learner(env, algo_cfg, critic_input: str, compile: bool = False, cudagraphs: bool = False):
    return LEARNERS[algo_cfg.name](env, algo_cfg, critic_input, compile=compile, cudagraphs=cudagraphs)
