"""Throughput, each figure a ratio against a baseline run in the same process.

* **env**: env-steps/s of one batched ``FlockingEnv`` (eager, and with ``compile_step``)
  against TorchRL's ``VmasEnv("flocking", n_agents=5)`` (the ``bench`` extra), both under the
  same loop (random actions, ``env.step``), at B = 64, 1024, 4096;
* **swarm scale**: UAV-steps/s at N = 20, 50, 100 with the same number of UAVs (B x N = 5120)
  against N = 5, with the world state's bytes per UAV;
* **learner**: SAC gradient steps/s at the fast recipe's minibatch (1280 UAV transitions)
  and the paper's (128), ours (eager, and with the compiled loss) against the learner as it
  was before the speed work (``MultiAgentMLP`` networks, three Adam optimisers), same batches;
* **paper loop**: the paper recipe's whole training loop (one env, one update per step),
  compiled against eager, in updates/s, with each run's time split;
* **host reads**: reads of tensor values on the host per iteration of the paper recipe's loop,
  solo without and with a reserve of fresh worlds (``reset_pool``) and as a population of 10
  with one (:mod:`benchmarks.host_reads`): on a GPU each one waits;
* **GPU** (when CUDA is present; :mod:`benchmarks.gpu`): the env at B = 65,536, the captured
  update, the loops solo and as populations of 10 and 80, and the projection of the paper's study.

Timings alternate the candidates and keep each one's best of several repetitions, so load
from other processes hits both sides alike; the ratios are what to read.

``make benchmark`` runs :mod:`benchmarks.run`, a Hydra app on ``benchmarks/conf/benchmark.yaml``
whose config is :class:`BenchmarkConfig` (a tool of the repository: see :mod:`benchmarks`).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import torch
from hydra.experimental.callback import Callback
from omegaconf import MISSING
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer

from flock_torchrl.cli import fail
from flock_torchrl.config import ConfigError, Schema, algo_config, check_device, check_threads, compose
from flock_torchrl.io import write_text
from flock_torchrl.policies.learners import OffPolicyLearner, compiled
from flock_torchrl.policies.models import ACTION, LOG_PROB
from flock_torchrl.run.batches import TRANSITION_KEYS, agentwise_done
from flock_torchrl.world.env import FlockingEnv
from benchmarks.gpu import gpu_lines, projection_line, synchronize
from benchmarks.host_reads import host_read_lines, launch_lines
from benchmarks.population import SHORT_RUN, population_lines
from benchmarks.reset import reset_lines
from benchmarks.rows import Row, env_rows, format_rows, random_stepper
from benchmarks.threed import threed_lines
from benchmarks.timing import paired


@dataclass
class BenchmarkConfig(Schema):
    """``benchmarks/conf/benchmark.yaml``: throughput, each figure against a baseline in the same process."""

    quick: bool = MISSING
    device: str = MISSING
    threads: int = MISSING

    def checked_fields(self, prefix: str) -> dict[str, Any]:
        check_device("device", self.device)
        check_threads("threads", self.threads)
        return {}


def checked(cfg: Any) -> BenchmarkConfig:
    """``cfg`` (the composed Hydra config) as a checked :class:`BenchmarkConfig`; a bad value
    prints one line naming its key and exits with status 2."""
    try:
        return BenchmarkConfig.from_config(cfg)
    except ConfigError as exc:
        fail(exc)
        raise  # unreachable: fail exits


class CheckFirst(Callback):
    """The config is checked before Hydra creates the output folder (``hydra.callbacks``)."""

    def on_run_start(self, config: Any, **kwargs: Any) -> None:
        checked(config)


def scale_rows(total: int = 5120, sizes=(5, 20, 50, 100), steps: int = 4, repeat: int = 3,
               reading: str = "paper_fit", device: str = "cpu") -> list[Row]:
    """UAV-steps/s at each swarm size with B x N = ``total``, against N = 5."""
    envs = {n: FlockingEnv("train", max(1, total // n), device, 0, reading=reading, policy_id="policy3_g", n_uavs=n)
            for n in sizes}
    best = paired({n: random_stepper(env, steps) for n, env in envs.items()}, repeat)
    uavs = {n: env.num_envs * n for n, env in envs.items()}
    rate = {n: uavs[n] * steps / best[n] for n in sizes}
    return [Row(f"swarm N={n}, B={envs[n].num_envs} ({reading}; vs N={sizes[0]})", rate[n], rate[sizes[0]],
                "UAV-steps/s", f"world state {envs[n].world.bytes() / uavs[n]:.0f} B/UAV") for n in sizes]


# ---------------------------------------------------------------------------- learner
def replay_batches(batch_uav: int, count: int, device: str = "cpu") -> tuple[FlockingEnv, list]:
    """``count`` minibatches of ``batch_uav`` UAV transitions from random-action rollouts."""
    env = FlockingEnv("train", 64, device, 0, policy_id="policy3_g")
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(4096, device=device),
                                    batch_size=max(1, math.ceil(batch_uav / env.n_agents)))
    td = env.reset()
    for _ in range(8):
        step, td = env.step_and_maybe_reset(env.rand_action(td))
        buffer.extend(agentwise_done(step.unsqueeze(-1), env.n_agents).select(*TRANSITION_KEYS, strict=False)
                      .reshape(-1))
    return env, [buffer.sample() for _ in range(count)]


class PreviousSACUpdate:
    """The SAC update as it was before the speed work, kept as this benchmark's baseline:
    ``MultiAgentMLP(share_params=True)`` networks and one Adam per network, same loss."""

    def __init__(self, env: FlockingEnv, cfg) -> None:
        from tensordict.nn import NormalParamExtractor, TensorDictModule
        from torch import nn
        from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal, ValueOperator
        from torchrl.objectives import SACLoss, SoftUpdate, ValueEstimators

        n, dev = env.n_agents, env.device
        n_obs = env.full_observation_spec_unbatched[("agents", "observation")].shape[-1]
        n_state = env.full_observation_spec_unbatched[("agents", "state")].shape[-1]

        def mlp(n_in: int, n_out: int) -> MultiAgentMLP:
            return MultiAgentMLP(n_agent_inputs=n_in, n_agent_outputs=n_out, n_agents=n, centralized=False,
                                 share_params=True, device=dev, depth=cfg.depth, num_cells=cfg.hidden,
                                 activation_class=nn.ReLU)

        spec = env.full_action_spec_unbatched[ACTION]
        actor = ProbabilisticActor(
            TensorDictModule(nn.Sequential(mlp(n_obs, 4), NormalParamExtractor(scale_mapping="biased_softplus_1.0",
                                                                            scale_lb=1e-4)),
                             in_keys=[("agents", "observation")], out_keys=[("agents", "loc"), ("agents", "scale")]),
            in_keys=[("agents", "loc"), ("agents", "scale")], out_keys=[ACTION], distribution_class=TanhNormal,
            distribution_kwargs={"low": spec.space.low, "high": spec.space.high}, log_prob_key=LOG_PROB)
        qvalue = ValueOperator(mlp(n_state + 2, 1), in_keys=[("agents", "state"), ACTION],
                               out_keys=[("agents", "state_action_value")])
        self.loss = SACLoss(actor_network=actor, qvalue_network=qvalue, num_qvalue_nets=2, loss_function="l2",
                            alpha_init=cfg.alpha_init, target_entropy=cfg.target_entropy, action_spec=spec,
                            delay_qvalue=True)
        self.loss.set_keys(action=ACTION, state_action_value=("agents", "state_action_value"), log_prob=LOG_PROB,
                           reward=("agents", "reward"), done=("agents", "done"), terminated=("agents", "terminated"))
        self.loss.make_value_estimator(ValueEstimators.TD0, gamma=cfg.gamma)
        self.updater = SoftUpdate(self.loss, tau=cfg.tau)
        self.optimisers = [
            torch.optim.Adam(list(self.loss.actor_network_params.values(True, True)), lr=cfg.lr_actor),
            torch.optim.Adam(list(self.loss.qvalue_network_params.values(True, True)), lr=cfg.lr_critic),
            torch.optim.Adam([self.loss.log_alpha], lr=cfg.lr_alpha)]

    def update(self, batch) -> dict[str, float]:
        losses = self.loss(batch)
        for opt in self.optimisers:
            opt.zero_grad(set_to_none=True)
        (losses["loss_actor"] + losses["loss_qvalue"] + losses["loss_alpha"]).backward()
        for opt in self.optimisers:
            opt.step()
        self.updater.step()
        return {k: losses[k].item() for k in ("loss_actor", "loss_qvalue", "loss_alpha", "alpha", "entropy")}


def learner_rows(batches=((1280, "fast"), (128, "paper")), updates: int = 12, repeat: int = 3,
                 device: str = "cpu") -> list[Row]:
    """SAC updates/s, ours eager and with the compiled loss, against :class:`PreviousSACUpdate`;
    on a CPU also the compiled loss's scalar kernels against inductor's default (vectorised) ones."""
    rows = []
    for batch_uav, recipe in batches:
        cfg = algo_config(compose("train", [f"experiment={recipe}"]).algo)
        env, samples = replay_batches(batch_uav, updates, device)
        torch.manual_seed(0)
        candidates = {"previous": PreviousSACUpdate(env, cfg), "eager": OffPolicyLearner(env, cfg, "state"),
                      "compiled": OffPolicyLearner(env, cfg, "state", compile=True)}
        if device == "cpu":
            vectorised = candidates["compiled, vectorised kernels"] = OffPolicyLearner(env, cfg, "state")
            vectorised.loss_fn = compiled(vectorised.loss, True, options={})

        def run(learner) -> Callable[[], None]:
            def go() -> None:
                for batch in samples:
                    learner.update(batch)
                synchronize(device)
            return go

        for learner in candidates.values():  # compile (and warm up) outside the timed rounds
            for batch in samples[:3]:
                learner.update(batch)
        best = paired({name: run(learner) for name, learner in candidates.items()}, repeat)
        rate = {name: updates / seconds for name, seconds in best.items()}
        rows += [Row(f"SAC updates, batch {batch_uav} UAV transitions ({recipe}; {name} vs previous)", rate[name],
                     rate["previous"], "updates/s") for name in ("eager", "compiled")]
        if device == "cpu":  # why the losses compile to scalar CPU kernels (learners.py)
            rows.append(Row(f"SAC updates, batch {batch_uav} ({recipe}; scalar vs vectorised compiled kernels)",
                            rate["compiled"], rate["compiled, vectorised kernels"], "updates/s"))
    return rows


# The paper recipe's whole loop as it was measured before the speed work: Policy3-G's seed-0
# run of experiment=paper averaged 74 updates/s over its 3.1 hours (README, Throughput). Not a
# same-process baseline, so it is a note beside the eager loop, never a ratio.
PAPER_LOOP_BEFORE = 74.0
PAPER_LOOP_GOAL = 230.0


def loop_rows(frames: int = 3000, device: str = "cpu") -> tuple[list[Row], list[str]]:
    """The paper recipe's whole training loop (one env, one update per step) for ``frames``
    frames, compiled (loss and step) against eager, run one after the other in this process,
    each after a short warm-up run (the env step compiles there; each run's loss is a new module
    and compiles in its first update, which the run books as "compile" and this row leaves out);
    updates/s over the loop (env, collection, buffer, sampling, update, logging), and each run's
    time split."""
    import tempfile

    from flock_torchrl.run.launch import train
    from flock_torchrl.run.setup import make_train_config

    rates, splits = {}, []
    for name, compile in (("eager", False), ("compiled", True)):
        def run(n: int):
            cfg = make_train_config("policy3_g", "paper", [f"experiment.max_frames={n}", *SHORT_RUN,
                                                           f"compile={str(compile).lower()}", f"device={device}"])
            with tempfile.TemporaryDirectory() as tmp:
                return train(cfg, tmp)

        run(64)  # warm-up: the env step compiles here; the timed run books its loss's compilation apart
        result = run(frames)
        loop = sum(v for k, v in result.split.items() if k not in ("compile", "evaluation", "checkpoints"))
        rates[name] = result.updates / loop
        splits.append(f"paper loop ({name}, {frames} frames): {result.split_line()}")
    rows = [Row(f"paper recipe loop, {frames} frames (compiled vs eager)", rates["compiled"], rates["eager"],
                "updates/s", f"before the speed work: {PAPER_LOOP_BEFORE:.0f}/s over a whole run; "
                             f"goal {PAPER_LOOP_GOAL:.0f}/s")]
    return rows, splits


def run_all(quick: bool = False, device: str = "cpu", notes: list[str] | None = None) -> list[Row]:
    """Every row; the paper loop's time splits are appended to ``notes``."""
    repeat = 2 if quick else 3
    rows = env_rows(steps=10 if quick else 20, repeat=repeat, device=device)
    rows += scale_rows(repeat=repeat, device=device)
    rows += learner_rows(updates=6 if quick else 30, repeat=2 if quick else 5, device=device)
    loop, splits = loop_rows(frames=600 if quick else 3000, device=device)
    if notes is not None:
        notes += splits
    return rows + loop


def benchmark_app(cfg: BenchmarkConfig, out_dir: Path) -> None:
    """Every row (``cfg``: a checked :class:`BenchmarkConfig`), printed and written to
    ``out_dir/benchmark.md``."""
    if cfg.threads:
        torch.set_num_threads(int(cfg.threads))
    load = os.getloadavg()[0]
    quick = bool(cfg.quick)
    notes: list[str] = []
    lines = [format_rows(run_all(quick=quick, device=str(cfg.device), notes=notes)), *notes]
    # Populations against solo runs, the whole training loop (benchmarks/population.py).
    rates: dict = {}
    lines += population_lines(frames=400 if quick else 3000, print_each=False, rates=rates)
    members = max(k for _, k, _ in rates)
    lines.append(projection_line("CPU, 1 thread" if cfg.threads == 1 else "CPU", rates["paper", members, "false"],
                                 rates["fast", members, "false"], members))
    # The GPU's rows and projection, where CUDA exists (benchmarks/gpu.py).
    if torch.cuda.is_available():
        lines += gpu_lines(frames=400 if quick else 3000)
    else:
        lines.append("GPU rows: no CUDA device here (benchmarks/gpu.py runs them where torch.cuda.is_available())")
    # Host reads per iteration of the loop, what makes a GPU wait (benchmarks/host_reads.py).
    for members, pool in ((1, 0), (1, 256), (10, 256)):
        lines += host_read_lines("paper", members, iterations=50 if quick else 200, overrides=(f"reset_pool={pool}",))
    # The kernels launched one by one per iteration, uncaptured against captured (a GPU's launch cost).
    lines += launch_lines("paper", iterations=50 if quick else 200)
    # Partial resets against a step, and worlds ending often against rarely (benchmarks/reset.py).
    lines += reset_lines(batch=256 if quick else 1024, print_each=False)
    # The 3-D step against the 2-D one, per UAV-step (benchmarks/threed.py).
    lines += threed_lines(batch=64 if quick else 1024, rounds=1 if quick else 3, compiled=not quick, print_each=False)
    text = "\n".join(lines)
    print(text, flush=True)
    write_text(out_dir / "benchmark.md", benchmark_page(text, quick, int(cfg.threads or 0), load))


def benchmark_page(text: str, quick: bool, threads: int, load: float) -> str:
    """``benchmark.md``: a title, what ran where (the command, the machine's fingerprint and its
    load when the run started), then the rows as printed."""
    from flock_torchrl.report.splice import machine

    command = "make benchmark" + (" ARGS=quick=true" if quick else "")
    return (f"# Throughput, {command}\n\n`{command}` on {machine(threads or torch.get_num_threads())}; the machine's "
            f"load average was {load:.1f} when it started (a loaded machine's absolute rates are lower; the ratios "
            f"compare candidates measured in the same process).\n\n```\n{text}\n```\n")


__all__ = ["BenchmarkConfig", "CheckFirst", "PreviousSACUpdate", "benchmark_app", "benchmark_page", "checked",
           "learner_rows", "loop_rows", "replay_batches", "run_all", "scale_rows"]
