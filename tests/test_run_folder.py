"""The run folder: its lock (a second process on a folder is refused, naming the holder), a folder
copied or moved and continued where it stands, an old resume.yaml naming another folder, a
read-only one, what a dead run left (torn episode and scalar log lines, rows past the checkpoint,
stale temporaries of an atomic write), a full disk as the run starts."""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import TINY, finish, one_line, script, start, tiny, wait_for

from flock_torchrl import CheckpointError
from flock_torchrl.run.launch import train
from flock_torchrl.run.setup import make_train_config


# ---------------------------------------------------------------------------- the lock
@pytest.mark.slow
def test_a_second_process_on_the_same_folder_is_refused(tmp_path):
    folder = tmp_path / "run"
    first = start(*TINY, "experiment.max_frames=100000", f"hydra.run.dir={folder}", cwd=tmp_path)
    wait_for(folder / "last.pt", first)
    code, _, err = finish(start(*TINY, "experiment.max_frames=100000", "resume=true", f"hydra.run.dir={folder}",
                                cwd=tmp_path))
    assert code == 2 and f"is in use by PID {first.pid}" in err
    first.send_signal(signal.SIGINT)
    assert finish(first)[0] == 130
    # The lock died with its holder: the folder can be resumed now.
    assert finish(start(*TINY, "experiment.max_frames=200", "resume=true", f"hydra.run.dir={folder}",
                        cwd=tmp_path))[0] == 0


HOLD_THE_LOCK = """
import os, socket, sys
from filelock import FileLock
folder = sys.argv[1]
lock = FileLock(os.path.join(folder, ".lock"), timeout=0)
lock.acquire()
with open(os.path.join(folder, ".lock.holder"), "w") as holder:  # as RunLock records its holder
    holder.write(f"PID {os.getpid()} on {socket.gethostname()}, started 2026-01-01 00:00:00\\n")
print("held", flush=True)
sys.stdin.read()
"""


def test_a_busy_run_folder_names_the_process_to_stop(tmp_path):
    """A folder held by another process on this host (an orphan of a killed sweep, say): the
    refusal names its PID and the command that stops it; once it is gone the folder is free."""
    from flock_torchrl.run.run_folder import RunLock

    holder = subprocess.Popen([sys.executable, "-c", HOLD_THE_LOCK, str(tmp_path)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline() == "held\n"
        with pytest.raises(CheckpointError, match=rf"^{tmp_path} is in use by PID {holder.pid} on \S+, started "
                                                  rf"2026-01-01 00:00:00; wait for it or stop it \(kill {holder.pid}; "
                                                  r"a killed process releases its lock\)$"):
            with RunLock(tmp_path):
                pass
    finally:
        holder.kill()
        holder.wait()
    with RunLock(tmp_path):  # its lock died with it
        assert (tmp_path / ".lock.holder").read_text().startswith(f"PID {os.getpid()} on ")


# ---------------------------------------------------------------------------- copied, moved, read-only folders
def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


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


@pytest.mark.slow
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


def test_a_read_only_run_folder_is_one_line(tmp_path, monkeypatch):
    run = tmp_path / "run"
    cfg = make_train_config("policy3_g", "tiny", [*TINY, "experiment.max_frames=48"])
    train(cfg, run)
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, *a, **k: False if Path(p) == run else real(p, mode, *a, **k))
    with pytest.raises(CheckpointError, match="is not writable"):
        train(make_train_config("policy3_g", "tiny", [*TINY, "experiment.max_frames=96", "resume=true"]), run)


# ---------------------------------------------------------------------------- what a dead run left
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


def test_scalar_logs_drop_torn_tails_bad_bytes_and_rows_past_the_checkpoint(tmp_path):
    from flock_torchrl.run.run_folder import truncate_scalar_logs

    log = tmp_path / "logs" / "scalars" / "perf" / "frames_per_s.csv"
    log.parent.mkdir(parents=True)
    log.write_bytes(b"32,1.5\n64,2.5\n9\xff6,3.5\n96,x\n80\n128,4.5\n214")  # a bad byte, a torn tail, ...
    truncate_scalar_logs(tmp_path, 96)
    assert log.read_text() == "32,1.5\n64,2.5\n"
    truncate_scalar_logs(tmp_path, 96)  # nothing left to drop: unchanged
    assert log.read_text() == "32,1.5\n64,2.5\n"
    truncate_scalar_logs(tmp_path, None)  # a fresh run: the dead run's rows go
    assert not log.exists()


def test_the_episode_log_drops_what_a_dead_run_left(tmp_path):
    from flock_torchrl.run.run_folder import EpisodeLog

    path = tmp_path / "episodes.csv"
    path.write_bytes(b"episode,frames,reward\n1,40,0.5\n2,8\xff0,0.25\n3,120,0.75\n4,160,0.1\n5,2")
    log = EpisodeLog(path, ["episode", "frames", "reward"], keep_up_to=3)
    log.write([[4, 160, 0.5]])
    log.close()
    assert path.read_text() == "episode,frames,reward\n1,40,0.5\n3,120,0.75\n4,160,0.5\n"
    path.write_bytes(b"epi\xffsode,frames,reward\n1,40,0.5\n")  # a torn header is written again
    EpisodeLog(path, ["episode", "frames", "reward"], keep_up_to=3).close()
    assert path.read_text() == "episode,frames,reward\n1,40,0.5\n"


@pytest.mark.slow
def test_a_run_restarted_before_its_first_checkpoint_logs_like_an_uninterrupted_one(tmp_path):
    # A run killed before its first checkpoint left rows (and a torn, undecodable tail); a
    # restart with resume=auto (as make train-all does) starts afresh: its logs are the
    # uninterrupted run's.
    budget = ["experiment.max_frames=128", "experiment.checkpoint_every_frames=0", "experiment.log_every_frames=16",
              "logger=csv", "resume=auto"]
    dead = tmp_path / "dead" / "logs" / "scalars" / "perf" / "frames_per_s.csv"
    dead.parent.mkdir(parents=True)
    dead.write_bytes(b"16,123.0\n32,456.0\n48,7\xff")
    (tmp_path / "dead" / "episodes.csv").write_text("episode,frames\n1,40\n")
    train(tiny(*budget), tmp_path / "dead")
    train(tiny(*budget), tmp_path / "whole")
    whole = sorted(p.relative_to(tmp_path / "whole") for p in (tmp_path / "whole" / "logs").rglob("*.csv"))
    again = sorted(p.relative_to(tmp_path / "dead") for p in (tmp_path / "dead" / "logs").rglob("*.csv"))
    assert whole == again and whole
    for rel in whole:
        steps = [[line.split(",")[0] for line in (tmp_path / f / rel).read_text().splitlines()]
                 for f in ("whole", "dead")]
        assert steps[0] == steps[1], rel
        if "perf" not in rel.parts:  # timings differ, everything learned is equal
            assert (tmp_path / "whole" / rel).read_text() == (tmp_path / "dead" / rel).read_text(), rel
    assert (tmp_path / "whole" / "episodes.csv").read_text() == (tmp_path / "dead" / "episodes.csv").read_text()


# ---------------------------------------------------------------------------- a full disk as the run starts
def test_a_full_disk_at_run_start_is_one_line_naming_the_file(tmp_path, monkeypatch, capsys):
    import errno

    from flock_torchrl import io
    from flock_torchrl.cli import _guard

    real = io._atomic_write

    def full(path, write):
        if path.name == "config.yaml":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as a real write raises it: no file name
        return real(path, write)

    monkeypatch.setattr(io, "_atomic_write", full)
    run = tmp_path / "run"
    with pytest.raises(SystemExit) as info:
        _guard(lambda: train(tiny("experiment.max_frames=32"), run))
    assert info.value.code == 2
    one_line(capsys.readouterr().err, f"cannot write {run / 'config.yaml'}: no space left on the device")
    assert not (run / "config.yaml").exists() and not list(run.glob(".*.tmp"))
