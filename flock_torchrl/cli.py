"""The command-line apps: every script is a ``hydra.main`` app on the package's ``conf/``.

Hydra composes each job (the user's ``--config-dir``, ``hydra.searchpath``, sweepers and
launchers work as anywhere else); then, for every app alike:

* :class:`PreRunCheck`, a Hydra callback configured in each app's YAML, converts and checks
  the config of every job of a sweep before Hydra creates any folder (the running Hydra's own
  config loader composes each job; sweeps whose values are not a list, e.g. Optuna's
  intervals, are checked job by job as they start). A bad value prints one line,
  ``error: scenario.n_uavs: must be an integer >= 1, got 0``, and exits with status 2.
  Errors of the composition itself (an unknown choice, a value of the wrong type) are
  Hydra's own messages (status 1);
* the job converts its config to the app's schema once (reusing the check's object when it
  runs in the same process) and runs it; errors it meets later (a busy run folder, a
  corrupted checkpoint) also print one line and exit 2; a training stopped by a signal exits
  with 128 + the signal's number after printing the command that resumes it.

Each app is a schema (``flock_torchrl.config``), a ``prepare`` that checks what the schema
cannot (files, checkpoints, the swarm's spawn, memory) and a ``run``.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import os
import signal
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

from .io import shown, write_failure
from .run.signals import APP_SIGNALS, Stopped, TrainingInterrupted, end_with_parent, job_tag, leave, orphaned, say

from .config import (APP_SCHEMAS, CONF_DIR, ConfigError, EvaluateConfig, FiguresConfig, ReproduceConfig, ScalingConfig,
                     Schema, ShipConfig, TrainConfig, TuneConfig, register)
from .config.apps import DiagnoseConfig
from .config.compose import check_boolean_overrides
from .prerun import (AppError, blame, check_launcher, check_resume_folder, check_trained_dims, check_writable,
                     check_yaml_files, composed_yaml_files, config_folders, sweep_direction, sweep_jobs)

EXIT_ERROR = 2
# The resolvers and schemas the apps' YAMLs use, registered when the apps are imported: a
# launcher's worker process (joblib) unpickles this module's callback and task, and Hydra
# resolves the job's folder names before the task starts.
register()


def _errors() -> tuple[type[BaseException], ...]:
    from .run.publication import ERRORS  # ConfigError, CheckpointError, SpawnError, PublishError

    return AppError, *ERRORS


def fail(message: Any) -> None:
    """Print ``error: <message>`` (one line) and exit with status 2."""
    say(f"error: {' '.join(str(message).split())}")
    raise SystemExit(EXIT_ERROR)


# ---------------------------------------------------------------------------- the apps
@dataclass(frozen=True)
class App:
    """A command-line app: its schema, the checks beyond the schema, what it runs."""

    schema: type[Schema]
    prepare: Callable[[Any, Path], None]
    run: Callable[[Any, Path], Any]


def _set_threads(cfg: Any) -> None:
    """``threads`` of an app that has it (0: torch's default)."""
    if getattr(cfg, "threads", 0):
        import torch

        torch.set_num_threads(int(cfg.threads))


def _say(message: str) -> None:
    print(job_tag() + message, flush=True)


def _calls(module: str, name: str, **kwargs: Any) -> Callable[[Any, Path], Any]:
    """``<module>.<name>(cfg, out, **kwargs)``, its module imported only when the app gets there."""
    def call(cfg: Any, out: Path) -> Any:
        return getattr(importlib.import_module(module, __package__), name)(cfg, out, **kwargs)

    return call


def _run_train(cfg: TrainConfig, out: Path) -> float:
    import logging

    from .run.launch import train

    logging.getLogger("torchrl").setLevel(logging.WARNING)  # no "Initialized LazyTensorStorage" lines
    result = train(cfg, out)
    if any(result.split.values()):
        _say(result.split_line())
    else:   # nothing ran in this process: a finished run's folder, resumed (resume=auto)
        _say(f"reused the finished run in {shown(str(Path(result.run_dir).resolve()))} (resume={cfg.resume}): "
             "nothing was trained; its checkpoint and final evaluation follow (remove the folder to train it anew)")
    _say(f"checkpoint: {result.checkpoint} ({result.frames} frames, {result.episodes} episodes, "
         f"{result.updates} updates, {result.seconds:.0f} s)")
    last = result.evaluations[-1] if result.evaluations else {}
    if last:
        _say(f"evaluation ({int(last['n_episodes'])} episodes, seed {cfg.eval_seed}, deterministic): "
             f"success {last['success']:.3f}, safe_success {last['safe_success']:.3f}, "
             f"d_min_uav {last['d_min_uav']:.3f}, d_c {last['d_c']:.3f}, t_goal {last['t_goal']:.2f} s")
    return float(last.get(cfg.objective, float("nan")))


# -- evaluate
def _prepare_evaluate(cfg: EvaluateConfig, out: Path) -> None:
    from .run.evaluation import check_evaluation, evaluated_handles
    from .world.memory import check_episodes_memory
    from .world.spawn import check_spawn_feasible

    check_spawn_feasible(cfg.scenario)
    check_episodes_memory(cfg.scenario, cfg.episodes)
    check_evaluation(cfg)
    if cfg.contender is None:  # a contender's checkpoint met a real env in check_evaluation
        check_trained_dims(evaluated_handles(cfg), cfg.scenario)


def _run_evaluate(cfg: EvaluateConfig, out: Path) -> Any:
    from .run.evaluation import evaluate_app

    return evaluate_app(cfg, out, log=_say).rate("success").rate


# -- reproduce, figures, scaling (their runs: the report's functions)
def _prepare_reproduce(cfg: ReproduceConfig, out: Path) -> None:
    from .report.reproduce import check_table_inputs
    from .world.memory import check_episodes_memory

    check_episodes_memory(cfg.scenario, cfg.episodes)
    check_table_inputs(cfg.table, cfg.scenario.reading, cfg.checkpoints_dir, cfg.paper_recipe_dir, cfg.only,
                       recipe=cfg.recipe, contenders=cfg.contenders, compare_to=cfg.compare_to)


def _run_reproduce(cfg: ReproduceConfig, out: Path) -> None:
    from .report.reproduce import reproduce

    result = reproduce(cfg, out, log=_say)
    if result["failed"]:
        raise AppError(f"Table {cfg.table}: rows not evaluated: {', '.join(result['failed'])} (see above)")


def _prepare_figures(cfg: FiguresConfig, out: Path) -> None:
    from .report.figures import check_figure_inputs

    check_figure_inputs(cfg.scenario.reading, cfg.figs, cfg.checkpoints_dir)


def _prepare_scaling(cfg: ScalingConfig, out: Path) -> None:
    from .policies.registry import resolve
    from .world.memory import check_episodes_memory

    check_episodes_memory(dataclasses.replace(cfg.scenario, n_uavs=max(cfg.sizes)), cfg.episodes)
    for policy in (cfg.policy_name, *cfg.others):
        check_trained_dims(resolve(policy, cfg.scenario.reading, cfg.checkpoints_dir, device=cfg.device), cfg.scenario)


# -- ship, tune
def _prepare_ship(cfg: ShipConfig, out: Path) -> None:
    key, runs_dir = ((f"scenario_collections.{cfg.only}.runs_dir", cfg.scenario_collections[cfg.only]["runs_dir"])
                     if cfg.only is not None else ("runs_dir", cfg.runs_dir))
    if not Path(runs_dir).is_dir():
        raise ConfigError(key, f"{runs_dir} is not a folder of runs")


def _run_ship(cfg: ShipConfig, out: Path) -> None:
    from .run.shipping import ship_checkpoints, ship_scenario_collection

    if cfg.only is not None:   # one collection of another scenario's runs, alone
        spec = cfg.scenario_collections[cfg.only]
        source = Path(spec["runs_dir"]) / spec["experiment"] / cfg.scenario.reading
        if not source.is_dir():
            _say(f"nothing to ship under {source}")
            return
        ship_scenario_collection(cfg.scenario.reading, Path(spec["runs_dir"]), spec["experiment"], list(spec["names"]),
                                 Path(cfg.checkpoints_dir) / cfg.scenario.reading / cfg.only, log=_say,
                                 target=spec.get("target"))
        return
    folders = [Path(cfg.runs_dir) / e / cfg.scenario.reading
               for e in (cfg.experiment, cfg.paper_experiment, *cfg.collections)]
    if not any(f.is_dir() for f in folders):  # nothing trained under this reading: say so
        _say(f"nothing to ship under {', '.join(map(str, folders))}")
        return
    ship_checkpoints(cfg.scenario.reading, cfg.experiment, Path(cfg.runs_dir), Path(cfg.checkpoints_dir),
                     cfg.paper_experiment, Path(cfg.paper_recipe_dir), log=_say, collections=dict(cfg.collections))


def _prepare_tune(cfg: TuneConfig, out: Path) -> None:
    from .report.tuning import GRIDS

    unknown = sorted(set(cfg.controllers) - set(GRIDS))
    if unknown:
        raise ConfigError("controllers", f"unknown {unknown}; known: {sorted(GRIDS)}")


# -- diagnose
def _prepare_diagnose(cfg: Any, out: Path) -> None:
    from .config import scenario_config
    from .policies.registry import resolve
    from .report.diagnosis import check_diagnosis, diagnosed_checkpoints

    check_diagnosis(cfg)
    handles = [h for paths in diagnosed_checkpoints(cfg).values() for p in paths
               for h in resolve(p, cfg.scenario.reading, device=cfg.device)[:1]]  # the one diagnose flies
    for name in cfg.scenarios:
        check_trained_dims(handles, scenario_config(name, reading=cfg.scenario.reading), "scenarios", f"{name}'s ")


APPS: dict[str, App] = {
    "train": App(TrainConfig, _calls(".run.setup", "prepare"), _run_train),
    "evaluate": App(EvaluateConfig, _prepare_evaluate, _run_evaluate),
    "reproduce": App(ReproduceConfig, _prepare_reproduce, _run_reproduce),
    "figures": App(FiguresConfig, _prepare_figures, _calls(".report.figures", "make_figures", log=_say)),
    "scaling": App(ScalingConfig, _prepare_scaling, _calls(".report.scaling", "scaling", log=_say)),
    "ship": App(ShipConfig, _prepare_ship, _run_ship),
    "tune_baselines": App(TuneConfig, _prepare_tune, _calls(".report.tuning", "tune_app", log=_say)),
    "diagnose": App(DiagnoseConfig, _prepare_diagnose, _calls(".report.diagnosis", "diagnose_app", log=_say)),
}
assert set(APPS) == set(APP_SCHEMAS)


# ---------------------------------------------------------------------------- checked once
# Configs checked by PreRunCheck in this process, by their YAML: the job that runs one of them
# takes the checked object instead of converting and checking it again.
_CHECKED: dict[str, Schema] = {}


def _task_yaml(cfg: DictConfig) -> str:
    task = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]) if "hydra" in cfg else cfg
    return OmegaConf.to_yaml(task, resolve=True)


def _task_overrides(cfg: DictConfig) -> list[str]:
    """The command line's overrides of the job ``cfg`` (its own ``hydra`` node, or the running job's)."""
    from hydra.core.hydra_config import HydraConfig

    if "hydra" in cfg:
        return [str(o) for o in cfg.hydra.overrides.task]
    return [str(o) for o in HydraConfig.get().overrides.task] if HydraConfig.initialized() else []


def _adopt_checkpoint_world(config: DictConfig) -> None:
    """``checkpoint=`` without ``policy=``: the run's config (which Hydra then runs, and names its
    output folder from) takes the checkpoint's policy and world (:func:`checkpoint_world`)."""
    from .run.evaluation import checkpoint_world

    world = checkpoint_world(config, _task_overrides(config))
    if world is not config:
        with read_write(config), open_dict(config):
            config.policy = world.policy
            config.scenario = world.scenario


def checked(app: str, cfg: DictConfig, out: Path, key: str = "hydra.run.dir") -> Schema:
    """``cfg`` as the app's checked schema object, prepared for ``out`` (or the error); ``key``:
    the setting that chose ``out``."""
    overrides = _task_overrides(cfg)
    check_boolean_overrides(cfg, overrides)  # a value OmegaConf would have converted: 2 for true
    if app == "evaluate":  # checkpoint= without policy=: the checkpoint's policy and its world
        from .run.evaluation import checkpoint_world

        cfg = checkpoint_world(cfg, overrides)
    obj = APPS[app].schema.from_config(cfg)
    check_writable(out, key)
    APPS[app].prepare(obj, out)
    return obj


def _guard(fn: Callable[[], Any], config: DictConfig | None = None) -> Any:
    """Run ``fn``; report this project's errors as one line with exit status 2 (a config error
    also names the file its group's choice came from, when that is a file)."""
    try:
        return fn()
    except _errors() as exc:
        if config is None or not getattr(exc, "key", ""):
            fail(exc)
        key, source = blame(config, exc.key, getattr(exc, "also", ()))
        message = f"{key}: {exc.message}" if key != exc.key else str(exc)
        fail(f"{message} (in {source})" if source else message)
    except OSError as exc:  # a full disk, a file-size limit, a folder that cannot be written
        if write_failure(exc) is None:
            raise
        fail(f"{write_failure(exc)}; files are written whole or not at all, nothing half-written was left")


class PreRunCheck(Callback):
    """Check every job of a run or a sweep before Hydra creates anything (``hydra.callbacks``)."""

    def __init__(self, app: str) -> None:
        if app not in APPS:
            raise ValueError(f"unknown app {app!r}; known: {sorted(APPS)}")
        self.app = app

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        if self.app == "train":
            _guard(lambda: check_resume_folder(config))
        if self.app == "evaluate":  # the job's config and folder name the checkpoint's policy
            _guard(lambda: _adopt_checkpoint_world(config), config)
        out = Path(str(config.hydra.run.dir))
        _CHECKED[_task_yaml(config)] = _guard(lambda: checked(self.app, config, out), config)
        APP_SIGNALS.arm()

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check_sweep(config)
        launcher = str(config.hydra.launcher.get("_target_", "")).lower()
        APP_SIGNALS.arm(jobs_elsewhere="joblib" in launcher)  # the jobs run in joblib's local worker processes

    def _check_sweep(self, config: DictConfig) -> None:
        _guard(lambda: check_launcher(config))
        _guard(lambda: sweep_direction(config), config)
        jobs = sweep_jobs(config)
        if jobs is None:  # not a list of values (an Optuna interval ...): each job checks itself
            return
        from hydra.core.global_hydra import GlobalHydra

        loader = GlobalHydra.instance().config_loader()
        for overrides in jobs:
            job = loader.load_sweep_config(config, list(overrides))
            out = Path(str(job.hydra.sweep.dir)) / str(job.hydra.sweep.subdir)
            _CHECKED[_task_yaml(job)] = _guard(lambda: checked(self.app, job, out, "hydra.sweep.dir"), job)


# ---------------------------------------------------------------------------- the mains
def _task(app: str) -> Callable[[DictConfig], Any]:
    def task(cfg: DictConfig) -> Any:
        from hydra.core.hydra_config import HydraConfig

        out = Path(HydraConfig.get().runtime.output_dir)
        stopped = APP_SIGNALS.worker_stopped()
        if stopped:  # joblib hands out the jobs it holds: they do not start
            say(f"not started: {out} (the sweep was stopped by {signal.Signals(stopped).name})")
            return 128 + stopped
        parent = os.getppid() if APP_SIGNALS.in_sweep_worker() else 0
        if parent:  # a job worker: it ends with the sweep's process, even a killed one
            end_with_parent(parent)
        try:
            obj = _CHECKED.pop(_task_yaml(cfg), None) or _guard(lambda: checked(app, cfg, out))
            APP_SIGNALS.arm()  # also where no PreRunCheck ran (a config without the callback)
            _set_threads(obj)
            return _guard(lambda: APPS[app].run(obj, out))
        except TrainingInterrupted as exc:
            say(f"{exc}: checkpoint {exc.result.checkpoint} ({exc.result.frames} frames); resume with: {exc.command}")
            if APP_SIGNALS.in_sweep_worker():  # an exit here would make joblib cancel the jobs still checkpointing
                APP_SIGNALS.mark_worker_stopped(exc.signum)
                return exc.exit_status
            raise SystemExit(exc.exit_status) from None
        finally:
            if parent and orphaned(parent):  # the sweep's process is gone: nobody waits for this worker
                leave(128 + signal.SIGTERM)

    task.__name__ = app
    return task


def main(app: str, noted: list[int] | None = None) -> Any:
    """Run the Hydra app ``app`` on ``sys.argv`` (a console script or ``scripts/<app>.py``);
    ``noted``: stop signals a script noted while it imported the package (``scripts/_start.py``):
    the app stops on the first at once, in one line, before it reads or writes anything."""
    import hydra

    try:
        APP_SIGNALS.start(noted)
        if APP_SIGNALS.noted:
            raise Stopped(APP_SIGNALS.noted[0])
        _guard(lambda: check_yaml_files(composed_yaml_files(config_folders(sys.argv[1:]), app, sys.argv[1:])))
        result = hydra.main(version_base=None, config_path=str(CONF_DIR), config_name=app)(_task(app))()
        stopped = APP_SIGNALS.sweep_stopped()
        if stopped:  # a joblib sweep stopped: its jobs said so
            raise SystemExit(128 + stopped)
        return result
    except Stopped as stop:
        say(stop.message())
        raise SystemExit(128 + stop.signum) from None


# The console scripts' entry points (pyproject.toml's flock-<app>; scripts/<app>.py call main itself).
train_main = functools.partial(main, "train")
evaluate_main = functools.partial(main, "evaluate")
reproduce_main = functools.partial(main, "reproduce")
figures_main = functools.partial(main, "figures")
scaling_main = functools.partial(main, "scaling")
ship_main = functools.partial(main, "ship")   # the named step that updates checkpoints/
tune_baselines_main = functools.partial(main, "tune_baselines")
diagnose_main = functools.partial(main, "diagnose")


__all__ = ["APPS", "App", "AppError", "PreRunCheck", "checked", "diagnose_main", "evaluate_main", "fail",
           "figures_main", "main", "reproduce_main", "scaling_main", "ship_main", "sweep_jobs",
           "train_main", "tune_baselines_main"]
