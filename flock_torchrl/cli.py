"""The command-line apps: every script is a Hydra app on ``conf/``, run through :func:`run_app`.

``run_app`` gives all of them one behaviour:

* the configuration of every job (every combination of a ``-m`` sweep) is composed and
  checked *before* Hydra creates any folder; a bad value prints one line,
  ``error: scenario.n_uavs: expected an integer, got 'abc'``, and exits with status 2;
* Hydra's own flags (``--cfg job``, ``--help``, ``--info``) print what would run;
* errors a job meets later (a refused resume, a busy run folder, a corrupted checkpoint)
  also print one line and exit 2; a training stopped by SIGINT / SIGTERM exits 130 / 143
  after printing the command that resumes it.

``python scripts/train.py resume=<run folder> [budget overrides]`` recomposes the run from
the overrides it saved (``overrides.yaml``), so ``--cfg job`` shows exactly what continues.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Callable, Sequence

from omegaconf import DictConfig, OmegaConf

from .config import CONF_DIR, ConfigError, compose, config_error_from, resume_mode

HYDRA_INFO_FLAGS = ("--help", "-h", "--hydra-help", "--cfg", "-c", "--info", "-i", "--shell-completion", "-sc",
                    "--resolve", "--package", "-p")
EXIT_ERROR = 2


class AppError(Exception):
    """An error a job reports as one line (exit status 2)."""


def _error(message: str) -> int:
    print(f"error: {message}", file=sys.stderr, flush=True)
    return EXIT_ERROR


def _split(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """``(flags, overrides)``: Hydra's dash arguments (with their values) and the overrides."""
    flags, overrides, take_value = [], [], False
    for arg in argv:
        if take_value:
            flags.append(arg)
            take_value = False
        elif arg.startswith("-"):
            flags.append(arg)
            take_value = arg in ("--cfg", "-c", "--info", "-i", "--package", "-p", "--config-path", "-cp",
                                 "--config-name", "-cn", "--config-dir", "-cd", "--shell-completion", "-sc")
        else:
            overrides.append(arg)
    return flags, overrides


def job_overrides(overrides: Sequence[str], multirun: bool) -> list[list[str]]:
    """The task overrides of every job Hydra would launch (sweeps expanded), without the
    ``hydra.*`` / ``hydra/...`` ones."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser

    task = [o for o in overrides if not o.lstrip("+~").startswith(("hydra.", "hydra/"))]
    if not multirun:
        return [task]
    parsed = OverridesParser.create().parse_overrides(task)
    return [job for batch in BasicSweeper.split_arguments(parsed, max_batch_size=None) for job in batch]


def output_dir(cfg: DictConfig, multirun: bool) -> Path:
    """Where Hydra will put a job's outputs (from a config composed with its hydra node)."""
    hydra = cfg.hydra
    if multirun:
        return Path(str(hydra.sweep.dir)) / str(hydra.sweep.subdir)
    return Path(str(hydra.run.dir))


def run_app(config_name: str, job: Callable[[DictConfig], Any], check: Callable[[DictConfig, Path], None],
            argv: Sequence[str] | None = None, rewrite: Callable[[list[str]], list[str]] | None = None) -> int:
    """Run a Hydra app on ``conf/<config_name>.yaml``; returns the exit status.

    Args:
        job: the task function (called by Hydra once per job, in its output folder's context).
        check: ``check(cfg, output_dir)`` for one job's composed config, before anything runs;
            raises :class:`ConfigError` (or :class:`AppError`) with the message to print.
        rewrite: turns the command line into the one Hydra sees (e.g. ``resume=<folder>``).
    """
    import hydra

    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if rewrite is not None:
            argv = rewrite(argv)
        flags, overrides = _split(argv)
        multirun = any(f in ("-m", "--multirun") for f in flags)
        if not any(f.split("=")[0] in HYDRA_INFO_FLAGS for f in flags):
            for overrides_of_job in job_overrides(overrides, multirun):
                hydra_overrides = [o for o in overrides if o.lstrip("+~").startswith(("hydra.", "hydra/"))]
                cfg = compose(config_name, [*overrides_of_job, *hydra_overrides], return_hydra_config=True)
                check(cfg, output_dir(cfg, multirun))
    except (ConfigError, AppError) as exc:
        return _error(str(exc))
    except Exception as exc:  # Hydra's parser and composer
        return _error(str(config_error_from(exc)))

    status = {"code": 0}

    def task(cfg: DictConfig) -> None:
        from .policies.checkpoint import CheckpointError
        from .run.trainer import TrainingInterrupted

        try:
            job(cfg)
        except TrainingInterrupted as exc:
            print(f"{exc}: checkpoint {exc.result.checkpoint} ({exc.result.frames} frames); "
                  f"resume with: {exc.command}", file=sys.stderr, flush=True)
            raise SystemExit(exc.exit_status) from None
        except KeyboardInterrupt:
            print("aborted (no checkpoint written since the last periodic one)", file=sys.stderr, flush=True)
            raise SystemExit(130) from None
        except (ConfigError, CheckpointError, AppError) as exc:
            status["code"] = _error(str(exc))

    main = hydra.main(version_base=None, config_path=str(CONF_DIR), config_name=config_name)(task)
    saved = sys.argv
    sys.argv = [saved[0] if saved else config_name, *argv]
    try:
        main()
    finally:
        sys.argv = saved
    return status["code"]


# ---------------------------------------------------------------------------- train
def _rewrite_resume(argv: list[str]) -> list[str]:
    """``resume=<run folder>``: the run's saved overrides, then the new ones, then
    ``resume=true`` and the folder itself as Hydra's output folder."""
    rest, folder = [], None
    for arg in argv:
        key, sep, value = arg.partition("=")
        if sep and key == "resume" and isinstance(resume_mode(value), Path):
            folder = Path(value)
        else:
            rest.append(arg)
    if folder is None:
        return argv
    saved = folder / "overrides.yaml"
    if not saved.is_file():
        raise AppError(f"resume={folder}: no run there (no overrides.yaml; a run folder holds config.yaml, "
                       "overrides.yaml and last.pt)")
    previous = [str(o) for o in OmegaConf.load(saved)]
    given = {a.partition("=")[0].lstrip("+~") for a in rest if "=" in a}
    kept = [o for o in previous if o.partition("=")[0].lstrip("+~") not in given | {"resume"}]
    return [*kept, *rest, "resume=true", f"hydra.run.dir={folder}"]


def _check_train(cfg: DictConfig, run_dir: Path) -> None:
    from .policies.checkpoint import LAST
    from .run.trainer import check_train_config

    rc = check_train_config(_task(cfg))
    exists = (run_dir / LAST).exists()
    if rc.resume == "never" and exists:
        raise AppError(f"{run_dir} already holds a checkpoint; pass resume=true (or resume={run_dir}) to continue "
                       "it, or change the run's overrides (nothing was changed)")
    if rc.resume == "always" and not exists:
        raise AppError(f"resume=true, but there is no checkpoint at {run_dir / LAST}")


def _task(cfg: DictConfig) -> DictConfig:
    """The task part of a config composed with its hydra node."""
    task = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]) if "hydra" in cfg else cfg
    return task


def _train_job(cfg: DictConfig) -> None:
    import logging

    import torch

    from .run.trainer import train

    logging.getLogger("torchrl").setLevel(logging.WARNING)  # no "Initialized LazyTensorStorage" lines
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    result = train(cfg)
    if sum(result.split.values()) > 0:
        print(result.split_line(), flush=True)
    print(f"checkpoint: {result.checkpoint} ({result.frames} frames, {result.episodes} episodes, "
          f"{result.updates} updates, {result.seconds:.0f} s)", flush=True)
    if result.evaluations:
        last = result.evaluations[-1]
        print(f"evaluation ({int(last['n_episodes'])} episodes, seed {cfg.eval_seed}, deterministic): "
              f"success {last['success']:.3f}, safe_success {last['safe_success']:.3f}, "
              f"d_min_uav {last['d_min_uav']:.3f}, d_c {last['d_c']:.3f}, t_goal {last['t_goal']:.2f} s", flush=True)


def train_main(argv: Sequence[str] | None = None) -> int:
    """``scripts/train.py`` / ``flock-train``."""
    return run_app("train", _train_job, _check_train, argv, rewrite=_rewrite_resume)


# ---------------------------------------------------------------------------- evaluate
def _check_evaluate(cfg: DictConfig, out: Path) -> None:
    from .run.evaluation import check_evaluate_config

    check_evaluate_config(_task(cfg))


def _evaluate_job(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    from .run.evaluation import evaluate_app

    evaluate_app(cfg, Path(HydraConfig.get().runtime.output_dir))


def evaluate_main(argv: Sequence[str] | None = None) -> int:
    """``scripts/evaluate.py`` / ``flock-evaluate``."""
    return run_app("evaluate", _evaluate_job, _check_evaluate, argv)


# ---------------------------------------------------------------------------- reproduce, figures
def _hydra_out() -> Path:
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)


def _check_common(cfg: DictConfig) -> None:
    from .config import check_device, check_seed

    check_seed(cfg.seed)
    check_device(cfg.device)
    if not (isinstance(cfg.threads, int) and cfg.threads >= 0):
        raise ConfigError("threads", f"must be an integer >= 0, got {cfg.threads!r}")


def _check_reproduce(cfg: DictConfig, out: Path) -> None:
    from .config import ReproduceConfig, to_object
    from .report.tables import TABLE_NUMBERS, table_entries

    checked = to_object(_task(cfg), ReproduceConfig, "")
    if checked.table not in TABLE_NUMBERS:
        raise ConfigError("table", f"must be one of {', '.join(map(str, TABLE_NUMBERS))}, got {checked.table}")
    if checked.episodes < 1:
        raise ConfigError("episodes", f"must be an integer >= 1, got {checked.episodes}")
    names = {e.policy for e in table_entries(checked.table)}
    unknown = sorted(set(checked.only) - names)
    if unknown:
        raise ConfigError("only", f"{unknown} are not rows of Table {checked.table}; rows: {sorted(names)}")
    _check_common(cfg)


def _reproduce_job(cfg: DictConfig) -> None:
    import torch

    from .report.tables import reproduce

    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    out = reproduce(int(cfg.table), str(cfg.scenario.reading), episodes=int(cfg.episodes), seed=int(cfg.seed),
                    device=str(cfg.device), checkpoints_dir=str(cfg.checkpoints_dir), out_dir=_hydra_out(),
                    only=list(cfg.only) or None, episodes_csv=bool(cfg.episodes_csv),
                    paper_run=cfg.paper_run, log=lambda m: print(m, flush=True))
    if out["failed"]:
        raise AppError(f"Table {cfg.table}: rows not evaluated: {', '.join(out['failed'])} (see above)")


def reproduce_main(argv: Sequence[str] | None = None) -> int:
    """``scripts/reproduce.py`` / ``flock-reproduce``."""
    return run_app("reproduce", _reproduce_job, _check_reproduce, argv)


def _check_figures(cfg: DictConfig, out: Path) -> None:
    figs = list(cfg.figs)
    if not figs or any(f not in (4, 5, 6) for f in figs):
        raise ConfigError("figs", f"a list of 4, 5 and 6, got {figs}")
    _check_common(cfg)


def _figures_job(cfg: DictConfig) -> None:
    import torch

    from .report.figures import make_figures

    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    make_figures(str(cfg.scenario.reading), _hydra_out(), figs=list(cfg.figs), checkpoints_dir=str(cfg.checkpoints_dir),
                 seed=int(cfg.seed), device=str(cfg.device), paper_run=cfg.paper_run, log=lambda m: print(m, flush=True))


def figures_main(argv: Sequence[str] | None = None) -> int:
    """``scripts/figures.py`` / ``flock-figures``."""
    return run_app("figures", _figures_job, _check_figures, argv)


# ---------------------------------------------------------------------------- ship
def _check_ship(cfg: DictConfig, out: Path) -> None:
    runs = Path(str(cfg.runs_dir)) / str(cfg.experiment) / str(cfg.scenario.reading)
    if not runs.is_dir():
        raise AppError(f"no runs to ship under {runs}")


def _ship_job(cfg: DictConfig) -> None:
    from .run.shipping import ship_checkpoints

    ship_checkpoints(str(cfg.scenario.reading), str(cfg.experiment), Path(str(cfg.runs_dir)),
                     Path(str(cfg.checkpoints_dir)), str(cfg.paper_experiment), log=lambda m: print(m, flush=True))


def ship_main(argv: Sequence[str] | None = None) -> int:
    """``scripts/ship.py``: the named step that updates ``checkpoints/``."""
    return run_app("ship", _ship_job, _check_ship, argv)


# ---------------------------------------------------------------------------- tune, benchmark
def _check_tune(cfg: DictConfig, out: Path) -> None:
    from .report.tuning import GRIDS

    unknown = sorted(set(cfg.controllers) - set(GRIDS))
    if unknown:
        raise ConfigError("controllers", f"unknown {unknown}; known: {sorted(GRIDS)}")
    if cfg.episodes < 1:
        raise ConfigError("episodes", f"must be an integer >= 1, got {cfg.episodes}")


def _tune_job(cfg: DictConfig) -> None:
    from .report.tuning import tune_app

    tune_app(cfg, _hydra_out(), log=lambda m: print(m, flush=True))


def tune_baselines_main(argv: Sequence[str] | None = None) -> int:
    """``scripts/tune_baselines.py``."""
    return run_app("tune_baselines", _tune_job, _check_tune, argv)


def _check_benchmark(cfg: DictConfig, out: Path) -> None:
    from .config import check_device

    check_device(cfg.device)


def _benchmark_job(cfg: DictConfig) -> None:
    from .report.benchmark import benchmark_app

    benchmark_app(cfg, _hydra_out())


def benchmark_main(argv: Sequence[str] | None = None) -> int:
    """``scripts/benchmark.py`` / ``make benchmark``."""
    return run_app("benchmark", _benchmark_job, _check_benchmark, argv)


def _check_scaling(cfg: DictConfig, out: Path) -> None:
    if not list(cfg.sizes) or any(not isinstance(n, int) or n < 1 for n in cfg.sizes):
        raise ConfigError("sizes", f"a list of swarm sizes >= 1, got {list(cfg.sizes)}")
    if cfg.episodes < 1:
        raise ConfigError("episodes", f"must be an integer >= 1, got {cfg.episodes}")
    _check_common(cfg)


def _scaling_job(cfg: DictConfig) -> None:
    import torch

    from .report.scaling import scaling

    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    scaling(str(cfg.policy_name), str(cfg.scenario.reading), list(cfg.sizes), int(cfg.episodes), int(cfg.seed),
            str(cfg.checkpoints_dir), str(cfg.device), _hydra_out(), log=lambda m: print(m, flush=True))


def scaling_main(argv: Sequence[str] | None = None) -> int:
    """``scripts/scaling.py`` / ``make scaling``."""
    return run_app("scaling", _scaling_job, _check_scaling, argv)


__all__ = ["AppError", "benchmark_main", "scaling_main", "evaluate_main", "figures_main", "ship_main", "tune_baselines_main", "job_overrides", "reproduce_main", "run_app", "train_main"]
