"""Stop signals (SIGINT, SIGTERM, SIGHUP), in one module: what a run does on each.

* In the training loop (:class:`Signals`): the first signal finishes the current update,
  writes a checkpoint and stops with exit status 128 + the signal, printing the command that
  resumes; a second Ctrl-C aborts at once (:class:`Stopped`). While :attr:`Signals.abort` is
  set (the checkpoint is current, e.g. during the final evaluation) the first one stops at once.
* Collector processes ignore them (:func:`ignore_stop_signals`): the main process alone decides
  when the run stops, and :func:`shutdown` stops the collector, a watchdog bounding the wait.
* Worker processes start where a signal cannot reach them half-started (:func:`start_workers`).
* Multiprocessing's resource tracker starts with them ignored (:func:`start_resource_tracker`).
* A sweep's job worker (joblib) ends with the sweep's process, even one killed by SIGKILL
  (:func:`end_with_parent`).

* In an app, from its start to its run (:class:`AppSignals`, :data:`APP_SIGNALS`): signals
  are noted until the run is checked, then armed; a joblib sweep's parent waits for its jobs.
  Every script of ``scripts/`` notes signals while Python imports torch and the package (before
  this module exists: ``scripts/_start.py``) and hands them to :meth:`AppSignals.start`; the app
  then stops on one at once.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any, Iterator

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, *((signal.SIGHUP,) if hasattr(signal, "SIGHUP") else ()))
# Seconds the main process waits for collector processes to stop before killing them.
SHUTDOWN_TIMEOUT = 30.0


def say(line: str) -> None:
    """Write ``line`` and its newline to stderr in one write. ``print`` writes the text and the
    newline apart, so the jobs of a joblib sweep, which share one stderr, ran lines together."""
    sys.stderr.write(line + "\n")
    sys.stderr.flush()


@contextmanager
def stop_handlers(handler: Any) -> Iterator[None]:
    """``handler`` for every stop signal inside the block, the previous ones put back after (in the
    main thread; elsewhere no handler can be set, and none is)."""
    main = threading.current_thread() is threading.main_thread()
    previous = {s: signal.signal(s, handler) for s in STOP_SIGNALS} if main else {}
    try:
        yield
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)


def job_tag() -> str:
    """``[<job's folder>] `` in a job of a joblib sweep (whose jobs share one stdout and stderr, so
    their lines interleave), else nothing: the job's output folder under the sweep's."""
    if not APP_SIGNALS.in_sweep_worker():
        return ""
    try:
        from hydra.core.hydra_config import HydraConfig

        hydra = HydraConfig.get()
        folder = Path(hydra.runtime.output_dir)
        return f"[{folder.relative_to(Path(hydra.sweep.dir).resolve()) if folder.is_absolute() else folder}] "
    except (ValueError, AttributeError):
        return f"[job {os.getpid()}] "


class Stopped(BaseException):
    """A stop signal that cannot wait for the end of the update. ``resume``: the command that
    continues the training run it aborted (``None``: it stopped an app outside a training loop)."""

    def __init__(self, signum: int, resume: str | None = None) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.resume = resume

    def message(self) -> str:
        """What the app prints when it exits on this signal (one line)."""
        name = signal.Signals(self.signum).name
        if self.resume is not None:
            how = f"resume with: {self.resume}" if self.resume else "resume the run from its folder"
            return (f"stopped by {name} during training (a second signal aborts at once): the update in progress "
                    f"is lost, the last checkpoint, if any, is kept; {how}")
        return (f"stopped by {name} outside a training loop (starting, checking, or finishing): files are written "
                "whole or not at all, and the last checkpoint, if any, is kept")


class TrainingInterrupted(Exception):
    """The run was stopped by a signal after writing its checkpoint (``result``: its
    :class:`~.trainer.TrainResult`; ``command``: the one that resumes it)."""

    def __init__(self, signum: int, result: Any, command: str) -> None:
        super().__init__(f"stopped by {signal.Signals(signum).name}")
        self.signum, self.result, self.command = signum, result, command

    @property
    def exit_status(self) -> int:
        return 128 + int(self.signum)


class Signals:
    """The training loop's handlers: the first signal sets :attr:`received` (the loop stops after
    its update and checkpoints); a second one, or any while :attr:`abort` is set, raises
    :class:`Stopped`. Outside the main thread nothing is installed."""

    def __init__(self, resume: str | None = None) -> None:
        self.received = 0
        self.abort = False
        self.previous: dict[int, Any] = {}
        self.resume = resume  # the command that continues the run (said when a signal aborts it)

    def __enter__(self) -> "Signals":
        if threading.current_thread() is threading.main_thread():
            for signum in STOP_SIGNALS:
                self.previous[signum] = signal.signal(signum, self.handle)
        return self

    def handle(self, signum: int, frame: Any) -> None:
        if self.received or self.abort:
            self.received = self.received or signum
            raise Stopped(self.received, self.resume or "")
        self.received = signum
        say(f"\n{signal.Signals(signum).name} received: finishing this update and writing a checkpoint "
            "(Ctrl-C again aborts at once)")

    def __exit__(self, *exc: Any) -> None:
        for signum, handler in self.previous.items():
            signal.signal(signum, handler)


# A launcher that runs the jobs in worker processes of the app's (joblib): the variable names
# that process, so that a job knows that its sweep's parent waits for every job.
SWEEP_PARENT = "FLOCK_TORCHRL_SWEEP_PARENT"
# Set in a joblib worker whose job a signal stopped: its later jobs do not start. (An environment
# variable, not a Python global: the launcher pickles the task by value, with a copy of its globals.)
STOPPED_WORKER = "FLOCK_TORCHRL_SWEEP_STOPPED"


class AppSignals:
    """An app's stop signals, before and around its run (the training loop has :class:`Signals`).

    Until the run is checked a signal is only noted: an exception raised at an arbitrary bytecode
    inside Hydra's composition or OmegaConf can break their ``finally`` clean-ups and come out as
    another error with a traceback (seen under load). Once the run is checked (before anything is
    written), :meth:`arm` stops on a noted signal, and later ones raise :class:`Stopped` at once
    (an evaluation or a table can take minutes; the trainer installs its own handlers).
    """

    def __init__(self) -> None:
        self.noted: list[int] = []
        self.main_pid = 0  # the process that started the app; a launcher's workers keep their own handlers

    def start(self, noted: list[int] | None = None) -> None:
        """The app starts in this process: note signals from now on, after ``noted`` (those a
        script noted while it imported the package)."""
        self.main_pid = os.getpid()
        self.noted.clear()
        for signum in STOP_SIGNALS:
            signal.signal(signum, self._note)
        self.noted.extend(noted or [])  # after the handlers move here, so none is lost between

    def _note(self, signum: int, frame: Any) -> None:
        self.noted.append(signum)

    @staticmethod
    def _stop(signum: int, frame: Any) -> None:
        raise Stopped(signum)

    def arm(self, jobs_elsewhere: bool = False) -> None:
        """The run is checked: stop on a noted signal, and at once on later ones (in the process
        that started the app). With ``jobs_elsewhere`` (a joblib sweep), later signals are only
        noted: the workers stop their jobs, each with its checkpoint and its resume line, and
        this process waits for all of them, then exits with 128 + the signal
        (:meth:`sweep_stopped`)."""
        if self.main_pid != os.getpid():
            return
        if self.noted:
            raise Stopped(self.noted[0])
        if jobs_elsewhere:
            os.environ[SWEEP_PARENT] = str(os.getpid())
            return
        for signum in STOP_SIGNALS:
            signal.signal(signum, self._stop)

    def in_sweep_worker(self) -> bool:
        """This process runs a job for a sweep's parent that waits for every job (joblib)."""
        return os.environ.get(SWEEP_PARENT) == str(os.getppid()) and self.main_pid != os.getpid()

    def sweep_stopped(self) -> int:
        """In a joblib sweep's parent: the signal that stopped its jobs (0: none)."""
        return self.noted[0] if self.noted and os.environ.get(SWEEP_PARENT) == str(os.getpid()) else 0

    def worker_stopped(self) -> int:
        """In a joblib worker: the signal that stopped one of its jobs (0: none); its later jobs
        do not start."""
        return int(os.environ.get(STOPPED_WORKER, "0") or 0) if self.in_sweep_worker() else 0

    @staticmethod
    def mark_worker_stopped(signum: int) -> None:
        """A job of this joblib worker was stopped by ``signum``."""
        os.environ[STOPPED_WORKER] = str(int(signum))


# The app of this process (flock_torchrl.cli.main starts it).
APP_SIGNALS = AppSignals()
# Whether this process (a sweep's job worker) watches its parent already (end_with_parent).
_WATCHING: list[int] = []


def end_with_parent(parent: int, poll: float = 0.5, grace: float = SHUTDOWN_TIMEOUT) -> None:
    """In a sweep's job worker (joblib's, a child of the sweep's process ``parent``): end with
    the parent. A SIGKILL of the parent cannot be passed on, and the workers lived on, ran their
    jobs to the end and held their run folders' locks against the rerun. A daemon thread watches
    the parent; once it is gone the worker sends itself SIGTERM (a training job writes its
    checkpoint and stops, as on any SIGTERM; a worker between jobs ends) and exits ``grace``
    seconds later if it still runs. A job that returns after its parent died ends the worker
    (:func:`leave`). Started once per process."""
    if _WATCHING:
        return
    _WATCHING.append(parent)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll)
        with suppress(OSError, ValueError):  # its stderr may have gone with it: stop all the same
            say(f"the sweep's process (PID {parent}) is gone: stopping its job worker (PID {os.getpid()}) with SIGTERM")
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(grace)
        leave(128 + signal.SIGTERM)

    threading.Thread(target=watch, name="end-with-parent", daemon=True).start()


def orphaned(parent: int) -> bool:
    """This process's parent is no longer ``parent`` (it died: the process was handed to init)."""
    return os.getppid() != parent


def leave(status: int) -> None:
    """Exit this process now, with ``status``, its output flushed (an orphaned job worker: nobody
    waits for its result, and its pool would wait for a parent that is gone)."""
    for stream in (sys.stdout, sys.stderr):
        with suppress(OSError, ValueError):
            stream.flush()
    os._exit(status)


def ignore_stop_signals() -> None:
    """In a collector process: the main process alone decides when the run stops."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)


def shutdown(collector: Any, timeout: float = SHUTDOWN_TIMEOUT) -> None:
    """Stop a collector; kill its processes if they do not stop within ``timeout`` seconds."""
    worker = threading.Thread(target=collector.shutdown, daemon=True)
    worker.start()
    worker.join(timeout)
    if worker.is_alive():
        for proc in getattr(collector, "procs", []) or []:
            if proc.is_alive():
                proc.kill()


def start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker with the stop signals ignored: it blocks SIGINT
    and SIGTERM itself, but a SIGHUP to the process group (a closed terminal, an ssh drop)
    would kill it, and its replacement then prints tracebacks for every shared block."""
    from multiprocessing import resource_tracker

    with stop_handlers(signal.SIG_IGN):
        resource_tracker.ensure_running()


def abandon_queues() -> None:
    """Let the process exit after its workers were killed: TorchRL's weight-sync schemes are shut
    down now (their finalizer puts on a queue, which starts a thread: impossible once Python
    exits), and no queue waits to flush to a reader that is gone."""
    import gc
    from multiprocessing.queues import Queue

    from torchrl.weight_update import WeightSyncScheme

    gc.collect()
    for obj in gc.get_objects():
        kind = type(obj)  # type(): some objects warn when asked for __class__
        if issubclass(kind, WeightSyncScheme):
            with suppress(Exception):  # its workers are gone: what it could not send does not matter
                obj.shutdown()
    for obj in gc.get_objects():
        if issubclass(type(obj), Queue):
            obj.cancel_join_thread()


def start_workers(make: Any, poll: float = 0.05, grace: float = 5.0) -> Any:
    """``make()`` (a multi-process collector) built in a thread whose stop signals are blocked.

    A signal to the process group (a terminal's Ctrl-C, Slurm's SIGTERM, a dropped ssh
    connection) reaches every process of a run; a TorchRL collector worker that gets it while it
    starts dies before it reports, and the collector then raises ``Worker 0 failed to
    initialize`` and hangs in its shutdown. Here the worker processes inherit the block, so a
    signal never kills one half-started. The main thread keeps taking signals: on one, it kills
    the workers started so far and raises :class:`Stopped` at once (nothing was trained or
    written yet; a resumed run's checkpoint is untouched)."""
    import multiprocessing

    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        return make()
    before = set(multiprocessing.active_children())
    box: dict[str, Any] = {}

    def build() -> None:
        signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            box["collector"] = make()
        except BaseException as exc:  # handed to the main thread
            box["error"] = exc

    received: list[int] = []
    with stop_handlers(lambda signum, frame: received.append(signum)):
        thread = threading.Thread(target=build, name="collector-start", daemon=True)
        thread.start()
        while thread.is_alive() and not received:
            thread.join(poll)
        if received:
            deadline = time.monotonic() + grace
            while True:  # the thread may start another worker until it fails
                for proc in set(multiprocessing.active_children()) - before:
                    proc.kill()
                if not thread.is_alive() or time.monotonic() > deadline:
                    break
                thread.join(poll)
            box.clear()  # the half-built collector: its finalizers run now, not while Python exits
            abandon_queues()
            raise Stopped(received[0])
    if "error" in box:
        raise box["error"]
    return box["collector"]


__all__ = ["APP_SIGNALS", "AppSignals", "SHUTDOWN_TIMEOUT", "STOPPED_WORKER", "STOP_SIGNALS", "SWEEP_PARENT", "Signals",
           "Stopped", "TrainingInterrupted", "end_with_parent", "ignore_stop_signals", "leave", "orphaned", "shutdown",
           "start_resource_tracker", "start_workers", "stop_handlers"]
