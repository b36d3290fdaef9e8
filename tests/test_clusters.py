"""Runs that survive real clusters and real terminals: sweep jobs resumed by their
folder, signals to a whole process group with collector processes, hang-ups, the end-of-run
evaluation, bad checkpoints, a full disk, torn logs, values the run cannot take, folder names.
Real processes and real signals where the item is about processes."""

from __future__ import annotations

import errno
import os
import pickle
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from helpers import ROOT, run_script, script_env

from flock_torchrl import CheckpointError
from flock_torchrl.policies.checkpoint import load_checkpoint
from flock_torchrl.run import parts, trainer
from flock_torchrl.run.launch import train
from flock_torchrl.run.trainer import make_train_config

TINY = ["experiment=tiny", "scenario.max_steps=40", "experiment.eval_every_frames=0", "experiment.eval_episodes=2",
        "progress=false"]


def start(*args: str, cwd: Path, group: bool = False) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(ROOT / "scripts" / "train.py"), *args], cwd=cwd, env=script_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=group)


def wait_until(condition, proc: subprocess.Popen, timeout: float = 180) -> None:
    deadline = time.time() + timeout
    while not condition():
        if proc.poll() is not None:
            raise AssertionError(f"the run ended early: {proc.communicate()}")
        if time.time() > deadline:
            proc.kill()
            raise AssertionError("timed out waiting")
        time.sleep(0.05)


def frames_at(path: Path) -> int:
    try:
        return load_checkpoint(path)["counters"]["frames"]
    except (CheckpointError, FileNotFoundError):
        return -1


def printed_resume(err: str) -> list[str]:
    (line,) = [x for x in err.splitlines() if x.startswith("stopped by")]
    command = shlex.split(line.split("resume with: ", 1)[1])
    assert command[:2] == ["python", "scripts/train.py"], command
    return [sys.executable, *command[1:]]


# ---------------------------------------------------------------------------- 1: a sweep job resumes by its folder
@pytest.mark.slow
def test_a_sweep_job_resumes_by_its_folder_with_the_printed_line(tmp_path):
    budget = ["experiment.max_frames=4000", "experiment.checkpoint_every_frames=64"]
    proc = start("-m", *TINY, *budget, "algo.lr_actor=3e-4", f"hydra.sweep.dir={tmp_path / 'sweep'}", cwd=tmp_path)
    jobs = tmp_path / "sweep" / "tiny" / "paper_fit" / "policy3_g"
    wait_until(lambda: list(jobs.glob("seed0__algo.lr_actor-0.0003*/last.pt")), proc)
    (folder,) = [p.parent for p in jobs.glob("seed0__algo.lr_actor-0.0003*/last.pt")]
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    resumed = subprocess.run(printed_resume(err), cwd=ROOT, env=script_env(), capture_output=True, text=True,
                             timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert frames_at(folder / "last.pt") == 4000
    # The folder's name is a valid Hydra value as it is: no quoting needed to evaluate it.
    proc = run_script("evaluate.py", f"checkpoint={folder}/last.pt", "episodes=2", cwd=tmp_path)
    assert "Policy3-G on train" in proc.stdout


# ---------------------------------------------------------------------------- 2, 4: signals to the process group
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
@pytest.mark.slow
def test_signals_to_the_process_group_with_collector_processes(tmp_path, signum):
    """A terminal's Ctrl-C, Slurm's SIGTERM and a dropped ssh connection reach every process
    of the run: the collector processes ignore them, the main process checkpoints and exits
    with 128 + the signal, within the watchdog's bound."""
    folder = tmp_path / "run"
    proc = start(*TINY, "experiment.workers=2", "experiment.max_frames=100000", "experiment.checkpoint_every_frames=320",
                 f"hydra.run.dir={folder}", cwd=tmp_path, group=True)
    wait_until(lambda: (folder / "last.pt").exists(), proc)
    os.killpg(proc.pid, signum)
    began = time.time()
    try:
        out, err = proc.communicate(timeout=trainer.SHUTDOWN_TIMEOUT + 60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise AssertionError("the run hung after the signal")
    assert proc.returncode == 128 + signum, err
    assert time.time() - began < trainer.SHUTDOWN_TIMEOUT + 30
    assert "Traceback" not in err and f"stopped by {signal.Signals(signum).name}" in err
    assert 0 < frames_at(folder / "last.pt") < 100000


# ---------------------------------------------------------------------------- 3: the end-of-run evaluation
@pytest.mark.slow
def test_a_signal_during_the_final_evaluation_keeps_the_run_and_its_evaluation(tmp_path):
    folder = tmp_path / "run"
    args = [*TINY, "experiment.max_frames=96", "experiment.eval_episodes=4000", "scenario.max_steps=300",
            f"hydra.run.dir={folder}"]
    proc = start(*args, cwd=tmp_path)
    # The checkpoint written just before the final evaluation holds every frame.
    wait_until(lambda: frames_at(folder / "last.pt") == 96, proc)
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    payload = load_checkpoint(folder / "last.pt")
    assert payload["counters"]["frames"] == 96 and not any(e["frames"] == 96 for e in payload["evaluations"])
    # The resumed run is not "finished" until it has its final evaluation.
    done = subprocess.run(printed_resume(err), cwd=ROOT, env=script_env(), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "evaluation (4000 episodes" in done.stdout
    assert load_checkpoint(folder / "last.pt")["evaluations"][-1]["frames"] == 96


@pytest.mark.slow
def test_a_signal_while_starting_is_one_line(tmp_path):
    proc = start(*TINY, cwd=tmp_path)
    time.sleep(0.3)  # Python is still importing torch
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143 and "Traceback" not in err and err.startswith("stopped by SIGTERM"), \
        (proc.returncode, err)
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- 5: bad checkpoints
def _malicious(path: Path) -> None:
    class Payload:
        def __reduce__(self):
            return (os.system, ("echo this-must-never-run",))

    with path.open("wb") as handle:
        pickle.dump({"payload": Payload()}, handle)


@pytest.mark.parametrize("make, words", [
    (lambda p: p.write_bytes(b""), "is empty"),
    (lambda p: p.write_text("my notes\n"), "not a readable checkpoint"),
    (_malicious, "holds Python objects a checkpoint never contains"),
])
@pytest.mark.slow
def test_a_bad_checkpoint_is_one_line_naming_it_and_never_suggests_unsafe_loading(tmp_path, make, words):
    bad = tmp_path / "bad.pt"
    make(bad)
    proc = run_script("evaluate.py", f"checkpoint={bad}", "episodes=2", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert str(bad) in proc.stderr and words in proc.stderr
    assert "weights_only" not in proc.stderr and "this-must-never-run" not in proc.stdout


# ---------------------------------------------------------------------------- 6: disk full, torn logs, stale files
def test_a_full_disk_says_so_in_one_line_and_keeps_the_last_checkpoint(tmp_path, monkeypatch):
    cfg = make_train_config("policy3_g", "tiny", [*TINY, "experiment.max_frames=160",
                                                  "experiment.checkpoint_every_frames=64"])
    real, calls = parts.save_checkpoint, {"n": 0}

    def full_after_one(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] > 1:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(*args, **kwargs)

    monkeypatch.setattr(parts, "save_checkpoint", full_after_one)
    with pytest.raises(CheckpointError) as info:
        train(cfg, tmp_path / "run")
    message = str(info.value)
    assert "no space left on the device" in message and "the last good checkpoint is" in message
    assert "\n" not in message and frames_at(tmp_path / "run" / "last.pt") == 64


def test_resume_repairs_torn_log_lines_and_removes_stale_temporaries(tmp_path):
    run = tmp_path / "run"
    train(make_train_config("policy3_g", "tiny", [*TINY, "experiment.max_frames=96", "logger=csv"]), run)
    with (run / "episodes.csv").open("a") as handle:
        handle.write("57,12")  # what a full disk leaves: half a row, no newline
    scalar = next((run / "logs" / "scalars").rglob("*.csv"))
    with scalar.open("a") as handle:
        handle.write("9")
    (run / ".last.pt.k3j2.tmp").write_bytes(b"\x00" * 100)  # an atomic write killed halfway
    resumed = train(make_train_config("policy3_g", "tiny", [*TINY, "experiment.max_frames=160", "logger=csv",
                                                           "resume=true"]), run)
    assert resumed.frames == 160 and not list(run.glob(".*.tmp"))
    rows = (run / "episodes.csv").read_text().splitlines()
    assert all(len(r.split(",")) == len(rows[0].split(",")) for r in rows)
    assert all(len(line.split(",")) == 2 for line in scalar.read_text().splitlines())


# ---------------------------------------------------------------------------- 7, 8: values the run cannot take
@pytest.mark.slow
@pytest.mark.parametrize("bad, key", [
    ("seed=1700000000000000000", "seed"),
    ("algo.buffer_size=900000000", "algo.buffer_size"),
    ("experiment.num_envs=10000000", "experiment.num_envs"),
    ("scenario.n_uavs=10000", "scenario.n_uavs"),
    ("scenario.dt=1e30", "scenario.dt"),
    ("experiment.name=../../../x", "experiment.name"),
    ("policy.id=../../x/y", "policy.id"),
])
def test_values_the_run_cannot_take_are_refused_before_anything_is_written(tmp_path, bad, key):
    proc = run_script("train.py", *TINY, bad, cwd=tmp_path, check=False)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith(f"error: {key}") and proc.stderr.count("\n") == 1, proc.stderr
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- 10: late or raw
@pytest.mark.slow
def test_a_corrupted_paper_recipe_checkpoint_is_found_before_the_first_row(tmp_path):
    recipe = tmp_path / "recipe" / "policy3_g"
    recipe.mkdir(parents=True)
    (recipe / "seed0.pt").write_text("truncated")
    proc = run_script("reproduce.py", "table=3", "episodes=2", f"paper_recipe_dir={tmp_path / 'recipe'}",
                      f"hydra.run.dir={tmp_path / 'out'}", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and str(recipe / "seed0.pt") in proc.stderr
    assert not (tmp_path / "out").exists() and "[table 3," not in proc.stdout  # no row evaluated


def test_a_read_only_run_folder_is_one_line(tmp_path, monkeypatch):
    run = tmp_path / "run"
    cfg = make_train_config("policy3_g", "tiny", [*TINY, "experiment.max_frames=48"])
    train(cfg, run)
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, *a, **k: False if Path(p) == run else real(p, mode, *a, **k))
    with pytest.raises(CheckpointError, match="is not writable"):
        train(make_train_config("policy3_g", "tiny", [*TINY, "experiment.max_frames=96", "resume=true"]), run)


@pytest.mark.slow
def test_an_int_inside_a_float_list_is_taken(tmp_path):
    proc = run_script("evaluate.py", "policy=policy_ma", "scenario.circles=[[40,40,6]]", "episodes=2", cwd=tmp_path)
    assert "Policy-MA on train" in proc.stdout


def test_a_checkpoint_of_a_newer_format_says_newer(tmp_path):
    torch.save({"format": "flock_torchrl/checkpoint-v3"}, tmp_path / "new.pt")
    with pytest.raises(CheckpointError, match="newer flock_torchrl"):
        load_checkpoint(tmp_path / "new.pt")


def test_app_signals_note_until_the_run_is_checked_then_stop():
    """run/signals.py's AppSignals, in this process (the handlers are called, not signalled)."""
    from flock_torchrl.run.signals import STOP_SIGNALS, AppSignals, Stopped

    previous = {signum: signal.getsignal(signum) for signum in STOP_SIGNALS}
    app = AppSignals()
    try:
        # A signal the script noted while importing stops the run once it is checked.
        app.start([signal.SIGTERM])
        with pytest.raises(Stopped) as stop:
            app.arm()
        assert stop.value.signum == signal.SIGTERM
        # Before the check, a signal is only noted ...
        app.start()
        signal.getsignal(signal.SIGINT)(signal.SIGINT, None)
        assert app.noted == [signal.SIGINT]
        # ... once armed, it stops at once.
        app.start()
        app.arm()
        with pytest.raises(Stopped):
            signal.getsignal(signal.SIGTERM)(signal.SIGTERM, None)
        # Not a joblib sweep's parent or worker: nothing stopped a sweep.
        assert (app.sweep_stopped(), app.worker_stopped(), app.in_sweep_worker()) == (0, 0, False)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
