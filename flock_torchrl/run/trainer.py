"""The training loop: TorchRL collector -> replay buffer -> learner, with evaluation,
logging, and exact, atomic, digest-checked checkpoints.

``train(cfg)`` takes the config Hydra composed from ``conf/train.yaml`` (``scripts/train.py``)
or :func:`make_train_config` composed the same way. Everything a run writes goes into one
folder (Hydra's output folder, or ``run_dir``): ``config.yaml`` (the resolved config, what
ran), ``overrides.yaml``, ``last.pt``, ``episodes.csv``, ``logs/`` and a ``.lock`` while it runs.

A run survives its users (docs in README, "Reproducibility"):

* a second process on the same folder is refused, naming the holder (``.lock``, ``fcntl``);
* SIGINT / SIGTERM finish the current update, write a checkpoint and stop with exit status
  130 / 143, printing the command that resumes; a second Ctrl-C aborts at once;
* ``resume`` compares the saved config with the requested one and refuses any difference
  but budgets, logging and runtime knobs; a finished run resumes to a no-op; logs are cut
  back to the checkpoint, so a resumed run's logs equal an uninterrupted run's.
"""

from __future__ import annotations

import csv
import dataclasses
import fcntl
import functools
import math
import os
import shlex
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs.utils import ExplorationType

from ..config import (POLICY_SCENARIO_FIELDS, ConfigError, ExperimentConfig, LoggerConfig, PolicyConfig, ScenarioConfig,
                      check_algo, check_device, check_experiment, check_logger, check_policy, check_scenario,
                      check_seed, compose, flatten, plain, resume_mode, to_object)
from ..io import write_text
from ..policies.checkpoint import LAST, CheckpointError, load_checkpoint, save_checkpoint
from ..policies.learners import make_learner
from ..world.env import FlockingEnv
from ..world.metrics import CELL_METRICS
from ..world.spawn import check_spawn_feasible

# One row per finished training episode (Fig. 4 reads episode, reward).
EPISODE_COLUMNS = ("episode", "frames", "reward", "success", "safe_success", *CELL_METRICS, "steps")
# Keys a learner needs from a transition; everything else stays out of the replay buffer.
TRANSITION_KEYS = [("agents", "observation"), ("agents", "state"), ("agents", "action"),
                   ("agents", "action_log_prob"), ("next", "agents", "observation"), ("next", "agents", "state"),
                   ("next", "agents", "reward"), ("next", "agents", "done"), ("next", "agents", "terminated"),
                   ("next", "done"), ("next", "terminated")]
# What a resume may change: budgets, logging and runtime knobs. Anything else would train a
# model with other settings than the ones its checkpoint and config.yaml record.
RESUMABLE_CHANGES = ("experiment.max_frames", "experiment.max_episodes", "experiment.max_minutes",
                     "experiment.log_every_frames", "experiment.eval_every_frames", "experiment.eval_episodes",
                     "experiment.checkpoint_every_frames", "logger.", "resume", "progress", "threads", "device",
                     "compile")
EXIT_SIGINT, EXIT_SIGTERM = 130, 143


@dataclass
class RunConfig:
    """A train config, checked group by group (every error names its key)."""

    scenario: ScenarioConfig          # what the policy is evaluated and shipped with
    train_scenario: ScenarioConfig    # the same plus the experiment's train_env recipe
    policy: PolicyConfig
    algo: Any
    experiment: ExperimentConfig
    logger: LoggerConfig
    seed: int
    device: str
    eval_seed: int
    resume: str | Path
    progress: bool
    threads: int
    compile: bool


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
        """``time split: env 10.2 s (31 %), collection ...`` over this process's training loop."""
        total = sum(self.split.values())
        if total <= 0:
            return "time split: no training steps in this process"
        parts = ", ".join(f"{k} {v:.1f} s ({100 * v / total:.0f} %)" for k, v in self.split.items())
        return f"time split ({total:.0f} s of training loop): {parts}"


class TrainingInterrupted(Exception):
    """The run was stopped by a signal after writing its checkpoint."""

    def __init__(self, signum: int, result: TrainResult, command: str) -> None:
        super().__init__(f"stopped by {signal.Signals(signum).name}")
        self.signum, self.result, self.command = signum, result, command

    @property
    def exit_status(self) -> int:
        return EXIT_SIGINT if self.signum == signal.SIGINT else EXIT_SIGTERM


# ---------------------------------------------------------------------------- config
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


def check_train_config(cfg: DictConfig | dict) -> RunConfig:
    """Validate every group of a train config; raise :class:`ConfigError` naming the key."""
    if isinstance(cfg, dict):
        cfg = OmegaConf.create(cfg)
    policy = check_policy(to_object(cfg.policy, PolicyConfig, "policy"))
    if policy.kind != "learned":
        raise ConfigError("policy", f"{policy.name} is rule-based: there is nothing to train (evaluate it with "
                                    f"scripts/evaluate.py policy={policy.id})")
    experiment = check_experiment(to_object(cfg.experiment, ExperimentConfig, "experiment"))
    if cfg.get("algo") is None:
        raise ConfigError("algo", f"policy {policy.id} selects no learner")
    algo = check_algo(cfg.algo)
    scenario = check_scenario(to_object(cfg.scenario, ScenarioConfig, "scenario"))
    check_spawn_feasible(scenario)
    train_scenario = dataclasses.replace(scenario, **dict(experiment.train_env))
    check_scenario(train_scenario)
    if not isinstance(cfg.progress, bool):
        raise ConfigError("progress", f"must be true or false, got {cfg.progress!r}")
    if not isinstance(cfg.compile, bool):
        raise ConfigError("compile", f"must be true or false, got {cfg.compile!r}")
    if not (isinstance(cfg.threads, int) and cfg.threads >= 0):
        raise ConfigError("threads", f"must be an integer >= 0, got {cfg.threads!r}")
    return RunConfig(
        scenario=scenario, train_scenario=train_scenario, policy=policy, algo=algo, experiment=experiment,
        logger=check_logger(to_object(cfg.logger, LoggerConfig, "logger")), seed=check_seed(cfg.seed),
        device=check_device(cfg.device), eval_seed=check_seed(cfg.eval_seed, "eval_seed"),
        resume=resume_mode(cfg.resume), progress=cfg.progress, threads=cfg.threads, compile=cfg.compile)


def config_differences(saved: Any, requested: Any, allowed: Sequence[str] = RESUMABLE_CHANGES) -> list[str]:
    """Dotted keys whose values differ between two resolved configs, except ``allowed`` ones
    (an entry ending in ``.`` allows a whole group)."""
    a, b = flatten(saved), flatten(requested)

    def free(key: str) -> bool:
        return any(key == p or (p.endswith(".") and key.startswith(p)) for p in allowed)

    return sorted(k for k in set(a) | set(b) if not free(k) and a.get(k, "<absent>") != b.get(k, "<absent>"))


# ---------------------------------------------------------------------------- run folder
class RunLock:
    """An exclusive ``fcntl`` lock on ``<run>/.lock`` for the life of a training process.

    The kernel drops the lock when its process dies, so a lock left by a killed run is never
    stale; the file also records the holder's PID, host and start time for the message.
    """

    def __init__(self, run_dir: Path) -> None:
        self.path = run_dir / ".lock"
        self.handle = None

    def __enter__(self) -> "RunLock":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        handle = open(self.path, "a+")
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "another process"
            handle.close()
            raise CheckpointError(f"{self.path.parent} is in use by {holder}; wait for it or stop it "
                                  "(a killed process releases its lock)") from None
        handle.seek(0)
        handle.truncate()
        handle.write(f"PID {os.getpid()} on {os.uname().nodename}, started {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
        handle.flush()
        self.handle = handle
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.handle is not None:
            fcntl.flock(self.handle.fileno(), fcntl.LOCK_UN)
            self.handle.close()
            self.handle = None


def truncate_log(path: Path, keep: Any, header: bool = True) -> None:
    """Keep the rows of a CSV log for which ``keep(row)`` is true (atomically)."""
    if not path.is_file():
        return
    with path.open(newline="") as handle:
        rows = list(csv.reader(handle))
    head, body = (rows[:1], rows[1:]) if header else ([], rows)
    kept = [r for r in body if r and keep(r)]
    if len(kept) != len(body):
        write_text(path, "".join(",".join(r) + "\n" for r in head + kept))


class _EpisodeLog:
    """Append-only CSV of finished training episodes, cut back to a checkpoint on resume."""

    def __init__(self, path: Path, keep_up_to: int | None) -> None:
        self.path = path
        if keep_up_to is None or not path.is_file():
            write_text(path, ",".join(EPISODE_COLUMNS) + "\n")
        else:
            truncate_log(path, lambda r: int(r[0]) <= keep_up_to)
        self.handle = path.open("a", newline="")
        self.writer = csv.writer(self.handle, lineterminator="\n")

    def write(self, rows: list[list[Any]]) -> None:
        self.writer.writerows(rows)
        self.handle.flush()

    def rows(self) -> list[list[float]]:
        self.handle.flush()
        with self.path.open(newline="") as handle:
            reader = csv.reader(handle)
            next(reader, None)
            return [[float(x) if x else math.nan for x in r] for r in reader if r]

    def close(self) -> None:
        self.handle.close()


def _make_logger(rc: RunConfig, run_dir: Path, name: str):
    backend = rc.logger.backend
    if backend == "none":
        return None
    if backend == "csv":
        from torchrl.record.loggers import CSVLogger

        return CSVLogger(exp_name="logs", log_dir=str(run_dir))
    if backend == "wandb":
        os.environ.setdefault("WANDB_MODE", rc.logger.mode)
        from torchrl.record.loggers import WandbLogger

        return WandbLogger(exp_name=name, offline=rc.logger.mode == "offline", save_dir=str(run_dir),
                           project=rc.logger.project)
    if backend == "tensorboard":
        try:
            import tensorboard  # noqa: F401
        except ImportError as exc:
            raise ConfigError("logger.backend", "tensorboard needs `pip install flock_torchrl[tensorboard]`") from exc
        from torchrl.record.loggers import TensorboardLogger

        return TensorboardLogger(exp_name=name, log_dir=str(run_dir / "tensorboard"))
    raise ConfigError("logger.backend", f"unknown logger {backend!r}")


def _agentwise_done(batch: TensorDictBase, n_agents: int) -> TensorDictBase:
    """Give the losses per-UAV ``done`` / ``terminated`` (the env shares them across the swarm)."""
    for key in ("done", "terminated"):
        value = batch.get(("next", key))
        batch.set(("next", "agents", key), value.unsqueeze(-2).expand(*value.shape[:-1], n_agents, 1))
    return batch


def checkpoint_meta(rc: RunConfig) -> dict[str, Any]:
    """What a checkpoint records about its policy: enough to rebuild and evaluate it anywhere."""
    scenario = dataclasses.asdict(rc.scenario)
    return {
        "policy": rc.policy.name, "policy_id": rc.policy.id, "reading": rc.scenario.reading,
        "scenario": scenario, "policy_scenario": {k: scenario[k] for k in POLICY_SCENARIO_FIELDS},
        "n_agents": rc.scenario.n_uavs, "algo": rc.algo.name, "critic_input": rc.policy.critic_input,
        "stochastic": rc.algo.name != "ddpg", "hidden": rc.algo.hidden, "depth": rc.algo.depth,
        "obs_dim": 2 + 2 * rc.scenario.n_scan + 3 * rc.scenario.n_cam, "seed": rc.seed,
        "experiment": rc.experiment.name,
    }


def _done(exp: ExperimentConfig, counters: dict, elapsed: float) -> bool:
    return bool((exp.max_frames and counters["frames"] >= exp.max_frames)
                or (exp.max_episodes and counters["episodes"] >= exp.max_episodes)
                or (exp.max_minutes and elapsed >= 60 * exp.max_minutes))


def _next_multiple(frames: int, every: int) -> float:
    return (frames // every + 1) * every if every else math.inf


def resume_command(run_dir: Path) -> str:
    return f"python scripts/train.py resume={shlex.quote(str(run_dir))}"


class _Signals:
    """SIGINT / SIGTERM: the first asks the loop to stop after the current update (and
    checkpoint); a second SIGINT aborts at once (KeyboardInterrupt)."""

    def __init__(self) -> None:
        self.received = 0
        self.previous: dict[int, Any] = {}

    def __enter__(self) -> "_Signals":
        if threading_main():
            for signum in (signal.SIGINT, signal.SIGTERM):
                self.previous[signum] = signal.signal(signum, self._handle)
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        if self.received:
            signal.signal(signal.SIGINT, signal.default_int_handler)
            raise KeyboardInterrupt
        self.received = signum
        print(f"\n{signal.Signals(signum).name} received: finishing this update and writing a checkpoint "
              "(Ctrl-C again aborts at once)", file=sys.stderr, flush=True)

    def __exit__(self, *exc: Any) -> None:
        for signum, handler in self.previous.items():
            signal.signal(signum, handler)


def threading_main() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


# ---------------------------------------------------------------------------- training
def train(cfg: DictConfig | dict, run_dir: str | os.PathLike | None = None) -> TrainResult:
    """Train one learned policy.

    Args:
        cfg: the composed ``conf/train.yaml`` (Hydra's, or :func:`make_train_config`'s).
        run_dir: the run folder; default: Hydra's output folder (``scripts/train.py``).

    Raises:
        ConfigError: a bad config value (nothing is written).
        CheckpointError: a refused resume or a busy / mismatched run folder (nothing changes).
        TrainingInterrupted: SIGINT / SIGTERM stopped the run after it wrote its checkpoint.
    """
    if isinstance(cfg, dict):
        cfg = OmegaConf.create(cfg)
    rc = check_train_config(cfg)
    run_dir = Path(run_dir) if run_dir is not None else _hydra_output_dir()
    resolved = plain(cfg)
    with RunLock(run_dir):
        return _Training(rc, run_dir, resolved, _task_overrides(cfg)).run()


def _hydra_output_dir() -> Path:
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        raise ConfigError("run_dir", "train() needs run_dir=... when it is not run by Hydra (scripts/train.py)")
    return Path(HydraConfig.get().runtime.output_dir)


def _task_overrides(cfg: DictConfig) -> list[str]:
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized():
        return list(HydraConfig.get().overrides.task)
    return []


class _Training:
    """One run: the pieces and the loop (``train`` is its entry point)."""

    def __init__(self, rc: RunConfig, run_dir: Path, resolved: dict, overrides: list[str]) -> None:
        self.rc, self.run_dir, self.resolved, self.overrides = rc, run_dir, resolved, overrides
        self.ckpt_path = run_dir / LAST
        self.meta = checkpoint_meta(rc)
        self.counters = {"frames": 0, "episodes": 0, "updates": 0, "iterations": 0, "seconds": 0.0}
        self.evaluations: list[dict[str, float]] = []

    # ---------------------------------------------------------------- checkpoint in
    def _load(self) -> dict | None:
        """The checkpoint to continue, after every check; ``None`` for a fresh run."""
        mode, exists = self.rc.resume, self.ckpt_path.exists()
        if mode == "never":
            if exists:
                raise CheckpointError(f"{self.run_dir} already holds a checkpoint; pass resume=true (or "
                                      f"resume={self.run_dir}) to continue it, or choose another folder "
                                      "(nothing was changed)")
            return None
        if mode == "auto" and not exists:
            return None
        payload = load_checkpoint(self.ckpt_path, kind="training")
        diff = config_differences(payload["config"], self.resolved)
        if diff:
            shown = "; ".join(f"{k}: {_get(payload['config'], k)!r} there, {_get(self.resolved, k)!r} here"
                              for k in diff[:6])
            raise CheckpointError(f"the checkpoint in {self.run_dir} was trained with other settings ({shown}"
                                  f"{' ...' if len(diff) > 6 else ''}); only budgets, logging and runtime "
                                  "options may change on resume (nothing was changed)")
        return payload

    # ---------------------------------------------------------------- run
    def run(self) -> TrainResult:
        rc, exp = self.rc, self.rc.experiment
        payload = self._load()
        if payload is not None:
            self.counters.update(payload["counters"])
            self.evaluations = list(payload.get("evaluations", []))
            if _done(exp, self.counters, self.counters["seconds"]):
                return self._finished_already(payload)
        torch.manual_seed(rc.seed)
        device = torch.device(rc.device)
        n_agents = rc.scenario.n_uavs
        per_worker = exp.num_envs // exp.workers

        def env_factory(worker: int = 0) -> FlockingEnv:
            return FlockingEnv(rc.train_scenario, num_envs=per_worker, device=device,
                               seed=rc.seed * 1000 + worker, compile_step=rc.compile)

        env = env_factory()
        learner = make_learner(env, rc.algo, rc.policy.critic_input, compile=rc.compile)
        buffer = None
        if learner.off_policy:
            batch_swarm = max(1, math.ceil(rc.algo.batch_size / n_agents))
            capacity = max(batch_swarm, math.ceil(rc.algo.buffer_size / n_agents))
            buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(capacity, device=device), batch_size=batch_swarm)
        if payload is not None:
            learner.load_state_dict(payload["learner"])
            if buffer is not None:
                if "buffer" not in payload:
                    raise CheckpointError(f"the checkpoint in {self.run_dir} holds no replay buffer "
                                          "(experiment.keep_buffer_in_checkpoint=false): it cannot be resumed "
                                          "exactly; start a new run")
                buffer.load_state_dict(payload["buffer"])
            if exp.workers == 1:
                env.set_state(payload["env_state"])
        # Only now, with the checkpoint (if any) known to fit, does the run folder change.
        write_text(self.run_dir / "config.yaml", OmegaConf.to_yaml(OmegaConf.create(self.resolved)))
        write_text(self.run_dir / "overrides.yaml", OmegaConf.to_yaml(OmegaConf.create(self.overrides)))

        steps = exp.steps_per_batch if learner.off_policy else rc.algo.rollout_steps
        init_random = max(0, exp.init_random_frames - self.counters["frames"]) if learner.off_policy else 0
        collector_kwargs = dict(frames_per_batch=exp.num_envs * steps, total_frames=-1, device=device,
                                init_random_frames=init_random or None, exploration_type=ExplorationType.RANDOM,
                                auto_register_policy_transforms=False)
        if exp.workers > 1:
            collector = MultiSyncCollector([functools.partial(env_factory, w) for w in range(exp.workers)],
                                           learner.collector_policy, **collector_kwargs)
        else:
            collector = Collector(env, learner.collector_policy, track_traj_ids=False, **collector_kwargs)
        if payload is not None:
            torch.set_rng_state(payload["rng"]["torch"])

        logger = _make_logger(rc, self.run_dir, f"{rc.policy.id}_seed{rc.seed}")
        if payload is not None:
            self._truncate_scalar_logs()
        if logger is not None:
            logger.log_hparams(flatten(self.resolved))
        self.episode_log = _EpisodeLog(self.run_dir / "episodes.csv",
                                       self.counters["episodes"] if payload is not None else None)
        self.learner, self.buffer, self.env, self.logger = learner, buffer, env, logger
        progress = _Progress(rc, self.counters)
        next_eval = _next_multiple(self.counters["frames"], exp.eval_every_frames)
        # Logged at the first batch past each multiple of log_every_frames (every batch if 0),
        # so a resumed run logs the same steps as an uninterrupted one.
        next_log = _next_multiple(self.counters["frames"], exp.log_every_frames) if exp.log_every_frames else 0
        next_ckpt = _next_multiple(self.counters["frames"], exp.checkpoint_every_frames)
        self.start = time.perf_counter() - self.counters["seconds"]
        # The running means over the last 100 episodes continue from the (cut back) episode log.
        recent = [(row[2], bool(row[3])) for row in self.episode_log.rows()[-100:]]
        interrupted = 0
        split = self.split = dict.fromkeys(("env", "collection", "buffer", "sampling", "update", "logging"), 0.0)
        env_busy = env.busy_seconds
        t_last = time.perf_counter()
        try:
            with _Signals() as signals:
                for batch in collector:
                    t_collected = time.perf_counter()
                    if exp.workers == 1:
                        split["env"] += env.busy_seconds - env_busy
                        split["collection"] -= env.busy_seconds - env_busy
                        env_busy = env.busy_seconds
                    split["collection"] += t_collected - t_last
                    frames = batch.numel()
                    self.counters["frames"] += frames
                    self.counters["iterations"] += 1
                    batch = _agentwise_done(batch, n_agents)
                    rows = self._finished_episodes(batch)
                    if rows:
                        self.episode_log.write(rows)
                        recent = (recent + [(r[2], bool(r[3])) for r in rows])[-100:]
                    if hasattr(learner, "on_frames"):
                        learner.on_frames(frames)
                    stats, n_updates = self._learn(batch)
                    self.counters["updates"] += n_updates
                    if exp.workers > 1:  # a single collector shares the learner's policy
                        collector.update_policy_weights_()
                    t_learned = time.perf_counter()
                    if self.counters["frames"] >= next_log:
                        if exp.log_every_frames:
                            next_log = _next_multiple(self.counters["frames"], exp.log_every_frames)
                        log = {f"train/{k}": float(v) for k, v in stats.items()}
                        if recent:
                            log["train/episode_reward"] = sum(r for r, _ in recent) / len(recent)
                            log["train/success_rate"] = sum(s for _, s in recent) / len(recent)
                        update_seconds = split["sampling"] + split["update"]
                        log["perf/updates_per_s"] = self.counters["updates"] / max(update_seconds, 1e-9)
                        log["perf/frames_per_s"] = self.counters["frames"] / max(split["env"] + split["collection"], 1e-9)
                        self._log(log)
                        progress.update(self.counters, log)
                    if exp.eval_every_frames and self.counters["frames"] >= next_eval:
                        next_eval = _next_multiple(self.counters["frames"], exp.eval_every_frames)
                        result = self._evaluate()
                        progress.write(f"eval @ {self.counters['frames']} frames: success {result['success']:.3f} "
                                       f"safe_success {result['safe_success']:.3f}")
                    if exp.checkpoint_every_frames and self.counters["frames"] >= next_ckpt:
                        next_ckpt = _next_multiple(self.counters["frames"], exp.checkpoint_every_frames)
                        self._save()
                    t_last = time.perf_counter()
                    split["logging"] += t_last - t_learned
                    if signals.received:
                        interrupted = signals.received
                        break
                    if _done(exp, self.counters, time.perf_counter() - self.start):
                        break
        except FloatingPointError as exc:
            progress.write(f"stopping: {exc}; the last good checkpoint is kept at {self.ckpt_path}")
            raise
        finally:
            collector.shutdown()
            progress.close()
        if not interrupted and exp.eval_episodes and (not self.evaluations
                                                      or self.evaluations[-1]["frames"] != self.counters["frames"]):
            self._evaluate()  # every run ends with an evaluation of what it ships
        path = self._save()
        self.episode_log.close()
        if rc.logger.backend == "wandb" and logger is not None:
            logger.experiment.finish()
        result = TrainResult(self.run_dir, path, self.counters["frames"], self.counters["episodes"],
                             self.counters["updates"], self.counters["seconds"], self.evaluations, interrupted,
                             dict(self.split))
        if interrupted:
            raise TrainingInterrupted(interrupted, result, resume_command(self.run_dir))
        return result

    def _finished_already(self, payload: dict) -> TrainResult:
        """Resuming a finished run changes nothing (whether or not it kept its buffer)."""
        c = self.counters
        return TrainResult(self.run_dir, self.ckpt_path, c["frames"], c["episodes"], c["updates"], c["seconds"],
                           self.evaluations)

    def _learn(self, batch: TensorDictBase) -> tuple[dict[str, torch.Tensor], int]:
        learner, exp, split = self.learner, self.rc.experiment, self.split
        if not learner.off_policy:
            start = time.perf_counter()
            stats = learner.update(batch)
            split["update"] += time.perf_counter() - start
            return stats, 1
        start = time.perf_counter()
        self.buffer.extend(batch.select(*TRANSITION_KEYS, strict=False).reshape(-1))
        split["buffer"] += time.perf_counter() - start
        stats: dict[str, torch.Tensor] = {}
        n = 0
        if self.counters["frames"] >= exp.init_random_frames and len(self.buffer) >= self.buffer.batch_size:
            device = torch.device(self.rc.device)
            for _ in range(exp.updates_per_batch):
                t0 = time.perf_counter()
                sample = self.buffer.sample().to(device)
                t1 = time.perf_counter()
                stats = learner.update(sample)
                split["sampling"] += t1 - t0
                split["update"] += time.perf_counter() - t1
                n += 1
        return stats, n

    def _finished_episodes(self, batch: TensorDictBase) -> list[list[Any]]:
        """CSV rows for the episodes that ended in this batch (frames counted at batch end)."""
        done = batch.get(("next", "done")).squeeze(-1)
        if not done.any():
            return []
        ep = batch.get(("next", "episode"))[done]
        columns = {k: ep[k].tolist() for k in ("return", "success", "safe_success", *CELL_METRICS, "steps")}
        rows = []
        for i in range(ep.shape[0]):
            self.counters["episodes"] += 1
            rows.append([self.counters["episodes"], self.counters["frames"], round(columns["return"][i], 5),
                         int(columns["success"][i]), int(columns["safe_success"][i]),
                         *(round(columns[m][i], 4) for m in CELL_METRICS), int(columns["steps"][i])])
        return rows

    def _log(self, values: dict[str, float]) -> None:
        if self.logger is not None:
            for key, value in values.items():
                self.logger.log_scalar(key, value, step=self.counters["frames"])

    def _truncate_scalar_logs(self) -> None:
        """Cut the CSV logger's files back to the checkpoint's step (a resume rewrites the rest)."""
        frames = self.counters["frames"]
        for path in (self.run_dir / "logs" / "scalars").glob("**/*.csv"):
            truncate_log(path, lambda r: float(r[0]) <= frames, header=False)

    def _evaluate(self) -> dict[str, float]:
        from .evaluation import evaluate

        result = evaluate(self.learner.actor, scenario=self.rc.scenario, n_episodes=self.rc.experiment.eval_episodes,
                          seed=self.rc.eval_seed, device=self.rc.device)
        row = {k: float(v) for k, v in result.summary().items()}
        row["success"], row["safe_success"] = row["success_rate"], row["safe_success_rate"]
        row["frames"] = self.counters["frames"]
        self.evaluations.append(row)
        self._log({f"eval/{k}": v for k, v in row.items() if k != "frames"})
        return row

    def _save(self) -> Path:
        self.counters["seconds"] = time.perf_counter() - self.start
        exp = self.rc.experiment
        state = {
            "meta": self.meta, "config": self.resolved, "counters": dict(self.counters),
            "actor": self.learner.actor.state_dict(), "learner": self.learner.state_dict(),
            "rng": {"torch": torch.get_rng_state()}, "evaluations": self.evaluations,
            "curve": torch.tensor(self.episode_log.rows(), dtype=torch.float64).reshape(-1, len(EPISODE_COLUMNS)),
        }
        if exp.workers == 1:
            state["env_state"] = self.env.get_state()
        if self.buffer is not None and exp.keep_buffer_in_checkpoint:
            state["buffer"] = self.buffer.state_dict()
        return save_checkpoint(state, self.ckpt_path, kind="training")


def _get(tree: Any, dotted: str) -> Any:
    return flatten(tree).get(dotted, "<absent>")


class _Progress:
    """tqdm bar over frames (or a no-op)."""

    def __init__(self, rc: RunConfig, counters: dict) -> None:
        self.bar = None
        if rc.progress:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=rc.experiment.max_frames or None, initial=counters["frames"], unit="frame",
                            dynamic_ncols=True, desc=f"{rc.policy.name} seed {rc.seed}")
        self.last = counters["frames"]

    def update(self, counters: dict, log: dict) -> None:
        if self.bar is None:
            return
        self.bar.update(counters["frames"] - self.last)
        self.last = counters["frames"]
        self.bar.set_postfix(episodes=counters["episodes"], reward=f"{log.get('train/episode_reward', math.nan):.2f}",
                             success=f"{log.get('train/success_rate', math.nan):.2f}", refresh=False)

    def write(self, message: str) -> None:
        if self.bar is not None:
            self.bar.write(message)
        else:
            print(message, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


__all__ = ["EPISODE_COLUMNS", "RESUMABLE_CHANGES", "RunConfig", "RunLock", "TRANSITION_KEYS", "TrainResult",
           "TrainingInterrupted", "check_train_config", "checkpoint_meta", "config_differences",
           "make_train_config", "train"]
