"""Where things run: policies follow their env or module, training envs and time splits do not
wait on a GPU, and checkpoints keep the CUDA generator (the CUDA runs themselves: test_cuda.py)."""

from pathlib import Path
from types import SimpleNamespace

import torch

from flock_torchrl import FlockingEnv, load_policy, make_train_config
from flock_torchrl.config import TrainConfig
from flock_torchrl.policies import registry
from flock_torchrl.run import rollout
from flock_torchrl.run.parts import make_env, restore_rng, rng_state
from flock_torchrl.run.timing import TimeSplit

SHIPPED = Path(__file__).resolve().parent.parent / "checkpoints" / "paper_fit" / "policy3_g" / "seed0.pt"


def test_make_policy_defaults_to_the_envs_device(monkeypatch):
    asked = []
    monkeypatch.setattr(registry, "resolve", lambda policy, reading, device: asked.append(device) or [])
    env = SimpleNamespace(device=torch.device("meta"), cfg=SimpleNamespace(reading="paper_fit"))  # an env's surface
    try:
        registry.make_policy(str(SHIPPED), env)
    except ValueError:  # the stub resolves to nothing; what matters is where it was asked to load
        pass
    assert asked == ["meta"]


def test_evaluate_defaults_to_the_modules_device(monkeypatch):
    asked = []

    def fake(handle, scenario, reading, n_episodes, seed, device, overrides):
        asked.append(str(device))
        raise StopIteration

    monkeypatch.setattr(rollout, "evaluate_handle", fake)
    module = load_policy(SHIPPED)
    for expected in ("cpu", "meta"):
        module.follow(expected)
        try:
            rollout.evaluate(module, "train", n_episodes=1)
        except StopIteration:
            pass
        assert asked[-1] == expected


def test_a_loaded_policy_follows_its_observations_device():
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    policy = load_policy(SHIPPED)
    env = FlockingEnv("train", 2, seed=0, reading=policy.flock_meta["reading"],
                      policy_id=policy.flock_meta["policy_id"])
    td = env.reset()
    moved = load_policy(SHIPPED).follow("meta")  # as if moved to an accelerator: weights and action box
    assert {p.device.type for p in moved.parameters()} == {"meta"}
    assert {v.device.type for v in moved.actor.module[-1].distribution_kwargs.values()} == {"meta"}
    calls = []
    follow = policy.follow
    policy.follow = lambda device: calls.append(str(device)) or follow(device)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        before = policy(td.clone())["agents", "action"]
        assert calls == []  # already where the observations are
        policy._device = torch.device("meta")  # as if it had been elsewhere: CPU observations bring it back
        after = policy(td.clone())["agents", "action"]
    assert calls == ["cpu"] and {p.device.type for p in policy.parameters()} == {"cpu"}
    assert torch.equal(before, after)  # the weights moved with it


def test_training_envs_skip_the_synchronising_action_checks():
    cfg = TrainConfig.from_config(make_train_config("policy3_g", "tiny"))
    env = make_env(cfg, 2, torch.device("cpu"), 0, parent=0)
    assert env.check_actions is False


def test_time_split_synchronises_at_its_boundaries_only_when_profiling_on_cuda(monkeypatch):
    """On CUDA the split records events and waits only when settled (tests/test_host_reads.py counts
    the waits on the simulated device); with ``profile`` it synchronises at each block's edges."""
    calls = []
    monkeypatch.setattr(torch.cuda, "synchronize", lambda device=None: calls.append(str(device)))
    cpu = TimeSplit()
    with cpu.timer("update"):
        pass
    assert calls == []
    gpu = TimeSplit(device="cuda:0", profile=True)
    with gpu.timer("update"):
        assert calls == ["cuda:0"]  # the work before the block is booked to its own part
    assert calls == ["cuda:0", "cuda:0"] and gpu["update"] >= 0.0


def test_rng_state_holds_the_cuda_generator_only_for_a_cuda_run(monkeypatch):
    state = rng_state(torch.device("cpu"))
    assert set(state) == {"torch"}
    fake = torch.tensor([7], dtype=torch.uint8)
    monkeypatch.setattr(torch.cuda, "get_rng_state", lambda device=None: fake)
    restored = []
    monkeypatch.setattr(torch.cuda, "set_rng_state", lambda value, device=None: restored.append((value, str(device))))
    state = rng_state(torch.device("cuda:0"))
    assert set(state) == {"torch", "cuda"} and state["cuda"] is fake
    restore_rng(state, torch.device("cuda:0"))
    assert restored == [(fake, "cuda:0")]
    restore_rng({"torch": state["torch"]}, torch.device("cuda:0"))  # a CPU run's checkpoint resumed on a GPU
    assert len(restored) == 1
