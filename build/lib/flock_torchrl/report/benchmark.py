"""Throughput benchmarks, each against a baseline run in the same process.

* env: frames/s of one batched ``FlockingEnv(num_envs=B)`` against TorchRL's ``SerialEnv``
  of B single-env copies (the usual way to batch a non-vectorised env);
* collection: frames/s of a TorchRL ``Collector`` running the shared SAC actor on each;
* updates: SAC gradient steps/s of our learner against a plain TorchRL SAC update (one
  optimiser over ``SACLoss``'s summed losses), same networks, same batch.

Run ``python scripts/benchmark.py``; numbers depend on the machine and on its load, the
ratios much less.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import SerialEnv
from torchrl.objectives import SACLoss, SoftUpdate, ValueEstimators

from ..config import check_algo, compose
from ..io import write_text
from ..policies.learners import SACLearner
from ..policies.models import ACTION, make_actor, make_qvalue
from ..run.trainer import TRANSITION_KEYS, _agentwise_done
from ..world.env import FlockingEnv


@dataclass
class Row:
    what: str
    ours: float
    baseline: float
    unit: str

    @property
    def ratio(self) -> float:
        return self.ours / self.baseline if self.baseline else float("nan")


def _rate(fn, count: int, repeat: int) -> float:
    """Best of ``repeat`` timed calls (after a warm-up): the least disturbed by other load."""
    fn()
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return count / best


def _paired(ours, base, count: int, repeat: int) -> tuple[float, float]:
    """Alternate the two so that background load hits both alike."""
    ours(), base()
    best_o = best_b = float("inf")
    for _ in range(repeat):
        for fn, which in ((ours, "o"), (base, "b")):
            start = time.perf_counter()
            fn()
            took = time.perf_counter() - start
            if which == "o":
                best_o = min(best_o, took)
            else:
                best_b = min(best_b, took)
    return count / best_o, count / best_b


def env_throughput(num_envs: int, steps: int = 20) -> Row:
    batched = FlockingEnv("train", num_envs=num_envs, seed=0, policy_id="policy3_g")
    serial = SerialEnv(num_envs, lambda: FlockingEnv("train", num_envs=1, seed=0, policy_id="policy3_g"))

    def run(env):
        td = env.reset()

        def go():
            nonlocal td
            for _ in range(steps):
                td = env.rand_action(td)
                td = env.step_and_maybe_reset(td)[1]
        return go

    ours = _rate(run(batched), num_envs * steps, 3)
    base = _rate(run(serial), num_envs * steps, 3)
    serial.close()
    return Row(f"env steps, {num_envs} envs (batched vs SerialEnv)", ours, base, "frames/s")


def collection_throughput(num_envs: int, frames_per_batch: int, batches: int = 4) -> Row:
    def collect(make_env) -> float:
        env = make_env()
        actor = make_actor(FlockingEnv("train", num_envs=1, policy_id="policy3_g"))
        collector = Collector(env, actor, frames_per_batch=frames_per_batch, total_frames=-1, track_traj_ids=False,
                              auto_register_policy_transforms=False)
        it = iter(collector)
        next(it)
        start = time.perf_counter()
        frames = sum(next(it).numel() for _ in range(batches))
        rate = frames / (time.perf_counter() - start)
        collector.shutdown()
        return rate

    ours = collect(lambda: FlockingEnv("train", num_envs=num_envs, seed=0, policy_id="policy3_g"))
    base = collect(lambda: SerialEnv(num_envs, lambda: FlockingEnv("train", num_envs=1, seed=0, policy_id="policy3_g")))
    return Row(f"Collector + SAC actor, {num_envs} envs (batched vs SerialEnv)", ours, base, "frames/s")


def _replay_batch(batch_swarm: int) -> tuple[FlockingEnv, object]:
    env = FlockingEnv("train", num_envs=64, seed=0, policy_id="policy3_g")
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(4096), batch_size=batch_swarm)
    td = env.reset()
    for _ in range(8):
        td = env.rand_action(td)
        step, td = env.step_and_maybe_reset(td)
        buffer.extend(_agentwise_done(step.unsqueeze(-1), env.n_agents).select(*TRANSITION_KEYS, strict=False)
                      .reshape(-1))
    return env, buffer


def update_throughput(batch_uav_transitions: int = 1280, steps: int = 20) -> Row:
    cfg = check_algo(compose("train", [f"algo.batch_size={batch_uav_transitions}"]).algo)
    env, buffer = _replay_batch(batch_uav_transitions // 5)
    batches = [buffer.sample() for _ in range(steps)]

    torch.manual_seed(0)
    learner = SACLearner(env, cfg, "state")

    def ours():
        for b in batches:
            learner.update(b)

    # The plain loop: one Adam over every loss parameter, summed losses (TorchRL tutorial style).
    torch.manual_seed(0)
    actor = make_actor(env)
    loss = SACLoss(actor, make_qvalue(env, "state"), num_qvalue_nets=2, loss_function="l2", alpha_init=0.2,
                   target_entropy=-2.0, action_spec=env.full_action_spec_unbatched[ACTION])
    loss.set_keys(action=ACTION, state_action_value=("agents", "state_action_value"), reward=("agents", "reward"),
                  done=("agents", "done"), terminated=("agents", "terminated"))
    loss.make_value_estimator(ValueEstimators.TD0, gamma=0.99)
    updater = SoftUpdate(loss, tau=0.01)
    optim = torch.optim.Adam(loss.parameters(), lr=1e-3)

    def plain():
        for b in batches:
            out = loss(b)
            total = out["loss_actor"] + out["loss_qvalue"] + out["loss_alpha"]
            optim.zero_grad()
            total.backward()
            optim.step()
            updater.step()

    rate_ours, rate_plain = _paired(ours, plain, steps, 3)
    return Row(f"SAC updates, batch {batch_uav_transitions} UAV transitions (ours vs plain loop)",
               rate_ours, rate_plain, "updates/s")


def run_all(quick: bool = False) -> list[Row]:
    rows = [env_throughput(32, steps=10 if quick else 20)]
    rows.append(collection_throughput(32, 256, batches=2 if quick else 4))
    rows.append(update_throughput(1280, steps=5 if quick else 20))
    return rows


def format_rows(rows: list[Row]) -> str:
    lines = [f"torch {torch.__version__}, {torch.get_num_threads()} threads",
             f"{'benchmark':<70} {'ours':>10} {'baseline':>10} {'ratio':>7}  unit"]
    for r in rows:
        lines.append(f"{r.what:<70} {r.ours:>10.1f} {r.baseline:>10.1f} {r.ratio:>6.2f}x  {r.unit}")
    return "\n".join(lines)


def benchmark_app(cfg, out_dir) -> None:
    import torch as _torch

    if cfg.threads:
        _torch.set_num_threads(int(cfg.threads))
    text = format_rows(run_all(quick=bool(cfg.quick)))
    print(text, flush=True)
    write_text(out_dir / "benchmark.md", "```\n" + text + "\n```\n")
