"""The benchmarks of the repository (``benchmarks/``, ``make benchmark``): their rows run and
print, their Hydra app checks its config first (their figures are read from `make benchmark`,
never asserted: a timed unit test would measure the machine, not the code)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from helpers import ROOT, script_env

from benchmarks.reset import reset_lines, resetter
from benchmarks.rows import format_rows
from benchmarks.step import stepper
from benchmarks.throughput import BenchmarkConfig, CheckFirst, learner_rows
from flock_torchrl import ConfigError, FlockingEnv


@pytest.mark.slow
def test_the_update_rows_compare_eager_compiled_and_vectorised_kernels():
    rows = learner_rows(batches=((128, "paper"),), updates=2, repeat=1)
    names = [row.what for row in rows]
    assert names == ["SAC updates, batch 128 UAV transitions (paper; eager vs previous)",
                     "SAC updates, batch 128 UAV transitions (paper; compiled vs previous)",
                     "SAC updates, batch 128 (paper; scalar vs vectorised compiled kernels)"]
    assert all(row.ours > 0 and row.baseline > 0 for row in rows)
    assert "scalar vs vectorised" in format_rows(rows)


def benchmark(*args: str, cwd, module: bool = True, **env: str) -> subprocess.CompletedProcess:
    """``python -m benchmarks.run <args>`` (or ``python <root>/benchmarks/run.py``) in ``cwd``."""
    command = ["-m", "benchmarks.run"] if module else [str(ROOT / "benchmarks" / "run.py")]
    return subprocess.run([sys.executable, *command, *args], cwd=cwd, env=script_env(**env), capture_output=True,
                          text=True, timeout=300)


@pytest.mark.slow
def test_a_bad_benchmark_value_is_one_line_before_any_folder(tmp_path):
    # Run as a file, with nothing on PYTHONPATH: the script finds the repository's root itself,
    # and its callback checks the config before Hydra creates outputs/benchmark.
    proc = benchmark("threads=-1", cwd=tmp_path, module=False, PYTHONPATH="")
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: threads: "), proc.stderr
    assert not (tmp_path / "outputs").exists()


@pytest.mark.slow
def test_the_benchmark_app_shows_its_config_as_a_module(tmp_path):
    proc = benchmark("threads=2", "--cfg", "job", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "quick: false" in proc.stdout and "threads: 2" in proc.stdout
    assert not (tmp_path / "outputs").exists()


@pytest.mark.parametrize("override, key", [("device=tpu", "device"), ("quick=maybe", "quick"),
                                           ("+extra=1", "extra")])
def test_the_benchmark_callback_reports_a_bad_value_in_one_line(override, key, capsys):
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(ROOT / "benchmarks" / "conf"), version_base=None):
        cfg = compose("benchmark", [override])
    with pytest.raises(SystemExit) as stop:
        CheckFirst().on_run_start(cfg)
    assert stop.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {key}"), lines


def test_the_benchmark_config_is_checked():
    cfg = BenchmarkConfig.from_config({"quick": True, "device": "cpu", "threads": 0})
    assert cfg.quick is True and cfg.threads == 0
    with pytest.raises(ConfigError, match="threads"):
        BenchmarkConfig.from_config({"quick": True, "device": "cpu", "threads": 2000})


@pytest.mark.parametrize("api", ["step", "_step", "advance"])
def test_the_step_benchmark_steps_from_one_fixed_state(api):
    """Each timed step starts from the same world state: the state the env had when the
    stepper was made is never written to, while the step itself runs (the env's world moves on)."""
    env = FlockingEnv("train", 2, "cpu", 0, policy_id="policy3_g")
    go = stepper(env, 2, api)
    fixed = env.world
    start = fixed["position"].clone()
    go()
    go()
    assert torch.equal(fixed["position"], start)
    if api != "advance":  # the pure step function returns its state; env.step stores it
        assert env.world is not fixed and not torch.equal(env.world["position"], start)


def test_the_reset_rows_reset_only_the_masked_worlds_and_count_endings():
    """A partial reset changes the masked worlds and no other; the rows name each case."""
    env = FlockingEnv("train", 4, "cpu", 0, policy_id="policy3_g")
    env.reset()
    before = env.world["position"].clone()
    resetter(env, 1, 1)()
    after = env.world["position"]
    assert not torch.equal(after[0], before[0]) and torch.equal(after[1:], before[1:])
    lines = reset_lines(batch=4, rounds=1, print_each=False)
    assert len(lines) == 5 and "reset 2 worlds" in lines[1] and "reset 4 worlds" in lines[2] and "worlds ending per step" in lines[-1]


def test_the_projection_line_divides_the_studys_updates_by_the_measured_rates():
    from benchmarks.gpu import fast_updates, projection_line

    # experiment=fast: 32 worlds x 8 steps = 256 frames a batch; 120,000 frames end after batch
    # ceil(120000 / 256) = 469; updates start once 2048 random frames are in (batch 8): 462
    # batches x 7 updates = 3234.
    assert fast_updates() == 3234
    # 8 x 10 x 816,000 member-updates at 8 x 10 x 816,000 / 3600 per second: one hour; likewise
    # 10 x 10 x 3234 at 10 x 10 x 3234 / 3600 per second.
    line = projection_line("here", 8 * 10 * 816_000 / 3600, 10 * 10 * 3234 / 3600, 10)
    assert line.startswith("projection (here): the paper's study (8 policies x 10 seeds x 816,000 updates")
    assert ": 1.0 h;" in line and "(3,234 updates each)" in line and line.endswith(": 1.00 h")
    assert projection_line("here", 100.0, 0.0) == ("projection (here): none, a loop measured no updates (paper 100, "
                                                   "fast 0 member-updates/s)")


@pytest.mark.slow  # five short training runs in child processes
@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is here: make benchmark runs these rows on it")
def test_the_gpu_rows_run_on_simulated_cuda(monkeypatch):
    """benchmarks/gpu.py's every row, tiny, with ``device="cuda"`` on CUDA simulated on the CPU
    (``tests/simulated_cuda.py``; the loops' child processes too, through its ``sitecustomize.py``):
    what a GPU runs, every tensor on the device, minus CUDA graphs and pinned memory."""
    from benchmarks.gpu import gpu_lines

    from simulated_cuda import simulated_cuda

    site = Path(__file__).resolve().parent / "simulated_cuda_site"
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")])))
    with simulated_cuda():
        lines = gpu_lines(device="cuda", frames=40, members=(2,), fast_frames=64, update_members=(1, 2),
                          update_calls=2, env_batch=8)
    assert lines[0].startswith("GPU: simulated CUDA (CPU)")
    assert sum("GPU update alone" in line for line in lines) == 2
    loops = [line for line in lines if line.startswith("GPU loop")]
    assert len(loops) == 5 and sum("reset_pool=0:" in line for line in loops) == 1, loops
    assert all("member-updates/s" in line for line in loops), loops
    assert any(line.startswith("projection (GPU)") for line in lines)
    assert any("env steps, B=8" in line for line in lines)
