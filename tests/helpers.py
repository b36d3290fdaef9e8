"""Shared helpers of the test suite: the scripts as a user runs them, in a subprocess, bad
scenario values that the config and the env both refuse, and the tiny runs, started and watched,
of the run-level tests (signals, resume, run folder, checkpoint files, memory, start-up)."""

from __future__ import annotations

import math
import os
import shlex
import subprocess
import sys
import time
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


# Bad scenario values and the field each error names: ScenarioConfig refuses them
# (tests/test_config_scenario.py), FlockingEnv at construction (tests/test_env.py).
BAD_SCENARIO_VALUES = [
    (dict(n_uavs=0), "n_uavs"),
    (dict(n_uavs=-3), "n_uavs"),
    (dict(n_uavs=60, spawn_reference_uavs=60), "n_uavs"),  # 60 UAVs 1 m apart in a 3 m disc: refused, not hung
    (dict(fov=0.0), "fov"),
    (dict(fov=-1.0), "fov"),
    (dict(fov=2 * math.pi + 0.01), "fov"),
    (dict(fov=float("nan")), "fov"),
    (dict(dt=0.0), "dt"),
    (dict(dt=-0.2), "dt"),
    (dict(dt=float("inf")), "dt"),
    (dict(tau_v=0.0), "tau_v"),
    (dict(tau_v=-1.0), "tau_v"),
    (dict(v_max=0.0), "v_max"),
    (dict(camera_range=0.0), "camera_range"),
    (dict(max_steps=0), "max_steps"),
    (dict(n_scan=37), "n_scan"),
    (dict(collision_reward_source="lidar"), "collision_reward_source"),
    (dict(collision_shape="smooth"), "collision_shape"),
    (dict(cohesion_range="linear"), "cohesion_range"),
    (dict(actor_camera="wide"), "actor_camera"),
    (dict(action_mode="torque"), "action_mode"),
    (dict(circles=[[40.0, 40.0, 6.0], [45.0, 40.0, 2.0]]), "circles"),          # circle-circle overlap
    (dict(circles=[[14.0, 40.0, 2.0]]), "circles"),                            # circle inside rect x in [7, 13] +2
    (dict(rectangles=[[10.0, 40.0, 6.0, 16.0], [14.0, 40.0, 4.0, 4.0]]), "rectangles"),  # rect-rect overlap
    (dict(circles=[[40.0, 40.0, -1.0]]), "circles"),
    (dict(rectangles=[[10.0, 40.0, 0.0, 16.0]]), "rectangles"),
    (dict(safe_distance=-1.0), "safe_distance"),
    (dict(n_moving=-1), "n_moving"),
    (dict(n_moving=1, moving_box=[70.0, 10.0]), "moving_box"),
]



def first_fast(cases) -> list:
    """``cases`` for ``pytest.mark.parametrize`` with every case but the first marked slow: a family
    whose every case starts a process or trains keeps one case in ``make test`` and runs whole in
    ``make test-all``."""
    import pytest

    return [case if i == 0 else pytest.param(*(case if isinstance(case, tuple) else (case,)), marks=pytest.mark.slow)
            for i, case in enumerate(cases)]


# ---------------------------------------------------------------------------- runs as a user starts them
# The tiny experiment with short episodes and no periodic evaluation: a run of seconds.
TINY = ["experiment=tiny", "scenario.max_steps=40", "experiment.eval_every_frames=0", "experiment.eval_episodes=2",
        "progress=false", "threads=1"]
SHIPPED = ROOT / "checkpoints" / "paper_fit" / "policy3_g" / "seed0.pt"


def tiny(*overrides: str):
    """Policy3-G's config on :data:`TINY` and ``overrides``."""
    from flock_torchrl.run.setup import make_train_config

    return make_train_config("policy3_g", "tiny", [*TINY, *overrides])


def tiny_pipeline(policy: str = "policy3_g", *overrides: str, logger: str = "csv"):
    """The learning pipeline's tiny run (tests/test_training.py): the tiny experiment with its own
    periodic evaluations, 60-step episodes and a logger."""
    from flock_torchrl.run.setup import make_train_config

    # Short episodes keep the periodic evaluations (untrained policies never arrive) fast.
    return make_train_config(policy, "tiny", ["scenario.max_steps=60", "progress=false", f"logger={logger}",
                                              *overrides])


def script(name: str, *args: str, cwd: Path, timeout: float = 300, preexec=None, **env: str):
    """``python scripts/<name> <args>`` in ``cwd`` (``preexec``: a ``preexec_fn``, e.g. a limit), unchecked."""
    return subprocess.run([sys.executable, str(ROOT / "scripts" / name), *args], cwd=cwd, env=script_env(**env),
                          capture_output=True, text=True, timeout=timeout, preexec_fn=preexec)


def start(*args: str, cwd: Path, group: bool = False) -> subprocess.Popen:
    """``python scripts/train.py <args>`` started in ``cwd`` (``group``: in a process group of its own)."""
    return subprocess.Popen([sys.executable, str(ROOT / "scripts" / "train.py"), *args], cwd=cwd, env=script_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=group)


def finish(proc: subprocess.Popen, timeout: float = 300) -> tuple[int, str, str]:
    out, err = proc.communicate(timeout=timeout)
    return proc.returncode, out, err


def wait_until(condition, proc: subprocess.Popen, timeout: float = 180) -> None:
    deadline = time.time() + timeout
    while not condition():
        if proc.poll() is not None:
            raise AssertionError(f"the run ended early: {proc.communicate()}")
        if time.time() > deadline:
            proc.kill()
            raise AssertionError("timed out waiting")
        time.sleep(0.05)


def wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120) -> None:
    """Until ``path`` exists (the run's first checkpoint, say)."""
    wait_until(path.exists, proc, timeout)


def frames_at(path: Path) -> int:
    """The frames of the checkpoint at ``path``; -1 while there is none (or it is being written)."""
    from flock_torchrl import CheckpointError
    from flock_torchrl.policies.checkpoint import load_checkpoint

    try:
        return load_checkpoint(path)["counters"]["frames"]
    except (CheckpointError, FileNotFoundError):
        return -1


def resume_line(err: str) -> list[str]:
    """The command a stopped run printed to continue it, as argv (run from the repository)."""
    (line,) = [x for x in err.splitlines() if x.startswith("stopped by")]
    command = shlex.split(line.split("resume with: ", 1)[1])
    assert command[:2] == ["python", "scripts/train.py"], command
    return [sys.executable, *command[1:]]


def one_line(err: str, start: str) -> None:
    """``err`` is one line, ``error: <start>...``, and no traceback."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {start}"), err
    assert "Traceback" not in err
