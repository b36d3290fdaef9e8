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
import os
import signal
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from .config import (CONF_DIR, APP_SCHEMAS, ConfigError, EvaluateConfig, FiguresConfig,
                     ReproduceConfig, ScalingConfig, Schema, ShipConfig, TrainConfig, TuneConfig)

EXIT_ERROR = 2


class AppError(Exception):
    """An error a job reports as one line (exit status 2)."""


def _errors() -> tuple[type[BaseException], ...]:
    from .policies.checkpoint import CheckpointError
    from .world.spawn import SpawnError

    return ConfigError, AppError, CheckpointError, SpawnError


def fail(message: Any) -> None:
    """Print ``error: <message>`` (one line) and exit with status 2."""
    print(f"error: {' '.join(str(message).split())}", file=sys.stderr, flush=True)
    raise SystemExit(EXIT_ERROR)


# ---------------------------------------------------------------------------- the apps
@dataclass(frozen=True)
class App:
    """A command-line app: its schema, the checks beyond the schema, what it runs."""

    schema: type[Schema]
    prepare: Callable[[Any, Path], None]
    run: Callable[[Any, Path], Any]


def _set_threads(threads: int) -> None:
    import torch

    if threads:
        torch.set_num_threads(int(threads))


def _say(message: str) -> None:
    print(message, flush=True)


# -- train
def _prepare_train(cfg: TrainConfig, out: Path) -> None:
    from .run.trainer import prepare

    prepare(cfg, out)


def _run_train(cfg: TrainConfig, out: Path) -> float:
    import logging

    from .run.launch import train

    logging.getLogger("torchrl").setLevel(logging.WARNING)  # no "Initialized LazyTensorStorage" lines
    _set_threads(cfg.threads)
    result = train(cfg, out)
    if any(result.split.values()):
        _say(result.split_line())
    _say(f"checkpoint: {result.checkpoint} ({result.frames} frames, {result.episodes} episodes, "
         f"{result.updates} updates, {result.seconds:.0f} s)")
    last = result.evaluations[-1] if result.evaluations else {}
    if last:
        _say(f"evaluation ({int(last['n_episodes'])} episodes, seed {cfg.eval_seed}, deterministic): "
             f"success {last['success']:.3f}, safe_success {last['safe_success']:.3f}, "
             f"d_min_uav {last['d_min_uav']:.3f}, d_c {last['d_c']:.3f}, t_goal {last['t_goal']:.2f} s")
    return float(last.get(cfg.objective, float("nan")))


# -- evaluate
def _evaluate_handles(cfg: EvaluateConfig) -> list:
    from .policies.registry import contender_handle, resolve

    if cfg.contender is not None:
        return [contender_handle(cfg.contender, cfg.device, key="contender")]
    handles = resolve(cfg.checkpoint or cfg.policy.id, cfg.scenario.reading, cfg.checkpoints_dir,
                      device=cfg.device, policy_config=None if cfg.checkpoint else cfg.policy)
    if cfg.checkpoint and handles[0].id != cfg.policy.id:
        raise ConfigError("policy", f"{cfg.checkpoint} holds {handles[0].name}; pass policy={handles[0].id} so that "
                                    "its world is composed")
    return handles


def _prepare_evaluate(cfg: EvaluateConfig, out: Path) -> None:
    from .world.memory import check_episodes_memory
    from .run.rollout import try_contender
    from .world.spawn import check_spawn_feasible

    check_spawn_feasible(cfg.scenario)
    check_episodes_memory(cfg.scenario, cfg.episodes)
    handles = _evaluate_handles(cfg)
    if cfg.contender is not None:  # tried on a small batch now: a bad one is one line before any episode
        try_contender(handles[0], cfg.scenario, None, cfg.device, key="contender")


def _run_evaluate(cfg: EvaluateConfig, out: Path) -> Any:
    from .policies.registry import world_label
    from .run.results import EvaluationResult, write_result
    from .run.rollout import evaluate_handle

    _set_threads(cfg.threads)
    results = []
    handles = _evaluate_handles(cfg)
    for i, handle in enumerate(handles, 1):
        _say(f"[{i}/{len(handles)}] {handle.name} ({handle.origin}): {cfg.episodes} episodes on {cfg.scenario.name} ...")
        results.append(evaluate_handle(handle, cfg.scenario, None, cfg.episodes, cfg.seed, cfg.device,
                                       contender_key="contender", log=_say))
        world = f"; world: {world_label(handle.scenario)}" if handle.kind == "contender" else ""
        _say(f"{results[-1]} [{handle.origin}{world}]")
    result = EvaluationResult.pooled(results)
    if len(results) > 1:
        _say(f"pooled over {len(results)} checkpoints: {result}")
    record = dataclasses.asdict(cfg)
    if cfg.contender is not None:  # the world it flew in, named in summary.json too
        record["contender_world"] = {**handles[0].scenario, "label": world_label(handles[0].scenario)}
    paths = write_result(result, out, record)
    _say("wrote " + " and ".join(str(p) for p in paths))
    return result.rate("success").rate


# -- reproduce, figures, scaling
def _prepare_reproduce(cfg: ReproduceConfig, out: Path) -> None:
    from .report.reproduce import check_table_inputs
    from .world.memory import check_episodes_memory

    check_episodes_memory(cfg.scenario, cfg.episodes)
    check_table_inputs(cfg.table, cfg.scenario.reading, cfg.checkpoints_dir, cfg.paper_recipe_dir, cfg.only,
                       recipe=cfg.recipe, contenders=cfg.contenders, compare_to=cfg.compare_to)


def _run_reproduce(cfg: ReproduceConfig, out: Path) -> None:
    from .report.reproduce import reproduce

    _set_threads(cfg.threads)
    result = reproduce(cfg.table, cfg.scenario.reading, episodes=cfg.episodes, seed=cfg.seed, device=cfg.device,
                       checkpoints_dir=cfg.checkpoints_dir, out_dir=out, only=list(cfg.only) or None,
                       episodes_csv=cfg.episodes_csv, paper_recipe_dir=cfg.paper_recipe_dir,
                       recipe=cfg.recipe, contenders=cfg.contenders, compare_to=cfg.compare_to,
                       compare_tolerance=cfg.compare_tolerance, log=_say)
    if result["failed"]:
        raise AppError(f"Table {cfg.table}: rows not evaluated: {', '.join(result['failed'])} (see above)")


def _prepare_figures(cfg: FiguresConfig, out: Path) -> None:
    from .report.figures import check_figure_inputs

    check_figure_inputs(cfg.scenario.reading, cfg.figs, cfg.checkpoints_dir)


def _run_figures(cfg: FiguresConfig, out: Path) -> None:
    from .report.figures import make_figures

    _set_threads(cfg.threads)
    make_figures(cfg.scenario.reading, out, figs=list(cfg.figs), checkpoints_dir=cfg.checkpoints_dir, seed=cfg.seed,
                 device=cfg.device, paper_recipe_dir=cfg.paper_recipe_dir, log=_say)


def _prepare_scaling(cfg: ScalingConfig, out: Path) -> None:
    from .policies.registry import resolve
    from .world.memory import check_episodes_memory

    check_episodes_memory(dataclasses.replace(cfg.scenario, n_uavs=max(cfg.sizes)), cfg.episodes)
    for policy in (cfg.policy_name, *cfg.others):
        resolve(policy, cfg.scenario.reading, cfg.checkpoints_dir, device=cfg.device)


def _run_scaling(cfg: ScalingConfig, out: Path) -> None:
    from .report.scaling import scaling

    _set_threads(cfg.threads)
    scaling(cfg.policy_name, cfg.scenario.reading, list(cfg.sizes), cfg.episodes, cfg.seed, cfg.checkpoints_dir,
            cfg.device, out, log=_say, others=list(cfg.others))


# -- ship, tune
def _prepare_ship(cfg: ShipConfig, out: Path) -> None:
    if not Path(cfg.runs_dir).is_dir():
        raise ConfigError("runs_dir", f"{cfg.runs_dir} is not a folder of runs")


def _ship_folders(cfg: ShipConfig) -> list[Path]:
    return [Path(cfg.runs_dir) / e / cfg.scenario.reading
            for e in (cfg.experiment, cfg.paper_experiment, *cfg.collections)]


def _run_ship(cfg: ShipConfig, out: Path) -> None:
    from .run.shipping import ship_checkpoints

    folders = _ship_folders(cfg)
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


def _run_tune(cfg: TuneConfig, out: Path) -> None:
    from .report.tuning import tune_app

    _set_threads(cfg.threads)
    tune_app(cfg, out, log=_say)


APPS: dict[str, App] = {
    "train": App(TrainConfig, _prepare_train, _run_train),
    "evaluate": App(EvaluateConfig, _prepare_evaluate, _run_evaluate),
    "reproduce": App(ReproduceConfig, _prepare_reproduce, _run_reproduce),
    "figures": App(FiguresConfig, _prepare_figures, _run_figures),
    "scaling": App(ScalingConfig, _prepare_scaling, _run_scaling),
    "ship": App(ShipConfig, _prepare_ship, _run_ship),
    "tune_baselines": App(TuneConfig, _prepare_tune, _run_tune),
}
assert set(APPS) == set(APP_SCHEMAS)


# ---------------------------------------------------------------------------- checked once
# Configs checked by PreRunCheck in this process, by their YAML: the job that runs one of them
# takes the checked object instead of converting and checking it again.
_CHECKED: dict[str, Schema] = {}


def _task_yaml(cfg: DictConfig) -> str:
    task = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]) if "hydra" in cfg else cfg
    return OmegaConf.to_yaml(task, resolve=True)


def checked(app: str, cfg: DictConfig, out: Path, key: str = "hydra.run.dir") -> Schema:
    """``cfg`` as the app's checked schema object, prepared for ``out`` (or the error); ``key``:
    the setting that chose ``out``."""
    obj = APPS[app].schema.from_config(cfg)
    check_writable(out, key)
    APPS[app].prepare(obj, out)
    return obj


def check_writable(folder: Path, key: str) -> None:
    """Refuse an output folder that cannot be made or written, before Hydra creates it: a file
    tried in its nearest existing folder (and removed at once) must be writable."""
    import tempfile

    from .io import write_failure

    probe = Path(folder).absolute()
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise ConfigError(key, f"{folder} cannot be made: {probe} is a file, not a folder")
    try:
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as exc:
        why = (write_failure(OSError(exc.errno, exc.strerror, str(probe))) or
               f"cannot write {probe}: {exc.strerror}")
        raise ConfigError(key, f"{folder} cannot be written ({why})") from None


def _guard(fn: Callable[[], Any], config: DictConfig | None = None) -> Any:
    """Run ``fn``; report this project's errors as one line with exit status 2 (a config error
    also names the file its group's choice came from, when that is a file)."""
    from .io import write_failure

    try:
        return fn()
    except _errors() as exc:
        if config is None or not getattr(exc, "key", ""):
            fail(exc)
        key, source = _blame(config, exc.key, getattr(exc, "also", ()))
        message = f"{key}: {exc.message}" if key != exc.key else str(exc)
        fail(f"{message} (in {source})" if source else message)
    except OSError as exc:  # a full disk, a file-size limit, a folder that cannot be written
        if write_failure(exc) is None:
            raise
        fail(f"{write_failure(exc)}; files are written whole or not at all, nothing half-written was left")


def _covers(a: str, b: str) -> bool:
    """Dotted keys ``a`` and ``b`` are the same, or one holds the other (``x.y`` and ``x.y[0]``, ``x.y.z``)."""
    return a == b or any(b.startswith(a + sep) or a.startswith(b + sep) for sep in ".[")


def _blame(config: DictConfig, key: str, also: tuple[str, ...] = ()) -> tuple[str, str | None]:
    """The key to name for an error about ``key`` (or, when the user set one of them on the
    command line, one of ``also``) and where its value came from: the command line's override,
    the YAML file of its group that sets it, or ``None`` (a default, or not known)."""
    hydra = config.get("hydra") if isinstance(config, DictConfig) else None
    if hydra is None:
        return key, None
    choices = set(hydra.runtime.choices)
    for candidate in (key, *also):
        for override in hydra.overrides.task:
            name = str(override).lstrip("+~").split("=")[0]
            if name == candidate or (name not in choices and _covers(name, candidate)):  # not a group's choice
                return candidate, f"the command line's {override}"
    return key, _source_of(config, key)


def _sets(text: str, path: list[str]) -> bool:
    """The YAML ``text`` sets the nested key ``path``."""
    import yaml

    try:
        node: Any = yaml.safe_load(text)
    except yaml.YAMLError:
        return False
    for part in path:
        if not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def _source_of(config: DictConfig, key: str) -> str | None:
    """The YAML file behind the group a dotted ``key`` belongs to (``scenario.n_uavs`` ->
    ``.../scenario/corridor.yaml``) when that file sets it, from the composed config's own
    record of its choices and search path; ``None`` when it is not a file."""
    import re
    from importlib.resources import files

    group = (key or "").split(".")[0]
    hydra = config.get("hydra") if isinstance(config, DictConfig) else None
    if not group or hydra is None:
        return None
    inner = [p for p in re.sub(r"\[\d+\]", "", key).split(".")[1:] if p]
    choice = hydra.runtime.choices.get(group)
    if not choice:
        return None
    for source in hydra.runtime.config_sources:
        path, schema = str(source.path), str(source.schema)
        try:
            if schema == "file":
                candidate = Path(path) / group / f"{choice}.yaml"
                if candidate.is_file():
                    return str(candidate) if _sets(candidate.read_text(), inner) else None
            elif schema == "pkg":
                candidate = files(path) / group / f"{choice}.yaml"
                if candidate.is_file():
                    return f"pkg://{path}/{group}/{choice}.yaml" if _sets(candidate.read_text(), inner) else None
        except (ModuleNotFoundError, TypeError, ValueError):
            continue
    return None


class PreRunCheck(Callback):
    """Check every job of a run or a sweep before Hydra creates anything (``hydra.callbacks``)."""

    def __init__(self, app: str) -> None:
        if app not in APPS:
            raise ValueError(f"unknown app {app!r}; known: {sorted(APPS)}")
        self.app = app

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        if self.app == "train":
            _guard(lambda: _check_resume_folder(config))
        out = Path(str(config.hydra.run.dir))
        _CHECKED[_task_yaml(config)] = _guard(lambda: checked(self.app, config, out), config)
        _armed()

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check_sweep(config)
        _armed(jobs_elsewhere=_jobs_in_workers(config))

    def _check_sweep(self, config: DictConfig) -> None:
        _guard(lambda: _check_launcher(config))
        _guard(lambda: _sweep_direction(config), config)
        jobs = sweep_jobs(config)
        if jobs is None:  # not a list of values (an Optuna interval ...): each job checks itself
            return
        from hydra.core.global_hydra import GlobalHydra

        loader = GlobalHydra.instance().config_loader()
        for overrides in jobs:
            job = loader.load_sweep_config(config, list(overrides))
            out = Path(str(job.hydra.sweep.dir)) / str(job.hydra.sweep.subdir)
            _CHECKED[_task_yaml(job)] = _guard(lambda: checked(self.app, job, out, "hydra.sweep.dir"), job)


def _check_resume_folder(config: DictConfig) -> None:
    """A ``resume.yaml`` written before run folders could move names its folder by its absolute
    path: read from a copy or a moved folder, it would continue (or miss) the original."""
    from .config import config_folder
    from .run.run_folder import RESUME_CONFIG

    if str(config.hydra.job.config_name) != RESUME_CONFIG:
        return
    folder = Path(config_folder(config.hydra.runtime.config_sources, RESUME_CONFIG))
    out = Path(str(config.hydra.run.dir)).resolve()
    chosen = any(str(o).startswith("hydra.run.dir=") for o in config.hydra.overrides.hydra)
    if out != folder and not chosen:
        raise ConfigError("hydra.run.dir", f"{folder / (RESUME_CONFIG + '.yaml')} names another run folder, {out} "
                                           f"(it was copied or moved); pass hydra.run.dir={folder} to continue "
                                           "this one (nothing was changed)")


def sweep_jobs(config: DictConfig) -> list[list[str]] | None:
    """The task overrides of every job of a sweep whose values are lists or ranges (the
    cartesian product, as Hydra's basic sweeper makes it); ``None`` for another sweeper or a
    sweep it cannot enumerate. Only Hydra's public override parser is used."""
    import itertools

    from hydra.core.override_parser.overrides_parser import OverridesParser

    sweeper = str(config.hydra.sweeper.get("_target_", ""))
    if not sweeper.endswith("BasicSweeper"):
        return None
    parsed = OverridesParser.create().parse_overrides([str(o) for o in config.hydra.overrides.task])
    axes = []
    for override in parsed:
        if override.is_hydra_override():
            continue
        if not override.is_sweep_override():
            axes.append([override.input_line])
        elif override.is_discrete_sweep() and not override.value_type.name.startswith("GLOB"):
            key = override.get_key_element()
            axes.append([f"{key}={value}" for value in override.sweep_string_iterator()])
        else:
            return None
    return [list(job) for job in itertools.product(*axes)]


_LAUNCHER_EXTRAS = {"hydra_plugins.hydra_submitit_launcher": "slurm", "hydra_plugins.hydra_joblib_launcher": "",
                    "hydra_plugins.hydra_optuna_sweeper": "optuna"}


def _check_launcher(config: DictConfig) -> None:
    """A launcher or sweeper that cannot start: its plugin not installed (say which extra
    installs it), or Slurm's launcher where no ``srun`` is on the PATH (submitit would raise
    only after Hydra wrote the sweep's ``multirun.yaml``)."""
    import importlib.util
    import shutil

    for node in ("launcher", "sweeper"):
        target = str(config.hydra[node].get("_target_", ""))
        module = ".".join(target.split(".")[:2])
        if module.startswith("hydra_plugins.") and importlib.util.find_spec(module) is None:
            extra = _LAUNCHER_EXTRAS.get(module)
            hint = f"pip install 'flock_torchrl[{extra}]'" if extra else f"pip install {module.split('.')[1]}"
            raise AppError(f"hydra/{node}: the plugin {module} is not installed ({hint})")
    launcher = str(config.hydra.launcher.get("_target_", ""))
    if launcher.endswith(".SlurmLauncher") and shutil.which("srun") is None:
        raise AppError("hydra/launcher=slurm: this machine has no Slurm (no srun on the PATH); run the sweep on a "
                       "Slurm login node, or locally with hydra/launcher=local")


# What each train objective asks of a sweeper (every one is a rate or a return: larger is better).
OBJECTIVE_DIRECTIONS = {"success_rate": "maximize", "safe_success_rate": "maximize", "return": "maximize"}


def _direction_names(value: Any) -> list[str]:
    """``maximize`` / ``Direction.maximize`` / a list of them -> their names."""
    values = list(value) if isinstance(value, (list, tuple)) or OmegaConf.is_list(value) else [value]
    return [str(getattr(v, "name", v)).split(".")[-1].lower() for v in values]


def _sweep_direction(config: DictConfig) -> None:
    """Optuna's ``direction`` follows the train app's ``objective`` (the plugin's default,
    ``minimize``, would minimise success): set from the objective unless the command line sets
    it; one set there that contradicts the objective is a config error. Runs before Hydra
    instantiates the sweeper (``on_multirun_start``)."""
    from omegaconf import read_write

    sweeper = config.hydra.sweeper
    if not str(sweeper.get("_target_", "")).endswith("OptunaSweeper") or "objective" not in config:
        return
    want = OBJECTIVE_DIRECTIONS.get(str(config.objective))
    if want is None:
        return
    given = [str(o) for o in config.hydra.overrides.hydra
             if str(o).lstrip("+~").split("=")[0] == "hydra.sweeper.direction"]
    if given:
        wrong = [d for d in _direction_names(sweeper.direction) if d != want]
        if wrong:
            raise ConfigError("hydra.sweeper.direction", f"{given[-1]} contradicts objective={config.objective}, "
                                                         f"which is to {want}; pass hydra.sweeper.direction={want} "
                                                         "or leave it out (it follows the objective)")
        return
    with read_write(sweeper):
        sweeper.direction = want


# ---------------------------------------------------------------------------- the mains
def _task(app: str) -> Callable[[DictConfig], Any]:
    def task(cfg: DictConfig) -> Any:
        from hydra.core.hydra_config import HydraConfig

        from .run.trainer import TrainingInterrupted

        out = Path(HydraConfig.get().runtime.output_dir)
        stopped = int(os.environ.get(STOPPED_WORKER, "0") or 0)
        if stopped and _in_sweep_worker():  # joblib hands out the jobs it holds: they do not start
            print(f"not started: {out} (the sweep was stopped by {signal.Signals(stopped).name})", file=sys.stderr,
                  flush=True)
            return 128 + stopped
        obj = _CHECKED.pop(_task_yaml(cfg), None) or _guard(lambda: checked(app, cfg, out))
        _armed()  # also where no PreRunCheck ran (a config without the callback)
        try:
            return _guard(lambda: APPS[app].run(obj, out))
        except TrainingInterrupted as exc:
            print(f"{exc}: checkpoint {exc.result.checkpoint} ({exc.result.frames} frames); "
                  f"resume with: {exc.command}", file=sys.stderr, flush=True)
            if _in_sweep_worker():  # an exit here would make joblib cancel the jobs still checkpointing
                os.environ[STOPPED_WORKER] = str(int(exc.signum))
                return exc.exit_status
            raise SystemExit(exc.exit_status) from None

    task.__name__ = app
    return task


# Stop signals before the run is checked are only noted: an exception raised at an arbitrary
# bytecode inside Hydra's composition or OmegaConf can break their `finally` clean-ups and come
# out as another error with a traceback (seen under load). Once the run is checked (PreRunCheck,
# before anything is written), a noted signal stops the process, and later ones raise `Stopped`
# at once (an evaluation or a table can take minutes; the trainer installs its own handlers).
_NOTED: list[int] = []
_MAIN_PID = 0  # the process that called main(); a launcher's workers keep their own handlers
# Set in a joblib worker whose job a signal stopped: its later jobs do not start. (An environment
# variable, not a global: the launcher pickles the task by value, with a copy of its globals.)
STOPPED_WORKER = "FLOCK_TORCHRL_SWEEP_STOPPED"


def _note(signum: int, frame: Any) -> None:
    _NOTED.append(signum)


def _stop(signum: int, frame: Any) -> None:
    from .run.trainer import Stopped

    raise Stopped(signum)


def _early_signals() -> None:
    """Until the run is checked: a stop signal is noted (see :func:`_armed`)."""
    from .run.trainer import STOP_SIGNALS

    for signum in STOP_SIGNALS:
        signal.signal(signum, _note)


# A launcher that runs the jobs in worker processes of this one (joblib): the variable names
# this process, so that a job knows that its sweep's parent waits for every job.
SWEEP_PARENT = "FLOCK_TORCHRL_SWEEP_PARENT"


def _jobs_in_workers(config: DictConfig) -> bool:
    """The sweep's launcher runs its jobs in local worker processes (joblib's)."""
    return "joblib" in str(config.hydra.launcher.get("_target_", "")).lower()


def _armed(jobs_elsewhere: bool = False) -> None:
    """The run is checked: stop on a noted signal, and at once on later ones (in the process
    that started the app; a launcher's worker processes keep their own handlers). With
    ``jobs_elsewhere`` (a joblib sweep), later signals are only noted: the workers stop their
    jobs, each with its checkpoint and its resume line, and this process waits for all of them
    and then exits with 128 + the signal (:func:`main`)."""
    from .run.trainer import STOP_SIGNALS, Stopped

    if _MAIN_PID != os.getpid():
        return
    if _NOTED:
        raise Stopped(_NOTED[0])
    if jobs_elsewhere:
        os.environ[SWEEP_PARENT] = str(os.getpid())
        return
    for signum in STOP_SIGNALS:
        signal.signal(signum, _stop)


def _in_sweep_worker() -> bool:
    """This process runs a job for a sweep's parent that waits for every job (joblib)."""
    return os.environ.get(SWEEP_PARENT) == str(os.getppid()) and _MAIN_PID != os.getpid()


def _config_folders(argv: list[str]) -> list[Path]:
    """The folders a command line adds to Hydra's search path: ``--config-dir`` / ``-cd`` and the
    ``file://`` (or plain) entries of ``hydra.searchpath=[...]`` (parsed by Hydra's public
    override parser)."""
    import argparse

    from hydra.core.override_parser.overrides_parser import OverridesParser

    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    parser.add_argument("--config-dir", "-cd")
    known, rest = parser.parse_known_args(argv)
    folders = [Path(known.config_dir)] if known.config_dir else []
    for arg in rest:
        if arg.lstrip("+~").startswith("hydra.searchpath="):
            try:
                value = OverridesParser.create().parse_overrides([arg])[0].value()
            except Exception:  # Hydra names a malformed override itself
                continue
            for entry in value if isinstance(value, list) else [value]:
                entry = str(entry)
                if entry.startswith("file://") or "://" not in entry:
                    folders.append(Path(entry.removeprefix("file://")))
    return folders


def check_yaml_files(folders: list[Path], depth: int = 4) -> None:
    """Refuse a YAML file that does not parse in a folder the command line adds to the search
    path (Hydra would fail on it with a long ``yaml.parser`` traceback), naming the file and
    the line."""
    import yaml

    for folder in folders:
        if not folder.is_dir():
            continue
        for path in sorted(folder.rglob("*.yaml")):
            parts = path.relative_to(folder).parts
            if len(parts) > depth or any(p.startswith(".") for p in parts[:-1]):
                continue
            try:
                yaml.safe_load(path.read_text())
            except yaml.YAMLError as exc:
                mark = getattr(exc, "problem_mark", None)
                where = f" (line {mark.line + 1}, column {mark.column + 1}: {exc.problem})" if mark else ""
                raise AppError(f"{path} is not valid YAML{where}") from None
            except (OSError, UnicodeDecodeError) as exc:
                raise AppError(f"{path} cannot be read ({type(exc).__name__}: {exc})") from None


def main(app: str, noted: list[int] | None = None) -> Any:
    """Run the Hydra app ``app`` on ``sys.argv`` (a console script or ``scripts/<app>.py``);
    ``noted``: stop signals a script noted while it imported the package."""
    import hydra

    from .run.trainer import Stopped

    global _MAIN_PID
    _MAIN_PID = os.getpid()
    _NOTED.clear()
    try:
        _early_signals()
        _NOTED.extend(noted or [])  # after the handlers move here, so none is lost between
        _guard(lambda: check_yaml_files(_config_folders(sys.argv[1:])))
        result = hydra.main(version_base=None, config_path=str(CONF_DIR), config_name=app)(_task(app))()
        if _NOTED and os.environ.get(SWEEP_PARENT) == str(os.getpid()):  # a joblib sweep stopped: its jobs said so
            raise SystemExit(128 + _NOTED[0])
        return result
    except Stopped as stop:
        print(f"stopped by {stop} outside a training loop (starting, checking, or finishing): files are "
              "written whole or not at all, and the last checkpoint, if any, is kept", file=sys.stderr, flush=True)
        raise SystemExit(128 + stop.signum) from None


def train_main(noted: list[int] | None = None) -> Any:
    """``scripts/train.py`` / ``flock-train``."""
    return main("train", noted)


def evaluate_main() -> Any:
    """``scripts/evaluate.py`` / ``flock-evaluate``."""
    return main("evaluate")


def reproduce_main() -> Any:
    """``scripts/reproduce.py`` / ``flock-reproduce``."""
    return main("reproduce")


def figures_main() -> Any:
    """``scripts/figures.py`` / ``flock-figures``."""
    return main("figures")


def scaling_main() -> Any:
    """``scripts/scaling.py`` / ``flock-scaling``."""
    return main("scaling")


def ship_main() -> Any:
    """``scripts/ship.py``: the named step that updates ``checkpoints/``."""
    return main("ship")


def tune_baselines_main() -> Any:
    """``scripts/tune_baselines.py``."""
    return main("tune_baselines")


__all__ = ["APPS", "App", "AppError", "PreRunCheck", "checked", "evaluate_main", "fail",
           "figures_main", "main", "reproduce_main", "scaling_main", "ship_main", "sweep_jobs",
           "train_main", "tune_baselines_main"]
