"""Runs that survive their users: config errors, signals, concurrent runs, resumes, corrupted
files. Each test is an observation that failed before (env misuse is in tests/test_env.py)."""

from __future__ import annotations

import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml
from helpers import first_fast, script_env

from flock_torchrl import CheckpointError
from flock_torchrl.policies.checkpoint import export_policy, load_checkpoint, save_checkpoint
from flock_torchrl.run.launch import train
from flock_torchrl.run.trainer import make_train_config

ROOT = Path(__file__).resolve().parent.parent
TINY = ["experiment=tiny", "scenario.max_steps=40", "experiment.eval_every_frames=0", "experiment.eval_episodes=2",
        "progress=false", "threads=1"]


def start(*args: str, cwd: Path) -> subprocess.Popen:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, str(ROOT / "scripts" / "train.py"), *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def finish(proc: subprocess.Popen, timeout: float = 300) -> tuple[int, str, str]:
    out, err = proc.communicate(timeout=timeout)
    return proc.returncode, out, err


def wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120) -> None:
    deadline = time.time() + timeout
    while not path.exists():
        if proc.poll() is not None:
            raise AssertionError(f"the run ended before {path} appeared: {proc.communicate()}")
        if time.time() > deadline:
            proc.kill()
            raise AssertionError(f"{path} did not appear")
        time.sleep(0.05)


def tiny(*overrides: str):
    return make_train_config("policy3_g", "tiny", [*TINY, *overrides])


# ---------------------------------------------------------------------------- 6: config errors
@pytest.mark.parametrize("bad, key", first_fast([
    ("seed=-1", "seed: must be an integer >= 0"),
    ("seed=99999999999999999999", "seed: must be an integer >= 0 and <= 4294967295"),
    ("device=gpu0", "device: must be cpu, cuda"),
    ("device=cuda", "device: 'cuda'"),
    ("algo.lr_actor=-1", "algo.lr_actor: must be a positive"),
    ("scenario.fov=7", "scenario.fov: must be a positive finite number and <= 6.28319"),
    ("policy=policy_ma", "policy: Policy-MA is rule-based"),
    ("experiment.workers=3", "experiment.workers: 3 must divide num_envs=4"),
    ("scenario.tangential=2", "scenario.tangential: must be true or false, got 2"),
]))
def test_config_errors_are_one_line_exit_2_and_leave_nothing(tmp_path, bad, key):
    if bad == "device=cuda" and torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    code, out, err = finish(start(*TINY, bad, cwd=tmp_path))
    assert code == 2, err
    assert err.strip().splitlines() == [f"error: {err.strip()[7:]}"] and err.startswith(f"error: {key}")
    assert list(tmp_path.iterdir()) == []  # no run folder, no .hydra, no log


@pytest.mark.slow
@pytest.mark.parametrize("bad, key", [("scenario.n_uavs=abc", "scenario.n_uavs"), ("seed=abc", "seed"),
                                      ("policy=nope", "policy/nope"), ("algo.lr_critc=1", "lr_critc")])
def test_composition_errors_are_hydras_own_and_leave_nothing(tmp_path, bad, key):
    # A value of the wrong type, an unknown choice or key: Hydra's message (naming it), status 1.
    code, out, err = finish(start(*TINY, bad, cwd=tmp_path))
    assert code == 1 and key in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_a_sweep_is_checked_whole_before_any_job_runs(tmp_path):
    code, _, err = finish(start("-m", *TINY, "seed=0,1", "algo.lr_actor=0.001,-1", cwd=tmp_path))
    assert code == 2 and "algo.lr_actor" in err and list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- 2: signals
def resume_line(err: str) -> list[str]:
    """The command a stopped run printed to continue it, as argv (run from the repository)."""
    (line,) = [x for x in err.splitlines() if x.startswith("stopped by")]
    command = shlex.split(line.split("resume with: ", 1)[1])
    assert command[:2] == ["python", "scripts/train.py"], command
    return [sys.executable, *command[1:]]


@pytest.mark.parametrize("signum, status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
@pytest.mark.slow
def test_a_signal_checkpoints_then_resume_matches_an_uninterrupted_run(tmp_path, signum, status):
    budget = ["experiment.max_frames=3200", "experiment.checkpoint_every_frames=64"]
    folder = tmp_path / "run"
    proc = start(*TINY, *budget, f"hydra.run.dir={folder}", cwd=tmp_path)
    wait_for(folder / "last.pt", proc)
    proc.send_signal(signum)
    code, out, err = finish(proc)
    assert code == status, err
    stopped = load_checkpoint(folder / "last.pt", kind="training")["counters"]["frames"]
    assert 64 <= stopped < 3200, "the signal did not land mid-run"
    assert "Traceback" not in err
    # The printed command, run verbatim, continues the run.
    resumed = subprocess.run(resume_line(err), cwd=ROOT, env=script_env(), capture_output=True, text=True,
                             timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    whole = train(tiny(*budget), tmp_path / "whole")
    a, b = load_checkpoint(whole.checkpoint), load_checkpoint(folder / "last.pt")
    assert a["counters"]["frames"] == b["counters"]["frames"] == 3200
    for key, value in a["actor"].items():
        assert torch.equal(value, b["actor"][key]), key
    assert (tmp_path / "whole" / "episodes.csv").read_text() == (folder / "episodes.csv").read_text()


@pytest.mark.slow
def test_a_second_ctrl_c_aborts_at_once():
    from flock_torchrl.run.trainer import Signals, Stopped

    before = signal.getsignal(signal.SIGINT)
    with Signals() as signals:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.01)
        assert signals.received == signal.SIGINT
        with pytest.raises(Stopped):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.01)
    assert signal.getsignal(signal.SIGINT) is before


def test_a_second_signal_in_training_says_where_it_stopped_and_how_to_resume():
    """The Stopped of a second Ctrl-C in the loop carries the run's resume command, and says
    "during training"; one outside a loop (an app's start) says that."""
    from flock_torchrl.run.trainer import Signals, Stopped

    with Signals("python scripts/train.py -cd runs/x -cn resume") as signals:
        signals.handle(signal.SIGINT, None)
        with pytest.raises(Stopped) as stop:
            signals.handle(signal.SIGINT, None)
    message = stop.value.message()
    assert "during training" in message and "outside" not in message
    assert message.endswith("resume with: python scripts/train.py -cd runs/x -cn resume")
    assert "outside a training loop" in Stopped(signal.SIGTERM).message()


# The child sends itself SIGINT from inside `import torch`, which every app reaches through its
# imports: the signal lands where a Ctrl-C a second after the start lands, every time.
INTERRUPT_IN_IMPORT = """
import os, signal, sys

class InterruptTorchsImport:
    def find_spec(self, name, path=None, target=None):
        if name == "torch":
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)
        return None

sys.meta_path.insert(0, InterruptTorchsImport())
"""


@pytest.mark.parametrize("app", first_fast(["evaluate", "diagnose", "scaling", "train", "reproduce", "figures", "ship",
                                            "tune_baselines"]))
def test_ctrl_c_while_an_app_imports_is_one_line_and_exit_130(tmp_path, app):
    from flock_torchrl.cli import APPS

    assert app in APPS
    site, work = tmp_path / "site", tmp_path / "work"
    site.mkdir()
    work.mkdir()
    (site / "sitecustomize.py").write_text(INTERRUPT_IN_IMPORT)
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / f"{app}.py")], cwd=work, capture_output=True,
                          text=True, timeout=300, env=script_env(PYTHONPATH=f"{site}{os.pathsep}{ROOT}"))
    assert proc.returncode == 130, proc.stderr[-3000:]
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()], proc.stderr[-3000:]
    assert proc.stderr.startswith("stopped by SIGINT outside a training loop") and "Traceback" not in proc.stderr
    assert list(work.iterdir()) == []  # it stopped before reading a config or making a folder


# ---------------------------------------------------------------------------- 3: concurrent runs
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


# ---------------------------------------------------------------------------- 4 and 1: resume
def test_resume_with_other_settings_is_refused_and_changes_nothing(tmp_path):
    result = train(tiny("experiment.max_frames=64"), tmp_path / "run")
    files = {p: p.read_bytes() for p in (tmp_path / "run").rglob("*") if p.is_file() and p.name != ".lock"}
    for bad in ("scenario.tau_v=0.5", "scenario.fov=3.0", "algo.lr_actor=0.1"):
        with pytest.raises(CheckpointError, match=bad.split("=")[0].replace(".", r"\.")):
            train(tiny("experiment.max_frames=96", "resume=true", bad), result.run_dir)
    assert {p: p.read_bytes() for p in (tmp_path / "run").rglob("*") if p.is_file() and p.name != ".lock"} == files
    # Budgets, logging and runtime knobs may change.
    resumed = train(tiny("experiment.max_frames=96", "resume=true", "logger=none", "progress=true"), result.run_dir)
    assert resumed.frames == 96


def test_a_finished_run_without_its_buffer_resumes_to_a_no_op(tmp_path):
    cfg = tiny("experiment.max_frames=64", "experiment.keep_buffer_in_checkpoint=false", "resume=auto")
    first = train(cfg, tmp_path / "run")
    before = (tmp_path / "run" / "last.pt").read_bytes()
    again = train(cfg, tmp_path / "run")
    assert (again.frames, again.updates) == (first.frames, first.updates)
    assert (tmp_path / "run" / "last.pt").read_bytes() == before


@pytest.mark.slow
def test_the_demo_twice(tmp_path):
    # Observation 1: `make demo` run twice exited 2 the second time.
    args = ["experiment=demo", "resume=auto", "experiment.max_frames=512", "experiment.init_random_frames=256",
            "experiment.checkpoint_every_frames=256", "experiment.eval_episodes=4", "scenario.max_steps=40",
            "progress=false"]
    code, first, err = finish(start(*args, cwd=tmp_path))
    assert code == 0, err
    code, second, err = finish(start(*args, cwd=tmp_path))
    assert code == 0, err
    assert first.splitlines()[-1] == second.splitlines()[-1]  # the same evaluation line
    assert first.splitlines()[-2].split(" (")[1].split(", ")[:3] == second.splitlines()[-2].split(" (")[1].split(", ")[:3]


# ---------------------------------------------------------------------------- 5: corrupted files
def test_corrupted_foreign_and_wrong_kind_checkpoints_say_which(tmp_path):
    result = train(tiny("experiment.max_frames=48"), tmp_path / "run")
    data = bytearray(result.checkpoint.read_bytes())
    actor = load_checkpoint(result.checkpoint)["actor"]
    weights = next(v for v in actor.values() if v.numel() > 100).numpy().tobytes()
    at = bytes(data).find(weights[:64])
    assert at > 0
    data[at + 40:at + 56] = bytes(255 - b for b in data[at + 40:at + 56])  # 16 bytes inside a weight tensor
    flipped = tmp_path / "flipped.pt"
    flipped.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match="corrupted: its payload does not match its SHA-256"):
        load_checkpoint(flipped)
    text = tmp_path / "notes.pt"
    text.write_text("these are my notes\n")
    with pytest.raises(CheckpointError, match="not a readable checkpoint"):
        load_checkpoint(text)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(CheckpointError, match="foreign"):
        load_checkpoint(foreign)
    slim = export_policy(result.checkpoint, tmp_path / "slim.pt")
    with pytest.raises(CheckpointError, match="slim shipped policy"):
        load_checkpoint(slim, kind="training")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "last.pt").write_bytes(slim.read_bytes())
    with pytest.raises(CheckpointError, match="slim shipped policy"):
        train(tiny("resume=true"), tmp_path / "other")
    # Digest-valid, but not what a kind holds : refused naming the missing keys.
    save_checkpoint({"x": 1}, tmp_path / "odd.pt", kind="policy")
    with pytest.raises(CheckpointError, match="policy checkpoint without meta, actor"):
        load_checkpoint(tmp_path / "odd.pt")


# ---------------------------------------------------------------------------- 8: logs after kill -9
@pytest.mark.slow
def test_logs_after_kill_and_resume_equal_an_uninterrupted_runs(tmp_path):
    budget = ["experiment.max_frames=2400", "experiment.checkpoint_every_frames=160", "logger=csv"]
    folder = tmp_path / "run"
    proc = start(*TINY, *budget, f"hydra.run.dir={folder}", cwd=tmp_path)
    wait_for(folder / "last.pt", proc)
    time.sleep(0.3)  # let it log past the checkpoint
    proc.kill()
    proc.wait()
    assert load_checkpoint(folder / "last.pt")["counters"]["frames"] < 2400
    assert finish(start("-cd", str(folder), "-cn", "resume", cwd=tmp_path))[0] == 0
    whole = tmp_path / "whole"
    assert finish(start(*TINY, *budget, f"hydra.run.dir={whole}", cwd=tmp_path))[0] == 0
    logs = sorted(p.relative_to(whole) for p in (whole / "logs" / "scalars").rglob("*.csv"))
    assert logs
    for rel in logs:
        steps_a = [line.split(",")[0] for line in (whole / rel).read_text().splitlines()]
        steps_b = [line.split(",")[0] for line in (folder / rel).read_text().splitlines()]
        assert steps_a == steps_b, rel
        if "perf" not in rel.parts:  # timings differ, everything learned is equal
            assert (whole / rel).read_text() == (folder / rel).read_text(), rel
    assert (whole / "episodes.csv").read_text() == (folder / "episodes.csv").read_text()
    saved = yaml.safe_load((folder / "config.yaml").read_text())
    assert saved["experiment"]["max_frames"] == 2400


def test_a_resume_without_its_episode_log_is_refused_naming_it(tmp_path):
    """The log a resume continues is gone while the checkpoint counts episodes: one line naming
    the file, nothing changed (restarting it would leave a curve shorter than the counters)."""
    run = train(tiny("experiment.max_frames=96", "logger=none", "scenario.max_steps=12"), tmp_path / "run")
    assert run.episodes > 0
    (tmp_path / "run" / "episodes.csv").unlink()
    with pytest.raises(CheckpointError, match=rf"^{tmp_path / 'run' / 'episodes.csv'} is missing, but the "
                                              rf"checkpoint in {tmp_path / 'run'} counts {run.episodes} episodes"):
        train(tiny("experiment.max_frames=128", "logger=none", "scenario.max_steps=12", "resume=true"), tmp_path / "run")
    assert not (tmp_path / "run" / "episodes.csv").exists()
