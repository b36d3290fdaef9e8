"""Resume: a run stopped (killed, or at a smaller budget) and continued ends bit for bit the
uninterrupted run, its episode and scalar logs included; resume=auto starts afresh or leaves a
finished run unchanged; a resume with other settings, without a checkpoint or without its episode
log is refused and changes nothing; a fresh run never overwrites a checkpoint. (A resume after a
signal: tests/test_signals.py; of captured, mixed-size, population and reserve runs: their files.)"""

from __future__ import annotations

import time

import pytest
import torch
import yaml
from helpers import TINY, finish, start, tiny, tiny_pipeline, wait_for

from flock_torchrl import CheckpointError
from flock_torchrl.policies.checkpoint import load_checkpoint
from flock_torchrl.run.launch import train


# ---------------------------------------------------------------------------- bit for bit the uninterrupted run
@pytest.mark.slow
def test_kill_and_resume_matches_uninterrupted_run(tmp_path):
    whole = train(tiny_pipeline(), tmp_path / "whole")
    first = train(tiny_pipeline("policy3_g", "experiment.max_frames=96"), tmp_path / "split")
    assert first.frames == 96
    resumed = train(tiny_pipeline("policy3_g", "resume=true"), tmp_path / "split")
    a = load_checkpoint(whole.checkpoint)
    b = load_checkpoint(resumed.checkpoint)
    assert a["counters"]["frames"] == b["counters"]["frames"]
    assert a["counters"]["updates"] == b["counters"]["updates"]
    assert a["counters"]["episodes"] == b["counters"]["episodes"]
    for key, value in a["actor"].items():
        assert torch.equal(value, b["actor"][key]), key
    assert torch.equal(a["learner"]["loss"]["log_alpha"], b["learner"]["loss"]["log_alpha"])
    # the episode log has no duplicate rows after the resume
    lines = (tmp_path / "split" / "episodes.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in lines] == list(range(1, len(lines) + 1))


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


# ---------------------------------------------------------------------------- resume=auto
def test_resume_auto_starts_fresh_then_leaves_a_finished_run_unchanged(tmp_path):
    cfg = tiny_pipeline("policy3_g", "resume=auto")
    first = train(cfg, tmp_path / "run")  # no checkpoint yet: a fresh run
    before = load_checkpoint(first.checkpoint)
    again = train(cfg, tmp_path / "run")  # finished: nothing more is collected or learned
    after = load_checkpoint(again.checkpoint)
    assert after["counters"]["frames"] == before["counters"]["frames"]
    for key, value in before["actor"].items():
        assert torch.equal(value, after["actor"][key]), key


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


# ---------------------------------------------------------------------------- refused, and nothing changed
def test_resume_without_checkpoint_is_refused(tmp_path):
    with pytest.raises(CheckpointError, match="no checkpoint"):
        train(tiny_pipeline("policy3_g", "resume=true"), tmp_path / "run")


def test_fresh_run_never_overwrites_an_existing_checkpoint(tmp_path):
    result = train(tiny_pipeline(), tmp_path / "run")
    before = result.checkpoint.read_bytes()
    with pytest.raises(CheckpointError, match="already holds a checkpoint"):
        train(tiny_pipeline(), tmp_path / "run")
    assert result.checkpoint.read_bytes() == before


def test_mismatched_checkpoint_is_refused(tmp_path):
    result = train(tiny_pipeline(), tmp_path / "run")
    before = result.checkpoint.read_bytes()
    config_before = (result.run_dir / "config.yaml").read_text()
    other = tiny_pipeline("policy3", "resume=true")  # critic on the observation, same folder
    with pytest.raises(CheckpointError, match="critic_input"):
        train(other, tmp_path / "run")
    assert result.checkpoint.read_bytes() == before
    assert (result.run_dir / "config.yaml").read_text() == config_before


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
