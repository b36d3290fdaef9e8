"""The CUDA device simulated on the CPU (``tests/simulated_cuda.py``): it refuses what CUDA refuses,
it catches a tensor of the step left on the CPU, and the env's GPU path (captured step, reserve of
fresh worlds, every extra) runs on it as the CPU's, bitwise. ``tests/test_cuda.py`` runs its GPU
tests on it too where there is no GPU."""

from __future__ import annotations

import io

import pytest
import torch

from flock_torchrl import FlockingEnv
from flock_torchrl.world import geometry

from simulated_cuda import OnGpu, simulated_cuda

pytestmark = pytest.mark.skipif(torch.cuda.is_available(), reason="a real CUDA device is here: tests/test_cuda.py")

MIXED = "found at least two devices, cuda:0 and cpu"


def test_the_simulated_device_refuses_what_cuda_refuses_and_allows_what_it_allows():
    with simulated_cuda():
        assert torch.cuda.is_available()
        x = torch.zeros(3, device="cuda")
        assert isinstance(x, OnGpu) and x.device == torch.device("cuda", 0) and x.is_cuda
        assert (x + 1).device.type == "cuda" and x[0].device.type == "cuda"
        with pytest.raises(RuntimeError, match=MIXED):
            x + torch.ones(3)
        with pytest.raises(RuntimeError, match=MIXED):
            torch.where(x > 0, x, torch.ones(3))
        with pytest.raises(RuntimeError, match="Expected a 'cuda' device type for generator"):
            torch.rand(3, device="cuda", generator=torch.Generator().manual_seed(0))
        with pytest.raises(RuntimeError, match="Expected a 'cpu' device type for generator"):
            torch.rand(3, generator=torch.Generator(device="cuda"))
        with pytest.raises(RuntimeError, match="can't convert cuda:0 device type tensor to numpy"):
            x.numpy()
        # what CUDA allows: a CPU scalar, a CPU index, a copy across, a move
        assert (x + torch.tensor(2.0)).tolist() == [2.0, 2.0, 2.0]
        assert x[torch.tensor([0, 2])].device.type == "cuda"
        x.copy_(torch.arange(3.0))
        assert x.tolist() == [0.0, 1.0, 2.0] and x.sum().item() == 3.0
        back = x.cpu()
        assert type(back) is torch.Tensor and back.device.type == "cpu"
        assert torch.ones(2).to("cuda").device.type == "cuda" and torch.ones(2).cuda().device.type == "cuda"
        assert type(torch.ones(2).to("cuda").to("cpu")) is torch.Tensor


def test_a_graph_of_the_simulated_device_is_given_only_its_tensors():
    """A CUDA graph replays on its own copies of its inputs: a CPU tensor given to one would be read
    at the capture only, so the simulation refuses it."""
    from flock_torchrl.capture import captured

    with simulated_cuda():
        double = captured(lambda x: x * 2, torch.device("cuda"))
        assert double(torch.ones(2, device="cuda")).device.type == "cuda"
        with pytest.raises(RuntimeError, match="a CUDA graph is given a CPU tensor"):
            double(torch.ones(2))


def test_a_module_and_its_optimiser_live_on_the_simulated_device_and_save_as_the_cpu_reads_them():
    with simulated_cuda():
        layer = torch.nn.Linear(3, 2).to("cuda")
        assert isinstance(layer.weight, torch.nn.Parameter) and layer.weight.device.type == "cuda"
        with pytest.raises(RuntimeError, match=MIXED):
            layer(torch.ones(4, 3))
        layer(torch.ones(4, 3, device="cuda")).sum().backward()
        assert layer.weight.grad.device.type == "cuda"
        optimiser = torch.optim.Adam(layer.parameters(), fused=True)
        optimiser.step()
        assert optimiser.state[layer.weight]["exp_avg"].device.type == "cuda"
        buffer = io.BytesIO()
        torch.save(layer.state_dict(), buffer)
    saved = torch.load(io.BytesIO(buffer.getvalue()), map_location="cpu", weights_only=True)
    assert type(saved["weight"]) is torch.Tensor and saved["weight"].shape == (2, 3)


def _steps(env: FlockingEnv, actions: torch.Tensor, device: str):
    td, outs = env.reset(), []
    for action in actions:
        out, td = env.step_and_maybe_reset(td.set(("agents", "action"), action.to(device)))
        outs.append(out)
    return torch.stack(outs)


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["s4", "train3d"])
def test_the_env_steps_on_the_simulated_device_as_on_the_cpu_bitwise(scenario):
    """The GPU path of the env (the captured static-shape step, the reserve's hand-out, every extra
    key) keeps every tensor on the device, and gives the CPU's transitions."""
    kw = dict(num_envs=8, seed=1, policy_id="policy3_g", max_steps=12, reset_pool=32, check_actions=False,
              extras="all", capture_step=True)
    env = FlockingEnv(scenario, **kw)
    actions = torch.rand(30, 8, env.n_agents, env.cfg.dims,
                         generator=torch.Generator().manual_seed(0)) * 2 - 1
    want = _steps(env, actions, "cpu")
    with simulated_cuda():
        got = _steps(FlockingEnv(scenario, device="cuda", **kw), actions, "cuda")
        assert {t.device.type for t in got.values(True, True)} == {"cuda"}
        got = got.cpu()
    assert want["next", "done"].any()  # the reserve handed out fresh worlds
    for key in want.keys(True, True):
        torch.testing.assert_close(got[key], want[key], rtol=0, atol=0, equal_nan=True, msg=str(key))


def test_a_tensor_of_the_step_left_on_the_cpu_is_caught(monkeypatch):
    """The bug the simulation is for: a table of the step made on the CPU whatever the device (as
    ``geometry.constant`` would without its ``device``) stops the first step, naming the mix."""
    monkeypatch.setattr(geometry, "_constant", lambda values, dtype, device: torch.tensor(values, dtype=dtype))
    with simulated_cuda():
        env = FlockingEnv("s4", num_envs=2, seed=0, policy_id="policy3_g", device="cuda", check_actions=False)
        with pytest.raises(RuntimeError, match=MIXED):
            env.rollout(2)


@pytest.mark.slow  # two tiny trainings
def test_a_captured_run_on_the_simulated_device_trains_the_cpu_runs_weights(tmp_path):
    """``device=cuda cudagraphs=true reset_pool=...`` changes where the tensors are, not what they
    hold: the simulated run's actor is the CPU run's, bit for bit (on a GPU the kernels round
    differently, and the CUDA generator draws other numbers)."""
    from flock_torchrl import make_train_config, train
    from flock_torchrl.policies.checkpoint import load_checkpoint

    base = ["scenario.max_steps=40", "progress=false", "logger=none", "cudagraphs=true", "reset_pool=8"]
    cpu = train(make_train_config("policy3_g", "tiny", ["device=cpu", *base]), tmp_path / "cpu")
    with simulated_cuda():
        cuda = train(make_train_config("policy3_g", "tiny", ["device=cuda", *base]), tmp_path / "cuda")
    want, got = load_checkpoint(cpu.checkpoint), load_checkpoint(cuda.checkpoint)
    assert (got["config"]["device"], want["config"]["device"]) == ("cuda", "cpu")
    assert cuda.updates == cpu.updates > 0
    for name, value in want["actor"].items():
        assert torch.equal(got["actor"][name], value), name
