"""The evaluate app (``conf/evaluate.yaml``, ``scripts/evaluate.py``): one policy's shipped seeds,
a checkpoint or a contender on one scenario by the section 5 protocol, taking its checked config."""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path
from typing import Callable, Sequence

from omegaconf import DictConfig, OmegaConf, open_dict

from ..config import ConfigError, EvaluateConfig
from ..config.paths import seeds_dir
from ..policies.registry import (PolicyHandle, checkpoint_handle, contender_handle, policy_config_of, resolve,
                                 shipped_checkpoints, world_label)
from .results import EvaluationResult, write_result
from .rollout import evaluate_handle, try_contender


def evaluated_handles(cfg: EvaluateConfig) -> list[PolicyHandle]:
    """What ``cfg`` evaluates: the contender, the checkpoint (a population's: every member, or
    ``member``), or the policy's shipped seeds of the scenario's dimension (a 3-D scenario's:
    ``<checkpoints_dir>/<reading>/threed/<policy>/``)."""
    if cfg.contender is not None:
        return [contender_handle(cfg.contender, cfg.device, key="contender")]
    handles = resolve(cfg.checkpoint or cfg.policy.id, cfg.scenario.reading, cfg.checkpoints_dir,
                      device=cfg.device, policy_config=None if cfg.checkpoint else cfg.policy, member=cfg.member,
                      dims=cfg.scenario.dims)
    if cfg.checkpoint and handles[0].id != cfg.policy.id:
        raise ConfigError("policy", f"{cfg.checkpoint} holds {handles[0].name}, not {cfg.policy.name}: leave policy= "
                                    f"out (the checkpoint's policy is taken) or pass policy={handles[0].id}")
    return handles


def checkpoint_world(cfg: DictConfig, overrides: Sequence[str]) -> DictConfig:
    """The evaluate app's composed ``cfg`` in the world of the policy it evaluates: of its
    ``checkpoint``, that policy's ``policy`` node (when the command line, ``overrides``, chose no
    ``policy=``) and the scenario fields it flies with; of a learned ``policy=`` without one, the
    scenario fields its shipped seeds fly with (those of the scenario's dimension). The fields the
    command line sets itself stay (a conflict is then :func:`~.rollout.policy_env`'s one-line
    error). With another ``policy=`` given than the checkpoint's, ``cfg`` as it is
    (:func:`evaluated_handles` refuses a policy other than the checkpoint's)."""
    given = {str(o).lstrip("+~").split("=", 1)[0] for o in overrides}
    if cfg.get("contender") is not None:
        return cfg
    if cfg.get("checkpoint"):
        handle = resolve(str(cfg.checkpoint), member=cfg.get("member"))[0]  # a population's members share their policy
        if handle.id != cfg.policy.id and "policy" in given:
            return cfg
    else:
        handle = shipped_seed(cfg)
        if handle is None:
            return cfg
    out = copy.deepcopy(cfg)
    with open_dict(out):
        if handle.id != cfg.policy.id:
            out.policy = OmegaConf.structured(policy_config_of(handle.id, str(cfg.scenario.reading))[0])
        # The fields it was trained with, also where its policy's config now sets others (a field
        # added since it was written: docs/specification.md section 11's taper and vertical beams).
        for key, value in handle.scenario.items():
            if f"scenario.{key}" not in given:
                out.scenario[key] = value
    return out


def shipped_seed(cfg: DictConfig) -> PolicyHandle | None:
    """The first shipped seed of a learned ``cfg.policy`` under ``cfg.checkpoints_dir``, in the
    scenario's dimension (its seeds share the world they were trained in); ``None`` for a
    rule-based policy or where none is shipped (:func:`evaluated_handles` then says so)."""
    if cfg.policy.get("kind") != "learned":
        return None
    folder = seeds_dir(str(cfg.checkpoints_dir), str(cfg.scenario.reading), int(cfg.scenario.get("dims", 2)))
    seeds = shipped_checkpoints(str(cfg.policy.id), folder)
    return checkpoint_handle(seeds[0]) if seeds else None


def check_evaluation(cfg: EvaluateConfig) -> None:
    """What the schema cannot check, before any episode: the checkpoints load, and a contender
    acts on a small batch (a bad one is one line before the first episode)."""
    handles = evaluated_handles(cfg)
    if cfg.contender is not None:
        try_contender(handles[0], cfg.scenario, None, cfg.device, key="contender")


def evaluate_app(cfg: EvaluateConfig, out_dir: str | Path, log: Callable[[str], None] = print) -> EvaluationResult:
    """Evaluate what ``cfg`` names for ``cfg.episodes`` episodes each; write ``episodes.csv`` and
    ``summary.json`` (the config beside the pooled result) into ``out_dir``. Build ``cfg`` with
    :func:`flock_torchrl.config.app_config`, e.g. ``app_config("evaluate", policy="policy_ma", scenario="s1")``."""
    results = []
    handles = evaluated_handles(cfg)
    for i, handle in enumerate(handles, 1):
        log(f"[{i}/{len(handles)}] {handle.name} ({handle.source}): {cfg.episodes} episodes on {cfg.scenario.name} ...")
        results.append(evaluate_handle(handle, cfg.scenario, None, cfg.episodes, cfg.seed, cfg.device,
                                       contender_key="contender", log=log))
        world = f"; world: {world_label(handle.scenario)}" if handle.kind == "contender" else ""
        log(f"{results[-1]} [{handle.source}{world}]")
    result = EvaluationResult.pooled(results)
    if len(results) > 1:
        log(f"pooled over {len(results)} checkpoints: {result}")
    record = dataclasses.asdict(cfg)
    if cfg.contender is not None:  # the world it flew in, named in summary.json too
        record["contender_world"] = {**handles[0].scenario, "label": world_label(handles[0].scenario)}
    paths = write_result(result, Path(out_dir), record)
    log("wrote " + " and ".join(str(p) for p in paths))
    return result


__all__ = ["check_evaluation", "checkpoint_world", "evaluate_app", "evaluated_handles", "shipped_seed"]
