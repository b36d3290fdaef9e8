"""Runs that survive what the last fault probe found (issue 30): moved run folders, memory the
run cannot have, logs a dead run left, disk and file-size faults, crafted checkpoints, env
misuse, messages that name the right place, signals while collector workers start, sweeps."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import script_env

from flock_torchrl.run.trainer import make_train_config, train

ROOT = Path(__file__).resolve().parent.parent
TINY = ["experiment=tiny", "scenario.max_steps=40", "experiment.eval_every_frames=0", "experiment.eval_episodes=2",
        "progress=false", "threads=1"]


def tiny(*overrides: str):
    return make_train_config("policy3_g", "tiny", [*TINY, *overrides])


def script(name: str, *args: str, cwd: Path, timeout: float = 300, preexec=None, **env: str):
    return subprocess.run([sys.executable, str(ROOT / "scripts" / name), *args], cwd=cwd, env=script_env(**env),
                          capture_output=True, text=True, timeout=timeout, preexec_fn=preexec)


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def one_line(err: str, start: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {start}"), err
    assert "Traceback" not in err


# ---------------------------------------------------------------------------- 1: moved run folders
@pytest.mark.slow
def test_a_copied_folder_continues_the_copy_and_a_moved_one_where_it_stands(tmp_path):
    run = tmp_path / "run"
    train(tiny("experiment.max_frames=64"), run)
    original = digest(run / "last.pt")
    shutil.copytree(run, tmp_path / "copy")
    proc = script("train.py", "-cd", "copy", "-cn", "resume", "experiment.max_frames=96", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert digest(run / "last.pt") == original  # the original is never touched
    assert f"{tmp_path / 'copy' / 'last.pt'} (96 frames" in proc.stdout
    (tmp_path / "copy").rename(tmp_path / "moved")
    proc = script("train.py", "-cd", "moved", "-cn", "resume", "experiment.max_frames=128", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert f"{tmp_path / 'moved' / 'last.pt'} (128 frames" in proc.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["moved", "run"]
    assert digest(run / "last.pt") == original


def test_an_old_resume_yaml_naming_another_folder_is_refused(tmp_path):
    # resume.yaml files written before run folders could move name their folder by its path.
    folder = tmp_path / "copy"
    folder.mkdir()
    (folder / "resume.yaml").write_text(
        "defaults:\n- train_schema\n- _self_\nresume: 'true'\nhydra:\n  callbacks:\n    check:\n"
        "      _target_: flock_torchrl.cli.PreRunCheck\n      app: train\n  run:\n"
        f"    dir: {tmp_path / 'run'}\n")
    proc = script("train.py", "-cd", "copy", "-cn", "resume", cwd=tmp_path)
    assert proc.returncode == 2
    one_line(proc.stderr, f"hydra.run.dir: {folder / 'resume.yaml'} names another run folder, {tmp_path / 'run'}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["copy"]


# ---------------------------------------------------------------------------- 2: memory
def limit_memory(gib: float):
    """A ``preexec_fn``: the child's address space is limited to ``gib`` GiB (``ulimit -v``)."""
    def limit() -> None:
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (int(gib * 2**30), int(gib * 2**30)))
    return limit


@pytest.mark.parametrize("app, args, gib, key", [
    ("evaluate.py", ["policy=policy_ma", "episodes=10000000"], None, "episodes: evaluating 10000000 episodes"),
    ("evaluate.py", ["policy=policy_ma", "episodes=1000000"], 8, "episodes: evaluating 1000000 episodes"),
    ("train.py", [*TINY, "experiment.eval_episodes=1000000"], None, "experiment.eval_episodes: the run needs"),
    ("train.py", [*TINY, "algo.buffer_size=20000000"], 5, "algo.buffer_size: the run needs"),
    ("train.py", [*TINY, "experiment.swarm_sizes=[5,100000]"], None,
     "experiment.swarm_sizes[1]: must be an integer >= 1 and <= 2000"),
    ("evaluate.py", ["policy=policy_ma", "scenario=forest", "scenario.random_circles=1000", "episodes=2",
                     "scenario.random_region=[-1000000,-1000000,1000000,1000000]"], None,
     "scenario.random_region: checking that the swarm and the forest can always be placed needs about"),
])
def test_memory_the_run_cannot_have_is_refused_before_anything_is_written(tmp_path, app, args, gib, key):
    proc = script(app, *args, f"hydra.run.dir={tmp_path / 'out'}", cwd=tmp_path, timeout=120,
                  preexec=limit_memory(gib) if gib else None)
    assert proc.returncode == 2, proc.stderr[-3000:]
    one_line(proc.stderr, key)
    if gib:
        assert f"its ulimit -v of {gib:.1f} GiB" in proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_check_memory_names_the_costliest_key_and_the_bound():
    from flock_torchrl.config import ConfigError
    from flock_torchrl.run.memory import Usable, check_memory

    check_memory({"a": 2**30, "b": 2**30}, "x", Usable(3 * 2**30, "a test bound"))  # fits
    with pytest.raises(ConfigError, match=r"^b: x needs about 3.0 GiB, 2.0 GiB of it for b, but this process can "
                                          r"use 2.5 GiB \(a test bound\)"):
        check_memory({"a": 2**30, "b": 2 * 2**30}, "x", Usable(int(2.5 * 2**30), "a test bound"))


def test_usable_memory_sees_the_processs_own_limit():
    code = ("import resource; resource.setrlimit(resource.RLIMIT_AS, (6 * 2**30, 6 * 2**30)); "
            "from flock_torchrl.run.memory import usable_memory; u = usable_memory(); print(u.bytes, u.what)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=script_env(), timeout=60)
    used, what = int(out.stdout.split()[0]), out.stdout.split(" ", 1)[1]
    assert what.startswith("its ulimit -v of 6.0 GiB") and 0 < used < 6 * 2**30, out


@pytest.mark.parametrize("scenario, n, worlds", [("s1", 5, 4000), ("s2", 100, 400)])
def test_the_world_estimate_bounds_the_measured_peak(scenario, n, worlds):
    # Peak resident memory of stepping `worlds` worlds, in a fresh process, against world_bytes.
    code = f"""
from flock_torchrl import FlockingEnv
from flock_torchrl.config import EvaluateConfig, compose
from flock_torchrl.run.memory import world_bytes
s = EvaluateConfig.from_config(compose("evaluate", ["scenario={scenario}", "scenario.n_uavs={n}", "episodes=1"])).scenario
env = FlockingEnv(s, num_envs=1, seed=0); env.rollout(3, break_when_any_done=False)
def status(field):
    return next(int(l.split()[1]) * 1024 for l in open("/proc/self/status") if l.startswith(field))
open("/proc/self/clear_refs", "w").write("5")  # the peak (VmHWM) starts again from here
base = status("VmRSS:")
env = FlockingEnv(s, num_envs={worlds}, seed=0); env.rollout(5, break_when_any_done=False)
print(status("VmHWM:") - base, {worlds} * world_bytes(s))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=script_env(), timeout=120)
    measured, estimate = map(int, out.stdout.split())
    assert measured <= estimate <= 6 * measured, (measured, estimate)
