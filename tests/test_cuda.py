"""The GPU path end to end: env, training, evaluation on CUDA (skipped where there is none)."""

import pytest
import torch

from flock_torchrl import FlockingEnv, evaluate, make_train_config, train
from flock_torchrl.policies.scripted import goal_seeking_policy

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")


@pytest.mark.parametrize("scenario", ["train", "s4", "s5"])
def test_env_rollout_on_cuda_matches_cpu_shapes(scenario):
    env = FlockingEnv(scenario, num_envs=8, device="cuda", seed=0, policy_id="policy3_g", extras="all")
    td = env.rollout(20, break_when_any_done=False)
    assert td.device.type == "cuda" and td["next", "agents", "reward"].device.type == "cuda"
    assert torch.isfinite(td["next", "agents", "observation"]).all()


def test_training_and_evaluation_on_cuda(tmp_path):
    result = train(make_train_config("policy3_g", "tiny", ["device=cuda", "scenario.max_steps=40", "progress=false"]),
                   tmp_path / "run")
    assert result.frames >= 160
    evaluation = evaluate(result.checkpoint, "s2", n_episodes=8, device="cuda")
    assert evaluation.n_episodes == 8
    assert evaluate(goal_seeking_policy(), "s1", n_episodes=4, device="cuda").rate("success").rate == 1.0
