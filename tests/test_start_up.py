"""What an app refuses as it starts, before it writes anything: config errors and values the run
cannot take (one line, exit 2), composition errors (Hydra's own, exit 1), a sweep checked whole,
messages naming the command line or the file a value came from, broken YAML in the search path,
output folders that cannot be made or written, a checkpoint of the other dimension."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
import torch
from helpers import ROOT, SHIPPED, TINY, finish, first_fast, one_line, run_script, script, start


# ---------------------------------------------------------------------------- config errors and values the run cannot take
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


@pytest.mark.slow
def test_an_int_inside_a_float_list_is_taken(tmp_path):
    proc = run_script("evaluate.py", "policy=policy_ma", "scenario.circles=[[40,40,6]]", "episodes=2", cwd=tmp_path)
    assert "Policy-MA on train" in proc.stdout


# ---------------------------------------------------------------------------- where a value came from
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


# ---------------------------------------------------------------------------- output folders
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


# ---------------------------------------------------------------------------- a checkpoint of the other dimension
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
