"""Shared helpers of the test suite: the scripts as a user runs them, in a subprocess, and
bad scenario values that the config and the env both refuse."""

from __future__ import annotations

import math
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
