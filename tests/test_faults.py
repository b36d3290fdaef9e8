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
