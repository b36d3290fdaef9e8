"""How every app of scripts/ starts (not an app itself): ``start("evaluate")`` at the top of a script
(``noting()`` and ``load()`` for one whose entry is not ``flock_torchrl.cli.main``).

Python takes seconds to load torch and the package, before ``flock_torchrl.cli`` exists. Here,
first, with nothing but the standard library loaded:

* a stop signal (Ctrl-C, SIGTERM, SIGHUP) is noted, not raised inside a library's import (a
  ``KeyboardInterrupt`` traceback, or a library left half-built that fails later as another
  error); the app stops on it in one line, exit 128 + the signal, before it reads or writes
  anything (``flock_torchrl.cli.main``);
* an import that fails under the process's own memory limit (``ulimit -v`` / ``ulimit -d``: torch
  cannot map its libraries) is one ``error:`` line naming the limit, exit 2, as the apps'
  other memory refusals (``flock_torchrl/world/memory.py``) are.
"""

from __future__ import annotations

import signal
import sys

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, *((signal.SIGHUP,) if hasattr(signal, "SIGHUP") else ()))


def address_limit() -> str | None:
    """The process's address-space or data limit in words (``ulimit -v of 0.3 GiB``); ``None``: none."""
    import resource

    limits = []
    for name, which in (("ulimit -v", "RLIMIT_AS"), ("ulimit -d", "RLIMIT_DATA")):
        soft = resource.getrlimit(getattr(resource, which))[0] if hasattr(resource, which) else resource.RLIM_INFINITY
        if soft != resource.RLIM_INFINITY:
            limits.append((soft, name))
    if not limits:
        return None
    soft, name = min(limits)
    size = f"{soft / 2**30:.1f} GiB" if soft >= 2**30 / 10 else f"{soft / 2**20:.0f} MiB"
    return f"{name} of {size}"


def out_of_memory(exc: BaseException) -> str | None:
    """Why loading the app failed, in one line, when the process's memory limit is the cause: a
    ``MemoryError``, or a library that could not be mapped (``None``: another failure, left to
    its traceback)."""
    import errno

    limit = address_limit()
    text = str(exc).lower()
    mapping = "failed to map" in text or "cannot allocate memory" in text or getattr(exc, "errno", None) == errno.ENOMEM
    if limit is None or not (isinstance(exc, MemoryError) or mapping):
        return None
    why = " ".join(f"{type(exc).__name__}: {exc}".split())
    return f"error: starting the app needs more memory than its {limit} lets this process map ({why}); raise the limit"


def noting() -> list[int]:
    """Note stop signals from now on (the app stops on them once loaded); the list they go in."""
    noted: list[int] = []
    for signum in STOP_SIGNALS:
        signal.signal(signum, lambda signum, frame: noted.append(signum))
    return noted


def load(module: str, name: str):
    """``module.name``, imported; a failure under the process's memory limit is one line, exit 2."""
    import importlib

    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, MemoryError, OSError) as exc:
        line = out_of_memory(exc)
        if line is None:
            raise
        sys.stderr.write(line + "\n")
        raise SystemExit(2) from None


def start(app: str) -> None:
    """Run the Hydra app ``app`` (``flock_torchrl.cli.main``) on ``sys.argv``."""
    noted = noting()
    load("flock_torchrl.cli", "main")(app, noted)
