"""The training loop: TorchRL collector -> replay buffer -> learner, with evaluation,
logging and exact, atomic checkpoints.

``train(cfg)`` takes the composed Hydra config (``conf/train.yaml``) or an equivalent
DictConfig/dict; :func:`make_train_config` builds one without Hydra.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from torchrl.collectors import Collector, MultiSyncCollector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs.utils import ExplorationType

from .checkpoint import LAST, FORMAT, CheckpointError, atomic_save, load_checkpoint
from .config import ConfigError, ScenarioConfig, load_scenario
from .env import FlockingEnv
from .learners import make_learner
from .schema import (ExperimentConfig, LoggerConfig, PolicyConfig, load_group, validate_algo, validate_experiment,
                     validate_logger, validate_policy)

EPISODE_COLUMNS = ("episode", "frames", "reward", "success", "safe_success", "d_min_obs", "d_min_uav", "d_c",
                   "v_error", "phi_error", "speed", "t_goal", "steps")
# Keys a learner needs from a transition; everything else stays out of the replay buffer.
TRANSITION_KEYS = [("agents", "observation"), ("agents", "state"), ("agents", "action"),
                   ("agents", "action_log_prob"), ("next", "agents", "observation"), ("next", "agents", "state"),
                   ("next", "agents", "reward"), ("next", "agents", "done"), ("next", "agents", "terminated"),
                   ("next", "done"), ("next", "terminated")]


@dataclass
class ResolvedConfig:
    """A train config, checked group by group."""

    scenario: ScenarioConfig          # what the policy is evaluated (and shipped) with
    train_scenario: ScenarioConfig    # the same plus the experiment's train_env recipe
    policy: PolicyConfig
    policy_id: str
    algo: Any
    experiment: ExperimentConfig
    logger: LoggerConfig
    seed: int
    device: str
    run_dir: Path
    resume: bool | str
    progress: bool
    eval_seed: int


@dataclass
class TrainResult:
    run_dir: Path
    checkpoint: Path
    frames: int
    episodes: int
    updates: int
    seconds: float
    evaluations: list[dict[str, float]] = field(default_factory=list)


def make_train_config(policy: str = "policy3_g", experiment: str = "fast", scenario: str = "train",
                      logger: str = "csv", **top: Any) -> DictConfig:
    """Compose the same config as ``scripts/train.py`` without Hydra.

    ``top`` sets top-level keys (``seed``, ``device``, ``run_dir``, ``resume``, ``progress``,
    ``eval_seed``); dotted keys such as ``{"algo.lr_actor": 1e-4}`` may be passed through
    ``overrides={...}``.
    """
    from .schema import policy_algo_name

    overrides = top.pop("overrides", {}) or {}
    policy_node = load_group("policy", policy)
    algo_name = policy_algo_name(policy)
    cfg = OmegaConf.create({
        "scenario": load_group("scenario", "train") if scenario == "train" else
        OmegaConf.create(dataclasses.asdict(load_scenario(scenario))),
        "policy": policy_node,
        "algo": load_group("algo", algo_name) if algo_name else None,
        "experiment": load_group("experiment", experiment),
        "logger": load_group("logger", logger),
        "seed": 0, "device": "cpu", "eval_seed": 2024, "resume": False, "progress": False,
        "run_dir": f"runs/{experiment}/{policy}/seed{top.get('seed', 0)}",
        "policy_id": policy,
    })
    for key, value in top.items():
        cfg[key] = value
    for key, value in overrides.items():
        OmegaConf.update(cfg, key, value, force_add=False)
    cfg["cli_overrides"] = [f"{k}={v}" for k, v in overrides.items()]
    return cfg


def resolve_config(cfg: DictConfig | dict) -> ResolvedConfig:
    """Validate every group of a train config; errors name the group and field."""
    if isinstance(cfg, dict):
        cfg = OmegaConf.create(cfg)
    policy = validate_policy(cfg.policy)
    if policy.kind != "learned":
        raise ConfigError(f"policy {policy.name!r} is rule-based: there is nothing to train (evaluate it instead)")
    experiment = validate_experiment(cfg.experiment)
    algo_node = cfg.get("algo")
    if algo_node is not None:
        # Precedence: algo YAML < the experiment's algo_overrides < the user's own algo.* overrides.
        extra = experiment.algo_overrides.get(str(algo_node.get("name")), {})
        algo_node = OmegaConf.merge(algo_node, extra, _user_overrides(cfg, "algo"))
    algo = validate_algo(algo_node)
    scenario_node = OmegaConf.to_container(cfg.scenario, resolve=True)
    # Precedence: scenario YAML < the policy's env block < the user's own scenario.* overrides.
    user = OmegaConf.to_container(_user_overrides(cfg, "scenario"))
    scenario = load_scenario(scenario_node, **{**policy.env, **user})
    train_scenario = load_scenario(scenario_node, **{**policy.env, **experiment.train_env, **user})
    policy_id = cfg.get("policy_id") or _hydra_choice("policy") or policy.name.lower().replace("-", "_")
    return ResolvedConfig(
        scenario=scenario, train_scenario=train_scenario, policy=policy, policy_id=str(policy_id), algo=algo, experiment=experiment,
        logger=validate_logger(cfg.logger), seed=int(cfg.seed), device=str(cfg.device),
        run_dir=Path(str(cfg.run_dir)), resume=_resume_mode(cfg.resume), progress=bool(cfg.get("progress", True)),
        eval_seed=int(cfg.get("eval_seed", 2024)),
    )


def _resume_mode(value: Any) -> bool | str:
    if isinstance(value, bool):
        return value
    if str(value).lower() in ("auto", "true", "false"):
        return {"auto": "auto", "true": True, "false": False}[str(value).lower()]
    raise ConfigError(f"field 'resume': must be true, false or auto, got {value!r}")


def _user_overrides(cfg: DictConfig, group: str) -> DictConfig:
    """``<group>.*`` overrides the user gave (``cli_overrides``: Hydra's task overrides), so they
    can be applied after the experiment's or policy's own patches."""
    dotlist = []
    for item in cfg.get("cli_overrides") or []:
        key, sep, value = str(item).lstrip("+~").partition("=")
        if sep and key.startswith(group + "."):
            dotlist.append(f"{key[len(group) + 1:]}={value}")
    return OmegaConf.from_dotlist(dotlist)


def _hydra_choice(group: str) -> str | None:
    try:
        from hydra.core.hydra_config import HydraConfig

        return HydraConfig.get().runtime.choices.get(group)
    except Exception:
        return None


# ---------------------------------------------------------------------------------------
class _EpisodeLog:
    """Append-only CSV of finished training episodes (for Fig. 4), truncated on resume."""

    def __init__(self, path: Path, keep_up_to: int | None) -> None:
        self.path = path
        rows: list[list[str]] = []
        if keep_up_to is not None and path.is_file():
            with path.open() as handle:
                reader = csv.reader(handle)
                next(reader, None)
                rows = [r for r in reader if r and int(r[0]) <= keep_up_to]
        tmp = path.with_suffix(".tmp")
        with tmp.open("w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(EPISODE_COLUMNS)
            writer.writerows(rows)
        os.replace(tmp, path)
        self.handle = path.open("a", newline="")
        self.writer = csv.writer(self.handle)

    def write(self, rows: list[list[Any]]) -> None:
        self.writer.writerows(rows)
        self.handle.flush()

    def close(self) -> None:
        self.handle.close()


def _make_logger(cfg: ResolvedConfig):
    backend = cfg.logger.backend
    name = f"{cfg.policy_id}_seed{cfg.seed}"
    if backend == "none":
        return None
    if backend == "csv":
        from torchrl.record.loggers import CSVLogger

        return CSVLogger(exp_name="logs", log_dir=str(cfg.run_dir))
    if backend == "wandb":
        os.environ.setdefault("WANDB_MODE", cfg.logger.mode)
        from torchrl.record.loggers import WandbLogger

        return WandbLogger(exp_name=name, offline=cfg.logger.mode == "offline", save_dir=str(cfg.run_dir),
                           project=cfg.logger.project)
    if backend == "tensorboard":
        try:
            import tensorboard  # noqa: F401
        except ImportError as exc:
            raise ConfigError("logger=tensorboard needs `pip install tensorboard`") from exc
        from torchrl.record.loggers import TensorboardLogger

        return TensorboardLogger(exp_name=name, log_dir=str(cfg.run_dir / "tensorboard"))
    raise ConfigError(f"logger field 'backend': unknown logger {backend!r}")


def _agentwise_done(batch: TensorDictBase, n_agents: int) -> TensorDictBase:
    """Give the losses per-UAV ``done`` / ``terminated`` (the env shares them across the swarm)."""
    for key in ("done", "terminated"):
        value = batch.get(("next", key))
        batch.set(("next", "agents", key), value.unsqueeze(-2).expand(*value.shape[:-1], n_agents, 1))
    return batch


def _meta(cfg: ResolvedConfig) -> dict[str, Any]:
    return {
        "policy": cfg.policy.name,
        "policy_id": cfg.policy_id,
        "env": dict(cfg.policy.env),
        "scenario": dataclasses.asdict(cfg.scenario),
        "n_agents": cfg.scenario.n_uavs,
        "algo": cfg.algo.name,
        "critic_input": cfg.policy.critic_input,
        "stochastic": cfg.algo.name != "ddpg",
        "hidden": cfg.algo.hidden,
        "depth": cfg.algo.depth,
        "obs_dim": 2 + 2 * cfg.scenario.n_scan + 3 * cfg.scenario.n_cam,
    }


def _check_resume_fits(payload: dict, cfg: ResolvedConfig, meta: dict) -> None:
    old = payload["meta"]
    for key in ("policy", "algo", "critic_input", "obs_dim", "n_agents", "hidden", "depth"):
        if old.get(key) != meta.get(key):
            raise CheckpointError(
                f"checkpoint in {cfg.run_dir} does not fit this run: {key} is {old.get(key)!r} there, "
                f"{meta.get(key)!r} here")


def train(cfg: DictConfig | dict) -> TrainResult:
    """Train one learned policy; see ``conf/train.yaml`` for the fields."""
    rc = resolve_config(cfg)
    exp = rc.experiment
    run_dir = rc.run_dir
    ckpt_path = run_dir / LAST
    payload = None
    if rc.resume is True or (rc.resume == "auto" and ckpt_path.exists()):
        payload = load_checkpoint(ckpt_path)  # raises a clear error when absent or corrupted
    elif ckpt_path.exists() and rc.resume is False:
        raise CheckpointError(f"{run_dir} already holds a checkpoint; pass resume=true to continue it, "
                              "or choose another run_dir (nothing was changed)")
    torch.manual_seed(rc.seed)
    device = torch.device(rc.device)
    n_agents = rc.scenario.n_uavs
    per_worker = exp.num_envs // exp.workers

    def env_factory(worker: int = 0):
        return FlockingEnv(rc.train_scenario, num_envs=per_worker, device=device, seed=rc.seed * 1000 + worker)

    env = env_factory()
    learner = make_learner(env, rc.algo, rc.policy.critic_input)
    meta = _meta(rc)
    counters = {"frames": 0, "episodes": 0, "updates": 0, "iterations": 0, "seconds": 0.0}
    buffer = None
    if learner.off_policy:
        batch_swarm = max(1, math.ceil(rc.algo.batch_size / n_agents))
        capacity = max(batch_swarm, math.ceil(rc.algo.buffer_size / n_agents))
        buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(capacity, device=device), batch_size=batch_swarm)
    if payload is not None:
        _check_resume_fits(payload, rc, meta)
        learner.load_state_dict(payload["learner"])
        counters.update(payload["counters"])
        if buffer is not None:
            if "buffer" not in payload:
                raise CheckpointError(f"checkpoint in {run_dir} holds no replay buffer; it cannot be resumed exactly")
            buffer.load_state_dict(payload["buffer"])
        if exp.workers == 1:
            env.set_state(payload["env_state"])
    # Only now, with the checkpoint (if any) known to fit, does the run folder change.
    run_dir.mkdir(parents=True, exist_ok=True)
    OmegaConf.save(OmegaConf.create(_as_plain(cfg)), run_dir / "config.yaml")

    steps = exp.steps_per_batch if learner.off_policy else rc.algo.rollout_steps
    frames_per_batch = exp.num_envs * steps
    init_random = max(0, exp.init_random_frames - counters["frames"]) if learner.off_policy else 0
    collector_kwargs = dict(frames_per_batch=frames_per_batch, total_frames=-1, device=device,
                            init_random_frames=init_random or None, exploration_type=ExplorationType.RANDOM,
                            auto_register_policy_transforms=False)
    if exp.workers > 1:
        collector = MultiSyncCollector([functools.partial(env_factory, w) for w in range(exp.workers)],
                                       learner.collector_policy, **collector_kwargs)
    else:
        collector = Collector(env, learner.collector_policy, track_traj_ids=False, **collector_kwargs)
    if payload is not None:
        torch.set_rng_state(payload["rng"]["torch"])

    logger = _make_logger(rc)
    episode_log = _EpisodeLog(run_dir / "episodes.csv", counters["episodes"] if payload is not None else None)
    evaluations: list[dict[str, float]] = list(payload.get("evaluations", [])) if payload else []
    progress = _progress(rc, counters)
    next_eval = _next_multiple(counters["frames"], exp.eval_every_frames)
    next_ckpt = _next_multiple(counters["frames"], exp.checkpoint_every_frames)
    start = time.perf_counter() - counters["seconds"]
    recent: list[tuple[float, bool]] = []

    def save() -> Path:
        counters["seconds"] = time.perf_counter() - start
        state = {
            "format": FORMAT, "meta": meta, "config": _as_plain(cfg), "counters": dict(counters),
            "actor": learner.actor.state_dict(), "learner": learner.state_dict(),
            "rng": {"torch": torch.get_rng_state()}, "evaluations": evaluations,
        }
        if exp.workers == 1:
            state["env_state"] = env.get_state()
        if buffer is not None and exp.keep_buffer_in_checkpoint:
            state["buffer"] = buffer.state_dict()
        return atomic_save(state, ckpt_path)

    def evaluate_now() -> dict[str, float]:
        result = _evaluate_during_training(learner.actor, rc)
        result["frames"] = counters["frames"]
        evaluations.append(result)
        if logger is not None:
            for key, value in result.items():
                if key != "frames":
                    logger.log_scalar(f"eval/{key}", value, step=counters["frames"])
        return result

    t_last = time.perf_counter()  # end of the previous iteration: collection time is measured from here
    already_done = _done(exp, counters, counters["seconds"])  # resuming a finished run changes nothing
    try:
        for batch in ([] if already_done else collector):
            t_collect_end = time.perf_counter()
            frames = batch.numel()
            counters["frames"] += frames
            counters["iterations"] += 1
            batch = _agentwise_done(batch, n_agents)
            rows = _finished_episodes(batch, counters)
            if rows:
                episode_log.write(rows)
                recent.extend((r[2], bool(r[3])) for r in rows)
                recent = recent[-100:]
            if hasattr(learner, "on_frames"):
                learner.on_frames(frames)
            stats: dict[str, float] = {}
            t_update = time.perf_counter()
            n_updates = 0
            if learner.off_policy:
                buffer.extend(batch.select(*TRANSITION_KEYS, strict=False).reshape(-1))
                if counters["frames"] >= exp.init_random_frames and len(buffer) >= buffer.batch_size:
                    for _ in range(exp.updates_per_batch):
                        stats = learner.update(buffer.sample().to(device))
                        n_updates += 1
            else:
                stats = learner.update(batch)
                n_updates = 1
            counters["updates"] += n_updates
            update_seconds = time.perf_counter() - t_update
            collector.update_policy_weights_()

            log = {f"train/{k}": v for k, v in stats.items()}
            if recent:
                log["train/episode_reward"] = sum(r for r, _ in recent) / len(recent)
                log["train/success_rate"] = sum(s for _, s in recent) / len(recent)
            log["perf/updates_per_s"] = n_updates / update_seconds if update_seconds > 0 else 0.0
            log["perf/frames_per_s"] = frames / max(t_collect_end - t_last, 1e-9)
            t_last = time.perf_counter()
            if logger is not None:
                for key, value in log.items():
                    logger.log_scalar(key, value, step=counters["frames"])
            progress.update(counters, log)

            if exp.eval_every_frames and counters["frames"] >= next_eval:
                next_eval = _next_multiple(counters["frames"], exp.eval_every_frames)
                result = evaluate_now()
                progress.write(f"eval @ {counters['frames']} frames: success {result['success']:.3f} "
                               f"safe_success {result['safe_success']:.3f}")
            if exp.checkpoint_every_frames and counters["frames"] >= next_ckpt:
                next_ckpt = _next_multiple(counters["frames"], exp.checkpoint_every_frames)
                save()
            if _done(exp, counters, time.perf_counter() - start):
                break
    except FloatingPointError as exc:
        progress.write(f"stopping: {exc}; the last good checkpoint is kept at {ckpt_path}")
        raise
    finally:
        collector.shutdown()
        episode_log.close()
        progress.close()
    if exp.eval_episodes and (not evaluations or evaluations[-1]["frames"] != counters["frames"]):
        evaluate_now()  # every run ends with an evaluation of what it ships
    path = save()
    if rc.logger.backend == "wandb" and logger is not None:
        logger.experiment.finish()
    return TrainResult(run_dir, path, counters["frames"], counters["episodes"], counters["updates"],
                       counters["seconds"], evaluations)


def _as_plain(cfg: DictConfig | dict) -> dict:
    if isinstance(cfg, DictConfig):
        try:
            return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
        except Exception:
            return OmegaConf.to_container(cfg, resolve=False)  # type: ignore[return-value]
    return dict(cfg)


def _next_multiple(frames: int, every: int) -> int:
    return (frames // every + 1) * every if every else math.inf  # type: ignore[return-value]


def _done(exp: ExperimentConfig, counters: dict, elapsed: float) -> bool:
    return bool((exp.max_frames and counters["frames"] >= exp.max_frames)
                or (exp.max_episodes and counters["episodes"] >= exp.max_episodes)
                or (exp.max_minutes and elapsed >= 60 * exp.max_minutes))


def _finished_episodes(batch: TensorDictBase, counters: dict) -> list[list[Any]]:
    """CSV rows for the episodes that ended in this batch (frames counted at batch end)."""
    done = batch.get(("next", "done")).squeeze(-1)
    if not done.any():
        return []
    ep = batch.get(("next", "episode"))[done]
    rows = []
    for i in range(ep.shape[0]):
        counters["episodes"] += 1
        rows.append([counters["episodes"], counters["frames"], round(float(ep["return"][i]), 5),
                     int(ep["success"][i]), int(ep["safe_success"][i]), round(float(ep["d_min_obs"][i]), 4),
                     round(float(ep["d_min_uav"][i]), 4), round(float(ep["d_c"][i]), 4),
                     round(float(ep["v_error"][i]), 4), round(float(ep["phi_error"][i]), 4),
                     round(float(ep["speed"][i]), 4), round(float(ep["t_goal"][i]), 2), int(ep["steps"][i])])
    return rows


def _evaluate_during_training(actor, rc: ResolvedConfig) -> dict[str, float]:
    from .evaluation import evaluate

    result = evaluate(actor, scenario=dataclasses.asdict(rc.scenario), n_episodes=rc.experiment.eval_episodes,
                      seed=rc.eval_seed, device=rc.device)
    row = {k: float(v) for k, v in result.summary().items() if isinstance(v, (int, float))}
    row["success"], row["safe_success"] = row["success_rate"], row["safe_success_rate"]
    return row


class _progress:
    """tqdm bar over frames (or a no-op)."""

    def __init__(self, rc: ResolvedConfig, counters: dict) -> None:
        self.bar = None
        if rc.progress:
            from tqdm.auto import tqdm

            total = rc.experiment.max_frames or None
            self.bar = tqdm(total=total, initial=counters["frames"], unit="frame", dynamic_ncols=True,
                            desc=f"{rc.policy.name} seed {rc.seed}")
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
