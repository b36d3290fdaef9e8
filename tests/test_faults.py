"""Runs that survive what a fault probe found: moved run folders, memory the
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
from helpers import first_fast, script_env

from flock_torchrl.run.launch import train
from flock_torchrl.run.trainer import make_train_config

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
@pytest.mark.slow
def test_memory_the_run_cannot_have_is_refused_before_anything_is_written(tmp_path, app, args, gib, key):
    proc = script(app, *args, f"hydra.run.dir={tmp_path / 'out'}", cwd=tmp_path, timeout=120,
                  preexec=limit_memory(gib) if gib else None)
    assert proc.returncode == 2, proc.stderr[-3000:]
    one_line(proc.stderr, key)
    if gib:  # the limit is the bound, unless the machine has even less free
        assert f"its ulimit -v of {gib:.1f} GiB" in proc.stderr or "what this machine has free" in proc.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("app", first_fast(["evaluate", "train", "diagnose", "scaling", "reproduce", "figures", "ship",
                                            "tune_baselines", "publish"]))
def test_a_limit_too_small_to_load_torch_is_one_line_naming_it(tmp_path, app):
    """``ulimit -v 307200`` (300 MiB): torch cannot map its libraries; one line naming the limit,
    exit 2, as the other memory refusals, not an ImportError traceback."""
    proc = script(f"{app}.py", f"hydra.run.dir={tmp_path / 'out'}", cwd=tmp_path, timeout=120,
                  preexec=limit_memory(300 / 1024))
    assert proc.returncode == 2, proc.stderr[-3000:]
    one_line(proc.stderr, "starting the app needs more memory than its ulimit -v of 0.3 GiB lets this process map (")
    assert proc.stderr.strip().endswith("; raise the limit")
    assert list(tmp_path.iterdir()) == []


def test_check_memory_names_the_costliest_key_and_the_bound():
    from flock_torchrl.config import ConfigError
    from flock_torchrl.world.memory import Usable, check_memory

    check_memory({"a": 2**30, "b": 2**30}, "x", Usable(3 * 2**30, "a test bound"))  # fits
    with pytest.raises(ConfigError, match=r"^b: x needs about 3.0 GiB, 2.0 GiB of it for b, but this process can "
                                          r"use 2.5 GiB \(a test bound\)"):
        check_memory({"a": 2**30, "b": 2 * 2**30}, "x", Usable(int(2.5 * 2**30), "a test bound"))


def test_the_memory_estimate_counts_the_checkpoints_write_of_the_rows_the_run_fills():
    from flock_torchrl.config import TrainConfig
    from flock_torchrl.world.memory import train_bytes

    def buffer(*extra: str) -> int:
        cfg = TrainConfig.from_config(make_train_config("policy3_g", "tiny", ["algo.buffer_size=100000", *extra]))
        return train_bytes(cfg)["algo.buffer_size"]

    unlimited = ["experiment.max_frames=0", "experiment.max_minutes=5"]
    held = buffer(*unlimited, "experiment.keep_buffer_in_checkpoint=false")
    # A full buffer is held once; its checkpoint's write copies the filled rows and serialises them.
    assert buffer(*unlimited) == 3 * held
    # 160 frames fill 160 rows of 5 UAV transitions: the write costs their bytes twice, no more.
    assert buffer("experiment.max_frames=160") == held + 2 * 160 * 5 * held // 100_000


def test_a_checkpoint_holds_only_the_replay_rows_it_filled(tmp_path):
    import torch

    from flock_torchrl.policies.checkpoint import load_checkpoint

    run = train(tiny("experiment.max_frames=64", "logger=none"), tmp_path / "run")
    storage = load_checkpoint(run.checkpoint)["buffer"]["_storage"]
    rows = storage["_len"]
    assert 0 < rows < 1000 and rows == run.frames  # a swarm transition per frame, of a 1000-row storage
    assert {v.shape[0] for v in storage["_storage"].values() if isinstance(v, torch.Tensor)} == {rows}


@pytest.mark.slow
def test_a_checkpoints_write_holds_one_copy_of_its_payload():
    """The estimate's share of a checkpoint's write (the filled rows' copy and their serialised
    bytes) bounds what the write holds: measured, the peak beyond the payload is one copy of it
    (the envelope is streamed to the file, not serialised a second time in memory)."""
    code = """
import tempfile, torch
from flock_torchrl.policies.checkpoint import save_checkpoint
def status(field):
    return next(int(l.split()[1]) * 1024 for l in open("/proc/self/status") if l.startswith(field))
blob = torch.ones(50 * 2**20)  # 200 MiB
open("/proc/self/clear_refs", "w").write("5")  # the peak (VmHWM) starts again from here
base = status("VmRSS:")
save_checkpoint({"buffer": blob}, tempfile.mktemp(suffix=".pt"), "training")
print((status("VmHWM:") - base) / blob.nbytes)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=script_env(), timeout=120)
    assert 0.9 < float(out.stdout) < 1.2, out


OUT_OF_MEMORY = """
import resource, sys, torch
from pathlib import Path
from flock_torchrl.policies.checkpoint import CheckpointError
from flock_torchrl.run.parts import write_checkpoint
path = Path(sys.argv[1])
write_checkpoint({"step": torch.zeros(3)}, path)  # the last good checkpoint
print(path.read_bytes().hex())
big = torch.ones(64 * 2**20)  # 256 MiB, held before the limit
size = next(int(l.split()[1]) * 1024 for l in open("/proc/self/status") if l.startswith("VmSize:"))
resource.setrlimit(resource.RLIMIT_AS, (size + 64 * 2**20, size + 64 * 2**20))  # 64 MiB more: not enough
try:
    write_checkpoint({"step": torch.ones(3), "buffer": big}, path)
except CheckpointError as exc:
    print(exc)
"""


@pytest.mark.slow
def test_a_checkpoint_write_that_runs_out_of_memory_keeps_the_last_good_one(tmp_path):
    """Under a process limit (setrlimit) a checkpoint's write runs out of memory: one line saying
    the last good checkpoint is kept, and it is (no temporary file left)."""
    path = tmp_path / "last.pt"
    out = subprocess.run([sys.executable, "-c", OUT_OF_MEMORY, str(path)], capture_output=True, text=True,
                         env=script_env(), timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    good, message = out.stdout.strip().split("\n")
    assert message == (f"writing the checkpoint {path} ran out of memory; the last good checkpoint is kept at {path}; "
                       "lower algo.buffer_size (the replay buffer it saves) or free memory, then resume")
    assert path.read_bytes().hex() == good
    assert [p.name for p in tmp_path.iterdir()] == ["last.pt"]


@pytest.mark.slow
def test_a_large_replay_buffer_under_a_limit_trains_and_checkpoints(tmp_path):
    """A 5M-transition buffer (1.5 GiB) under ulimit -v 6 GiB: its checkpoints write the rows it
    filled, not the whole storage three times over, so the run finishes and resumes."""
    from flock_torchrl.world.memory import usable_memory

    if usable_memory().bytes < 6 * 2**30:
        pytest.skip("this machine has less than 6 GiB free")
    run = tmp_path / "run"
    proc = script("train.py", *TINY, "algo.buffer_size=5000000", f"hydra.run.dir={run}", cwd=tmp_path,
                  preexec=limit_memory(6), timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    proc = script("train.py", *TINY, "algo.buffer_size=5000000", "experiment.max_frames=192", "resume=true",
                  f"hydra.run.dir={run}", cwd=tmp_path, preexec=limit_memory(6), timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "checkpoint:" in proc.stdout and "192 frames" in proc.stdout


@pytest.mark.slow
def test_usable_memory_sees_the_processs_own_limit():
    code = ("import resource; resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30)); "
            "from flock_torchrl.world.memory import usable_memory; u = usable_memory(); print(u.bytes, u.what)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=script_env(), timeout=60)
    left, what = int(out.stdout.split()[0]), out.stdout.split(" ", 1)[1]
    assert what.startswith("its ulimit -v of 3.0 GiB") and 0 < left < 3 * 2**30, out


@pytest.mark.parametrize("scenario, n, worlds", [("s1", 5, 4000), ("s2", 100, 400)])
@pytest.mark.slow
def test_the_world_estimate_bounds_the_measured_peak(scenario, n, worlds):
    # Peak resident memory of stepping `worlds` worlds, in a fresh process, against world_bytes.
    code = f"""
from flock_torchrl import FlockingEnv
from flock_torchrl.config import EvaluateConfig, compose
from flock_torchrl.world.memory import world_bytes
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


@pytest.mark.parametrize("scenario, n, worlds, pool", [("train", 5, 500, 2000), ("forest3d", 20, 100, 400)])
@pytest.mark.slow
def test_the_reserve_estimate_bounds_the_measured_peak(scenario, n, worlds, pool):
    # Peak resident memory of stepping `worlds` worlds with a reserve of `pool` (every world ends
    # each step: the reserve is filled, then refilled twice, each refill drawing and concatenating),
    # in a fresh process, against the estimate of the worlds and the reserve (measured: 3.8x for
    # train, 1.6x for forest3d). Every allocation of 64 kB or more is its own mapping there, so the
    # kernel records the peak when it is freed (a heap trimmed with madvise drops it: VmHWM then
    # read below the start one run in three).
    code = f"""
from flock_torchrl import FlockingEnv
from flock_torchrl.config import TrainConfig, compose
from flock_torchrl.world.memory import reserve_bytes, world_bytes
s = TrainConfig.from_config(compose("train", ["experiment=tiny", "scenario={scenario}", "scenario.n_uavs={n}",
                                              "scenario.max_steps=1"])).train_scenario
env = FlockingEnv(s, num_envs=4, seed=0, reset_pool=8); env.rollout(6, break_when_any_done=False)
del env
def status(field):
    return next(int(l.split()[1]) * 1024 for l in open("/proc/self/status") if l.startswith(field))
open("/proc/self/clear_refs", "w").write("5")  # the peak (VmHWM) starts again from here
base = status("VmRSS:")
env = FlockingEnv(s, num_envs={worlds}, seed=0, reset_pool={pool})
env.rollout({2 * pool // worlds + 2}, break_when_any_done=False)
print(status("VmHWM:") - base, {worlds} * world_bytes(s) + reserve_bytes(s, {pool}))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         env=script_env(MALLOC_MMAP_THRESHOLD_="65536"))
    measured, estimate = map(int, out.stdout.split())
    assert measured <= estimate <= 6 * measured, (measured, estimate)


def test_the_memory_estimate_counts_every_reserve_of_fresh_worlds():
    from flock_torchrl.config import TrainConfig
    from flock_torchrl.world.memory import reserve_bytes, train_bytes

    def estimate(*extra: str) -> tuple[TrainConfig, dict[str, int]]:
        cfg = TrainConfig.from_config(make_train_config("policy3_g", "tiny", ["experiment.num_envs=8", *extra]))
        return cfg, train_bytes(cfg)

    assert "reset_pool" not in estimate()[1]
    cfg, parts = estimate("reset_pool=40")
    one = reserve_bytes(cfg.train_scenario, 40)
    assert one == 40 * 5 * (8192 + 40 * 5 + 64 * cfg.train_scenario.n_laser) * 5 // 4 and parts["reset_pool"] == one
    assert estimate("reset_pool=40", "population=3")[1]["reset_pool"] == 3 * one  # a reserve per member
    assert estimate("reset_pool=40", "experiment.workers=2")[1]["reset_pool"] == 3 * one  # two workers' and the main's
    cfg, parts = estimate("reset_pool=40", "experiment.swarm_sizes=[5,10]")  # one env, one reserve per size
    assert parts["reset_pool"] == one + reserve_bytes(cfg.train_scenarios[1], 40) > 2 * one


@pytest.mark.parametrize("args, start", [
    (["reset_pool=100000000"], "reset_pool: must be an integer >= 0 and <= 10000000, got 100000000"),
    (["experiment.num_envs=1000", "reset_pool=1000000"], "reset_pool: the run needs about"),
])
@pytest.mark.slow
def test_an_unbounded_reset_pool_is_refused_before_anything_is_allocated(tmp_path, args, start):
    """The probe's ``(ulimit -v 6291456; scripts/train.py experiment=tiny reset_pool=100000000)``
    allocated the reserve for 45 s, then a traceback, and left the run folder's .lock: the bound
    refuses it at once, and the memory check a reserve below the bound that the limit cannot hold."""
    proc = script("train.py", *TINY, *args, f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path, timeout=120,
                  preexec=limit_memory(6))
    assert proc.returncode == 2, proc.stderr[-3000:]
    one_line(proc.stderr, start)
    if "needs about" in start:  # the reserve is the costliest part, and the limit is named
        assert "of it for reset_pool, but this process can use" in proc.stderr
        assert "its ulimit -v of 6.0 GiB" in proc.stderr or "what this machine has free" in proc.stderr
    assert list(tmp_path.iterdir()) == []  # no folder, no .lock


# ---------------------------------------------------------------------------- 4: logs
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


# ---------------------------------------------------------------------------- 6: disks, limits, folders, YAML
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


def limit_file_size(size: int):
    def limit() -> None:
        import resource

        resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))
    return limit


@pytest.mark.slow
def test_a_file_size_limit_at_checkpoint_time_is_one_line_naming_the_checkpoint(tmp_path):
    run = tmp_path / "run"
    proc = script("train.py", *TINY, f"hydra.run.dir={run}", cwd=tmp_path, preexec=limit_file_size(100_000))
    assert proc.returncode == 2, proc.stderr[-3000:]
    one_line(proc.stderr, f"cannot write {run / 'last.pt'}: it would pass this process's file-size limit (ulimit -f)")
    assert "no checkpoint yet" in proc.stderr
    assert not (run / "last.pt").exists() and not list(run.glob(".*.tmp"))


@pytest.mark.parametrize("how", ["-cd", "searchpath"])
@pytest.mark.slow
def test_a_broken_yaml_in_the_search_path_is_one_line_naming_the_file(tmp_path, how):
    bad = tmp_path / "mine" / "scenario" / "bad.yaml"
    bad.parent.mkdir(parents=True)
    bad.write_text("name: x\nn_uavs: [1, 2\nfoo: 1\n")
    where = ["-cd", str(tmp_path / "mine")] if how == "-cd" else [f"hydra.searchpath=[file://{tmp_path / 'mine'}]"]
    proc = script("evaluate.py", *where, "policy=policy_ma", "scenario=bad", "episodes=2",
                  f"hydra.run.dir={tmp_path / 'out'}", cwd=tmp_path, timeout=120)
    assert proc.returncode == 2
    one_line(proc.stderr, f"{bad} is not valid YAML (line 3, column 4: expected ',' or ']', but got ':')")
    assert not (tmp_path / "out").exists()
    # a broken file the composition does not read is no reason to refuse (Hydra does not parse it either)
    (tmp_path / "mine" / "scenario" / "corridor.yaml").write_text("defaults: [train, _self_]\nname: corridor\n")
    proc = script("evaluate.py", *where, "policy=policy_ma", "scenario=corridor", "--cfg", "job", cwd=tmp_path,
                  timeout=120)
    assert proc.returncode == 0 and "name: corridor" in proc.stdout, proc.stderr[-2000:]


@pytest.mark.parametrize("args, key", [
    (["hydra.run.dir={blocker}/out"], "hydra.run.dir: {blocker}/out cannot be made: {blocker} is a file"),
    (["-m", "hydra.sweep.dir={blocker}/sweep"], "hydra.sweep.dir: {blocker}/sweep/"),
])
@pytest.mark.slow
def test_an_output_folder_that_cannot_be_made_is_one_line(tmp_path, args, key):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    proc = script("evaluate.py", *(a.format(blocker=blocker) for a in args), "policy=policy_ma", "episodes=2",
                  cwd=tmp_path, timeout=120)
    assert proc.returncode == 2
    one_line(proc.stderr, key.format(blocker=blocker))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_output_folder_is_one_line(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        proc = script("evaluate.py", "policy=policy_ma", "episodes=2", f"hydra.run.dir={folder}", cwd=tmp_path)
    finally:
        folder.chmod(0o755)
    assert proc.returncode == 2
    one_line(proc.stderr, f"hydra.run.dir: {folder} cannot be written (cannot write {folder}: permission denied)")


# ---------------------------------------------------------------------------- 7: crafted checkpoints
SHIPPED = ROOT / "checkpoints" / "paper_fit" / "policy3_g" / "seed0.pt"


def crafted(path: Path, how: str) -> Path:
    """A digest-valid checkpoint of the shipped Policy3-G, changed in one field."""
    import torch

    from flock_torchrl.policies import checkpoint as ck

    payload = ck.load_checkpoint(SHIPPED)
    kind = payload.pop("kind")
    first = next(iter(payload["actor"]))
    if how == "kind":
        kind = "weird"
    elif how == "shape":
        payload["actor"][first] = torch.zeros(3, 3)
    elif how == "nan":
        payload["actor"][first] = payload["actor"][first].clone().fill_(float("nan"))
    elif how == "reading":
        payload["meta"]["reading"] = "weird"
    data = ck._serialise(payload)
    envelope = {"format": ck.FORMAT, "kind": kind, "sha256": hashlib.sha256(data).hexdigest(),
                "payload": torch.frombuffer(bytearray(data), dtype=torch.uint8)}
    path.write_bytes(ck._serialise(envelope))
    return path


CRAFTED = {"kind": "kind 'weird' is not a checkpoint kind (training, policy)",
           "shape": "actor.{first} is [3, 3], but the network its meta describes",
           "nan": "actor.{first} holds NaN or infinite weights",
           "reading": "meta.reading is 'weird', not one of literal, paper_fit"}


@pytest.mark.parametrize("how", sorted(CRAFTED))
def test_a_crafted_digest_valid_checkpoint_is_refused_naming_the_field(tmp_path, how):
    from flock_torchrl import CheckpointError
    from flock_torchrl.policies.checkpoint import load_checkpoint, load_policy

    bad = crafted(tmp_path / "bad.pt", how)
    first = next(iter(load_checkpoint(SHIPPED)["actor"]))
    with pytest.raises(CheckpointError) as info:
        load_policy(bad)
    message = str(info.value)
    assert message.startswith(f"{bad}: {CRAFTED[how].format(first=first)}") and "\n" not in message
    assert "pass reading=weird" not in message


@pytest.mark.parametrize("how", ["kind", "nan"])
@pytest.mark.slow
def test_evaluate_refuses_a_crafted_checkpoint_in_one_line(tmp_path, how):
    bad = crafted(tmp_path / "bad.pt", how)
    proc = script("evaluate.py", f"checkpoint={bad}", "policy=policy3_g", "episodes=2",
                  f"hydra.run.dir={tmp_path / 'out'}", cwd=tmp_path, timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    one_line(proc.stderr, f"{bad}: {CRAFTED[how].split('{')[0]}")
    assert not (tmp_path / "out").exists()


THREED = ROOT / "checkpoints" / "paper_fit" / "threed" / "policy3_g" / "seed0.pt"


def mixed_dims_checkpoints(root: Path) -> Path:
    """A checkpoints folder whose policy3_g seed1.pt is a 3-D checkpoint among 2-D ones."""
    folder = root / "paper_fit" / "policy3_g"
    folder.mkdir(parents=True)
    for k in (0, 2):
        shutil.copy(SHIPPED.parent / f"seed{k}.pt", folder / f"seed{k}.pt")
    shutil.copy(THREED, folder / "seed1.pt")
    return root


# The probe's six cases: the refusal's start, and the checkpoint it names.
DIMS_MISMATCHES = {
    "2-D on train3d": ("evaluate.py", [f"checkpoint={SHIPPED}", "scenario=train3d"],
                       f"scenario.dims: is 3 here, but {SHIPPED} was trained in a world with dims 2"),
    "3-D on train": ("evaluate.py", [f"checkpoint={THREED}", "scenario=train"],
                     f"scenario.dims: is 2 here, but {THREED} was trained in a world with dims 3"),
    "3-D, no scenario": ("evaluate.py", [f"checkpoint={THREED}"],
                         f"scenario.dims: is 2 here, but {THREED} was trained in a world with dims 3"),
    "scaling others": ("scaling.py", [f"others=[{THREED}]", "sizes=[5]"],
                       f"scenario.dims: is 2 here, but {THREED} was trained in a world with dims 3"),
    "diagnose train3d": ("diagnose.py", ["scenarios=[train3d]", "policies=[policy3_g]", "sizes=[5]", "variants=[paper]"],
                         f"scenarios: train3d's scenario.dims is 3 here, but {SHIPPED} was trained in a world with "
                         "dims 2"),
    "diagnose 3-D seed1": ("diagnose.py", ["checkpoints_dir={mixed}", "policies=[policy3_g]", "scenarios=[train]",
                                           "sizes=[5]", "variants=[paper]"],
                           "scenarios: train's scenario.dims is 2 here, but {mixed}/paper_fit/policy3_g/seed1.pt was "
                           "trained in a world with dims 3"),
}


@pytest.mark.parametrize("case", sorted(DIMS_MISMATCHES))
@pytest.mark.slow
def test_a_checkpoint_of_the_other_dimension_is_refused_before_any_folder(tmp_path, case):
    app, args, start = DIMS_MISMATCHES[case]
    mixed = mixed_dims_checkpoints(tmp_path / "mixed") if "{mixed}" in start else None
    proc = script(app, *(a.format(mixed=mixed) for a in args), "episodes=2", f"hydra.run.dir={tmp_path / 'out'}",
                  cwd=tmp_path, timeout=180)
    assert proc.returncode == 2, proc.stderr[-3000:]
    one_line(proc.stderr, start.format(mixed=mixed))
    assert not (tmp_path / "out").exists()  # refused by the pre-run check, before Hydra made the folder


def test_the_pre_run_check_refuses_a_checkpoint_of_the_other_dimension(tmp_path):
    """What PreRunCheck calls (cli.checked) reads the checkpoint's dimension: no folder yet."""
    from flock_torchrl.cli import checked
    from flock_torchrl.config import ConfigError, compose

    cfg = compose("evaluate", [f"checkpoint={THREED}", "scenario=train", "episodes=2"])
    with pytest.raises(ConfigError, match=rf"^scenario\.dims: is 2 here, but {THREED} was trained in a world with "
                                          r"dims 3: evaluate it on a 3-D scenario"):
        checked("evaluate", cfg, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    assert checked("evaluate", compose("evaluate", [f"checkpoint={THREED}", "scenario=train3d", "episodes=2"]),
                   tmp_path / "out").scenario.dims == 3  # its own dimension passes


# ---------------------------------------------------------------------------- 8: env API
@pytest.mark.parametrize("scenario", ["s1", "s5", "forest"])
def test_set_state_refuses_a_non_finite_state_and_takes_a_finite_one(scenario):
    import torch

    from flock_torchrl import FlockingEnv

    env = FlockingEnv(scenario, num_envs=2, seed=0)
    env.rollout(3, break_when_any_done=False)
    state = env.get_state()
    env.set_state(state)  # a real state round-trips
    bad = {"world": {**state["world"]}, "generator": state["generator"]}
    bad["world"]["position"] = state["world"]["position"].clone()
    bad["world"]["position"][1, 0, 0] = float("nan")
    with pytest.raises(ValueError, match=r"^env state: 'position' contains NaN or inf"):
        env.set_state(bad)
    assert torch.equal(env.world["position"], state["world"]["position"])  # unchanged


@pytest.mark.parametrize("seed", [-1, 2**64, 1.5, float("nan"), "3", True])
def test_bad_seeds_are_refused_naming_seed(seed):
    from flock_torchrl import FlockingEnv

    with pytest.raises(ValueError, match=r"^seed must be None or an integer in \[0, 2\*\*64 - 1\], got"):
        FlockingEnv("s1", num_envs=1, seed=seed)
    env = FlockingEnv("s1", num_envs=1, seed=2**64 - 1)  # the largest one works
    with pytest.raises(ValueError, match=r"^seed must be"):
        env.set_seed(seed)


def test_cuda_without_cuda_is_one_line_naming_device():
    import torch

    from flock_torchrl import FlockingEnv

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(ValueError, match=r"^device 'cuda': this machine has no CUDA device") as info:
        FlockingEnv("s1", num_envs=1, device="cuda")
    assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match=r"^device 'gpu0' is not a torch device"):
        FlockingEnv("s1", num_envs=1, device="gpu0")


# ---------------------------------------------------------------------------- 9: where a value came from
@pytest.mark.parametrize("args, line", [
    (["experiment.num_envs=10000000"], "experiment.num_envs: the run needs about .* \\(in the command line's "
                                       "experiment.num_envs=10000000\\)"),
    (["experiment.swarm_sizes=[0,5]"], "experiment.swarm_sizes\\[0\\]: must be an integer >= 1 and <= 2000, got 0 "
                                       "\\(in the command line's experiment.swarm_sizes=\\[0,5\\]\\)"),
    (["+experiment.train_env.bogus=1"], "experiment.train_env: unknown scenario field\\(s\\) \\['bogus'\\] \\(in the "
                                        "command line's \\+experiment.train_env.bogus=1\\)"),
    (["scenario=forest", "scenario.random_clearance=1000"], "scenario.random_clearance: 12 circles .* \\(in the "
                                                            "command line's scenario.random_clearance=1000\\)"),
])
@pytest.mark.slow
def test_a_message_names_the_command_line_when_the_value_came_from_it(tmp_path, args, line):
    import re

    proc = script("train.py", *TINY, *args, f"hydra.run.dir={tmp_path / 'out'}", cwd=tmp_path, timeout=120)
    assert proc.returncode == 2
    one_line(proc.stderr, "")
    assert re.fullmatch(f"error: {line}", proc.stderr.strip()), proc.stderr
    assert "tiny.yaml" not in proc.stderr and "forest.yaml" not in proc.stderr


@pytest.mark.slow
def test_a_message_names_the_file_that_set_the_value(tmp_path):
    mine = tmp_path / "mine" / "experiment" / "broad.yaml"
    mine.parent.mkdir(parents=True)
    mine.write_text((ROOT / "conf" / "experiment" / "tiny.yaml").read_text().replace("swarm_sizes", "x")
                    + "swarm_sizes: [0, 5]\n")
    proc = script("train.py", "-cd", str(tmp_path / "mine"), *TINY, "experiment=broad",
                  f"hydra.run.dir={tmp_path / 'out'}", cwd=tmp_path, timeout=120)
    assert proc.returncode == 2
    one_line(proc.stderr, f"experiment.swarm_sizes[0]: must be an integer >= 1 and <= 2000, got 0 (in {mine})")


# ---------------------------------------------------------------------------- 3: signals while workers start
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
    import signal
    import time

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


# ---------------------------------------------------------------------------- 10: a joblib sweep stopped
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


@pytest.mark.slow
def test_every_job_of_a_stopped_joblib_sweep_prints_its_resume_line_and_held_jobs_do_not_start(tmp_path):
    import signal
    import time

    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    sweep = tmp_path / "sweep"
    proc = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "train.py"), "-m", "hydra/launcher=joblib",
                             "hydra.launcher.n_jobs=2", *TINY, "experiment.max_frames=100000",
                             "experiment.checkpoint_every_frames=64", "seed=0,1,2", f"hydra.sweep.dir={sweep}"],
                            cwd=tmp_path, env=script_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    deadline = time.time() + 300
    while len(list(sweep.rglob("last.pt"))) < 2 and proc.poll() is None and time.time() < deadline:
        time.sleep(0.1)
    folders = sorted(p.parent for p in sweep.rglob("last.pt"))
    assert len(folders) == 2, proc.communicate() if proc.poll() is not None else "no checkpoints"
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
    import signal
    import time

    from filelock import FileLock

    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    sweep = tmp_path / "sweep"
    proc = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "train.py"), "-m", "hydra/launcher=joblib",
                             "hydra.launcher.n_jobs=2", *TINY, "experiment.max_frames=100000",
                             "experiment.checkpoint_every_frames=64", "seed=0,1", f"hydra.sweep.dir={sweep}"],
                            cwd=tmp_path, env=script_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    deadline = time.time() + 300
    while len(list(sweep.rglob("last.pt"))) < 2 and proc.poll() is None and time.time() < deadline:
        time.sleep(0.1)
    folders = sorted(p.parent for p in sweep.rglob("last.pt"))
    assert len(folders) == 2, proc.communicate() if proc.poll() is not None else "no checkpoints"
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
