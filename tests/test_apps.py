"""The command-line apps as a user meets them: sweeps, output folders, what --cfg job shows,
packaging. Each test is an observation that failed before the Hydra-native configuration."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import yaml
from helpers import first_fast, run_script

ROOT = Path(__file__).resolve().parent.parent
TINY = ["experiment=tiny", "scenario.max_steps=40", "experiment.max_frames=48", "experiment.eval_every_frames=0",
        "experiment.eval_episodes=2", "progress=false"]


def default_reading() -> str:
    """The reading conf/world.yaml selects: where apps write when no reading is given."""
    from flock_torchrl.config import compose
    return compose("world").scenario.reading


run = run_script


@pytest.mark.slow
def test_a_sweep_gives_each_job_its_own_folder_and_config(tmp_path):
    # Observation 1: jobs 2-4 "resumed" job 1's run and rewrote its config. Now each job has a
    # folder named after its overrides, holding the config it trained with.
    # hydra.sweep.dir=runs: the same sweep folder both times (by default each sweep gets its own).
    run("train.py", "-m", *TINY, "seed=6", "resume=auto", "algo.lr_actor=0.001,0.0001", "scenario.tau_v=0.5,2.0",
        "hydra.sweep.dir=runs", cwd=tmp_path)
    runs = sorted((tmp_path / "runs" / "tiny" / default_reading() / "policy3_g").iterdir())
    # key-value pairs joined by "__": a folder name is a valid Hydra value as it is (no "=" or ",").
    assert [r.name for r in runs] == [f"seed6__algo.lr_actor-{lr}__scenario.max_steps-40__scenario.tau_v-{tau}"
                                      for lr in ("0.0001", "0.001") for tau in ("0.5", "2.0")]
    for folder in runs:
        config = yaml.safe_load((folder / "config.yaml").read_text())
        lr, _, tau = folder.name.split("__")[1:]
        assert config["algo"]["lr_actor"] == float(lr.split("-", 1)[1])
        assert config["scenario"]["tau_v"] == float(tau.split("-", 1)[1])
        assert (folder / "last.pt").is_file() and (folder / "episodes.csv").is_file()
    # The same sweep again resumes each job's own finished run: nothing changes.
    before = {f: (f / "last.pt").read_bytes() for f in runs}
    run("train.py", "-m", *TINY, "seed=6", "resume=auto", "algo.lr_actor=0.001,0.0001", "scenario.tau_v=0.5,2.0",
        "hydra.sweep.dir=runs", cwd=tmp_path)
    assert all((f / "last.pt").read_bytes() == data for f, data in before.items())


@pytest.mark.slow
def test_sweep_dir_moves_everything_and_config_is_what_cfg_job_prints(tmp_path):
    # Observation 2: hydra.sweep.dir moved only .hydra/; observation 3: config.yaml and
    # --cfg job showed other values than the run used.
    out = tmp_path / "cluster"
    run("train.py", "-m", *TINY, "experiment=fast", "experiment.num_envs=4", "experiment.max_frames=64",
        "experiment.init_random_frames=32", f"hydra.sweep.dir={out}", "logger=csv", cwd=tmp_path)
    assert not (tmp_path / "runs").exists()
    (folder,) = list((out / "fast" / default_reading() / "policy3_g").iterdir())
    assert {p.name for p in folder.iterdir()} >= {"config.yaml", "resume.yaml", "last.pt", "episodes.csv", "logs"}
    saved = yaml.safe_load((folder / "config.yaml").read_text())
    assert saved["algo"]["batch_size"] == 1280  # the fast tuning, as trained
    shown = run("train.py", *TINY, "experiment=fast", "experiment.num_envs=4", "experiment.max_frames=64",
                "experiment.init_random_frames=32", "logger=csv", "--cfg", "job", "--resolve", cwd=tmp_path).stdout
    assert yaml.safe_load(shown) == saved
    # Hyperparameters reach the logger.
    hparams = (folder / "logs" / "texts" / "hparams0.txt").read_text()
    assert "algo.batch_size: 1280" in hparams and "scenario.instinct: True" in hparams


@pytest.mark.slow
def test_apps_write_only_their_output_folders(tmp_path):
    # Observation 2: evaluate.py wrote into the repository and reproduce / figures overwrote the
    # shipped results/ and figures/. Each app now writes under outputs/ of the working folder.
    shipped = {p: hashlib.sha256(p.read_bytes()).hexdigest() for d in ("results", "figures", "checkpoints")
               for p in (ROOT / d).rglob("*") if p.is_file()}
    run("evaluate.py", "policy=policy_op", "scenario=s1", "episodes=2", cwd=tmp_path)
    assert (tmp_path / "outputs" / "evaluate" / default_reading() / "policy_op" / "s1__episodes-2" / "summary.json").is_file()
    run("reproduce.py", "table=5", "episodes=2", cwd=tmp_path)
    assert (tmp_path / "outputs" / "reproduce" / default_reading() / "table5.md").is_file()
    after = {p: hashlib.sha256(p.read_bytes()).hexdigest() for d in ("results", "figures", "checkpoints")
             for p in (ROOT / d).rglob("*") if p.is_file()}
    assert after == shipped


@pytest.mark.slow
def test_the_wheel_carries_the_configs(tmp_path):
    # Observation 4: `pip install .` gave "unknown scenario 'train'; available: []".
    source = tmp_path / "source"  # built from a copy: the build writes build/ and *.egg-info beside it
    source.mkdir()
    for name in ("pyproject.toml", "README.md", "flock_torchrl", "conf", "checkpoints"):
        (shutil.copytree if (ROOT / name).is_dir() else shutil.copy)(ROOT / name, source / name)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(tmp_path), str(source)], check=True, capture_output=True, timeout=300)
    (wheel,) = tmp_path.glob("flock_torchrl-*.whl")
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        archive.extractall(site)
    assert "flock_torchrl/conf/train.yaml" in names and "flock_torchrl/conf/scenario/s3.yaml" in names
    assert "flock_torchrl/report/reference/table3.csv" in names
    # The shipped policies travel with it, so the apps reach them from any folder.
    assert "flock_torchrl/checkpoints/paper_fit/policy3_g/seed0.pt" in names
    # Every shipped seed of both readings travels, and the installed package stays under 50 MB.
    installed = sum(p.stat().st_size for p in site.rglob("*") if p.is_file())
    assert installed < 50e6, f"the installed wheel takes {installed / 1e6:.1f} MB; keep it under 50 MB"
    code = ("import flock_torchrl.config as c; from flock_torchrl import FlockingEnv; "
            "env = FlockingEnv('s2', policy_id='policy3_g'); print(c.CONF_DIR, env.n_agents, c.default_checkpoints_dir())")
    env = {**os.environ, "PYTHONPATH": str(site)}
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=300, check=True).stdout
    assert out.strip() == f"{site / 'flock_torchrl' / 'conf'} 9 {site / 'flock_torchrl' / 'checkpoints'}"
    evaluate = ("import sys; sys.argv = ['flock-evaluate', 'policy=policy3_g', 'episodes=2']; "
                "from flock_torchrl.cli import evaluate_main; evaluate_main()")
    proc = subprocess.run([sys.executable, "-c", evaluate], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    shipped = len(list((ROOT / "checkpoints" / "paper_fit" / "policy3_g").glob("seed*.pt")))
    assert f"pooled over {shipped} checkpoints" in proc.stdout and str(site / "flock_torchrl" / "checkpoints") in proc.stdout
    # A user's scenario folder outside the repository, trained on and evaluated from the wheel.
    conf = tmp_path / "my_conf" / "scenario"
    conf.mkdir(parents=True)
    (conf / "corridor.yaml").write_text("defaults: [train, _self_]\nname: corridor\ncircles: []\n"
                                        "rectangles: [[40.0, 30.0, 40.0, 4.0], [40.0, 50.0, 40.0, 4.0]]\n")
    for app, args in (("train", ["experiment=tiny", "experiment.max_frames=32", "experiment.eval_every_frames=0",
                                 "experiment.eval_episodes=1", "scenario.max_steps=20", "progress=false"]),
                      ("evaluate", ["policy=policy_ma", "episodes=2", "scenario.max_steps=20"])):
        run = (f"import sys; sys.argv = ['flock-{app}', '--config-dir', {str(tmp_path / 'my_conf')!r}, "
               f"'scenario=corridor', *{args!r}]; from flock_torchrl.cli import {app}_main; {app}_main()")
        proc = subprocess.run([sys.executable, "-c", run], cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, proc.stderr
    (run,) = (tmp_path / "runs" / "tiny" / "paper_fit" / "policy3_g").glob("seed0__*scenario-corridor")
    assert (run / "last.pt").is_file()
    assert "Policy-MA on corridor" in proc.stdout


def test_every_package_folder_is_packaged():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    # Every folder of the package (code or data) and of conf/ is listed, so setuptools ships it.
    found = {".".join(p.relative_to(ROOT).parts) for p in [ROOT / "flock_torchrl", *(ROOT / "flock_torchrl").rglob("*")]
             if p.is_dir() and p.name != "__pycache__"}
    configs = {".".join(("flock_torchrl",) + p.relative_to(ROOT).parts) for p in [ROOT / "conf", *(ROOT / "conf").rglob("*")]
               if p.is_dir()}
    assert found | configs | {"flock_torchrl.checkpoints"} == listed  # checkpoints/: one package, files by glob


@pytest.mark.parametrize("script", first_fast(["train.py", "evaluate.py", "reproduce.py", "figures.py",
                                               "tune_baselines.py", "ship.py", "scaling.py"]))
def test_every_script_is_a_hydra_app(script, tmp_path):
    proc = run(script, "--cfg", "job", cwd=tmp_path)
    assert proc.stdout.strip() and not (tmp_path / "outputs").exists() and not (tmp_path / "runs").exists()
