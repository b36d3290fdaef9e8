"""The captured update and env step (``cudagraphs=true``): one function per gradient step, and the
env's step and reserve hand-out, that never read a tensor on the host, wrapped in tensordict's
``CudaGraphModule``. Without CUDA the module calls them as they are, so these tests run the
captured code path here against the uncaptured learner and step."""

from __future__ import annotations

import pytest
import torch

from flock_torchrl.config import ConfigError, TrainConfig
from flock_torchrl.policies.checkpoint import load_checkpoint
from flock_torchrl.policies.learners import make_learner
from flock_torchrl.policies.learners import OffPolicyLearner
from flock_torchrl.run.launch import train
from flock_torchrl.run.trainer import Training
from flock_torchrl.run.setup import make_train_config

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
    for name, value in eager.actor_state(0).items():
        torch.testing.assert_close(captured.actor_state(0)[name], value, rtol=1e-6, atol=1e-7)
    for a, b in zip(captured.optimizer.state_dict()["state"].values(), eager.optimizer.state_dict()["state"].values()):
        torch.testing.assert_close(a["exp_avg_sq"], b["exp_avg_sq"], rtol=1e-6, atol=1e-9)


def test_a_captured_population_update_equals_the_eager_one():
    env, cfg, td = transitions()
    pops = []
    for cudagraphs in (True, False):
        torch.manual_seed(0)
        pops.append(OffPolicyLearner(env, cfg.algo, cfg.policy.critic_input, [0, 1], cudagraphs=cudagraphs))
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
    pop = OffPolicyLearner(env, cfg.algo, cfg.policy.critic_input, [0, 1], cudagraphs=True)
    two = torch.stack([td[52:78].clone(), poisoned()], 1)  # member 1's column diverges
    pop.update(two)
    with pytest.raises(FloatingPointError, match="of member 1 was not finite"):
        pop.check()


@pytest.mark.slow   # the fast tier: the captured update against the eager one, and tests/test_solo_reference.py
def test_a_captured_run_equals_the_uncaptured_one(tmp_path):
    """The trainer with ``cudagraphs=true``: the solo run as the uncaptured one (up to float
    round-off; on a CPU the same arithmetic)."""
    plain = Training(quick_config(1), tmp_path / "plain").run()
    captured = Training(quick_config(1, "policy3_g", "cudagraphs=true"), tmp_path / "captured").run()
    assert plain.updates > 0 and (plain.frames, plain.updates) == (captured.frames, captured.updates)
    a = load_checkpoint(tmp_path / "plain" / "last.pt")
    b = load_checkpoint(tmp_path / "captured" / "last.pt")
    for name, value in a["actor"].items():
        torch.testing.assert_close(b["actor"][name], value, rtol=1e-5, atol=1e-6)


# with a reserve: the hand-out captured too
@pytest.mark.slow   # as tests/test_solo_reference.py's captured run, whole and resumed (also the full tier)
@pytest.mark.parametrize("extra", [[], ["reset_pool=8"]])
def test_a_captured_run_resumes_bitwise(tmp_path, extra):
    whole = train(quick_config(1, "policy3_g", "cudagraphs=true", *extra), tmp_path / "whole")
    assert whole.updates > 0
    train(quick_config(1, "policy3_g", "cudagraphs=true", "experiment.max_frames=64", *extra), tmp_path / "resumed")
    train(quick_config(1, "policy3_g", "cudagraphs=true", "resume=true", *extra), tmp_path / "resumed")
    a = load_checkpoint(tmp_path / "whole" / "last.pt")
    b = load_checkpoint(tmp_path / "resumed" / "last.pt")
    assert all(torch.equal(v, b["actor"][k]) for k, v in a["actor"].items())


def test_cudagraphs_is_refused_for_ppo_in_one_line():
    with pytest.raises(ConfigError, match="cudagraphs") as info:
        TrainConfig.from_config(make_train_config("policyp_g", "tiny", ["cudagraphs=true"]))
    assert "\n" not in str(info.value)


# s4: sensor noise, drawn before the step and passed in; train3d: the 3-D world's constants
@pytest.mark.parametrize("scenario", ["train", pytest.param("s4", marks=pytest.mark.slow), "train3d"])
def test_the_captured_step_and_hand_out_are_given_only_tensors_and_read_nothing(scenario):
    """``capture_step=True`` (what ``cudagraphs=true`` gives the training env): the step and the
    reserve's hand-out wrapped in ``CudaGraphModule`` (a pass-through here). What a graph's
    replay needs holds on a CPU: every call gives them tensors only (copied into the graph's
    inputs on a GPU), a step between refills reads nothing on the host, and the env steps as the
    uncaptured static-shape step, bit for bit."""
    from functools import partial

    from tensordict.nn import CudaGraphModule
    from torch.utils._pytree import tree_leaves

    from flock_torchrl import FlockingEnv
    from benchmarks.counting import HostReads
    from flock_torchrl.world.step import transition

    kwargs = dict(num_envs=4, seed=1, policy_id="policy3_g", max_steps=3, reset_pool=12, check_actions=False)
    env = FlockingEnv(scenario, capture_step=True, **kwargs)
    twin = FlockingEnv(scenario, **kwargs)
    twin._transition = partial(transition, static_shapes=True, static=twin._static, cfg=twin.cfg)
    assert isinstance(env._transition, CudaGraphModule) and isinstance(env.reserve._take, CudaGraphModule)
    given = set()
    for module in (env._transition, env.reserve._take):
        def spy(*args, _inner=module.module, **kw):
            given.update(type(leaf).__name__ for leaf in tree_leaves((args, kw)))
            return _inner(*args, **kw)
        module.module = spy
    refills = []
    refill = env.reserve.refill
    env.reserve.refill = lambda draw: (refills.append(True), refill(draw))
    gen = torch.Generator().manual_seed(0)
    td, td_twin = env.reset(), twin.reset()
    quiet = 0
    for _ in range(12):
        action = torch.rand(4, 5, env.cfg.dims, generator=gen) * 2 - 1
        refills.clear()
        with HostReads(launches=scenario != "train3d") as reads:  # kernels: 2-D only (a stack per operator)
            out, td = env.step_and_maybe_reset(td.set(("agents", "action"), action))
        want, td_twin = twin.step_and_maybe_reset(td_twin.set(("agents", "action"), action.clone()))
        if not refills:
            assert reads.total == 0, reads.table()
            assert not reads.made, reads.made  # no copy from the host either (its constants are made once)
            # The step's kernels run inside its graph: none of its modules launches one outside but
            # the sensor noise's draw, made before the step from the env's generator (and a refill, on
            # the host, draws its worlds with them).
            step_modules = tuple(f"flock_torchrl/world/{m}.py" for m in ("step", "sensors", "geometry", "instinct",
                                                                          "dynamics", "reward"))
            outside = [p for p in reads.launched if p.startswith(step_modules) and not p.endswith(":draw")]
            assert (reads.launched_in_graphs > 100 or scenario == "train3d") and not outside, reads.launched
            quiet += 1
        for key in want.keys(True, True):
            torch.testing.assert_close(out[key], want[key], rtol=0, atol=0, equal_nan=True, msg=key)
    assert quiet == 8 and out["next", "done"].any()  # refills every 12 // 4 = 3 calls; worlds ended
    assert given == ({"Tensor"} if scenario == "s4" else {"Tensor", "NoneType"})  # no noise: normals=None
