"""The learning pipeline end to end on the `tiny` experiment (seconds per run)."""

import pytest
import torch
from helpers import tiny_pipeline
from torchrl.envs.utils import ExplorationType, set_exploration_type

from flock_torchrl import FlockingEnv, load_policy
from flock_torchrl.policies.checkpoint import load_checkpoint
from flock_torchrl.run.launch import train


def ckpt_reading(result) -> str:
    """The reading the run trained under, as its config.yaml records it."""
    import yaml
    return yaml.safe_load((result.run_dir / "config.yaml").read_text())["scenario"]["reading"]


# SAC's tiny run is also tests/test_solo_reference.py's (fast tier, bit for bit); DDPG's there in the full tier
@pytest.mark.parametrize("policy, algo", [("policyp_g", "ppo"),
                                          pytest.param("policy3_g", "sac", marks=pytest.mark.slow),
                                          pytest.param("policyd_g", "ddpg", marks=pytest.mark.slow)])
def test_tiny_run_of_each_learner(tmp_path, policy, algo):
    result = train(tiny_pipeline(policy), tmp_path / "run")
    ckpt = load_checkpoint(result.checkpoint)
    assert ckpt["meta"]["algo"] == algo and ckpt["meta"]["policy_id"] == policy
    assert ckpt["counters"]["frames"] >= 160 and ckpt["counters"]["updates"] > 0
    assert set(ckpt) >= {"actor", "learner", "counters", "rng", "env_state", "meta", "config"}
    assert "optimizer" in ckpt["learner"]
    if algo != "ppo":
        assert ckpt["buffer"]["_storage"]["_len"] > 0
        # One Adam, a parameter group per network with its own learning rate (Table I's three for SAC).
        lrs = [g["lr"] for g in ckpt["learner"]["optimizer"]["param_groups"]]
        assert lrs == ([5e-5, 1e-3, 1e-3] if algo == "sac" else [5e-5, 1e-3])
    # evaluation metrics appear, in the checkpoint and in the logs
    assert result.evaluations, "no evaluation ran"
    for key in ("success", "safe_success", "d_min_obs", "d_min_uav", "d_c", "v_error", "phi_error", "speed"):
        assert key in result.evaluations[-1]
    assert (result.run_dir / "episodes.csv").is_file()
    assert (result.run_dir / "config.yaml").is_file()
    # the shipped-policy loader returns a module ready for env.rollout, for any N
    policy_module = load_policy(result.checkpoint)
    meta = policy_module.flock_meta
    assert meta["reading"] == ckpt_reading(result) and meta["policy_id"] == policy
    for scenario in ("train", "s2"):
        env = FlockingEnv(scenario, num_envs=2, seed=1, reading=meta["reading"], policy_id=meta["policy_id"])
        with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
            td = env.rollout(5, policy_module)
        assert td["agents", "action"].shape == (2, 5, env.n_agents, 2)
        assert td["agents", "action"].abs().max() <= 1


@pytest.mark.parametrize("cudagraphs", [False, pytest.param(True, marks=pytest.mark.slow)], ids=["eager", "captured"])
def test_nan_loss_stops_the_run_and_keeps_the_last_checkpoint(tmp_path, monkeypatch, cudagraphs):
    """The captured update keeps its finite-loss flags on the device and checks them before every
    checkpoint: a diverged run stops the same way and keeps its last good checkpoint."""
    from torchrl.data import TensorDictReplayBuffer

    cfg = tiny_pipeline("policy3_g", "experiment.max_frames=320", f"cudagraphs={str(cudagraphs).lower()}")
    calls = {"n": 0}
    original = TensorDictReplayBuffer.sample

    def poisoned(self, *args, **kwargs):
        batch = original(self, *args, **kwargs)
        calls["n"] += 1
        if calls["n"] > 20:  # 2 updates per 16 frames from frame 32: past the checkpoints at 64 and 128
            batch.set(("next", "agents", "reward"), torch.full_like(batch["next", "agents", "reward"], float("nan")))
        return batch

    monkeypatch.setattr(TensorDictReplayBuffer, "sample", poisoned)
    with pytest.raises(FloatingPointError, match="loss"):
        train(cfg, tmp_path / "run")
    kept = load_checkpoint(tmp_path / "run")
    assert 0 < kept["counters"]["frames"] < 320
    for value in kept["actor"].values():
        assert torch.isfinite(value).all()


def test_each_logging_event_is_one_row_of_every_scalar(tmp_path, monkeypatch):
    """The trainer hands the logger one dict per logging event (TorchRL's Logger.log_metrics): a
    wandb run gets one history row per event, not one per scalar; the training rows carry the
    losses, the episode length, the gradient norms, the learning rates and the loop's speed."""
    from torchrl.record.loggers import CSVLogger

    rows, scalars = [], []
    log_metrics, log_scalar = CSVLogger.log_metrics, CSVLogger.log_scalar

    def metrics(self, values, step=None, **kwargs):
        rows.append((set(values), step))
        return log_metrics(self, values, step, **kwargs)

    def scalar(self, name, value, step=None):
        scalars.append(name)
        return log_scalar(self, name, value, step)

    monkeypatch.setattr(CSVLogger, "log_metrics", metrics)
    monkeypatch.setattr(CSVLogger, "log_scalar", scalar)
    train(tiny_pipeline("policy3_g", "experiment.max_frames=96", "scenario.max_steps=6", logger="csv"),
          tmp_path / "run")
    training = [keys for keys, _ in rows if "train/loss_actor" in keys]
    assert training, rows
    wanted = {"train/loss_qvalue", "train/alpha", "train/episode_length", "train/grad_norm_actor",
              "train/grad_norm_critic", "train/lr_actor", "perf/frames_per_s"}
    assert all(wanted <= keys for keys in training), [wanted - keys for keys in training]
    assert len(scalars) == sum(len(keys) for keys, _ in rows)   # every scalar came through a row


@pytest.mark.slow
def test_wandb_logger_works_offline(tmp_path, monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "offline")
    train(tiny_pipeline("policy3_g", "experiment.max_frames=48", logger="wandb"), tmp_path / "wb")
    assert list((tmp_path / "wb" / "wandb").glob("offline-run-*")), "no offline wandb run was written"


@pytest.mark.slow
def test_several_collector_processes(tmp_path):
    """workers=2: TorchRL's MultiSyncCollector over two env processes, same learner."""
    result = train(tiny_pipeline("policy3_g", "experiment.workers=2", "experiment.max_frames=64"), tmp_path / "run")
    ckpt = load_checkpoint(result.checkpoint)
    assert ckpt["counters"]["frames"] >= 64 and ckpt["counters"]["updates"] > 0
    assert "env_state" not in ckpt  # several processes: a resume restarts their episodes


@pytest.mark.slow
def test_compiled_learner_is_its_eager_twin():
    """compile=true changes the speed, not the learning: a few SAC updates agree with eager
    ones up to float round-off, and the compiled learner saves and restores its state."""
    from flock_torchrl.config import algo_config, compose
    from flock_torchrl.policies.learners import OffPolicyLearner
    from benchmarks.throughput import replay_batches

    env, batches = replay_batches(128, 3)
    cfg = algo_config(compose("train", ["experiment=paper"]).algo)
    learners = []
    for compile in (False, True):
        torch.manual_seed(0)
        learner = OffPolicyLearner(env, cfg, "state", compile=compile)
        for batch in batches:
            torch.manual_seed(1)
            learner.update(batch.clone())
        learners.append(learner)
    eager, compiled = (x.actor_state(0) for x in learners)
    for key, value in eager.items():
        assert torch.allclose(value, compiled[key], atol=1e-5), key
    state = learners[1].state_dict()
    learners[0].load_state_dict(state)
    assert "_target_entropy" in state["loss"]


@pytest.mark.slow
def test_a_compiled_runs_first_update_is_booked_as_compile(tmp_path):
    """The time split keeps torch.compile's work on the loss apart from the updates it speeds up
    (the paper-loop benchmark leaves it out); an eager run books none. The env's steps, compiled or
    not, are the collection's (timed from outside the env)."""
    compiled = train(tiny_pipeline("policy3_g", "compile=true", "experiment.max_frames=64"), tmp_path / "compiled")
    eager = train(tiny_pipeline("policy3_g", "experiment.max_frames=64"), tmp_path / "eager")
    step = train(tiny_pipeline("policy3_g", "compile=step", "experiment.max_frames=64"), tmp_path / "step")
    assert compiled.updates > 1 and compiled.split["compile"] > 0 and compiled.split["update"] > 0
    assert eager.split["compile"] == 0 and eager.split["update"] > 0
    # Only the step compiles: its compilation is part of the collection, the loss's updates are eager.
    assert step.split["compile"] == 0 and step.split["collection"] > 0 and step.split["update"] > 0
    assert "compile" in compiled.split_line()


def test_compile_step_compiles_the_env_and_leaves_the_loss_eager():
    """compile=step (make train-all): the training env steps through its compiled twin, the
    learner's loss stays the eager module; compile=loss the other way round."""
    import os

    from flock_torchrl.config import TrainConfig
    from flock_torchrl.policies.learners import make_learner
    from flock_torchrl.run.parts import make_env

    for mode, step, loss in (("step", True, False), ("loss", False, True)):
        cfg = TrainConfig.from_config(tiny_pipeline("policy3_g", f"compile={mode}"))
        env = make_env(cfg, 2, torch.device("cpu"), 0, os.getpid())
        learner = make_learner(env, cfg.algo, cfg.policy.critic_input, compile=cfg.compile_loss)
        assert env.compile_step is step and (learner.loss_fn is not learner.loss) is loss, mode


@pytest.mark.slow
def test_two_compiled_learners_of_different_sizes_share_a_process():
    """A sweep's worker process (or this test process) compiles learners of several sizes: each
    recompiles for its own shapes (static), where dynamic shapes broke TorchRL's vmapped twin Q."""
    import dataclasses

    from flock_torchrl.config import algo_config, compose
    from flock_torchrl.policies.learners import OffPolicyLearner
    from benchmarks.throughput import replay_batches

    env, batches = replay_batches(128, 2)
    cfg = algo_config(compose("train", ["experiment=paper"]).algo)
    for hidden in (64, 32):
        learner = OffPolicyLearner(env, dataclasses.replace(cfg, hidden=hidden), "state", compile=True)
        for batch in batches:
            stats = learner.update(batch.clone())
        assert torch.isfinite(stats["loss_qvalue"])


def test_the_training_progress_off_a_terminal_is_lines_to_a_whole_batch_and_rated_after_the_random_frames():
    """Off a terminal (a redirected log) the progress is a line now and then, no carriage return;
    its total is the budget rounded up to whole batches (8000 frames of 256 collect 8192), and its
    rate counts the frames after the random ones from when they began."""
    from flock_torchrl.run.timing import Progress

    lines = []
    progress = Progress(8000, {"frames": 0}, "Policy3-G seed 0", per_batch=256, random_frames=512, every=0.0,
                        write=lines.append)
    assert progress.bar.disable and progress.total == 8192
    for frames in range(256, 8193, 256):
        progress.update({"frames": frames, "episodes": frames // 100}, {"train/success_rate": 0.5})
        if frames == 512:
            assert progress.since[1] == 512  # the rate counts the frames after the random ones, from then on
    progress.close()
    assert len(lines) == 32 and not any("\r" in line for line in lines)
    assert lines[-1].startswith("[Policy3-G seed 0] 8192/8192 (100 %) frames") and "success 0.50" in lines[-1]
