"""The training loop: TorchRL collector -> replay buffer -> learner, with evaluation, logging
and exact, atomic, digest-checked checkpoints.

``train(cfg)`` takes a checked :class:`~flock_torchrl.config.TrainConfig` (or the composed
``conf/train.yaml`` that :func:`make_train_config` or Hydra gives, converted and checked once).
The run folder is :mod:`.run_folder`'s; when to log, evaluate and checkpoint is
:mod:`.schedule`'s; this module builds the pieces and runs the loop.

A run survives its users (README, "Training"):

* a second process on the same folder is refused, naming the holder;
* SIGINT, SIGTERM and SIGHUP finish the current update, write a checkpoint and stop with exit
  status 130 / 143 / 129, printing the command that resumes; a second Ctrl-C aborts at once;
  with ``workers > 1`` the collector processes ignore those signals and the main process
  stops them, a watchdog bounding the wait;
* the final evaluation runs after a checkpoint: a signal there stops at once, and a resumed
  run counts as finished only once its last evaluation is at its last frame;
* ``resume`` compares the saved config with the requested one and refuses any difference
  but the ``resumable`` keys; a finished run resumes to a no-op; logs are cut back to the
  checkpoint (torn last lines dropped), so a resumed run's logs equal an uninterrupted run's.
"""

from __future__ import annotations

import dataclasses
import errno
import functools
import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict, TensorDictBase
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs.utils import ExplorationType

from ..config import POLICY_SCENARIO_FIELDS, ConfigError, TrainConfig, compose, flatten, saved_scenario
from ..io import write_failure
from ..policies.checkpoint import LAST, CheckpointError, load_checkpoint, save_checkpoint
from ..policies.learners import make_learner
from ..world.env import FlockingEnv
from ..world.metrics import CELL_METRICS
from ..world.sensors import observation_size, state_size
from ..world.spawn import check_spawn_feasible
from ..world.memory import check_memory, train_bytes
from .run_folder import (EpisodeLog, RunLock, clean_stale_temporaries, logger_hparams, make_logger, resume_command,
                         truncate_scalar_logs, write_run_config)
from .schedule import Schedule, evaluated_at_end
from .workers import start_workers

# One row per finished training episode (Fig. 4 reads episode, reward).
EPISODE_COLUMNS = ("episode", "frames", "reward", "success", "safe_success", *CELL_METRICS, "steps")
# Keys a learner needs from a transition; everything else stays out of the replay buffer.
TRANSITION_KEYS = [("agents", "observation"), ("agents", "state"), ("agents", "action"),
                   ("agents", "action_log_prob"), ("next", "agents", "observation"), ("next", "agents", "state"),
                   ("next", "agents", "reward"), ("next", "agents", "done"), ("next", "agents", "terminated"),
                   ("next", "done"), ("next", "terminated")]
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, *((signal.SIGHUP,) if hasattr(signal, "SIGHUP") else ()))
# Seconds the main process waits for collector processes to stop before killing them.
SHUTDOWN_TIMEOUT = 30.0


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
        total = sum(self.split.values())
        parts = ", ".join(f"{k} {v:.1f} s ({100 * v / total:.0f} %)" for k, v in self.split.items())
        return f"time split ({total:.0f} s of training loop): {parts}"


class TrainingInterrupted(Exception):
    """The run was stopped by a signal after writing its checkpoint."""

    def __init__(self, signum: int, result: TrainResult, command: str) -> None:
        super().__init__(f"stopped by {signal.Signals(signum).name}")
        self.signum, self.result, self.command = signum, result, command

    @property
    def exit_status(self) -> int:
        return 128 + int(self.signum)


def make_train_config(policy: str = "policy3_g", experiment: str = "fast", overrides: Sequence[str] = (),
                      **choices: Any) -> DictConfig:
    """Compose ``conf/train.yaml`` exactly as ``scripts/train.py`` would (Hydra's compose API).

    Args:
        policy, experiment: group choices.
        overrides: further command-line style overrides, e.g. ``["algo.lr_actor=1e-4", "seed=3"]``.
        **choices: more ``key=value`` overrides, e.g. ``reading="paper_fit"``, ``seed=1``.
    """
    items = [f"policy={policy}", f"experiment={experiment}", *(f"{k}={v}" for k, v in choices.items()),
             *overrides]
    return compose("train", items)


def config_differences(saved: Any, requested: Any, allowed: Sequence[str]) -> list[str]:
    """Dotted keys whose values differ between two resolved configs, except ``allowed`` ones (a
    key, or a group and everything below it)."""
    a, b = flatten(saved), flatten(requested)

    def free(key: str) -> bool:
        return any(key == p or key.startswith(f"{p}.") for p in allowed)

    def added(key: str) -> bool:  # a field added since the run was saved, at its empty default
        return key not in a and b.get(key) in ([], {}, None)

    return sorted(k for k in set(a) | set(b)
                  if not free(k) and not added(k) and a.get(k, "<absent>") != b.get(k, "<absent>"))


# ---------------------------------------------------------------------------- before anything runs
def memory_estimate(cfg: TrainConfig) -> dict[str, int]:
    """Bytes the run will hold, by the config key that sets them (:func:`.memory.train_bytes`)."""
    return train_bytes(cfg)


def prepare(cfg: TrainConfig, run_dir: Path) -> None:
    """Everything that can refuse a run before its folder changes: the swarm can be spawned,
    the run fits in memory, the folder's state agrees with ``resume``, the folder is writable.
    Raises :class:`ConfigError` or :class:`CheckpointError` with one line to print."""
    check_spawn_feasible(cfg.scenario)
    for scenario in cfg.train_scenarios:
        try:
            check_spawn_feasible(scenario)
        except ConfigError as exc:
            raise ConfigError("experiment.swarm_sizes" if cfg.experiment.swarm_sizes else exc.key,
                              exc.message) from None
    check_memory(memory_estimate(cfg), "the run")
    exists = (run_dir / LAST).exists()
    mode = cfg.resume_mode
    if mode == "never" and exists:
        raise CheckpointError(f"{run_dir} already holds a checkpoint; pass resume=true (or run "
                              f"`{resume_command(run_dir)}`) to continue it, or change the run's overrides "
                              "(nothing was changed)")
    if mode == "always" and not exists:
        raise CheckpointError(f"resume=true, but there is no checkpoint at {run_dir / LAST}")
    probe = run_dir if run_dir.exists() else next((p for p in run_dir.parents if p.exists()), Path("."))
    if not os.access(probe, os.W_OK):
        raise CheckpointError(f"{probe} is not writable: the run cannot write its checkpoint there")


def checkpoint_meta(cfg: TrainConfig, env: FlockingEnv) -> dict[str, Any]:
    """What a checkpoint records about its policy: enough to rebuild and evaluate it anywhere."""
    scenario = dataclasses.asdict(cfg.scenario)
    return {
        "policy": cfg.policy.name, "policy_id": cfg.policy.id, "reading": cfg.scenario.reading,
        "scenario": scenario, "policy_scenario": {k: scenario[k] for k in POLICY_SCENARIO_FIELDS},
        "n_agents": cfg.scenario.n_uavs, "algo": cfg.algo.name, "critic_input": cfg.policy.critic_input,
        "stochastic": cfg.algo.name != "ddpg", "hidden": cfg.algo.hidden, "depth": cfg.algo.depth,
        "obs_dim": observation_size(cfg.scenario), "seed": cfg.seed,
        "experiment": cfg.experiment.name, "trained_sizes": [t.n_uavs for t in cfg.train_scenarios],
    }


# ---------------------------------------------------------------------------- signals
class Signals:
    """SIGINT / SIGTERM / SIGHUP: the first asks the loop to stop after the current update (and
    checkpoint); a second SIGINT aborts at once. While :attr:`abort` is set (the checkpoint is
    current), the first signal stops at once."""

    def __init__(self) -> None:
        self.received = 0
        self.abort = False
        self.previous: dict[int, Any] = {}

    def __enter__(self) -> "Signals":
        if threading.current_thread() is threading.main_thread():
            for signum in STOP_SIGNALS:
                self.previous[signum] = signal.signal(signum, self._handle)
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        if self.received or self.abort:
            self.received = self.received or signum
            raise Stopped(self.received)
        self.received = signum
        print(f"\n{signal.Signals(signum).name} received: finishing this update and writing a checkpoint "
              "(Ctrl-C again aborts at once)", file=sys.stderr, flush=True)

    def __exit__(self, *exc: Any) -> None:
        for signum, handler in self.previous.items():
            signal.signal(signum, handler)


class Stopped(BaseException):
    """A stop signal that cannot wait for the end of the update."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _ignore_stop_signals() -> None:
    """In a collector process: the main process alone decides when the run stops."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)


def _shutdown(collector: Any, timeout: float = SHUTDOWN_TIMEOUT) -> None:
    """Stop a collector; kill its processes if they do not stop within ``timeout`` seconds."""
    worker = threading.Thread(target=collector.shutdown, daemon=True)
    worker.start()
    worker.join(timeout)
    if worker.is_alive():
        for proc in getattr(collector, "procs", []) or []:
            if proc.is_alive():
                proc.kill()


def start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker with the stop signals ignored: it blocks SIGINT
    and SIGTERM itself, but a SIGHUP to the process group (a closed terminal, an ssh drop)
    would kill it, and its replacement then prints tracebacks for every shared block."""
    from multiprocessing import resource_tracker

    previous = {s: signal.signal(s, signal.SIG_IGN) for s in STOP_SIGNALS}
    try:
        resource_tracker.ensure_running()
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _make_env(cfg: TrainConfig, num_envs: int, device: torch.device, seed: int, parent: int,
              scenario: Any = None) -> FlockingEnv:
    if os.getpid() != parent:
        _ignore_stop_signals()
    return FlockingEnv(scenario or cfg.train_scenario, num_envs=num_envs, device=device, seed=seed,
                       compile_step=cfg.compile_step)


def per_uav(batch: TensorDictBase) -> TensorDictBase:
    """Swarm transitions ``[M]`` (agents ``[M, N]``) as single-UAV ones ``[M * N]`` (agents
    ``[M * N, 1]``): what a replay buffer shared by several swarm sizes holds. The networks are
    per UAV and the done flags per UAV (:func:`agentwise_done`), so the losses see the same
    terms. UAV ``j`` of swarm transition ``m`` lands at row ``m * N + j``."""
    flat = batch.select(*(k for k in TRANSITION_KEYS if "agents" in k), strict=False).reshape(-1)
    m, n = flat.get("agents").batch_size
    out = TensorDict({"agents": TensorDict({}, [m * n, 1]), "next": {"agents": TensorDict({}, [m * n, 1])}},
                     batch_size=[m * n], device=flat.device)
    for key in flat.keys(True, True):
        value = flat.get(key)
        out.set(key, value.reshape(m * n, 1, *value.shape[2:]))
    return out


EPISODE_METRICS = ("return", "success", "safe_success", *CELL_METRICS, "steps")


def episode_rows(episodes: TensorDictBase, first: int, frames: int) -> list[list[Any]]:
    """:data:`EPISODE_COLUMNS` rows of finished episodes (``episodes``: their ``"episode"``
    entries ``[E]``), numbered from ``first + 1``, all counted at ``frames``."""
    values = torch.stack([episodes[k].double() for k in EPISODE_METRICS], -1).tolist()   # [E, M]
    return [[first + 1 + i, frames, round(v[0], 5), int(v[1]), int(v[2]), *(round(x, 4) for x in v[3:-1]), int(v[-1])]
            for i, v in enumerate(values)]


def agentwise_done(batch: TensorDictBase, n_agents: int) -> TensorDictBase:
    """Give the losses per-UAV ``done`` / ``terminated`` (the env shares them across the swarm)."""
    for key in ("done", "terminated"):
        value = batch.get(("next", key))
        batch.set(("next", "agents", key), value.unsqueeze(-2).expand(*value.shape[:-1], n_agents, 1))
    return batch


# ---------------------------------------------------------------------------- training
def hydra_output_dir() -> Path:
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        raise ConfigError("run_dir", "train() needs run_dir=... when it is not run by Hydra (scripts/train.py)")
    return Path(HydraConfig.get().runtime.output_dir)


def _hydra_settings() -> dict[str, Any]:
    """The train app's Hydra settings a run's ``resume.yaml`` repeats (the running app's, or
    conf/train.yaml's)."""
    from hydra.core.hydra_config import HydraConfig

    hydra = HydraConfig.get() if HydraConfig.initialized() else compose("train", return_hydra_config=True).hydra
    return {"job": {"name": str(hydra.job.name), "chdir": bool(hydra.job.chdir)}, "output_subdir": None,
            "callbacks": OmegaConf.to_container(hydra.callbacks, resolve=True) if hydra.callbacks else {}}


class Training:
    """One run: its pieces, its loop, its checkpoints (``train`` is its entry point)."""

    def __init__(self, cfg: TrainConfig, run_dir: Path) -> None:
        self.cfg, self.run_dir = cfg, run_dir
        self.resolved = dataclasses.asdict(cfg)
        self.ckpt_path = run_dir / LAST
        self.counters = {"frames": 0, "episodes": 0, "updates": 0, "iterations": 0, "seconds": 0.0}
        self.evaluations: list[dict[str, float]] = []
        # "compile": a compiled learner's first update in this process, where torch.compile works.
        self.split = dict.fromkeys(("env", "collection", "buffer", "sampling", "update", "compile", "logging",
                                    "evaluation", "checkpoints"), 0.0)
        self.saved_frames = -1            # frames of the last checkpoint this process wrote
        self.start = time.perf_counter()

    # ---------------------------------------------------------------- checkpoint in
    def _load(self) -> dict | None:
        """The checkpoint to continue, after every check; ``None`` for a fresh run."""
        if self.cfg.resume_mode == "never" or not self.ckpt_path.exists():
            return None
        payload = load_checkpoint(self.ckpt_path, kind="training")
        saved = dict(payload["config"])
        saved["scenario"] = saved_scenario(saved["scenario"])  # fields added since it was written: as it was
        diff = config_differences(saved, self.resolved, self.cfg.resumable)
        if diff:
            shown = "; ".join(f"{k}: {flatten(payload['config']).get(k, '<absent>')!r} there, "
                              f"{flatten(self.resolved).get(k, '<absent>')!r} here" for k in diff[:6])
            raise CheckpointError(f"the checkpoint in {self.run_dir} was trained with other settings ({shown}"
                                  f"{' ...' if len(diff) > 6 else ''}); only {', '.join(self.cfg.resumable)} may "
                                  "change on resume (nothing was changed)")
        return payload

    # ---------------------------------------------------------------- the pieces
    def _build(self, payload: dict | None) -> None:
        cfg, exp = self.cfg, self.cfg.experiment
        start_resource_tracker()  # before the replay buffer's shared counter or any worker needs it
        torch.manual_seed(cfg.seed)
        device = torch.device(cfg.device)
        per_worker = exp.num_envs // exp.workers
        factory = functools.partial(_make_env, cfg, per_worker, device, parent=os.getpid())
        scenarios = cfg.train_scenarios
        self.mixed = bool(exp.swarm_sizes)
        if self.mixed:  # one env per swarm size, the worlds split evenly, seeds 1000 * seed + i
            share = exp.num_envs // len(scenarios)
            self.envs = [_make_env(cfg, share, device, cfg.seed * 1000 + i, os.getpid(), scenario)
                         for i, scenario in enumerate(scenarios)]
        else:
            self.envs = [factory(cfg.seed * 1000)]
        self.env = env = self.envs[0]
        self.learner = learner = make_learner(env, cfg.algo, cfg.policy.critic_input, compile=cfg.compile_loss)
        self.buffer = None
        if learner.off_policy:
            # Swarm transitions of one size (batch_size / N of them, rounded up), or single UAV
            # transitions when the sizes are mixed.
            n = 1 if self.mixed else cfg.scenario.n_uavs
            batch_swarm = max(1, math.ceil(cfg.algo.batch_size / n))
            capacity = max(batch_swarm, math.ceil(cfg.algo.buffer_size / n))
            self.buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(capacity, device=device),
                                                 batch_size=batch_swarm)
        if payload is not None:
            learner.load_state_dict(payload["learner"])
            if self.buffer is not None:
                if "buffer" not in payload:
                    raise CheckpointError(f"the checkpoint in {self.run_dir} holds no replay buffer "
                                          "(experiment.keep_buffer_in_checkpoint=false): it cannot be resumed "
                                          "exactly; start a new run")
                self.buffer.load_state_dict(payload["buffer"])
            if exp.workers == 1:
                states = payload["env_state"]
                for one, state in zip(self.envs, states if self.mixed else [states]):
                    one.set_state(state)
        steps = exp.steps_per_batch if learner.off_policy else cfg.algo.rollout_steps
        init_random = max(0, exp.init_random_frames - self.counters["frames"]) if learner.off_policy else 0
        kwargs = dict(frames_per_batch=(self.env.num_envs if self.mixed else exp.num_envs) * steps, total_frames=-1,
                      device=device,
                      init_random_frames=init_random or None, exploration_type=ExplorationType.RANDOM,
                      auto_register_policy_transforms=False)
        if exp.workers > 1:  # started where a stop signal cannot reach the workers (.workers)
            self.collector = start_workers(lambda: MultiSyncCollector(
                [functools.partial(factory, cfg.seed * 1000 + w) for w in range(exp.workers)],
                learner.collector_policy, **kwargs))
        else:
            self.collector = Collector(env, learner.collector_policy, track_traj_ids=False, **kwargs)
        # More sizes: one collector each, stepped in turn; their batches are learned from together.
        self.collectors = [self.collector] + [Collector(e, learner.collector_policy, track_traj_ids=False, **kwargs)
                                              for e in self.envs[1:]]
        if payload is not None:
            torch.set_rng_state(payload["rng"]["torch"])
        self.meta = checkpoint_meta(cfg, env)

    # ---------------------------------------------------------------- run
    def run(self) -> TrainResult:
        cfg, exp = self.cfg, self.cfg.experiment
        payload = self._load()
        if payload is not None:
            self.counters.update(payload["counters"])
            self.evaluations = list(payload.get("evaluations", []))
            self._restore(payload)
        schedule = Schedule(exp).start(self.counters["frames"])
        finished = schedule.finished(self.counters["frames"], self.counters["episodes"], self.counters["seconds"])
        if schedule.done(self.counters, self.evaluations):
            return self._result(self.ckpt_path)  # a finished run resumes to a no-op
        with Signals() as signals:
            self._build(payload)
            # Only now, with the checkpoint (if any) known to fit, does the run folder change.
            write_run_config(self.run_dir, self.resolved, _hydra_settings())
            self._open_logs(payload is not None)
            self.start = time.perf_counter() - self.counters["seconds"]
            try:
                if not finished:
                    self._loop(schedule, signals)
            finally:
                for collector in self.collectors:
                    _shutdown(collector)
            if signals.received:
                return self._stop(signals.received)
            return self._finish(signals)

    def _open_logs(self, resumed: bool) -> None:
        truncate_scalar_logs(self.run_dir, self.counters["frames"] if resumed else None)  # fresh: a dead run's go
        log = self.cfg.logger
        self.logger = make_logger(log.backend, log.project, log.mode, self.run_dir,
                                  f"{self.cfg.policy.id}_seed{self.cfg.seed}")
        if self.logger is not None:
            self.logger.log_hparams(logger_hparams(self.resolved))
        self._open_episode_logs(resumed)

    def _open_episode_logs(self, resumed: bool) -> None:
        self.episode_log = EpisodeLog(self.run_dir / "episodes.csv", EPISODE_COLUMNS,
                                      self.counters["episodes"] if resumed else None)
        # The running means over the last 100 episodes continue from the (cut back) episode log.
        self.recent = [(row[2], bool(row[3])) for row in self.episode_log.rows()[-100:]]

    def _restore(self, payload: dict) -> None:
        """What a subclass restores from a checkpoint beyond the counters and evaluations."""

    def _loop(self, schedule: Schedule, signals: Signals) -> None:
        counters, split = self.counters, self.split
        def busy() -> float:
            return sum(e.busy_seconds for e in self.envs)

        env_busy, t_last = busy(), time.perf_counter()
        try:
            for batches in zip(*self.collectors):
                t_collected = time.perf_counter()
                if self.cfg.experiment.workers == 1:  # collection = the collector's own work beside the env's
                    split["env"] += busy() - env_busy
                    split["collection"] -= busy() - env_busy
                    env_busy = busy()
                split["collection"] += t_collected - t_last
                stats = self._consume(batches)
                self._periodic(schedule, stats)
                t_last = time.perf_counter()
                if signals.received or schedule.finished(counters["frames"], counters["episodes"],
                                                         t_last - self.start):
                    break
        except FloatingPointError as exc:
            print(f"stopping: {exc}; the last good checkpoint is kept at {self.ckpt_path}", file=sys.stderr,
                  flush=True)
            raise

    def _consume(self, batches: Sequence[TensorDictBase]) -> dict[str, torch.Tensor]:
        """Count, log and learn from one batch of each collector (one, unless sizes are mixed)."""
        frames = sum(batch.numel() for batch in batches)
        self.counters["frames"] += frames
        self.counters["iterations"] += 1
        batches = [agentwise_done(batch, env.n_agents) for batch, env in zip(batches, self.envs)]
        rows = [row for batch in batches for row in self._finished_episodes(batch)]
        if rows:
            self.episode_log.write(rows)
            self.recent = (self.recent + [(r[2], bool(r[3])) for r in rows])[-100:]
        if hasattr(self.learner, "on_frames"):
            self.learner.on_frames(frames)
        stats, n_updates = self._learn(batches)
        self.counters["updates"] += n_updates
        if self.cfg.experiment.workers > 1:  # a single collector shares the learner's policy
            self.collector.update_policy_weights_()
        return stats

    def _periodic(self, schedule: Schedule, stats: dict[str, torch.Tensor]) -> None:
        """Log, evaluate and checkpoint when due; returns nothing, books its time by task."""
        frames, split = self.counters["frames"], self.split
        t0 = time.perf_counter()
        if schedule.log.due(frames):
            self._log_training(stats)
        t1 = time.perf_counter()
        if schedule.evaluate.due(frames):
            result = self._evaluate()
            self._print(f"eval @ {frames} frames: success {result['success']:.3f} "
                        f"safe_success {result['safe_success']:.3f}")
        t2 = time.perf_counter()
        if schedule.checkpoint.due(frames):
            self._save()
        t3 = time.perf_counter()
        split["logging"] += t1 - t0
        split["evaluation"] += t2 - t1
        split["checkpoints"] += t3 - t2

    def _learn(self, batches: Sequence[TensorDictBase]) -> tuple[dict[str, torch.Tensor], int]:
        learner, exp, split = self.learner, self.cfg.experiment, self.split
        if not learner.off_policy:  # one size (TrainConfig refuses mixed sizes on-policy)
            start = time.perf_counter()
            stats = learner.update(batches[0])
            split[self._update_bucket()] += time.perf_counter() - start
            return stats, 1
        start = time.perf_counter()
        for batch in batches:
            self.buffer.extend(self._transitions(batch))
        split["buffer"] += time.perf_counter() - start
        stats: dict[str, torch.Tensor] = {}
        n = 0
        if self.counters["frames"] >= exp.init_random_frames and len(self.buffer) >= self.buffer.batch_size:
            device = torch.device(self.cfg.device)
            for _ in range(exp.updates_per_batch):
                t0 = time.perf_counter()
                sample = self.buffer.sample().to(device)
                t1 = time.perf_counter()
                bucket = self._update_bucket()
                stats = learner.update(sample)
                split["sampling"] += t1 - t0
                split[bucket] += time.perf_counter() - t1
                n += 1
        return stats, n

    def _transitions(self, batch: TensorDictBase) -> TensorDictBase:
        """A collector batch as the replay buffer's items: swarm transitions, or single-UAV ones
        when the sizes are mixed."""
        return per_uav(batch) if self.mixed else batch.select(*TRANSITION_KEYS, strict=False).reshape(-1)

    def _update_bucket(self) -> str:
        """Where an update's time goes: a compiled learner's first one in this process compiles."""
        first = self.cfg.compile_loss and not self.split["compile"]
        return "compile" if first else "update"

    def _finished_episodes(self, batch: TensorDictBase) -> list[list[Any]]:
        """CSV rows for the episodes that ended in this batch (frames counted at batch end)."""
        done = batch.get(("next", "done")).squeeze(-1)
        if not done.any():
            return []
        rows = episode_rows(batch.get(("next", "episode"))[done], self.counters["episodes"], self.counters["frames"])
        self.counters["episodes"] += len(rows)
        return rows

    # ---------------------------------------------------------------- logging, evaluation
    def _log_training(self, stats: dict[str, torch.Tensor]) -> None:
        log = {f"train/{k}": float(v) for k, v in stats.items()}
        if self.recent:
            log["train/episode_reward"] = sum(r for r, _ in self.recent) / len(self.recent)
            log["train/success_rate"] = sum(s for _, s in self.recent) / len(self.recent)
        log["perf/updates_per_s"] = self.counters["updates"] / max(self.split["sampling"] + self.split["update"], 1e-9)
        log["perf/frames_per_s"] = self.counters["frames"] / max(self.split["env"] + self.split["collection"], 1e-9)
        self._log(log)
        if self.cfg.progress:
            self._bar().update(self.counters, log)

    def _log(self, values: dict[str, float]) -> None:
        if self.logger is not None:
            for key, value in values.items():
                self.logger.log_scalar(key, value, step=self.counters["frames"])

    def _bar(self) -> "_Progress":
        if not hasattr(self, "progress"):
            self.progress = _Progress(self.cfg, self.counters)
        return self.progress

    def _print(self, message: str) -> None:
        if self.cfg.progress:
            self._bar().write(message)
        else:
            print(message, flush=True)

    def _evaluation_row(self, actor: Any, frames: int) -> dict[str, float]:
        """The run's evaluation of ``actor`` (the protocol's summary, its success and return) at ``frames``."""
        from .rollout import evaluate

        result = evaluate(actor, scenario=self.cfg.scenario, n_episodes=self.cfg.experiment.eval_episodes,
                          seed=self.cfg.eval_seed, device=self.cfg.device)
        row = {k: float(v) for k, v in result.summary().items()}
        row["success"], row["safe_success"] = row["success_rate"], row["safe_success_rate"]
        row["return"] = float(result.episodes["return"].double().mean())
        row["frames"] = frames
        return row

    def _evaluate(self) -> dict[str, float]:
        row = self._evaluation_row(self.learner.actor, self.counters["frames"])
        self.evaluations.append(row)
        self._log({f"eval/{k}": v for k, v in row.items() if k != "frames"})
        return row

    # ---------------------------------------------------------------- the end
    def _finish(self, signals: Signals) -> TrainResult:
        """Every run ends with an evaluation of what it ships, after a checkpoint: a signal
        during it stops at once, and the resumed run evaluates before it counts as finished."""
        if not evaluated_at_end(self.counters, self.evaluations):
            self._save()
            signals.abort = True
            try:
                self._evaluate()
            except Stopped as stop:
                return self._stop(stop.signum)
            finally:
                signals.abort = False
        path = self._save()
        self._close()
        return self._result(path)

    def _stop(self, signum: int) -> TrainResult:
        path = self.ckpt_path if self.saved_frames == self.counters["frames"] else self._save()
        self._close()
        raise TrainingInterrupted(signum, self._result(path, signum), resume_command(self.run_dir))

    def _close(self) -> None:
        self.episode_log.close()
        if hasattr(self, "progress"):
            self.progress.close()
        if self.cfg.logger.backend == "wandb" and self.logger is not None:
            self.logger.experiment.finish()

    def _result(self, path: Path, interrupted: int = 0) -> TrainResult:
        c = self.counters
        return TrainResult(self.run_dir, path, c["frames"], c["episodes"], c["updates"], c["seconds"],
                           self.evaluations, interrupted, dict(self.split))

    def _state(self) -> dict[str, Any]:
        """Everything the checkpoint holds."""
        exp = self.cfg.experiment
        state = {
            "meta": self.meta, "config": self.resolved, "counters": dict(self.counters),
            "actor": self.learner.actor.state_dict(), "learner": self.learner.state_dict(),
            "rng": {"torch": torch.get_rng_state()}, "evaluations": self.evaluations,
            "curve": torch.tensor(self.episode_log.rows(), dtype=torch.float64).reshape(-1, len(EPISODE_COLUMNS)),
        }
        if exp.workers == 1:
            state["env_state"] = [e.get_state() for e in self.envs] if self.mixed else self.env.get_state()
        if self.buffer is not None and exp.keep_buffer_in_checkpoint:
            state["buffer"] = self.buffer.state_dict()
        return state

    def _save(self) -> Path:
        self.counters["seconds"] = time.perf_counter() - self.start
        state = self._state()
        try:
            path = save_checkpoint(state, self.ckpt_path, kind="training")
            self.saved_frames = self.counters["frames"]
            return path
        except OSError as exc:
            failure = write_failure(OSError(exc.errno, exc.strerror, str(self.ckpt_path)))
            if failure is None:
                raise
            exists = self.ckpt_path.exists()
            kept = f"the last good checkpoint is {self.ckpt_path}" if exists else "no checkpoint yet"
            fix = "free some space" if exc.errno in (errno.ENOSPC, errno.EDQUOT) else "fix that"
            raise CheckpointError(f"{failure} ({os.strerror(exc.errno)}); {kept}; {fix} and "
                                  f"{'resume' if exists else 'run again'}") from None


class _Progress:
    """tqdm bar over frames."""

    def __init__(self, cfg: TrainConfig, counters: dict) -> None:
        from tqdm.auto import tqdm

        self.bar = tqdm(total=cfg.experiment.max_frames or None, initial=counters["frames"], unit="frame",
                        dynamic_ncols=True, desc=f"{cfg.policy.name} seed {cfg.seed}")
        self.last = counters["frames"]

    def update(self, counters: dict, log: dict) -> None:
        self.bar.update(counters["frames"] - self.last)
        self.last = counters["frames"]
        self.bar.set_postfix(episodes=counters["episodes"], reward=f"{log.get('train/episode_reward', math.nan):.2f}",
                             success=f"{log.get('train/success_rate', math.nan):.2f}", refresh=False)

    def write(self, message: str) -> None:
        self.bar.write(message)

    def close(self) -> None:
        self.bar.close()


__all__ = ["EPISODE_COLUMNS", "Signals", "Stopped", "TRANSITION_KEYS", "TrainResult", "TrainingInterrupted",
           "Training", "agentwise_done", "checkpoint_meta", "episode_rows", "config_differences", "hydra_output_dir",
           "make_train_config", "memory_estimate", "prepare", "start_resource_tracker"]
