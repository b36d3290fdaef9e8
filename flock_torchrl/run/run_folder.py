"""A training run's folder: its lock, its logs, its saved config, and what a resume finds there.

Everything a run writes goes into one folder (Hydra's output folder, or ``run_dir``):

* ``config.yaml`` — the checked config, resolved: what ran (``--cfg job --resolve`` prints it);
* ``resume.yaml`` — the same as a Hydra primary config, so that
  ``python scripts/train.py -cd <folder> -cn resume`` composes exactly this run again;
* ``last.pt`` — the checkpoint; ``episodes.csv`` — one row per finished training episode;
* ``logs/`` — the scalar logger's files; ``.lock`` (and ``.lock.holder``) while a process runs it.
"""

from __future__ import annotations

import csv
import math
import os
import re
import shlex
import socket
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from omegaconf import OmegaConf

from ..config import ConfigError, flatten
from ..io import write_text
from ..policies.checkpoint import CheckpointError

RESUME_CONFIG = "resume"
# resume.yaml's output folder: the folder it is read from (a copy continues the copy, a moved
# run continues where it stands; the folder it was written in is never touched).
RUN_FOLDER = "${flock.config_folder:${hydra.runtime.config_sources},${hydra.job.config_name}}"


class RunLock:
    """An exclusive lock on ``<run>/.lock`` for the life of a training process (``filelock``:
    the operating system drops it when its process dies, so a lock left by a killed run is
    never stale). ``.lock.holder`` records the holder's PID, host and start time for the message,
    which, for a holder on this host, says how to stop it (``kill <pid>``)."""

    def __init__(self, run_dir: Path) -> None:
        self.path = run_dir / ".lock"
        self.holder = run_dir / ".lock.holder"
        self.lock = None

    def __enter__(self) -> "RunLock":
        from filelock import FileLock, Timeout

        self.path.parent.mkdir(parents=True, exist_ok=True)
        lock = FileLock(str(self.path), timeout=0)
        try:
            lock.acquire()
        except Timeout:
            holder = self.holder.read_text().strip() if self.holder.is_file() else "another process"
            found = re.match(r"PID (\d+) on (\S+),", holder)
            how = f"kill {found[1]}; " if found and found[2] == socket.gethostname() else ""
            raise CheckpointError(f"{self.path.parent} is in use by {holder}; wait for it or stop it "
                                  f"({how}a killed process releases its lock)") from None
        self.lock = lock
        write_text(self.holder, f"PID {os.getpid()} on {socket.gethostname()}, started "
                                f"{time.strftime('%Y-%m-%d %H:%M:%S')}\n")
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.lock is not None:
            self.holder.unlink(missing_ok=True)
            self.lock.release()
            self.lock = None


def clean_stale_temporaries(run_dir: Path) -> None:
    """Remove the temporary files an atomic write leaves when its process is killed
    (``.<name>.<random>.tmp``); only the run's own process, holding the lock, calls this."""
    for path in run_dir.glob(".*.tmp"):
        path.unlink(missing_ok=True)


def truncate_log(path: Path, keep: Callable[[list[str]], bool], header: bool = True, width: int | None = None,
                 columns: Sequence[str] | None = None) -> None:
    """Keep the rows of a CSV log for which ``keep(row)`` is true (atomically), whatever a dead
    process left: a row that cannot be read (a torn last line without its newline, bytes that
    are not UTF-8, the wrong number of fields) is dropped, and a header other than ``columns``
    is written again, so that the next row starts on a line of its own."""
    if not path.is_file():
        return
    text = path.read_bytes().decode("utf-8", errors="replace")  # a bad byte becomes U+FFFD: its row goes
    lines = text.split("\n")
    torn = lines.pop() != ""  # the text after the last newline: a row whose write did not finish
    rows = list(csv.reader(lines))
    head, body = (rows[:1], rows[1:]) if header else ([], rows)
    if columns is not None and head != [list(columns)]:
        head = [list(columns)]
    width = len(head[0]) if head else width

    def good(row: list[str]) -> bool:
        try:
            return (bool(row) and (width is None or len(row) == width) and not any("\ufffd" in x for x in row)
                    and keep(row))
        except (ValueError, IndexError):
            return False

    kept = [r for r in body if good(r)]
    if torn or len(kept) != len(body) or (header and rows[:1] != head):
        write_text(path, "".join(",".join(r) + "\n" for r in head + kept))


def _numbers(fields: Sequence[str]) -> bool:
    """Every field is a number or empty (``ValueError`` otherwise: the row is dropped)."""
    for x in fields:
        if x:
            float(x)
    return True


class EpisodeLog:
    """Append-only CSV of finished training episodes, cut back to a checkpoint on resume."""

    def __init__(self, path: Path, columns: Sequence[str], keep_up_to: int | None) -> None:
        self.path = path
        self.columns = tuple(columns)
        if keep_up_to is None or not path.is_file():
            write_text(path, ",".join(self.columns) + "\n")
        else:
            truncate_log(path, lambda r: int(r[0]) <= keep_up_to and _numbers(r[1:]), columns=self.columns)
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


def truncate_scalar_logs(run_dir: Path, frames: int | None) -> None:
    """Cut the CSV logger's files (``step,value`` rows) back to the checkpoint's step (a resume
    rewrites the rest); ``None``: a fresh run in a folder a run died in before its first
    checkpoint, whose files are removed (the new run writes them again)."""
    for path in (run_dir / "logs" / "scalars").glob("**/*.csv"):
        if frames is None:
            path.unlink()
        else:
            truncate_log(path, lambda r: float(r[0]) <= frames and _numbers(r[1:]), header=False, width=2)


def logger_hparams(resolved: dict[str, Any]) -> dict[str, Any]:
    """The resolved config as flat hyperparameters every logger takes: numbers, strings and
    booleans as they are; lists and ``None`` as their text (TensorBoard refuses anything else)."""
    return {k: v if isinstance(v, (bool, int, float, str)) else str(v) for k, v in flatten(resolved).items()}


def make_logger(backend: str, project: str, mode: str, run_dir: Path, name: str):
    """TorchRL's logger for ``backend`` (``csv``, ``wandb`` offline by default, ``tensorboard``),
    writing into the run folder; ``None`` for ``none``. wandb runs in ``mode`` (``logger.mode``),
    given to ``wandb.init``: a ``WANDB_MODE`` in the environment neither overrides it nor is set."""
    if backend == "none":
        return None
    if backend == "csv":
        from torchrl.record.loggers import CSVLogger

        return CSVLogger(exp_name="logs", log_dir=str(run_dir))
    if backend == "wandb":
        from torchrl.record.loggers import WandbLogger

        # The mode goes to wandb.init itself, so logger.mode is what runs whatever WANDB_MODE says;
        # TorchRL's offline=True would write WANDB_MODE into the process's environment instead.
        return WandbLogger(exp_name=name, offline=False, save_dir=str(run_dir), project=project, mode=mode)
    if backend == "tensorboard":
        from torchrl.record.loggers import TensorboardLogger

        return TensorboardLogger(exp_name=name, log_dir=str(run_dir / "tensorboard"))
    raise ConfigError("logger.backend", f"unknown logger {backend!r}")


def resume_command(run_dir: Path) -> str:
    """The command that continues the run in ``run_dir``, whatever its folder is called: the
    program that is running (``scripts/train.py`` or ``flock-train``) on the run's ``resume.yaml``."""
    program = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ""
    prefix = "flock-train" if program == "flock-train" else "python scripts/train.py"
    return f"{prefix} -cd {shlex.quote(str(run_dir))} -cn {RESUME_CONFIG}"


def write_run_config(run_dir: Path, resolved: dict[str, Any], hydra: dict[str, Any]) -> None:
    """``config.yaml`` (what runs, resolved) and ``resume.yaml`` (the same as a primary config of
    its own, with its Hydra settings and, as its output folder, the folder it is read from)."""
    write_text(run_dir / "config.yaml", OmegaConf.to_yaml(OmegaConf.create(resolved)))
    resume = {"defaults": ["train_schema", {"override hydra/job_logging": "stdout"}, "_self_"],
              **resolved, "resume": "true",
              "hydra": {**hydra, "run": {"dir": RUN_FOLDER}}}
    text = OmegaConf.to_yaml(OmegaConf.create(resume))
    write_text(run_dir / f"{RESUME_CONFIG}.yaml",
               f"# Continue this run (only budgets, logging and runtime options may change):\n"
               f"#   {resume_command(run_dir.resolve())} [experiment.max_frames=...]\n{text}")


__all__ = ["EpisodeLog", "RESUME_CONFIG", "RunLock", "clean_stale_temporaries", "logger_hparams", "make_logger",
           "resume_command", "truncate_log", "truncate_scalar_logs", "write_run_config"]
