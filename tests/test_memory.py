"""Memory: each app estimates what it will hold (flock_torchrl/world/memory.py) and refuses, in
one line naming the costliest key and the bound, what the process cannot have, before anything is
allocated or written; the estimates bound the measured peaks (worlds, reserves of fresh worlds, a
checkpoint's write); a checkpoint holds only the replay rows it filled, and a write that runs out
of memory keeps the last good checkpoint."""

from __future__ import annotations

import subprocess
import sys

import pytest
from helpers import TINY, first_fast, one_line, script, script_env, tiny

from flock_torchrl.run.launch import train
from flock_torchrl.run.setup import make_train_config


# ---------------------------------------------------------------------------- refused before anything is written
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


@pytest.mark.slow
def test_usable_memory_sees_the_processs_own_limit():
    code = ("import resource; resource.setrlimit(resource.RLIMIT_AS, (3 * 2**30, 3 * 2**30)); "
            "from flock_torchrl.world.memory import usable_memory; u = usable_memory(); print(u.bytes, u.what)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=script_env(), timeout=60)
    left, what = int(out.stdout.split()[0]), out.stdout.split(" ", 1)[1]
    assert what.startswith("its ulimit -v of 3.0 GiB") and 0 < left < 3 * 2**30, out


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


# ---------------------------------------------------------------------------- the estimates against what is measured
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


# ---------------------------------------------------------------------------- a checkpoint's write
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
