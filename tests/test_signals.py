"""Stop signals as a user and a cluster send them: Ctrl-C, SIGTERM and SIGHUP to a run, to its
process group with collector processes, while an app imports or its workers start, during the
final evaluation; the exit status (128 + the signal), the one line each stop prints and the resume
command it names, which continues the run bit for bit; a second Ctrl-C; joblib sweeps stopped or
killed, and their job workers. Real processes and real signals where the subject is processes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from helpers import (ROOT, TINY, finish, first_fast, frames_at, resume_line, run_script, script, script_env, start,
                     tiny, wait_for, wait_until)

from flock_torchrl.policies.checkpoint import load_checkpoint
from flock_torchrl.run.signals import SHUTDOWN_TIMEOUT
from flock_torchrl.run.launch import train


# ---------------------------------------------------------------------------- in this process: noted, armed, a second Ctrl-C
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


@pytest.mark.slow
def test_a_second_ctrl_c_aborts_at_once():
    from flock_torchrl.run.signals import Signals, Stopped

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
    from flock_torchrl.run.signals import Signals, Stopped

    with Signals("python scripts/train.py -cd runs/x -cn resume") as signals:
        signals.handle(signal.SIGINT, None)
        with pytest.raises(Stopped) as stop:
            signals.handle(signal.SIGINT, None)
    message = stop.value.message()
    assert "during training" in message and "outside" not in message
    assert message.endswith("resume with: python scripts/train.py -cd runs/x -cn resume")
    assert "outside a training loop" in Stopped(signal.SIGTERM).message()


def test_a_stop_line_reaches_stderr_in_one_write(monkeypatch):
    """The jobs of a joblib sweep share one stderr: a line written in two pieces (``print``
    writes the newline apart) ran into the next job's line."""
    from flock_torchrl.run.signals import say

    writes = []

    class Recorder:
        def write(self, text):
            writes.append(text)

        def flush(self):
            writes.append("<flush>")

    monkeypatch.setattr(sys, "stderr", Recorder())
    say("stopped by SIGTERM: checkpoint x")
    assert writes == ["stopped by SIGTERM: checkpoint x\n", "<flush>"]


# ---------------------------------------------------------------------------- a run stopped, and continued by the line it printed
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
    done = subprocess.run(resume_line(err), cwd=ROOT, env=script_env(), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "evaluation (4000 episodes" in done.stdout
    assert load_checkpoint(folder / "last.pt")["evaluations"][-1]["frames"] == 96


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
    resumed = subprocess.run(resume_line(err), cwd=ROOT, env=script_env(), capture_output=True, text=True,
                             timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert frames_at(folder / "last.pt") == 4000
    # The folder's name is a valid Hydra value as it is: no quoting needed to evaluate it.
    proc = run_script("evaluate.py", f"checkpoint={folder}/last.pt", "episodes=2", cwd=tmp_path)
    assert "Policy3-G on train" in proc.stdout


# ---------------------------------------------------------------------------- a signal while an app starts
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


@pytest.mark.slow
def test_a_signal_while_starting_is_one_line(tmp_path):
    proc = start(*TINY, cwd=tmp_path)
    time.sleep(0.3)  # Python is still importing torch
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143 and "Traceback" not in err and err.startswith("stopped by SIGTERM"), \
        (proc.returncode, err)
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- the process group, collector workers
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
        out, err = proc.communicate(timeout=SHUTDOWN_TIMEOUT + 60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise AssertionError("the run hung after the signal")
    assert proc.returncode == 128 + signum, err
    assert time.time() - began < SHUTDOWN_TIMEOUT + 30
    assert "Traceback" not in err and f"stopped by {signal.Signals(signum).name}" in err
    assert 0 < frames_at(folder / "last.pt") < 100000


def children(pid: int) -> list[int]:
    """The child processes of ``pid``, whichever of its threads started them."""
    found = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            found += [int(x) for x in (task / "children").read_text().split()]
        except OSError:
            continue
    return found


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ")
    except OSError:
        return ""


def alive(pid: int) -> bool:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in status


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
@pytest.mark.parametrize("signum", [15, 2])
def test_a_signal_to_the_group_while_collector_workers_start_ends_in_seconds(tmp_path, signum):
    run = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "train.py"), *TINY, "experiment.workers=2",
                             "experiment.max_frames=100000", f"hydra.run.dir={run}"], cwd=tmp_path, env=script_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.time() + 240
    workers: list[int] = []
    while not workers and proc.poll() is None and time.time() < deadline:
        workers = [c for c in children(proc.pid) if "spawn_main" in cmdline(c)]
        time.sleep(0.01)
    assert workers, "no collector worker started"
    os.killpg(proc.pid, signum)
    sent = time.time()
    try:
        out, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise AssertionError(f"still running 60 s after {signal.Signals(signum).name}: {proc.communicate()}")
    took = time.time() - sent
    assert proc.returncode == 128 + signum, err
    assert err.strip().splitlines() == [err.strip()] and err.startswith(f"stopped by {signal.Signals(signum).name}"), err
    assert took < 15, took  # seconds, not the workers' start-up, a batch and a 30 s shutdown
    time.sleep(1)
    assert not [w for w in workers if alive(w)]
    assert not (run / "config.yaml").exists()  # nothing of the run was written yet


# ---------------------------------------------------------------------------- joblib sweeps stopped or killed
def two_jobs_checkpointed(tmp_path, *overrides):
    """A tiny joblib sweep of two jobs at a time (its own process group), once both running jobs
    have written a checkpoint: ``(proc, sweep folder, the two jobs' folders)``."""
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    sweep = tmp_path / "sweep"
    proc = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "train.py"), "-m", "hydra/launcher=joblib",
                             "hydra.launcher.n_jobs=2", *TINY, "experiment.max_frames=100000",
                             "experiment.checkpoint_every_frames=64", *overrides, f"hydra.sweep.dir={sweep}"],
                            cwd=tmp_path, env=script_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    deadline = time.time() + 300
    while len(list(sweep.rglob("last.pt"))) < 2 and proc.poll() is None and time.time() < deadline:
        time.sleep(0.1)
    folders = sorted(p.parent for p in sweep.rglob("last.pt"))
    assert len(folders) == 2, proc.communicate() if proc.poll() is not None else "no checkpoints"
    return proc, sweep, folders


@pytest.mark.slow
def test_every_job_of_a_stopped_joblib_sweep_prints_its_resume_line_and_held_jobs_do_not_start(tmp_path):
    proc, sweep, folders = two_jobs_checkpointed(tmp_path, "experiment.eval_every_frames=64", "seed=0,1,2")
    os.killpg(proc.pid, signal.SIGTERM)
    try:
        out, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise AssertionError(f"the sweep hung: {proc.communicate()}")
    assert proc.returncode == 143, err
    lines = [line for line in err.splitlines() if line.startswith("stopped by SIGTERM: checkpoint")]
    assert sorted(line.split("resume with: ")[1].split(" -cd ")[1].split(" -cn ")[0] for line in lines) == \
        [str(f) for f in folders], err
    assert "Traceback" not in err and "leaked" not in err
    # The jobs' lines interleave on one stdout: each says whose it is (its folder under the sweep's).
    evals = [line for line in out.splitlines() if "eval @" in line]
    assert evals and all(line.startswith("[") and "] eval @ " in line for line in evals), out
    assert {line[1:].split("]")[0] for line in evals} <= {f.relative_to(sweep).as_posix() for f in folders}, out
    # The job joblib held back does not start after the signal.
    (held,) = [line for line in err.splitlines() if line.startswith("not started: ")]
    assert "seed2" in held and held.endswith("(the sweep was stopped by SIGTERM)")
    assert not list(sweep.rglob("seed2*/last.pt"))


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
def test_the_job_workers_of_a_killed_joblib_sweep_end_with_it_and_free_their_folders(tmp_path):
    """SIGKILL of a joblib sweep's process (the probe's case): its job workers lived on, ran their
    jobs to the end and held their run folders' locks. Now each stops with its checkpoint, at once,
    and the rerun takes the folder."""
    from filelock import FileLock

    proc, sweep, folders = two_jobs_checkpointed(tmp_path, "seed=0,1")
    workers = [int((f / ".lock.holder").read_text().split()[1]) for f in folders]  # "PID <pid> on <host>, ..."
    assert proc.pid not in workers and all(alive(w) for w in workers)
    os.kill(proc.pid, signal.SIGKILL)  # the sweep's process alone: it cannot pass anything on
    try:
        out, err = proc.communicate(timeout=90)  # its stderr closes when the last worker holding it ends
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise AssertionError(f"the job workers {workers} outlived their sweep: {proc.communicate()[1][-3000:]}")
    time.sleep(0.5)
    assert not [w for w in workers if alive(w)]
    lines = [line for line in err.splitlines() if line.startswith("stopped by SIGTERM: checkpoint")]
    assert sorted(line.split(" -cd ")[1].split(" -cn ")[0] for line in lines) == [str(f) for f in folders], err
    for folder in folders:
        with FileLock(str(folder / ".lock"), timeout=0):  # free: no worker holds it
            pass
    frames = int(lines[0].split(" frames)")[0].rsplit("(", 1)[1])
    folder = Path(lines[0].split(" -cd ")[1].split(" -cn ")[0])
    rerun = script("train.py", "-cd", str(folder), "-cn", "resume", f"experiment.max_frames={frames + 32}",
                   cwd=tmp_path)
    assert rerun.returncode == 0 and f"({frames + 32} frames" in rerun.stdout, rerun.stderr[-3000:]
