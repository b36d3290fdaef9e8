"""Shared helpers of the test suite: the scripts as a user runs them, in a subprocess."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def script_env(**extra: str) -> dict[str, str]:
    return {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT), **extra}


def run_script(script: str, *args: str, cwd: Path, check: bool = True, timeout: float = 600,
               **env: str) -> subprocess.CompletedProcess:
    """``python scripts/<script> <args>`` in ``cwd``; with ``check``, a non-zero exit fails the test."""
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / script), *args], cwd=cwd, env=script_env(**env),
                          capture_output=True, text=True, timeout=timeout)
    if check and proc.returncode != 0:
        raise AssertionError(f"{script} {args} exited {proc.returncode}:\n{proc.stdout}\n{proc.stderr}")
    return proc
