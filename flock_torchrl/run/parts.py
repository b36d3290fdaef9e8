"""The parts a training run is built from: its envs, collectors and replay buffer, what it
asks of a learner, its evaluation row, its checkpoint writes and its result."""

from __future__ import annotations

import copy
import errno
import functools
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs.utils import ExplorationType

from ..config import TrainConfig
from ..io import write_failure
from ..policies.checkpoint import CheckpointError, save_checkpoint
from .. import capture
from ..world.env import FlockingEnv
from ..world.population import PopulationEnv
from .batches import AgentwiseDone
from .signals import ignore_stop_signals, start_workers
from .timing import split_line


class Learner(Protocol):
    """What a training loop asks of a learner (:mod:`~flock_torchrl.policies.learners`, or a
    population's)."""

    off_policy: bool
    actor: Any                # the policy it ships (a TensorDictModule)
    collector_policy: Any     # what the collector acts with (the actor, plus exploration noise)

    def on_frames(self, frames: int) -> None: ...       # frames just collected (noise annealing)
    def update(self, batch: TensorDictBase) -> dict[str, torch.Tensor]: ...
    def check(self) -> None: ...                         # FloatingPointError if a captured update diverged
    def state_dict(self) -> dict[str, Any]: ...
    def load_state_dict(self, state: dict[str, Any]) -> None: ...


@dataclass
class TrainResult:
    run_dir: Path
    checkpoint: Path
    frames: int
    episodes: int
    updates: int
    seconds: float
    evaluations: list[dict[str, float]] = field(default_factory=list)
    interrupted: int = 0               # the signal that stopped the run early (0: none)
    split: dict[str, float] = field(default_factory=dict)  # seconds of this process's loop, by part

    def split_line(self) -> str:
        """``time split (..): env 10.2 s (31 %), collection ...`` over this process's training loop."""
        return split_line(self.split)


def rng_state(device: torch.device) -> dict[str, torch.Tensor]:
    """Torch's global generators a run draws from: the CPU's, and the CUDA device's when the
    run is on one (its policy and losses sample there), so that a resume continues bit for bit."""
    state = {"torch": torch.get_rng_state()}
    if device.type == "cuda":
        state["cuda"] = torch.cuda.get_rng_state(device)
    return state


def restore_rng(saved: dict[str, torch.Tensor], device: torch.device) -> None:
    """Put back :func:`rng_state` (a checkpoint of a CPU run resumed on a GPU keeps the
    device's own seeding)."""
    torch.set_rng_state(saved["torch"])
    if device.type == "cuda" and "cuda" in saved:
        torch.cuda.set_rng_state(saved["cuda"], device)


def make_env(cfg: TrainConfig, num_envs: int, device: torch.device, seed: int, parent: int,
             scenario: Any = None) -> FlockingEnv:
    """A training env (in a collector process, one that leaves stop signals to the main process)."""
    if os.getpid() != parent:
        ignore_stop_signals()
    return FlockingEnv(scenario or cfg.train_scenario, num_envs=num_envs, device=device, seed=seed,
                       compile_step=cfg.compile_step, check_actions=False, reset_pool=cfg.reset_pool,
                       capture_step=cfg.cudagraphs)


def make_envs(cfg: TrainConfig, device: torch.device) -> tuple[list[FlockingEnv], Any]:
    """The main process's training envs (one per swarm size and kind of world when they are
    mixed, the worlds split evenly, seeds ``1000 * seed + i``; for a population, each a
    :class:`~flock_torchrl.world.population.PopulationEnv` of every member's worlds), and the
    factory of a worker's env (by seed)."""
    exp = cfg.experiment
    factory = functools.partial(make_env, cfg, exp.num_envs // exp.workers, device, parent=os.getpid())
    share = exp.num_envs // len(cfg.train_scenarios)
    if cfg.population > 1:  # each member's worlds of size i draw from a generator seeded as its solo run's
        return [PopulationEnv(scenario, cfg.population, share, [s * 1000 + i for s in cfg.seeds], device=device,
                              compile_step=cfg.compile_step, check_actions=False, reset_pool=cfg.reset_pool,
                              capture_step=cfg.cudagraphs)
                for i, scenario in enumerate(cfg.train_scenarios)], factory
    if not (exp.swarm_sizes or exp.train_mix):
        return [factory(cfg.seed * 1000)], factory
    return [make_env(cfg, share, device, cfg.seed * 1000 + i, os.getpid(), scenario)
            for i, scenario in enumerate(cfg.train_scenarios)], factory


def make_collectors(cfg: TrainConfig, envs: list[FlockingEnv], factory: Any, policy: Any, steps: int,
                    init_random: int, device: torch.device, reuse_batch: bool = False) -> list[Any]:
    """One collector per env (more sizes: stepped in turn, their batches learned from together),
    each batch leaving it with per-UAV done flags; with ``workers > 1`` one multi-process
    collector, started where a stop signal cannot reach its workers.

    ``reuse_batch``: an in-process collector hands out the same batch each time, overwritten by
    the next (TorchRL's ``return_same_td``), for a loop that is done with a batch before it asks
    for the next one (an off-policy run copies it into the replay buffer); it saves a copy of
    every batch, a fifth of the paper recipe's collection time (one env step per batch). Its
    ``no_cuda_sync`` keeps a GPU's collection on the stream the update runs on, as without
    ``return_same_td`` (with it TorchRL collects on a side stream and waits for it on the host
    after every batch); the collector's env, policy and batch share one device, so it has no
    copy between devices to synchronise."""
    exp = cfg.experiment
    worlds = envs[0].num_envs if len(envs) > 1 or cfg.population > 1 else exp.num_envs
    kwargs = dict(frames_per_batch=worlds * steps, total_frames=-1, device=device,
                  init_random_frames=init_random or None, exploration_type=ExplorationType.RANDOM,
                  auto_register_policy_transforms=False,
                  cudagraph_policy=capture.policy_capture(cfg.device, cfg.cudagraphs))

    def single(env: FlockingEnv) -> Collector:
        return Collector(env, policy, track_traj_ids=False, postproc=AgentwiseDone(env.n_agents),
                         return_same_td=reuse_batch, no_cuda_sync=reuse_batch, **kwargs)

    first = start_workers(lambda: MultiSyncCollector(
        [functools.partial(factory, cfg.seed * 1000 + w) for w in range(exp.workers)], policy,
        postproc=AgentwiseDone(envs[0].n_agents), **kwargs)) if exp.workers > 1 else single(envs[0])
    return [first, *(single(env) for env in envs[1:])]


class UnreadCursorStorage(LazyTensorStorage):
    """TorchRL's ``LazyTensorStorage`` that does not read its write cursor on the host at every
    write. TorchRL records the last index written (for its slice samplers, which these buffers do
    not use) with an ``.item()`` of the index tensor: on a GPU, a synchronisation per batch. Here
    the index tensor is kept and read only if the cursor is asked for."""

    _unread_cursor: torch.Tensor | None = None

    def _set_last_cursor(self, cursor: Any) -> None:
        if isinstance(cursor, torch.Tensor) and not self._compilable:
            self._last_cursor, self._unread_cursor = cursor, cursor
            return
        self._unread_cursor = None
        super()._set_last_cursor(cursor)

    @property
    def _last_cursor_index(self) -> int | torch.Tensor | None:
        if self._unread_cursor is not None:
            cursor, self._unread_cursor = self._unread_cursor, None
            super()._set_last_cursor(cursor)
        return super()._last_cursor_index


def replay_buffer(cfg: TrainConfig, n_uavs: int, device: torch.device, **kwargs: Any) -> TensorDictReplayBuffer:
    """Swarm transitions of ``n_uavs`` UAVs (1: single-UAV ones): ``batch_size / n_uavs`` of them
    per sample and ``buffer_size / n_uavs`` held, rounded up (:class:`UnreadCursorStorage`)."""
    batch = max(1, math.ceil(cfg.algo.batch_size / n_uavs))
    capacity = max(batch, math.ceil(cfg.algo.buffer_size / n_uavs))
    return TensorDictReplayBuffer(storage=UnreadCursorStorage(capacity, device=device), batch_size=batch, **kwargs)


def buffer_state(buffer: TensorDictReplayBuffer) -> dict[str, Any]:
    """The replay buffer's ``state_dict`` with only its filled rows (a copy of them): the rows
    never written are not saved, nor is the whole preallocated storage copied (a view of it would
    save all of it). :func:`restore_buffer` gives the storage its capacity again."""
    state = buffer.state_dict()
    rows, capacity = int(state["_storage"].get("_len", 0)), buffer.storage.max_size
    if not 0 < rows < capacity:
        return state
    return _rows(state, lambda v: v[:rows].clone() if v.shape[0] == capacity else v)


def _rows(state: dict, fn: Any) -> dict:
    """A replay buffer's state dict with ``fn`` applied to its storage's tensors (the storage's
    TensorDict metadata, the batch size kept as an attribute of the dict, kept as it is)."""
    storage = state["_storage"]
    tensors = storage.get("_storage")
    if not isinstance(tensors, dict):
        return state
    out = copy.copy(tensors)
    for key, value in tensors.items():
        if isinstance(value, torch.Tensor) and value.dim():
            out[key] = fn(value)
    return {**state, "_storage": {**storage, "_storage": out}}


def restore_buffer(buffer: TensorDictReplayBuffer | None, payload: dict[str, Any], run_dir: Path) -> None:
    """Refill a run's replay buffer from its checkpoint (refused if the checkpoint holds none);
    filled rows only (:func:`buffer_state`) get the storage's capacity back, the rest zeros."""
    if buffer is None:
        return
    if "buffer" not in payload:
        raise CheckpointError(f"the checkpoint in {run_dir} holds no replay buffer "
                              "(experiment.keep_buffer_in_checkpoint=false): it cannot be resumed exactly; "
                              "start a new run")
    state = payload["buffer"]
    rows, capacity = int(state["_storage"].get("_len", 0)), buffer.storage.max_size
    device = buffer.storage.device

    def full(v: torch.Tensor) -> torch.Tensor:
        if 0 < rows < capacity and v.shape[0] == rows:
            out = v.new_zeros((capacity, *v.shape[1:]))
            out[:rows] = v
            v = out
        return v if device == "auto" else v.to(device)  # a checkpoint is read on the CPU

    buffer.load_state_dict(_rows(state, full))


def evaluation_row(cfg: TrainConfig, actor: Any, frames: int) -> dict[str, float]:
    """The run's evaluation of ``actor`` (the protocol's summary, its success and return) at ``frames``."""
    from .rollout import evaluate

    result = evaluate(actor, scenario=cfg.scenario, n_episodes=cfg.experiment.eval_episodes, seed=cfg.eval_seed,
                      device=cfg.device)
    return result_row(result, frames)


def member_evaluations(cfg: TrainConfig, actor: Any, learner: Any, members: Any, frames: int
                       ) -> tuple[dict[str, float], dict[str, float]]:
    """Evaluate every member that is not final (a final member's last evaluation stands): those
    still training in one batched rollout when there are several, a member alone as a solo run is
    (``actor``, the learner's copy, takes each one's weights). Returns the run's row (the members'
    mean) and the scalars to log (:meth:`~flock_torchrl.run.members.Members.evaluated`)."""
    from .rollout import evaluate_members as evaluate_batched

    live, batched = members.live(), {}
    if len(live) > 1:
        params = learner.params.get("actor_network_params")[torch.tensor(live, device=learner.params.device)]
        results = evaluate_batched(actor, params.detach(), cfg.scenario, cfg.experiment.eval_episodes,
                                   cfg.eval_seed, cfg.device)
        batched = {k: result_row(result, frames) for k, result in zip(live, results)}

    def alone(k: int, weights: dict[str, torch.Tensor], at: int) -> dict[str, float]:
        actor.load_state_dict(weights)
        return evaluation_row(cfg, actor, at)

    return members.evaluated(batched, alone, learner, frames)


def result_row(result: Any, frames: int) -> dict[str, float]:
    """An evaluation's row of a run's log: the protocol's summary, its success and return, at ``frames``."""
    row = {k: float(v) for k, v in result.summary().items()}
    row["success"], row["safe_success"] = row["success_rate"], row["safe_success_rate"]
    row["return"] = float(result.episodes["return"].double().mean())
    row["frames"] = frames
    return row


def out_of_memory(exc: BaseException | None) -> bool:
    """``exc``, or an error it was raised while handling, is an allocation that failed (Python's
    MemoryError, torch's allocator's RuntimeError): torch's archive writer, closing after a
    MemoryError, raises a RuntimeError of its own about the archive."""
    seen = 0
    while exc is not None and seen < 8:
        text = str(exc).lower()
        if isinstance(exc, MemoryError) or any(w in text for w in ("can't allocate memory", "out of memory",
                                                                    "not enough memory")):
            return True
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return False


def write_checkpoint(state: dict[str, Any], path: Path) -> Path:
    """:func:`~flock_torchrl.policies.checkpoint.save_checkpoint` of a training run; a write
    that fails (a full disk, a lost mount, memory that runs out) is a :class:`CheckpointError`
    naming the fix, and the last good checkpoint is kept (the write is atomic)."""
    try:
        return save_checkpoint(state, path, kind="training")
    except (MemoryError, RuntimeError) as exc:  # torch's allocator says RuntimeError
        if isinstance(exc, RuntimeError) and not out_of_memory(exc):
            raise
        kept = f"the last good checkpoint is kept at {path}" if path.exists() else "no checkpoint was written yet"
        raise CheckpointError(f"writing the checkpoint {path} ran out of memory; {kept}; "
                              "lower algo.buffer_size (the replay buffer it saves) or free memory, then "
                              f"{'resume' if path.exists() else 'run again'}") from None
    except OSError as exc:
        failure = write_failure(OSError(exc.errno, exc.strerror, str(path)))
        if failure is None:
            raise
        exists = path.exists()
        kept = f"the last good checkpoint is {path}" if exists else "no checkpoint yet"
        fix = "free some space" if exc.errno in (errno.ENOSPC, errno.EDQUOT) else "fix that"
        raise CheckpointError(f"{failure} ({os.strerror(exc.errno)}); {kept}; {fix} and "
                              f"{'resume' if exists else 'run again'}") from None


__all__ = ["Learner", "TrainResult", "UnreadCursorStorage", "buffer_state", "evaluation_row", "member_evaluations",
           "restore_rng", "rng_state", "make_collectors", "make_env", "make_envs", "replay_buffer",
           "restore_buffer", "write_checkpoint"]
