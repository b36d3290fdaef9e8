"""Training a population: ``population=K`` trains seeds ``seed .. seed + K - 1`` in one process.

The loop is the solo run's (:mod:`.trainer`): one collector (one per swarm size when sizes are
mixed), one replay buffer, one learner, the same schedule, checkpoints, signals and resume. What
changes is what each piece holds:

* the env is a :class:`~flock_torchrl.world.population.PopulationEnv`: ``K * B`` worlds,
  member-major, each member's spawns from its own generator (seeded as a solo run's env); with
  mixed sizes, one such env per size;
* the learner is a :class:`~flock_torchrl.policies.population.PopulationLearner`: the members'
  parameters stacked, TorchRL's loss called under ``torch.vmap``;
* the replay buffer's items are population rows ``[K]`` (one swarm transition per member, or
  one UAV's transition when the sizes are mixed),
  sampled per member (:class:`~flock_torchrl.policies.population.MemberSampler`);
* counters are per member: ``frames`` is each member's (all collect alike), episodes are
  counted per member, and the budget ``max_episodes`` is spent when every member has spent it.
  A member that reaches it first is *final* from then on: its actor, counters and training
  curve at that batch are what it ships (it keeps stepping with the others, but nothing it
  does later is kept), so each member's budget means what a solo run's does.

Each member's episodes go to ``<run>/seed<s>/episodes.csv``, its scalars to the logger under
``seed<s>/...`` (their population mean, and the loop's speed, under a solo run's names: ``train/...``,
``eval/...``, ``perf/frames_per_s``); the checkpoint holds every member's slim policy (``members``), which
``make ship-checkpoints`` exports as ``<policy>/seed<s>.pt``.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Sequence

import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType

from ..config import TrainConfig
from ..policies.population import MemberSampler, PopulationLearner
from ..world.population import PopulationEnv
from .run_folder import EpisodeLog
from .batches import EPISODE_COLUMNS, TRANSITION_KEYS, AgentwiseDone, episode_rows, per_uav
from .setup import checkpoint_meta
from .signals import start_resource_tracker
from .parts import evaluation_row, policy_capture, replay_buffer, restore_buffer, restore_rng, result_row
from .rollout import evaluate_members
from .timing import TimeSplit, rates
from .trainer import Training

def member_meta(meta: dict[str, Any], seed: int) -> dict[str, Any]:
    """A member's checkpoint metadata: the population's, with the member's own seed."""
    return {**meta, "seed": seed}


class PopulationTraining(Training):
    """One population run (``train`` dispatches here when ``cfg.population > 1``; a population of
    one may be built directly, and then trains exactly what the solo run trains)."""

    def __init__(self, cfg: TrainConfig, run_dir: Path) -> None:
        super().__init__(cfg, run_dir)
        self.seeds = cfg.seeds
        self.k = len(self.seeds)
        self.member_episodes = [0] * self.k
        self.member_evaluations: list[list[dict[str, float]]] = [[] for _ in self.seeds]
        self.final: list[dict[str, Any] | None] = [None] * self.k   # a member's frozen result, once final
        self.split = TimeSplit("members", device=cfg.device)  # and per-member bookkeeping (episode rows)

    # ---------------------------------------------------------------- the pieces
    def _build(self, payload: dict | None) -> None:
        cfg, exp = self.cfg, self.cfg.experiment
        start_resource_tracker()
        torch.manual_seed(cfg.seed)
        device = torch.device(cfg.device)
        # Mixed sizes: one PopulationEnv per size, the worlds split evenly; member k's worlds of
        # size i draw from a generator seeded as its solo run's (1000 seed_k + i).
        self.mixed = bool(exp.swarm_sizes or exp.train_mix)
        self.per_uav = bool(exp.swarm_sizes)
        scenarios = cfg.train_scenarios
        self.envs = [PopulationEnv(scenario, self.k, exp.num_envs // len(scenarios), [s * 1000 + i for s in self.seeds],
                                   device=device, compile_step=cfg.compile_step, check_actions=False,
                                   reset_pool=cfg.reset_pool, capture_step=cfg.cudagraphs)
                     for i, scenario in enumerate(scenarios)]
        self.env = env = self.envs[0]
        self.learner = learner = PopulationLearner(env, cfg.algo, cfg.policy.critic_input, self.seeds,
                                                   cudagraphs=cfg.cudagraphs)
        self.buffer = replay_buffer(cfg, 1 if self.per_uav else cfg.scenario.n_uavs, device,
                                    sampler=MemberSampler(self.k))
        if payload is not None:
            learner.load_state_dict(payload["learner"])
            restore_buffer(self.buffer, payload, self.run_dir)
            states = payload["env_state"]
            for one, state in zip(self.envs, states if self.mixed else [states]):
                one.set_state(state)
        init_random = max(0, exp.init_random_frames - self.counters["frames"])
        self.collectors = [Collector(one, learner.collector_policy, track_traj_ids=False,
                                     frames_per_batch=one.num_envs * exp.steps_per_batch, total_frames=-1,
                                     device=device, init_random_frames=init_random * self.k or None,
                                     exploration_type=ExplorationType.RANDOM, auto_register_policy_transforms=False,
                                     postproc=AgentwiseDone(one.n_agents), cudagraph_policy=policy_capture(cfg),
                                     # off-policy: each batch is copied into the buffer (make_collectors)
                                     return_same_td=True, no_cuda_sync=True)
                           for one in self.envs]
        self.collector = self.collectors[0]
        if payload is not None:
            restore_rng(payload["rng"], device)
        self.meta = {**checkpoint_meta(cfg, env), "population": self.k, "seeds": list(self.seeds)}
        self._eval_actor = copy.deepcopy(learner.actor)

    def _open_episode_logs(self, resumed: bool) -> None:
        self.member_logs = [EpisodeLog(self.run_dir / f"seed{s}" / "episodes.csv", EPISODE_COLUMNS,
                                       self.member_episodes[k] if resumed else None)
                            for k, s in enumerate(self.seeds)]
        self.episode_log = self.member_logs[0]
        self.recent = []
        self.member_recent = [[(row[2], bool(row[3])) for row in log.rows()[-100:]] for log in self.member_logs]

    def _close(self) -> None:
        for log in self.member_logs[1:]:
            log.close()
        super()._close()

    # ---------------------------------------------------------------- one batch
    def _consume(self, batches: Sequence[TensorDictBase]) -> dict[str, torch.Tensor]:
        frames = sum(batch.numel() for batch in batches) // self.k  # each member's
        self.counters["frames"] += frames
        self.counters["iterations"] += 1
        with self.split.timer("members"):
            for env, batch in zip(self.envs, batches):  # one per swarm size
                self.pending.add(batch, self.counters["frames"], source=env)
            budget = self.cfg.experiment.max_episodes
            # Each member holds 1/K of the pending worlds' steps: count when one could spend its budget.
            live = [e for e, f in zip(self.member_episodes, self.final) if f is None]
            if budget and live and max(live) + self.pending.slots // self.k >= budget:
                self._tally_episodes()
        self.learner.on_frames(frames)
        stats, n_updates = self._learn(batches)
        self.counters["updates"] += n_updates
        self._freeze_finished()
        return stats

    def _transitions(self, batch: TensorDictBase) -> TensorDictBase:
        """Population rows ``[R, K]``: member k's transitions in column k (swarm transitions, or
        single-UAV ones when the sizes are mixed)."""
        if self.per_uav:
            return per_uav(batch.reshape(self.k, -1), lead=1).transpose(0, 1).contiguous()
        rows = batch.select(*TRANSITION_KEYS, strict=False).reshape(self.k, -1)
        return rows.transpose(0, 1).contiguous()

    def _tally_episodes(self) -> None:
        """Each member's episodes pending since the last tally as rows of its own episode log
        (the member of each episode from its world's index)."""
        for finished in self.pending.flush():
            member = finished.source.member_of(torch.tensor(finished.worlds)).tolist()
            for k in sorted(set(member)):                                    # members with finished episodes
                mine = [v for m, v in zip(member, finished.values) if m == k]
                first = self.member_episodes[k]
                self.member_episodes[k] += len(mine)
                if self.final[k] is not None:
                    continue  # a final member's later episodes are not its run's
                rows = episode_rows(mine, first, finished.frames)
                self.member_logs[k].write(rows)
                self.member_recent[k] = (self.member_recent[k] + [(r[2], bool(r[3])) for r in rows])[-100:]
        self.counters["episodes"] = min(self.member_episodes)

    def _freeze_finished(self) -> None:
        """A member that spent ``max_episodes`` is final: keep its actor, counters and curve now."""
        budget = self.cfg.experiment.max_episodes
        if not budget:
            return
        for k, episodes in enumerate(self.member_episodes):
            if self.final[k] is None and episodes >= budget:
                self.final[k] = self._member_snapshot(k)

    def _member_snapshot(self, k: int) -> dict[str, Any]:
        counters = {**self.counters, "episodes": self.member_episodes[k]}
        return {"actor": self.learner.actor_state(k), "counters": counters,
                "curve": self._curve(k)}

    def _curve(self, k: int) -> torch.Tensor:
        rows = self.member_logs[k].rows()
        return torch.tensor(rows, dtype=torch.float64).reshape(-1, len(EPISODE_COLUMNS))

    # ---------------------------------------------------------------- logging, evaluation
    def _log_training(self, stats: dict[str, torch.Tensor]) -> None:
        self._tally_episodes()
        self.learner.check()
        log: dict[str, float] = {}
        for k, seed in enumerate(self.seeds):
            log.update({f"seed{seed}/train/{name}": float(v[k]) for name, v in stats.items()})
            recent = self.member_recent[k]
            if recent:
                log[f"seed{seed}/train/episode_reward"] = sum(r for r, _ in recent) / len(recent)
                log[f"seed{seed}/train/success_rate"] = sum(s for _, s in recent) / len(recent)
        # The population's mean of every member's scalar, under the solo run's names.
        names = [*stats, "episode_reward", "success_rate"]
        for name in names:
            values = [log[f"seed{s}/train/{name}"] for s in self.seeds if f"seed{s}/train/{name}" in log]
            if values:
                log[f"train/{name}"] = sum(values) / len(values)
        # Every member's frames and updates per second of the loop (the worlds this process steps):
        # under the solo run's names, and as before under perf/member_*.
        speed = rates(self.split.settle(), self.counters, self.k)
        log.update(speed)
        log.update({k.replace("perf/", "perf/member_"): v for k, v in speed.items()})
        self._log(log)
        if self.progress is not None:
            self.progress.update(self.counters, log)

    def _evaluate(self) -> dict[str, float]:
        """Evaluate every member that is not final (a final member's last evaluation stands):
        the members still training in one batched rollout (:func:`~.rollout.evaluate_members`)
        when there are several, a member alone as a solo run is evaluated."""
        live = [k for k in range(self.k) if self.final[k] is None]
        batched = self._evaluate_live(live) if len(live) > 1 else {}
        rows = []
        for k, seed in enumerate(self.seeds):
            final = self.final[k]
            if final is not None and self.member_evaluations[k] and \
                    self.member_evaluations[k][-1]["frames"] >= final["counters"]["frames"]:
                rows.append(self.member_evaluations[k][-1])
                continue
            row = batched.get(k)
            if row is None:
                self._eval_actor.load_state_dict(final["actor"] if final is not None else self.learner.actor_state(k))
                row = evaluation_row(self.cfg, self._eval_actor,
                                     final["counters"]["frames"] if final is not None else self.counters["frames"])
            self.member_evaluations[k].append(row)
            self._log({f"seed{seed}/eval/{key}": v for key, v in row.items() if key != "frames"})
            rows.append(row)
        summary = {key: sum(r[key] for r in rows) / len(rows) for key in rows[0] if key != "frames"}
        summary["frames"] = self.counters["frames"]
        self.evaluations.append(summary)
        self._log({f"eval/{key}": v for key, v in summary.items() if key != "frames"})
        return summary

    def _evaluate_live(self, live: list[int]) -> dict[int, dict[str, float]]:
        """Rows of members ``live`` (still training), evaluated together on the run's episodes."""
        params = self.learner.params.get("actor_network_params")[torch.tensor(live, device=self.learner.params.device)]
        results = evaluate_members(self._eval_actor, params.detach(), self.cfg.scenario,
                                   self.cfg.experiment.eval_episodes, self.cfg.eval_seed, self.cfg.device)
        return {k: result_row(result, self.counters["frames"]) for k, result in zip(live, results)}

    # ---------------------------------------------------------------- checkpoints
    def _state(self) -> dict[str, Any]:
        state = super()._state()
        counters = [dict(f["counters"]) if f is not None else {**self.counters, "episodes": e}
                    for f, e in zip(self.final, self.member_episodes)]
        members = []
        for k, seed in enumerate(self.seeds):
            final = self.final[k]
            members.append({
                "seed": seed, "final": final is not None,
                "meta": member_meta(self.meta, seed),
                "config": {**self.resolved, "seed": seed, "population": 1},
                "counters": counters[k],
                "actor": final["actor"] if final is not None else self.learner.actor_state(k),
                "evaluations": list(self.member_evaluations[k]),
                "curve": final["curve"] if final is not None else self._curve(k),
                "episodes_seen": self.member_episodes[k],
            })
        state["members"] = members
        state["actor"] = members[0]["actor"]
        state["curve"] = members[0]["curve"]
        return state

    def _restore(self, payload: dict[str, Any]) -> None:
        for k, member in enumerate(payload["members"]):
            self.member_episodes[k] = int(member["episodes_seen"])
            self.member_evaluations[k] = list(member["evaluations"])
            if member["final"]:
                self.final[k] = {"actor": member["actor"], "counters": dict(member["counters"]),
                                 "curve": member["curve"]}


__all__ = ["PopulationTraining", "member_meta"]
