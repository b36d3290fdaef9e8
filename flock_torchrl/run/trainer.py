"""The training loop: TorchRL collector -> replay buffer -> learner, for K members trained as one
(``population``; K = 1 the solo run), with evaluation, logging and exact, atomic, digest-checked
checkpoints (``train(cfg)``, :mod:`.launch`, is its entry point).

The checks before a run are :mod:`.setup`'s, its parts :mod:`.parts`' (envs, collectors whose
``postproc`` gives per-UAV done flags, the replay buffer), the members' bookkeeping
:mod:`.members`', the stop signals :mod:`.signals`', the schedule :mod:`.schedule`'s, the run
folder :mod:`.run_folder`'s, the time split :mod:`.timing`'s. A run survives its users (README,
"Training"): a second process on its folder is refused; a stop signal finishes the update,
writes a checkpoint and exits 128 + the signal, printing the command that resumes; the final
evaluation runs after a checkpoint, and a resumed run counts as finished only once its last
evaluation is at its last frame; ``resume`` refuses any changed setting but the ``resumable``
keys, and cuts the logs back to the checkpoint, so a resumed run's checkpoints and logs equal an
uninterrupted run's.

K members (docs/population.md) share the loop: their worlds are one batch (member-major), the
learner holds their K parameter sets (:class:`~flock_torchrl.policies.learners.OffPolicyLearner`),
the replay buffer's rows hold one transition per member, and the counters are each member's (all
collect alike). One member writes the solo run's files; several, a folder each (:mod:`.members`).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import time
from pathlib import Path
from typing import Any, Sequence

import torch
from tensordict import TensorDictBase

from ..config import TrainConfig
from ..policies.checkpoint import LAST
from ..policies.learners import make_learner
from ..policies.members import MemberSampler
from .batches import PendingEpisodes, replay_rows
from .members import Members
from .parts import (Learner, TrainResult, buffer_state, make_collectors, make_envs, member_evaluations,
                    replay_buffer, restore_buffer, restore_rng, rng_state, write_checkpoint)
from .run_folder import logger_hparams, make_logger, resume_command, truncate_scalar_logs, write_run_config
from .schedule import Schedule, evaluated_at_end
from .setup import checkpoint_meta, hydra_settings, resume_payload
from .signals import Signals, Stopped, TrainingInterrupted, job_tag, say, shutdown, start_resource_tracker
from .timing import Progress, TimeSplit, rates, seeds_label


class Training:
    """One run of K members: its pieces, its loop, its checkpoints (``train`` is its entry point)."""

    def __init__(self, cfg: TrainConfig, run_dir: Path) -> None:
        self.cfg, self.run_dir = cfg, run_dir
        self.resolved = dataclasses.asdict(cfg)
        self.ckpt_path = run_dir / LAST
        self.counters = {"frames": 0, "episodes": 0, "updates": 0, "iterations": 0, "seconds": 0.0}
        self.evaluations: list[dict[str, float]] = []  # the run's (several members: their mean)
        self.members = Members(list(cfg.seeds), run_dir)
        self.k = self.members.k
        self.split = TimeSplit(device=cfg.device)
        self.saved_frames = -1            # frames of the last checkpoint this process wrote
        self.start = time.perf_counter()
        self.progress: Progress | None = None
        self.updated = False              # whether this process has run an update yet
        self.pending = PendingEpisodes()  # episodes ended in batches whose rows are not written yet

    def _build(self, payload: dict | None) -> None:
        cfg, exp = self.cfg, self.cfg.experiment
        start_resource_tracker()  # before the replay buffer's shared counter or any worker needs it
        torch.manual_seed(cfg.seed)
        device = torch.device(cfg.device)
        self.mixed = bool(exp.swarm_sizes or exp.train_mix)  # an env per swarm size and kind of world
        self.per_uav = bool(exp.swarm_sizes)                  # the replay buffer holds single UAVs' transitions
        self.envs, factory = make_envs(cfg, device)
        self.env = self.envs[0]
        self.learner: Learner = make_learner(self.env, cfg.algo, cfg.policy.critic_input, self.members.seeds,
                                             compile=cfg.compile_loss, cudagraphs=cfg.cudagraphs)
        off_policy = self.learner.off_policy
        sampler = {"sampler": MemberSampler(self.k)} if self.k > 1 else {}
        self.buffer = replay_buffer(cfg, 1 if self.per_uav else cfg.scenario.n_uavs, device,
                                    **sampler) if off_policy else None
        if payload is not None:
            self.learner.load_state_dict(payload["learner"])
            restore_buffer(self.buffer, payload, self.run_dir)
            if exp.workers == 1:
                states = payload["env_state"]
                for env, state in zip(self.envs, states if self.mixed else [states]):
                    env.set_state(state)
        self.steps = steps = exp.steps_per_batch if off_policy else cfg.algo.rollout_steps  # per batch
        init_random = max(0, exp.init_random_frames - self.counters["frames"]) if off_policy else 0
        # An off-policy batch is copied into the replay buffer before the next is collected: the
        # collector may overwrite it (an on-policy learner writes its advantages into its batch).
        self.collectors = make_collectors(cfg, self.envs, factory, self.learner.collector_policy, steps,
                                          init_random * self.k, device, reuse_batch=off_policy)
        if payload is not None:
            restore_rng(payload["rng"], device)
        self.meta = checkpoint_meta(cfg, self.env)
        if self.k > 1:
            self.meta.update(population=self.k, seeds=list(self.members.seeds))
        self._eval_actor = copy.deepcopy(self.learner.actor)
        self._eval_actor.name = self.cfg.policy.name  # what the evaluation's progress calls it

    def run(self) -> TrainResult:
        payload = resume_payload(self.cfg, self.resolved, self.run_dir)
        if payload is not None:
            self.counters.update(payload["counters"])
            self.evaluations = list(payload.get("evaluations", []))
            self.members.restore(payload, self.counters)
        schedule = Schedule(self.cfg.experiment).start(self.counters["frames"])
        finished = schedule.finished(self.counters["frames"], self.counters["episodes"], self.counters["seconds"])
        if schedule.done(self.counters, self.evaluations):
            return self._result(self.ckpt_path)  # a finished run resumes to a no-op
        with Signals(resume_command(self.run_dir)) as signals:
            self._build(payload)
            # Only now, with the checkpoint (if any) known to fit, does the run folder change.
            write_run_config(self.run_dir, self.resolved, hydra_settings())
            self._open_logs(payload is not None)
            self.start = time.perf_counter() - self.counters["seconds"]
            try:
                if not finished:
                    self._loop(schedule, signals)
            finally:
                for collector in self.collectors:
                    shutdown(collector)
            if signals.received:
                return self._stop(signals.received)
            return self._finish(signals)

    def _loop(self, schedule: Schedule, signals: Signals) -> None:
        """Collect, count, learn; log, evaluate and checkpoint when due; until the budget or a signal."""
        counters, split = self.counters, self.split
        try:
            for batches in split.timed(zip(*self.collectors), "collection"):
                stats = self._consume(batches)
                with split.timer("logging"):
                    if schedule.log.due(counters["frames"]):
                        self._log_training(stats)
                with split.timer("evaluation"):
                    if schedule.evaluate.due(counters["frames"]):
                        row = self._evaluate()
                        self._print(f"eval @ {counters['frames']} frames: success {row['success']:.3f} "
                                    f"safe_success {row['safe_success']:.3f}")
                with split.timer("checkpoints"):
                    if schedule.checkpoint.due(counters["frames"]):
                        self._save()
                if signals.received or schedule.finished(counters["frames"], counters["episodes"],
                                                         time.perf_counter() - self.start):
                    break
        except FloatingPointError as exc:
            say(f"stopping: {exc}; the last good checkpoint is kept at {self.ckpt_path}")
            raise

    def _consume(self, batches: Sequence[TensorDictBase]) -> dict[str, torch.Tensor]:
        """Count, log and learn from one batch of each collector (one, unless sizes or worlds are mixed)."""
        frames = sum(batch.numel() for batch in batches) // self.k  # each member's
        self.counters["frames"] += frames
        self.counters["iterations"] += 1
        for env, batch in zip(self.envs, batches):
            self.pending.add(batch, self.counters["frames"], source=env)
        budget = self.cfg.experiment.max_episodes
        # Each member holds 1/K of the pending worlds' steps: count when one could spend its budget.
        if budget and self.members.could_spend(budget, self.pending.slots // self.k):
            self._tally_episodes()
        self.learner.on_frames(frames)
        stats, n_updates = self._learn(batches)
        self.counters["updates"] += n_updates
        if self.cfg.experiment.workers > 1:  # a single collector shares the learner's policy
            self.collectors[0].update_policy_weights_()
        if budget:
            self.members.freeze_spent(budget, self.learner, self.counters)
        return stats

    def _learn(self, batches: Sequence[TensorDictBase]) -> tuple[dict[str, torch.Tensor], int]:
        """The learner's updates on this batch: on-policy one on the batch itself; off-policy
        ``updates_per_batch`` on samples of the replay buffer, once it holds enough."""
        learner, exp, split = self.learner, self.cfg.experiment, self.split
        if not learner.off_policy:  # one size (TrainConfig refuses mixed sizes on-policy)
            with split.timer(self._update_bucket()):
                return learner.update(batches[0]), 1
        with split.timer("buffer"):
            for batch in batches:
                self.buffer.extend(replay_rows(batch, self.k, self.per_uav))
        if self.counters["frames"] < exp.init_random_frames or len(self.buffer) < self.buffer.batch_size:
            return {}, 0
        stats: dict[str, torch.Tensor] = {}
        for _ in range(exp.updates_per_batch):
            with split.timer("sampling"):
                sample = self.buffer.sample().to(torch.device(self.cfg.device))
            with split.timer(self._update_bucket()):
                stats = learner.update(sample)
        return stats, exp.updates_per_batch

    def _update_bucket(self) -> str:
        """Where an update's time goes: a compiled learner's first one in this process compiles."""
        first, self.updated = not self.updated, True
        return "compile" if self.cfg.compile_loss and first else "update"

    def _tally_episodes(self) -> None:
        """Write the rows of the episodes pending since the last tally (the loop reads the batches'
        episodes here, at logging, checkpoints and an episode budget, not after every batch: on a
        GPU an iteration then never waits for the device)."""
        self.counters["episodes"] = self.members.tally(self.pending.flush())

    def _open_logs(self, resumed: bool) -> None:
        truncate_scalar_logs(self.run_dir, self.counters["frames"] if resumed else None)  # fresh: a dead run's go
        log, label = self.cfg.logger, seeds_label(self.members.seeds)
        self.logger = make_logger(log.backend, log.project, log.mode, self.run_dir,
                                  f"{self.cfg.policy.id}_{label.replace(' ', '')}")
        if self.logger is not None:
            self.logger.log_hparams(logger_hparams(self.resolved))
        if self.cfg.progress:  # the random frames (no update) are left out of its rate
            exp = self.cfg.experiment
            random_frames = exp.init_random_frames if self.learner.off_policy else 0
            self.progress = Progress(exp.max_frames, self.counters, f"{self.cfg.policy.name} {label}",
                                     exp.num_envs * self.steps, random_frames)
        self.members.open_logs(resumed)

    def _log_training(self, stats: dict[str, torch.Tensor]) -> None:
        self._tally_episodes()
        self.learner.check()  # a captured update's finite-loss flags, read where the host reads anyway
        log = self.members.training_scalars(stats)
        log.update({f"train/{name}": lr for name, lr in self.learner.learning_rates().items()})
        log.update(rates(self.split.settle(), self.counters, self.k))
        self._log(log)
        if self.progress is not None:
            self.progress.update(self.counters, log)

    def _log(self, values: dict[str, float]) -> None:
        if self.logger is not None and values:
            self.logger.log_metrics(values, step=self.counters["frames"])  # one row per logging event

    def _print(self, message: str) -> None:  # a sweep's jobs share the terminal: each line says whose it is
        write = self.progress.write if self.progress is not None else functools.partial(print, flush=True)
        write(job_tag() + message)

    def _evaluate(self) -> dict[str, float]:
        summary, scalars = member_evaluations(self.cfg, self._eval_actor, self.learner, self.members,
                                              self.counters["frames"])
        self.evaluations.append(summary)
        self._log(scalars)
        return summary

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
        self.members.close()
        if self.progress is not None:
            self.progress.close()
        if self.cfg.logger.backend == "wandb" and self.logger is not None:
            self.logger.experiment.finish()

    def _result(self, path: Path, interrupted: int = 0) -> TrainResult:
        c = self.counters
        return TrainResult(self.run_dir, path, c["frames"], c["episodes"], c["updates"], c["seconds"],
                           self.evaluations, interrupted, dict(self.split.settle()))

    def _state(self) -> dict[str, Any]:
        """Everything the checkpoint holds."""
        exp = self.cfg.experiment
        state = {
            "meta": self.meta, "config": self.resolved, "counters": dict(self.counters),
            "learner": self.learner.state_dict(), "rng": rng_state(torch.device(self.cfg.device)),
            "evaluations": self.evaluations, **self.members.state(self.learner, self.counters, self.meta,
                                                                   self.resolved),
        }
        if exp.workers == 1:
            state["env_state"] = [e.get_state() for e in self.envs] if self.mixed else self.env.get_state()
        if self.buffer is not None and exp.keep_buffer_in_checkpoint:
            state["buffer"] = buffer_state(self.buffer)
        return state

    def _save(self) -> Path:
        self._tally_episodes()
        self.learner.check()  # never a checkpoint of a diverged learner
        self.counters["seconds"] = time.perf_counter() - self.start
        path = write_checkpoint(self._state(), self.ckpt_path)
        self.saved_frames = self.counters["frames"]
        return path


__all__ = ["Training"]
