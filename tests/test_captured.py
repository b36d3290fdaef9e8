"""The captured update (``cudagraphs=true``): one function per gradient step that never reads a
tensor on the host, wrapped in tensordict's ``CudaGraphModule``. Without CUDA the module calls it
as it is, so these tests run the captured code path here against the uncaptured learner."""

from __future__ import annotations

import pytest
import torch

from flock_torchrl.config import ConfigError, TrainConfig
from flock_torchrl.policies.checkpoint import load_checkpoint
from flock_torchrl.policies.learners import make_learner
from flock_torchrl.policies.population import PopulationLearner
from flock_torchrl.run.launch import train
from flock_torchrl.run.population import PopulationTraining
from flock_torchrl.run.trainer import Training, make_train_config

from test_population import quick_config, transitions


def _equal_updates(captured, eager, batches, seeds=100) -> None:
    for step, batch in enumerate(batches):
        torch.manual_seed(seeds + step)
        got = captured.update(batch)
        torch.manual_seed(seeds + step)
        want = eager.update(batch)
        assert set(got) == set(want)
        for key in want:
            torch.testing.assert_close(got[key], want[key], rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("policy", ["policy3_g", "policyd_g"])
def test_a_captured_update_equals_the_eager_one(policy):
    env, cfg, td = transitions(policy)
    learners = []
    for cudagraphs in (True, False):
        torch.manual_seed(0)
        learners.append(make_learner(env, cfg.algo, cfg.policy.critic_input, cudagraphs=cudagraphs))
    captured, eager = learners
    assert captured.cudagraphs and not eager.cudagraphs
    _equal_updates(captured, eager, [td[i * 26:(i + 1) * 26] for i in range(4)])
    for name, value in eager.actor.state_dict().items():
        torch.testing.assert_close(captured.actor.state_dict()[name], value, rtol=1e-6, atol=1e-7)
    for a, b in zip(captured.optimizer.state_dict()["state"].values(), eager.optimizer.state_dict()["state"].values()):
        torch.testing.assert_close(a["exp_avg_sq"], b["exp_avg_sq"], rtol=1e-6, atol=1e-9)


def test_a_captured_population_update_equals_the_eager_one():
    env, cfg, td = transitions()
    pops = []
    for cudagraphs in (True, False):
        torch.manual_seed(0)
        pops.append(PopulationLearner(env, cfg.algo, cfg.policy.critic_input, [0, 1], cudagraphs=cudagraphs))
    batches = [torch.stack([td[(2 * i + k) * 13:(2 * i + k + 1) * 13] for k in range(2)], 1) for i in range(3)]
    _equal_updates(*pops, batches)
    for k in range(2):
        for name, value in pops[1].actor_state(k).items():
            torch.testing.assert_close(pops[0].actor_state(k)[name], value, rtol=1e-6, atol=1e-7)


def test_a_captured_update_defers_the_finite_check_to_check():
    """Captured, a NaN loss does not stop the update (that would read the GPU every step);
    ``check()`` names it, and the uncaptured learner still refuses at once."""
    env, cfg, td = transitions()

    def poisoned():
        batch = td[:26].clone()
        batch.set(("next", "agents", "reward"), torch.full_like(batch["next", "agents", "reward"], float("nan")))
        return batch

    batch = poisoned()
    captured = make_learner(env, cfg.algo, cfg.policy.critic_input, cudagraphs=True)
    captured.update(td[26:52])
    captured.check()  # finite so far
    captured.update(batch)
    with pytest.raises(FloatingPointError, match="loss_qvalue was not finite"):
        captured.check()
    eager = make_learner(env, cfg.algo, cfg.policy.critic_input)
    with pytest.raises(FloatingPointError, match="loss"):
        eager.update(batch)
    pop = PopulationLearner(env, cfg.algo, cfg.policy.critic_input, [0, 1], cudagraphs=True)
    two = torch.stack([td[52:78].clone(), poisoned()], 1)  # member 1's column diverges
    pop.update(two)
    with pytest.raises(FloatingPointError, match="of member 1 was not finite"):
        pop.check()


def test_a_captured_run_equals_the_uncaptured_one_and_a_population_of_one(tmp_path):
    """The trainer with ``cudagraphs=true``: the solo run as the uncaptured one (up to float
    round-off; on a CPU the same arithmetic), and a captured population of one bitwise the
    captured solo run."""
    plain = Training(quick_config(1), tmp_path / "plain").run()
    captured_cfg = quick_config(1, "policy3_g", "cudagraphs=true")
    captured = Training(captured_cfg, tmp_path / "captured").run()
    one = PopulationTraining(captured_cfg, tmp_path / "one").run()
    assert plain.updates > 0 and (plain.frames, plain.updates) == (captured.frames, captured.updates)
    a = load_checkpoint(tmp_path / "plain" / "last.pt")
    b = load_checkpoint(tmp_path / "captured" / "last.pt")
    c = load_checkpoint(tmp_path / "one" / "last.pt")
    for name, value in a["actor"].items():
        torch.testing.assert_close(b["actor"][name], value, rtol=1e-5, atol=1e-6)
        assert torch.equal(c["members"][0]["actor"][name], b["actor"][name])
    assert (tmp_path / "captured" / "episodes.csv").read_text() == \
        (tmp_path / "one" / "seed0" / "episodes.csv").read_text()


def test_a_captured_run_resumes_bitwise(tmp_path):
    whole = train(quick_config(1, "policy3_g", "cudagraphs=true"), tmp_path / "whole")
    assert whole.updates > 0
    train(quick_config(1, "policy3_g", "cudagraphs=true", "experiment.max_frames=64"), tmp_path / "resumed")
    train(quick_config(1, "policy3_g", "cudagraphs=true", "resume=true"), tmp_path / "resumed")
    a = load_checkpoint(tmp_path / "whole" / "last.pt")
    b = load_checkpoint(tmp_path / "resumed" / "last.pt")
    assert all(torch.equal(v, b["actor"][k]) for k, v in a["actor"].items())


def test_cudagraphs_is_refused_for_ppo_in_one_line():
    with pytest.raises(ConfigError, match="cudagraphs") as info:
        TrainConfig.from_config(make_train_config("policyp_g", "tiny", ["cudagraphs=true"]))
    assert "\n" not in str(info.value)
