"""The GPU path end to end: env, training, evaluation on CUDA.

Each test runs on the GPU where there is one, and otherwise (in the full tier) on CUDA simulated on
the CPU (``tests/simulated_cuda.py``): every tensor where the device's are, as on a GPU, but no
CUDA graph, pinned memory or compilation; what only a GPU can show is asserted only there."""

import pytest
import torch

from flock_torchrl import FlockingEnv, evaluate, make_train_config, train
from flock_torchrl.policies.scripted import goal_seeking_policy

from simulated_cuda import simulated_cuda


@pytest.fixture(autouse=True, params=["gpu", pytest.param("simulated", marks=pytest.mark.slow)])
def real_cuda(request):
    """``True`` on a GPU; ``False`` on the simulated device (where there is no GPU)."""
    if request.param == "gpu":
        if not torch.cuda.is_available():
            pytest.skip("no CUDA device on this machine (the simulated one runs these tests)")
        yield True
    else:
        if torch.cuda.is_available():
            pytest.skip("a CUDA device is here: these tests run on it")
        with simulated_cuda():
            yield False


@pytest.mark.parametrize("scenario", ["train", "s4", "s5", "train3d"])
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


def test_a_captured_update_on_cuda_equals_the_uncaptured_one():
    from flock_torchrl.policies.learners import make_learner
    from flock_torchrl.run.batches import TRANSITION_KEYS, agentwise_done
    from flock_torchrl.config import TrainConfig

    cfg = TrainConfig.from_config(make_train_config("policy3_g", "tiny", ["device=cuda"]))
    env = FlockingEnv(cfg.train_scenario, num_envs=1, seed=3, device="cuda")
    td = agentwise_done(env.rollout(120, break_when_any_done=False), env.n_agents)
    td = td.select(*TRANSITION_KEYS, strict=False).reshape(-1)
    learners = []
    for cudagraphs in (True, False):
        torch.manual_seed(0)
        learners.append(make_learner(env, cfg.algo, cfg.policy.critic_input, cudagraphs=cudagraphs))
    for step in range(8):  # past the warm-up: the last calls replay the recorded graph
        batch = td[(step % 4) * 26:(step % 4 + 1) * 26]
        outs = []
        for learner in learners:  # the same draws on both sides (a replay reads the generator's seed)
            torch.manual_seed(100 + step)
            outs.append(learner.update(batch.clone()))
        got, want = outs
        for key in want:
            torch.testing.assert_close(got[key], want[key], rtol=1e-4, atol=1e-5)
    learners[0].check()


def test_a_captured_run_on_cuda_resumes(tmp_path):
    """A captured CUDA run resumes where it stopped (its replay rows back on the device, the CUDA
    generator restored) and ends at the uninterrupted run's counters. Unlike on the CPU it is not
    bitwise that run: on an H200 the resumed actor's weights differed (docs/decisions.md)."""
    base = ["device=cuda", "cudagraphs=true", "scenario.max_steps=40", "progress=false", "logger=none"]
    train(make_train_config("policy3_g", "tiny", base), tmp_path / "whole")
    train(make_train_config("policy3_g", "tiny", [*base, "experiment.max_frames=64"]), tmp_path / "resumed")
    train(make_train_config("policy3_g", "tiny", [*base, "resume=true"]), tmp_path / "resumed")
    from flock_torchrl.policies.checkpoint import load_checkpoint

    a, b = load_checkpoint(tmp_path / "whole" / "last.pt"), load_checkpoint(tmp_path / "resumed" / "last.pt")
    assert "cuda" in b["rng"]
    assert {k: b["counters"][k] for k in ("frames", "updates")} == {k: a["counters"][k] for k in ("frames", "updates")}
    assert all(torch.isfinite(v).all() for v in b["actor"].values())


def test_the_gpu_benchmark_rows_run():
    from benchmarks.gpu import update_lines

    lines = update_lines("cuda", members=(1, 2), calls=5)
    assert len(lines) == 2 and all("captured" in line for line in lines)


def test_a_captured_population_trains_on_cuda(tmp_path, real_cuda):
    """A population's captured update (vmapped over members, one CUDA graph) trains end to end."""
    base = ["device=cuda", "cudagraphs=true", "population=2", "scenario.max_steps=40", "progress=false",
            "logger=none", "compile=step"]
    result = train(make_train_config("policy3_g", "tiny", base), tmp_path / "population")
    assert result.updates > 0 and (result.split["compile"] > 0 or not real_cuda)  # simulated: eager


def test_host_reads_see_copies_between_the_cpu_and_cuda(real_cuda):
    from benchmarks.counting import HostReads

    if not real_cuda:
        pytest.skip("pinned memory is not simulated")
    x = torch.ones(4, device="cuda")
    pinned = torch.ones(4).pin_memory()
    with HostReads() as reads:
        x.cpu()
        torch.ones(4).to("cuda")
        x.copy_(torch.zeros(4))
        x.copy_(pinned, non_blocking=True)         # waits for nothing
        pinned.to("cuda", non_blocking=True)       # nor this
    assert reads.total == 3, reads.table()


def test_the_paper_loop_on_cuda_reads_nothing_per_iteration():
    from benchmarks.host_reads import count_reads

    reads, iterations = count_reads("paper", 1, iterations=30, overrides=("device=cuda", "reset_pool=256"))
    assert iterations == 30 and reads.total == 0, reads.table()


def test_a_captured_step_on_cuda_equals_the_uncaptured_one(real_cuda):
    """capture_step=True on CUDA: the step and the reserve's hand-out recorded as CUDA graphs and
    replayed, stepping as the uncaptured static-shape step (the same kernels)."""
    from functools import partial

    from flock_torchrl.capture import CUDAGRAPH_WARMUP
    from flock_torchrl.world.step import transition

    kwargs = dict(num_envs=8, seed=1, policy_id="policy3_g", max_steps=4, reset_pool=32, check_actions=False,
                  device="cuda")
    env = FlockingEnv("s4", capture_step=True, **kwargs)
    twin = FlockingEnv("s4", **kwargs)
    twin._transition = partial(transition, static_shapes=True, static=twin._static, cfg=twin.cfg)
    gen = torch.Generator(device="cuda").manual_seed(0)
    td, td_twin = env.reset(), twin.reset()
    for _ in range(16):
        action = torch.rand(8, 5, 2, generator=gen, device="cuda") * 2 - 1
        out, td = env.step_and_maybe_reset(td.set(("agents", "action"), action))
        want, td_twin = twin.step_and_maybe_reset(td_twin.set(("agents", "action"), action.clone()))
        for key in want.keys(True, True):
            torch.testing.assert_close(out[key], want[key], rtol=1e-5, atol=1e-5, equal_nan=True, msg=str(key))
    for module in (env._transition, env.reserve._take) if real_cuda else ():  # recorded at the last warm-up call
        assert module.counter == CUDAGRAPH_WARMUP and isinstance(module.graph, torch.cuda.CUDAGraph)
