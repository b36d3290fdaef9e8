"""Collector worker processes that a stop signal cannot catch half-started.

A signal to the process group (a terminal's Ctrl-C, Slurm's SIGTERM, a dropped ssh connection)
reaches every process of a run. A TorchRL collector worker that gets it while it starts dies
before it reports, and the collector then raises ``Worker 0 failed to initialize`` and hangs in
its shutdown. :func:`start_workers` builds the collector in a thread whose stop signals are
blocked (the workers inherit the block: only the main process decides when they stop) while
the main thread keeps taking signals, and stops in seconds when one comes.
"""

from __future__ import annotations

import signal
import threading
import time
from typing import Any


def _abandon_queues() -> None:
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
            try:
                obj.shutdown()
            except Exception:  # its workers are gone: what it could not send does not matter
                pass
    for obj in gc.get_objects():
        if issubclass(type(obj), Queue):
            obj.cancel_join_thread()


def start_workers(make: Any, poll: float = 0.05, grace: float = 5.0) -> Any:
    """``make()`` (a multi-process collector) built in a thread whose stop signals are blocked:
    its worker processes inherit the block, so a signal to the process group never kills one
    half-started (TorchRL then fails and hangs). The main thread keeps taking signals: on one,
    it kills the workers started so far and raises :class:`Stopped` at once (nothing was trained
    or written yet; a resumed run's checkpoint is untouched)."""
    import multiprocessing

    from .trainer import STOP_SIGNALS, Stopped

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
    previous = {signum: signal.signal(signum, lambda signum, frame: received.append(signum))
                for signum in STOP_SIGNALS}
    try:
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
            _abandon_queues()
            raise Stopped(received[0])
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    if "error" in box:
        raise box["error"]
    return box["collector"]


__all__ = ["start_workers"]
