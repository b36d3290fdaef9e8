"""The learners, wired from TorchRL parts only (no hand-written losses): SAC and DDPG for K members
(:class:`OffPolicyLearner`; K = 1 a solo run), PPO for one.

Each learner owns its networks, TorchRL loss module, optimiser and target updates behind the
trainer's small surface (:class:`flock_torchrl.run.parts.Learner`); ``actor_state(k)`` is member k's
weights, what it ships. ``update(batch)`` is one gradient step (off-policy) or one PPO pass; its
statistics stay tensors (``[K]`` per member), so an update never waits on a ``.item()``.

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
from dataclasses import dataclass, field
from typing import Any, Sequence

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.modules import AdditiveGaussianModule
from torchrl.objectives import ClipPPOLoss, DDPGLoss, SACLoss, SoftUpdate, ValueEstimators

from ..capture import captured
from ..config import DDPGConfig, PPOConfig, SACConfig
from .members import MemberPolicy, clip_per_member, for_members
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


def check_finite(losses: dict[str, torch.Tensor], members: int = 1) -> None:
    """Stop a diverged run: a non-finite loss (each a scalar, or ``[members]``) raises
    ``FloatingPointError`` naming it, and of several members the first member where it is not finite."""
    values = torch.stack([v.detach().reshape(-1) for v in losses.values()])
    if not bool(torch.isfinite(values).all()):
        name, member = next((k, int((~torch.isfinite(v.reshape(-1))).nonzero()[0, 0])) for k, v in losses.items()
                            if not torch.isfinite(v).all())
        of = f" of member {member}" if members > 1 else ""
        raise FloatingPointError(f"{name}{of} is {losses[name].reshape(-1)[member].item()}: training diverged")


@dataclass
class Parts:
    """One member's modules, built from the env's specs (what an update of it reads)."""

    actor: Any                    # the policy it ships
    loss: Any                     # TorchRL's loss module (its parameters and targets: the member's state)
    collector_policy: Any         # what the collector acts with
    exploration: Any = None       # DDPG's additive noise (shared by the members; annealed by frames)
    trained: tuple[str, ...] = () # the loss module's trained parameter sets, in the optimiser's order
    targets: tuple[str, ...] = () # the networks whose targets follow them (SoftUpdate's pairs)
    terms: dict[str, str] = field(default_factory=dict)   # our loss term -> the loss module's key
    stats: tuple[str, ...] = ()   # further values of the loss module's output logged per update


def sac_parts(env, cfg: SACConfig, critic_input: str) -> Parts:
    """SAC (paper Sec. III-C, Algorithm 1): twin Q, automatic temperature, soft targets."""
    actor = make_actor(env, stochastic=True, hidden=cfg.hidden, depth=cfg.depth)
    qvalue = make_qvalue(env, critic_input, hidden=cfg.hidden, depth=cfg.depth)
    loss = SACLoss(actor_network=actor, qvalue_network=qvalue, num_qvalue_nets=cfg.num_qvalue_nets,
                   loss_function=cfg.loss_function, alpha_init=cfg.alpha_init, target_entropy=cfg.target_entropy,
                   action_spec=env.full_action_spec_unbatched[ACTION], delay_qvalue=True)
    loss.set_keys(action=ACTION, state_action_value=("agents", "state_action_value"), log_prob=LOG_PROB,
                  **AGENT_KEYS)
    # The estimator's discount on the env's device: moved lazily inside the update, it would be a
    # host-to-device copy that a CUDA graph cannot record (and a functional call would undo).
    loss.make_value_estimator(ValueEstimators.TD0, gamma=cfg.gamma, device=env.device)
    # SACLoss turns its target entropy into a buffer on first use; do it here, outside any
    # compiled region (traced, the conversion is lost and state_dict() fails later).
    loss.target_entropy  # noqa: B018
    SoftUpdate(loss, tau=cfg.tau)  # TorchRL's pairing of targets; the learner updates them itself, in place
    return Parts(actor, loss, SamplingActor(actor),  # the actor's draws, without its per-step overhead
                 trained=("actor_network_params", "qvalue_network_params", "log_alpha"), targets=("qvalue_network",),
                 terms={"loss_actor": "loss_actor", "loss_qvalue": "loss_qvalue", "loss_alpha": "loss_alpha"},
                 stats=("alpha", "entropy"))


def ddpg_parts(env, cfg: DDPGConfig, critic_input: str) -> Parts:
    """DDPG (PolicyD-G): deterministic tanh actor, Q critic, target networks, Gaussian exploration."""
    actor = make_actor(env, stochastic=False, hidden=cfg.hidden, depth=cfg.depth)
    qvalue = make_qvalue(env, critic_input, hidden=cfg.hidden, depth=cfg.depth)
    exploration = AdditiveGaussianModule(
        spec=env.full_action_spec_unbatched[ACTION], sigma_init=cfg.noise_sigma, sigma_end=cfg.noise_sigma_end,
        annealing_num_steps=max(cfg.noise_anneal_frames, 1), action_key=ACTION)
    loss = DDPGLoss(actor_network=actor, value_network=qvalue, loss_function=cfg.loss_function,
                    delay_actor=True, delay_value=True)
    loss.set_keys(state_action_value=("agents", "state_action_value"), **AGENT_KEYS)
    loss.make_value_estimator(ValueEstimators.TD0, gamma=cfg.gamma, device=env.device)
    SoftUpdate(loss, tau=cfg.tau)  # TorchRL's pairing of targets; the learner updates them itself, in place
    return Parts(actor, loss, TensorDictSequential(actor, exploration), exploration,
                 trained=("actor_network_params", "value_network_params"), targets=("actor_network", "value_network"),
                 terms={"loss_actor": "loss_actor", "loss_qvalue": "loss_value"})


PARTS = {"sac": sac_parts, "ddpg": ddpg_parts}


class OffPolicyLearner:
    """SAC or DDPG for K members (``seeds``; K = 1: a solo run), trained as one.

    Each member has its own networks, target networks, entropy temperature (SAC), optimiser state
    and replay buffer rows; their parameters are stacked along a leading member dimension and
    TorchRL's own loss module (``SACLoss``, ``DDPGLoss``) is called once per update, under
    ``torch.vmap`` over that dimension for K > 1 (the members' fixed per-call costs paid once), as it
    is for one member. Members share no value: a member's gradients come from its own loss alone, one
    Adam steps every member elementwise (what K Adams would do), the target update is elementwise
    (SoftUpdate's arithmetic). What they share is the order of the draws from torch's generator:
    every draw has a fixed shape (``[K, ...]``, one slice per member), so no member's data or weights
    change what another member draws.

    Initial weights: member 0 draws from torch's global generator exactly as a solo run of
    ``seeds[0]`` does (the trainer seeds it); member k from a generator seeded ``seeds[k]``, so its
    initial networks are those of a solo run with that seed; later draws are shared, so member k > 0
    trains as a seed of its own, not as the solo run of ``seeds[k]``.

    ``update(batch)`` takes ``[batch, K]`` transitions (member k's in column k; ``[batch]`` for one
    member) and returns per-member statistics ``[K]``: one gradient step over the summed losses (they
    touch disjoint parameter sets), gradient clipping per network and member, the soft target
    update. Uncaptured, a non-finite loss stops the update before the optimiser steps; captured
    (``cudagraphs``: the whole step one function without a host read, ``flock_torchrl.capture``),
    the step runs whole and :meth:`check` reports it later (the run stops before its next
    checkpoint, so the last good checkpoint is kept either way). ``compile`` (one member): the loss
    module's forward ``torch.compile`` d (:func:`compiled`), its eager twin otherwise.
    """

    off_policy = True

    def __init__(self, env, algo_cfg, critic_input: str, seeds: Sequence[int] = (0,), compile: bool = False,
                 cudagraphs: bool = False) -> None:
        if compile and len(seeds) > 1:
            raise ValueError("compile: several members' update runs eagerly (torch.vmap over them); use compile=false "
                             "or compile=step")
        self.cfg, self.members = algo_cfg, len(seeds)
        build = PARTS[algo_cfg.name]
        members = [build(env, algo_cfg, critic_input)]
        for seed in seeds[1:]:
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(int(seed))
                members.append(build(env, algo_cfg, critic_input))
        self.parts = parts = members[0]
        self.loss, self.actor, self.exploration = parts.loss, parts.actor, parts.exploration
        if self.members == 1:  # views of the member's own tensors: its modules hold its trained weights
            stacked = TensorDict.from_module(parts.loss).detach().unsqueeze(0)
        else:
            stacked = torch.stack([TensorDict.from_module(m.loss).detach() for m in members]).clone()
        leaves: dict[str, list[torch.Tensor]] = {}
        for key in parts.trained:
            sub = stacked.get(key)
            sub = nn.Parameter(sub) if isinstance(sub, torch.Tensor) else sub.apply(nn.Parameter)
            stacked.set(key, sub)
            leaves[key] = [sub] if isinstance(sub, torch.Tensor) else list(sub.values(True, True))
        self.params = stacked
        lrs = {"actor_network_params": algo_cfg.lr_actor, "qvalue_network_params": algo_cfg.lr_critic,
               "value_network_params": algo_cfg.lr_critic, "log_alpha": getattr(algo_cfg, "lr_alpha", None)}
        self.optimizer = adam([{"params": leaves[k], "lr": lrs[k]} for k in parts.trained], env.device,
                              capturable=cudagraphs)
        self._clip_groups = [leaves[k] for k in parts.trained if k != "log_alpha"]
        # SoftUpdate's own arithmetic: target.lerp_(source, 1 - eps), eps = 1 - tau.
        self._target_weight = 1 - (1 - algo_cfg.tau)
        self._target_pairs = [(stacked.get(f"{n}_params"), stacked.get(f"target_{n}_params")) for n in parts.targets]
        if self.members == 1:  # the member's own policy (also what a multi-process collector's workers copy)
            self.collector_policy = parts.collector_policy
        else:
            acting = parts.collector_policy if isinstance(parts.collector_policy, SamplingActor) else None
            self.collector_policy = MemberPolicy(self.actor, stacked.get("actor_network_params"), self.members,
                                                 after=self.exploration, acting=acting)
        self.loss_fn = compiled(self.loss, compile)

        def member_losses(p: TensorDictBase, batch: TensorDictBase) -> dict[str, torch.Tensor]:
            with p.to_module(self.loss):
                out = self.loss_fn(batch)
            return {**{ours: out[theirs] for ours, theirs in parts.terms.items()}, **{k: out[k] for k in parts.stats}}

        self._losses = for_members(member_losses, self.members, 1)
        self.cudagraphs = bool(cudagraphs)
        self.finite = FiniteLosses(tuple(parts.terms), env.device, self.members if self.members > 1 else None)
        self._update = captured(self._captured_step, env.device, self.cudagraphs)

    # ------------------------------------------------------------------ training
    def on_frames(self, frames: int) -> None:
        """Called with the frames each member collected; DDPG anneals its exploration noise by them."""
        if self.exploration is not None:
            self.exploration.step(frames)

    def update(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """One gradient step of every member on its column of ``batch [batch, K]`` (``[batch]``: one member's)."""
        if batch.ndim == 1:
            batch = batch.unsqueeze(1)
        if self.cudagraphs:
            return self._update(batch)
        out = self._losses(self.params, batch)
        terms = {k: out[k] for k in self.parts.terms}
        check_finite(terms, self.members)
        return self._step(out, terms)

    def check(self) -> None:
        """Raise ``FloatingPointError`` if a captured update met a non-finite loss."""
        self.finite.check()

    def _captured_step(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """One whole update without a host synchronisation (what ``CudaGraphModule`` records)."""
        out = self._losses(self.params, batch)
        terms = {k: out[k] for k in self.parts.terms}
        self.finite.record(terms)
        return self._step(out, terms)

    def _step(self, out: dict[str, torch.Tensor], terms: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        self.optimizer.zero_grad(set_to_none=True)
        sum(terms.values()).sum().backward()
        # Each member's gradient norm of the actor and of the critics, before any clipping.
        norms = {f"grad_norm_{name}": _member_norms(group, self.members)
                 for name, group in zip(("actor", "critic"), self._clip_groups)}
        if self.cfg.max_grad_norm > 0:
            for group in self._clip_groups:
                (_clip if self.members == 1 else clip_per_member)(group, self.cfg.max_grad_norm)
        self.optimizer.step()
        with torch.no_grad():
            for source, target in self._target_pairs:
                for s, t in zip(source.values(True, True), target.values(True, True)):
                    t.lerp_(s, self._target_weight)
        stats = {k: v.detach() for k, v in terms.items()}
        stats.update({k: out[k].detach() for k in self.parts.stats}, **norms)
        if self.exploration is not None:
            stats["sigma"] = self.exploration.sigma.detach().clone().expand(self.members)
        return stats

    def learning_rates(self) -> dict[str, float]:
        """The optimiser's step size of each trained part (Table I's lr_pi, lr_Q, lr_alpha)."""
        names = {"actor_network_params": "actor", "qvalue_network_params": "critic", "value_network_params": "critic",
                 "log_alpha": "alpha"}
        return {f"lr_{names[key]}": group["lr"] for key, group in zip(self.parts.trained, self.optimizer.param_groups)}

    # ------------------------------------------------------------------ members and checkpoints
    def actor_state(self, member: int) -> dict[str, torch.Tensor]:
        """Member ``member``'s actor ``state_dict`` (loadable into ``make_actor``'s module)."""
        with self.params.get("actor_network_params")[member].to_module(self.actor):
            return {k: v.detach().clone() for k, v in self.actor.state_dict().items()}

    def state_dict(self) -> dict[str, Any]:
        """One member's: its loss module's and its optimiser's state (the solo run's checkpoint);
        several members': their stacked parameters and the one optimiser's state."""
        if self.members == 1:
            with self.params[0].to_module(self.loss):
                loss = {k: v.detach().clone() for k, v in self.loss.state_dict().items()}
            state = {"loss": loss, "optimizer": _member_axis(self.optimizer.state_dict(), torch.squeeze)}
        else:
            state = {"params": self.params.detach().clone().to_dict(), "optimizer": self.optimizer.state_dict()}
        if self.exploration is not None:
            state["exploration"] = self.exploration.state_dict()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if self.members == 1:
            with torch.no_grad(), self.params[0].to_module(self.loss):
                self.loss.load_state_dict(state["loss"])
            self.optimizer.load_state_dict(_member_axis(state["optimizer"], torch.unsqueeze))
        else:
            saved = TensorDict(state["params"], batch_size=[self.members])
            if saved.batch_size != self.params.batch_size:
                raise ValueError("the saved population has another number of members")
            with torch.no_grad():
                for key, value in saved.items(True, True):
                    self.params.get(key).copy_(value)
            self.optimizer.load_state_dict(state["optimizer"])
        if self.exploration is not None:
            self.exploration.load_state_dict(state["exploration"])


def _member_norms(params: list[torch.Tensor], members: int) -> torch.Tensor:
    """The norm of each member's slice of every gradient of ``params`` together, ``[members]``."""
    norms = [p.grad.detach().reshape(members, -1).norm(dim=1) for p in params if p.grad is not None]
    return torch.stack(norms).norm(dim=0) if norms else params[0].new_zeros(members)


def _member_axis(state: dict[str, Any], move) -> dict[str, Any]:
    """An optimiser ``state_dict`` with the member dimension of one member taken off
    (``torch.squeeze``) or put on (``torch.unsqueeze``) its per-parameter tensors (not ``step``)."""
    return {"state": {i: {k: v if k == "step" else move(v, 0) for k, v in s.items()}
                      for i, s in state["state"].items()},
            "param_groups": state["param_groups"]}


class PPOLearner:
    """PPO (PolicyP-G): clipped objective, GAE on the per-UAV value ``V(x_i)``; one member."""

    off_policy = False
    members = 1

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
            normalize_advantage=cfg.normalize_advantage)
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

    def learning_rates(self) -> dict[str, float]:
        """The optimiser's step size."""
        return {"lr": self.optimizer.param_groups[0]["lr"]}

    def actor_state(self, member: int = 0) -> dict[str, torch.Tensor]:
        """The actor's ``state_dict`` (its one member's)."""
        return {k: v.detach().clone() for k, v in self.actor.state_dict().items()}

    def state_dict(self) -> dict[str, Any]:
        return {"loss": self.loss.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loss.load_state_dict(state["loss"])
        self.optimizer.load_state_dict(state["optimizer"])


def make_learner(env, algo_cfg, critic_input: str, seeds: Sequence[int] = (0,), compile: bool = False,
                 cudagraphs: bool = False):
    """The learner of ``algo_cfg``: SAC's or DDPG's for the members ``seeds`` (:class:`OffPolicyLearner`),
    or PPO's (one member)."""
    if algo_cfg.name == "ppo":
        if len(seeds) > 1:
            raise ValueError(f"a population trains sac or ddpg, not {algo_cfg.name}")
        return PPOLearner(env, algo_cfg, critic_input, compile=compile, cudagraphs=cudagraphs)
    return OffPolicyLearner(env, algo_cfg, critic_input, seeds, compile=compile, cudagraphs=cudagraphs)
