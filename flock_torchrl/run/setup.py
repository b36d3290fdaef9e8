"""Everything about a training run that comes before its loop: its config (composed, compared
on resume), the checks that can refuse it before its folder changes, and what its checkpoints
record about the policy."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, Sequence

from omegaconf import DictConfig, OmegaConf

from ..config import POLICY_SCENARIO_FIELDS, ConfigError, TrainConfig, compose, flatten, saved_scenario
from ..policies.checkpoint import LAST, CheckpointError, load_checkpoint
from ..world.memory import check_memory, train_bytes
from ..world.sensors import observation_size
from ..world.spawn import check_spawn_feasible
from .run_folder import resume_command


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
    check_memory(train_bytes(cfg), "the run")  # bytes by the key that sets them
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


def resume_payload(cfg: TrainConfig, resolved: dict[str, Any], run_dir: Path) -> dict | None:
    """The checkpoint a run continues, after every check; ``None`` for a fresh run. Refuses one
    trained with other settings than ``resolved`` (but the ``resumable`` keys)."""
    path = run_dir / LAST
    if cfg.resume_mode == "never" or not path.exists():
        return None
    payload = load_checkpoint(path, kind="training")
    saved = dict(payload["config"])
    saved["scenario"] = saved_scenario(saved["scenario"])  # fields added since it was written: as it was
    diff = config_differences(saved, resolved, cfg.resumable)
    if diff:
        shown = "; ".join(f"{k}: {flatten(payload['config']).get(k, '<absent>')!r} there, "
                          f"{flatten(resolved).get(k, '<absent>')!r} here" for k in diff[:6])
        raise CheckpointError(f"the checkpoint in {run_dir} was trained with other settings ({shown}"
                              f"{' ...' if len(diff) > 6 else ''}); only {', '.join(cfg.resumable)} may "
                              "change on resume (nothing was changed)")
    check_episode_logs(payload, run_dir)
    return payload


def check_episode_logs(payload: dict, run_dir: Path) -> None:
    """A resume continues the run's episode logs (``episodes.csv``, a population member's
    ``seed<s>/episodes.csv``): one that is gone while the checkpoint counts episodes is refused,
    naming it (docs/reliability.md says why it is not rebuilt)."""
    members = payload.get("members") or []
    logs = ([(run_dir / f"seed{m['seed']}" / "episodes.csv", int(m.get("episodes_seen", 0))) for m in members]
            if members else [(run_dir / "episodes.csv", int(payload["counters"].get("episodes", 0)))])
    for path, episodes in logs:
        if episodes and not path.is_file():
            raise CheckpointError(f"{path} is missing, but the checkpoint in {run_dir} counts {episodes} episodes "
                                  "logged there: put it back to resume (nothing was changed), or start a new run")


def checkpoint_meta(cfg: TrainConfig, env: Any) -> dict[str, Any]:
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


def hydra_output_dir() -> Path:
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        raise ConfigError("run_dir", "train() needs run_dir=... when it is not run by Hydra (scripts/train.py)")
    return Path(HydraConfig.get().runtime.output_dir)


def hydra_settings() -> dict[str, Any]:
    """The train app's Hydra settings a run's ``resume.yaml`` repeats (the running app's, or
    conf/train.yaml's)."""
    from hydra.core.hydra_config import HydraConfig

    hydra = HydraConfig.get() if HydraConfig.initialized() else compose("train", return_hydra_config=True).hydra
    return {"job": {"name": str(hydra.job.name), "chdir": bool(hydra.job.chdir)}, "output_subdir": None,
            "callbacks": OmegaConf.to_container(hydra.callbacks, resolve=True) if hydra.callbacks else {}}


__all__ = ["check_episode_logs", "checkpoint_meta", "config_differences", "hydra_output_dir", "hydra_settings",
           "make_train_config", "prepare", "resume_payload"]
