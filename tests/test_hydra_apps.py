"""The apps through Hydra's own doors (and its config doors): a user's config
folder, the search path, other sweepers and launchers, the objective a sweeper optimises, one
check per job, and the ecosystem around the apps (loggers, TorchRL's own multi-agent wiring)."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch
import yaml
from helpers import ROOT, run_script, script_env

TINY = ["experiment=tiny", "scenario.max_steps=40", "experiment.max_frames=48", "experiment.eval_every_frames=0",
        "experiment.eval_episodes=2", "progress=false"]
CORRIDOR = """\
defaults:
  - train          # the training scenario's world ...
  - _self_
name: corridor     # ... in a corridor: two walls, no circle
circles: []
rectangles:
  - [40.0, 30.0, 40.0, 4.0]
  - [40.0, 50.0, 40.0, 4.0]
"""


def user_folder(root: Path, text: str = CORRIDOR, name: str = "corridor") -> Path:
    folder = root / "my_conf" / "scenario"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.yaml").write_text(text)
    return root / "my_conf"


@pytest.mark.slow
def test_a_users_scenario_from_config_dir_is_trained_on_and_evaluated(tmp_path):
    conf = user_folder(tmp_path)
    run_script("train.py", "--config-dir", str(conf), "scenario=corridor", *TINY, cwd=tmp_path)
    (run,) = (tmp_path / "runs" / "tiny").glob("*/policy3_g/seed0__*scenario-corridor*")
    saved = yaml.safe_load((run / "config.yaml").read_text())
    assert saved["scenario"]["name"] == "corridor" and len(saved["scenario"]["rectangles"]) == 2
    assert saved["scenario"]["circles"] == [] and saved["scenario"]["instinct"] is True  # the policy's fields on top
    proc = run_script("evaluate.py", "--config-dir", str(conf), "scenario=corridor", f"checkpoint={run / 'last.pt'}",
                      "episodes=3", cwd=tmp_path)
    assert "Policy3-G on corridor" in proc.stdout


@pytest.mark.slow
@pytest.mark.parametrize("door", ["file", "pkg"])
def test_hydra_searchpath_adds_a_scenario(tmp_path, door):
    if door == "file":
        conf = user_folder(tmp_path)
        entry, env = f"file://{conf}", {}
    else:  # a Python package of the user's that carries configs
        package = tmp_path / "lab" / "mylab"
        (package / "conf" / "scenario").mkdir(parents=True)
        (package / "__init__.py").write_text("")
        (package / "conf" / "__init__.py").write_text("")
        (package / "conf" / "scenario" / "corridor.yaml").write_text(CORRIDOR)
        entry, env = "pkg://mylab.conf", {"PYTHONPATH": f"{ROOT}{os.pathsep}{tmp_path / 'lab'}"}
    proc = run_script("evaluate.py", f"hydra.searchpath=[{entry}]", "scenario=corridor", "policy=policy_ma",
                      "episodes=2", cwd=tmp_path, **env)
    assert "Policy-MA on corridor" in proc.stdout


@pytest.mark.slow
def test_a_bad_value_in_a_users_file_names_the_file_and_the_key(tmp_path):
    conf = user_folder(tmp_path, CORRIDOR + "n_uavs: 0\n", "crowd")
    proc = run_script("evaluate.py", "--config-dir", str(conf), "scenario=crowd", "episodes=2", cwd=tmp_path,
                      check=False)
    assert proc.returncode == 2 and not (tmp_path / "outputs").exists()
    assert proc.stderr.startswith("error: scenario.n_uavs: must be an integer >= 1")
    assert str(conf / "scenario" / "crowd.yaml") in proc.stderr


@pytest.mark.slow
def test_optuna_tunes_a_policy_through_the_train_apps_objective(tmp_path):
    if importlib.util.find_spec("hydra_plugins.hydra_optuna_sweeper") is None:
        pytest.skip("the optuna sweeper is the optuna extra (pip install flock_torchrl[optuna])")
    sweep = tmp_path / "sweep"
    proc = run_script("train.py", "-m", "hydra/sweeper=optuna", "hydra.sweeper.n_trials=2",
                      "hydra.sweeper.direction=maximize", "algo.lr_actor=interval(1e-4,1e-3)", *TINY,
                      f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    trials = sorted((sweep / "tiny").glob("*/policy3_g/seed0__algo.lr_actor-*"))
    assert len(trials) == 2, proc.stdout
    result = yaml.safe_load((sweep / "optimization_results.yaml").read_text())
    finals = [yaml.safe_load((t / "config.yaml").read_text())["algo"]["lr_actor"] for t in trials]
    assert result["best_params"]["algo.lr_actor"] in finals
    # The objective is the final evaluation's success rate (conf/train.yaml: objective).
    assert 0.0 <= result["best_value"] <= 1.0


@pytest.mark.slow
def test_a_launcher_without_its_plugin_says_which_extra(tmp_path):
    if importlib.util.find_spec("hydra_plugins.hydra_submitit_launcher") is not None:
        pytest.skip("the slurm extra is installed")
    proc = run_script("train.py", "-m", "hydra/launcher=slurm", *TINY, "seed=0,1", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "flock_torchrl[slurm]" in proc.stderr and list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_help_names_the_app_and_offers_no_schemas(tmp_path):
    for script, app in (("train.py", "train"), ("evaluate.py", "evaluate"), ("reproduce.py", "reproduce")):
        text = run_script(script, "--help", cwd=tmp_path).stdout
        assert text.startswith(f"{app} is powered by Hydra") and "_schema" not in text, text[:400]


def test_each_job_is_converted_and_checked_once(tmp_path, monkeypatch):
    """In one process (Hydra's basic launcher), the sweep's check hands each job its checked object."""
    from flock_torchrl import cli
    from flock_torchrl.config import ScenarioConfig, TrainConfig

    calls = {"train": 0, "scenario": 0}
    train_check, scenario_check = TrainConfig.check, ScenarioConfig.check

    def count_train(self, prefix=None):
        calls["train"] += 1
        return train_check(self, prefix)

    def count_scenario(self, prefix=None):
        calls["scenario"] += 1
        return scenario_check(self, prefix)

    monkeypatch.setattr(TrainConfig, "check", count_train)
    monkeypatch.setattr(ScenarioConfig, "check", count_scenario)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["train.py", "-m", *TINY, "seed=0,1"])
    cli.train_main()
    assert calls == {"train": 2, "scenario": 2}  # two jobs: each config checked once, the world once
    assert len(list((tmp_path / "runs" / "multirun").glob("*/*/tiny/*/policy3_g/seed*"))) == 2  # the sweep's folder


@pytest.mark.slow
def test_tensorboard_logs_the_hyperparameters(tmp_path):
    if importlib.util.find_spec("tensorboard") is None:
        pytest.skip("tensorboard is the tensorboard extra")
    run_script("train.py", *TINY, "logger=tensorboard", f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    events = list((tmp_path / "run" / "tensorboard").rglob("events.out.tfevents.*"))
    assert events and sum(p.stat().st_size for p in events) > 0


@pytest.mark.slow
def test_a_logger_that_is_not_installed_is_a_config_error_before_any_folder(tmp_path):
    code = textwrap.dedent("""
        import importlib.util, sys
        real = importlib.util.find_spec
        importlib.util.find_spec = lambda name, *a: None if name == "tensorboard" else real(name, *a)
        sys.argv = ["train.py", "logger=tensorboard", "experiment=tiny"]
        from flock_torchrl.cli import train_main
        train_main()
    """)
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=script_env(), capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 2 and "pip install 'flock_torchrl[tensorboard]'" in proc.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_the_package_imports_where_fcntl_does_not_exist(tmp_path):
    code = ("import sys; sys.modules['fcntl'] = None; import flock_torchrl; from flock_torchrl import FlockingEnv; "
            "print(FlockingEnv('train', num_envs=2).num_envs)")
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=script_env(), capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0 and proc.stdout.strip() == "2", proc.stderr


@pytest.mark.filterwarnings("error::FutureWarning")   # make test ended with its FutureWarning
def test_torchrls_own_multiagent_sac_wiring_trains_on_the_env():
    """TorchRL's multi-agent SAC recipe (sota-implementations/multiagent/sac.py), with no helper
    of this project: MultiAgentMLP policy and critic, ProbabilisticActor + TanhNormal, SACLoss
    on the "agents" keys, a Collector, a replay buffer, and the render callback it evaluates with."""
    from tensordict.nn import NormalParamExtractor, TensorDictModule
    from torch import nn
    from torchrl.collectors import Collector
    from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
    from torchrl.envs.utils import ExplorationType, set_exploration_type
    from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal, ValueOperator
    from torchrl.objectives import SACLoss, SoftUpdate, ValueEstimators

    from flock_torchrl import FlockingEnv

    torch.manual_seed(0)
    env = FlockingEnv("train", num_envs=4, seed=0, policy_id="policy3_g")
    n = env.n_agents
    obs = env.observation_spec["agents", "observation"].shape[-1]
    state = env.observation_spec["agents", "state"].shape[-1]
    act = env.full_action_spec_unbatched["agents", "action"]
    actor_net = nn.Sequential(
        MultiAgentMLP(n_agent_inputs=obs, n_agent_outputs=2 * act.shape[-1], n_agents=n, centralized=False,
                      share_params=True, depth=2, num_cells=32, activation_class=nn.Tanh),
        NormalParamExtractor())
    policy = ProbabilisticActor(
        TensorDictModule(actor_net, in_keys=[("agents", "observation")], out_keys=[("agents", "loc"), ("agents", "scale")]),
        in_keys=[("agents", "loc"), ("agents", "scale")], out_keys=[("agents", "action")],
        distribution_class=TanhNormal, distribution_kwargs={"low": act.space.low, "high": act.space.high},
        return_log_prob=True)
    critic = ValueOperator(
        MultiAgentMLP(n_agent_inputs=state + act.shape[-1], n_agent_outputs=1, n_agents=n, centralized=True,
                      share_params=True, depth=2, num_cells=32, activation_class=nn.Tanh),
        in_keys=[("agents", "state"), ("agents", "action")], out_keys=[("agents", "state_action_value")])
    # auto_register_policy_transforms=False: TorchRL 0.14's opt-out of a default change (its FutureWarning)
    collector = Collector(env, policy, frames_per_batch=64, total_frames=384, auto_register_policy_transforms=False)
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(1000), batch_size=32)
    loss = SACLoss(actor_network=policy, qvalue_network=critic, delay_qvalue=True, action_spec=env.action_spec)
    loss.set_keys(state_action_value=("agents", "state_action_value"), action=("agents", "action"),
                  reward=("agents", "reward"), done=("agents", "done"), terminated=("agents", "terminated"))
    loss.make_value_estimator(ValueEstimators.TD0, gamma=0.99)
    updater = SoftUpdate(loss, eps=0.995)
    optim = torch.optim.Adam(loss.parameters(), lr=3e-4)
    losses = []
    for batch in collector:
        for key in ("done", "terminated"):  # the env's done is the swarm's: give each UAV its copy
            value = batch.get(("next", key))
            batch.set(("next", "agents", key), value.unsqueeze(-1).expand(*value.shape[:-1], n, 1))
        buffer.extend(batch.reshape(-1))
        for _ in range(2):
            out = loss(buffer.sample())
            total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
            optim.zero_grad()
            total.backward()
            optim.step()
            updater.step()
            losses.append(float(total.detach()))
    collector.shutdown()
    assert len(losses) == 12 and all(torch.isfinite(torch.tensor(losses)))
    frames = []

    def rendering_callback(env, td):
        frames.append(env.render(mode="rgb_array", agent_index_focus=None, visualize_when_possible=True))

    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        env.rollout(3, policy=policy, callback=rendering_callback, break_when_any_done=False)
    assert len(frames) >= 2 and frames[0].ndim == 3 and frames[0].shape[-1] == 3  # one per step after the first
