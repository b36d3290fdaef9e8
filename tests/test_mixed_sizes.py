"""Several swarm sizes trained at once (experiment.swarm_sizes): single-UAV transitions in the
replay buffer give the losses the same terms; a mixed run trains, checkpoints, resumes exactly
and its policy flies any N; bad recipes are refused before anything runs."""

import math

import pytest
import torch

from flock_torchrl import FlockingEnv, load_policy
from flock_torchrl.config import ConfigError, algo_config, app_config, compose
from flock_torchrl.policies.checkpoint import load_checkpoint
from flock_torchrl.policies.learners import OffPolicyLearner
from flock_torchrl.run.launch import train
from flock_torchrl.run.batches import TRANSITION_KEYS, agentwise_done, per_uav
from flock_torchrl.run.setup import make_train_config


def swarm_batch(n_uavs: int, steps: int = 3):
    env = FlockingEnv("train", 4, "cpu", 0, policy_id="policy3_g", n_uavs=n_uavs)
    torch.manual_seed(0)
    td, rows = env.reset(), []
    for _ in range(steps):
        step, td = env.step_and_maybe_reset(env.rand_action(td))
        rows.append(agentwise_done(step, n_uavs).select(*TRANSITION_KEYS, strict=False))
    return env, torch.stack(rows, 1).reshape(-1)  # [M] swarm transitions


def test_per_uav_puts_uav_j_of_transition_m_at_row_m_n_plus_j():
    _, batch = swarm_batch(3)
    single = per_uav(batch)
    m, n = batch.shape[0], 3
    assert single.batch_size == (m * n,) and single["agents"].batch_size == (m * n, 1)
    keys = [k for k in TRANSITION_KEYS if "agents" in k and k in batch.keys(True)]
    assert len(keys) == 8
    for key in keys:
        assert single[key].shape == (m * n, 1, *batch[key].shape[2:]), key
        for row, (i, j) in ((0, (0, 0)), (4, (1, 1)), (m * n - 1, (m - 1, n - 1))):
            assert torch.equal(single[key][row, 0], batch[key][i, j]), (key, row)


def test_sac_losses_on_single_uav_transitions_equal_those_on_swarm_transitions():
    env, batch = swarm_batch(5)
    learner = OffPolicyLearner(env, algo_config(compose("train", ["experiment=fast"]).algo), "state")
    values = []
    for data in (batch, per_uav(batch)):
        torch.manual_seed(3)  # the same draws, in the same order: UAV-major either way
        out = learner.loss(data.clone())
        values.append({k: out[k].detach() for k in ("loss_actor", "loss_qvalue", "loss_alpha")})
    for key in values[0]:
        assert torch.allclose(values[0][key], values[1][key], rtol=1e-5, atol=1e-6), key


def mixed(*overrides):
    return make_train_config("policy3_g", "tiny", ["scenario.max_steps=40", "progress=false",
                                                   "experiment.swarm_sizes=[3,6]", "experiment.eval_every_frames=0",
                                                   *overrides])


@pytest.mark.slow
def test_a_mixed_run_trains_resumes_exactly_and_flies_any_size(tmp_path):
    whole = train(mixed("experiment.max_frames=192"), tmp_path / "whole")
    train(mixed("experiment.max_frames=96"), tmp_path / "split")
    resumed = train(mixed("experiment.max_frames=192", "resume=true"), tmp_path / "split")
    a, b = load_checkpoint(whole.checkpoint), load_checkpoint(resumed.checkpoint)
    assert a["counters"] == {**b["counters"], "seconds": a["counters"]["seconds"]}
    assert a["counters"]["frames"] == 192 and a["counters"]["updates"] > 0
    assert len(a["env_state"]) == 2 and a["buffer"]["_storage"]["_len"] > 0
    for key, value in a["actor"].items():
        assert torch.equal(value, b["actor"][key]), key
    policy = load_policy(whole.checkpoint)
    for n in (2, 9):
        env = FlockingEnv("train", 2, "cpu", 1, policy_id="policy3_g", n_uavs=n)
        assert env.rollout(3, policy)["agents", "action"].shape == (2, 3, n, 2)
    # a row of the scaling table beside the shipped Policy3-G, with the sizes it was trained at
    from flock_torchrl.report.scaling import scaling

    cfg = app_config("scaling", reading="paper_fit", policy_name="policy3_g", sizes=[4], episodes=2,
                     others=[str(whole.checkpoint)])
    rows = scaling(cfg, tmp_path / "scaling", log=lambda _: None)
    assert [(r["policy"], r["trained_sizes"]) for r in rows] == [("Policy3-G", "5"), ("Policy3-G [tiny, seed 0]", "3+6")]
    assert "| Policy3-G [tiny, seed 0] | 3+6 | 4 |" in (tmp_path / "scaling" / "scaling.md").read_text()


@pytest.mark.parametrize("overrides, words", [
    (["experiment.swarm_sizes=[3,3]"], "sizes repeat"),
    (["experiment.swarm_sizes=[3,5,6]"], "must divide num_envs=4"),
    (["experiment.swarm_sizes=[3,0]"], "experiment.swarm_sizes[1]"),
    (["experiment.swarm_sizes=[3,5]", "experiment.workers=2"], "set workers=1"),
    (["experiment.swarm_sizes=[3,5]", "policy=policyp_g"], "off-policy"),
])
def test_bad_mixed_recipes_are_refused_by_name(overrides, words):
    from flock_torchrl.config import TrainConfig

    with pytest.raises(ConfigError, match="swarm_sizes") as info:
        TrainConfig.from_config(compose("train", ["experiment=tiny", *overrides]))
    assert words in str(info.value)


# ---------------------------------------------------------------------------- kinds of training world
WALL = "{circles:[],rectangles:[[40.0,40.0,2000.0,4.0,4.0,20.0]],chi_range:[0.7853981633974483,2.356194490192345]}"


def test_train_mix_splits_the_worlds_between_every_size_and_kind():
    """experiment.train_mix: an env per (swarm size, kind), sizes outermost; each kind's fields over
    the training scenario, the swarm transitions kept whole where the sizes are not mixed."""
    from flock_torchrl.run.parts import make_envs

    from flock_torchrl.config import TrainConfig

    cfg = TrainConfig.from_config(make_train_config("policy3_g", "tiny", [
        "scenario=train3d", f"experiment.train_mix=[{{}},{WALL}]", "experiment.swarm_sizes=[3,5]"]))
    kinds = cfg.train_scenarios
    assert [(s.n_uavs, len(s.circles), s.rectangles[0][2]) for s in kinds] == [
        (3, 1, 6.0), (3, 0, 2000.0), (5, 1, 6.0), (5, 0, 2000.0)]
    assert kinds[1].chi_range == pytest.approx([math.pi / 4, 3 * math.pi / 4]) and kinds[0].chi_range[0] == -math.pi
    envs, _ = make_envs(cfg, torch.device("cpu"))
    assert [e.num_envs for e in envs] == [1, 1, 1, 1]  # tiny's 4 worlds, one per size and kind
    # The wall's kind alone, without sizes: two envs of two worlds, and a run of it trains on both.
    cfg = TrainConfig.from_config(make_train_config("policy3_g", "tiny", [
        "scenario=train3d", f"experiment.train_mix=[{{}},{WALL}]"]))
    envs, _ = make_envs(cfg, torch.device("cpu"))
    assert [e.num_envs for e in envs] == [2, 2] and envs[1].cfg.rectangles[0][2] == 2000.0


@pytest.mark.slow
def test_a_run_of_two_kinds_of_world_trains_and_resumes_exactly(tmp_path):
    def kinds(*overrides):
        return make_train_config("policy3_g", "tiny", ["scenario=train3d", "scenario.max_steps=40", "progress=false",
                                                       f"experiment.train_mix=[{{}},{WALL}]",
                                                       "experiment.eval_every_frames=0", *overrides])

    whole = train(kinds("experiment.max_frames=192"), tmp_path / "whole")
    train(kinds("experiment.max_frames=96"), tmp_path / "split")
    resumed = train(kinds("experiment.max_frames=192", "resume=true"), tmp_path / "split")
    a, b = load_checkpoint(whole.checkpoint), load_checkpoint(resumed.checkpoint)
    assert len(a["env_state"]) == 2 and a["counters"]["updates"] > 0
    for key, value in a["actor"].items():
        assert torch.equal(value, b["actor"][key]), key


@pytest.mark.parametrize("overrides, words", [
    (["experiment.train_mix=[{},{nothing:1}]"], "experiment.train_mix[1]: unknown scenario field"),
    (["experiment.train_mix=[{},{n_uavs:9}]"], "experiment.swarm_sizes"),
    (["experiment.train_mix=[{},{},{}]"], "must divide num_envs=4"),
    (["experiment.train_mix=[{},{}]", "experiment.workers=2"], "set workers=1"),
    (["experiment.train_mix=[{},{}]", "policy=policyp_g"], "off-policy"),
    (["experiment.train_mix=[{},{rectangles:[[40.0,40.0,2000.0,4.0,4.0,20.0]]}]"], "scenario.rectangles"),
])
def test_bad_kinds_of_training_world_are_refused_by_name(overrides, words):
    from flock_torchrl.config import TrainConfig

    with pytest.raises(ConfigError, match="train_mix") as info:
        TrainConfig.from_config(compose("train", ["experiment=tiny", *overrides]))
    assert words in str(info.value)
