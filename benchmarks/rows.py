"""A benchmark's row (ours against a baseline measured in the same process) and the table of
rows; the env's rows, which the CPU's table (:mod:`benchmarks.throughput`) and the GPU's
(:mod:`benchmarks.gpu`) both print."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import torch

from flock_torchrl.world.env import FlockingEnv
from benchmarks.timing import paired


@dataclass
class Row:
    what: str
    ours: float
    baseline: float
    unit: str
    note: str = ""

    @property
    def ratio(self) -> float:
        return self.ours / self.baseline if self.baseline else math.nan


def random_stepper(env, steps: int) -> Callable[[], None]:
    """A callable taking ``steps`` steps of random actions (``env.step_and_maybe_reset``), each
    call going on from where the last one stopped."""
    td = env.reset()

    def go() -> None:
        nonlocal td
        for _ in range(steps):
            td = env.step_and_maybe_reset(env.rand_action(td))[1]
    return go


def vmas_env(num_envs: int, device: str = "cpu"):
    """TorchRL's VmasEnv flocking scenario with five agents, or ``None`` without vmas."""
    try:
        from torchrl.envs import VmasEnv

        return VmasEnv("flocking", num_envs=num_envs, n_agents=5, continuous_actions=True, device=device, seed=0)
    except Exception:  # vmas is the optional `bench` extra
        return None


def env_rows(batches=(64, 1024, 4096), steps: int = 20, repeat: int = 3, device: str = "cpu") -> list[Row]:
    """env-steps/s of the eager and the compiled step against ``VmasEnv``'s, and against each other."""
    rows = []
    for b in batches:
        n = max(3, steps * 64 // b)
        candidates = {name: random_stepper(FlockingEnv("train", b, device, 0, policy_id="policy3_g",
                                                       compile_step=name == "compiled"), n)
                      for name in ("eager", "compiled")}
        vmas = vmas_env(b, device)
        if vmas is not None:
            candidates["vmas"] = random_stepper(vmas, n)
        rate = {name: b * n / seconds for name, seconds in paired(candidates, repeat).items()}
        note = "" if vmas is not None else "vmas not installed: pip install -e .[bench]"
        rows += [Row(f"env steps, B={b}, N=5 ({name} vs VmasEnv flocking)", rate[name], rate.get("vmas", math.nan),
                     "env-steps/s", note) for name in ("eager", "compiled")]
        rows.append(Row(f"env steps, B={b}, N=5 (compiled vs eager)", rate["compiled"], rate["eager"], "env-steps/s"))
    return rows


def format_rows(rows: list[Row]) -> str:
    lines = [f"torch {torch.__version__}, {torch.get_num_threads()} thread(s), "
             f"CUDA: {torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'none'}",
             f"{'benchmark':<78} {'ours':>12} {'baseline':>12} {'ratio':>8}  unit"]
    for r in rows:
        ratio = "" if math.isnan(r.ratio) else f"{r.ratio:7.2f}x"
        lines.append(f"{r.what:<78} {r.ours:>12.1f} {r.baseline:>12.1f} {ratio:>8}  {r.unit}"
                     + (f"  ({r.note})" if r.note else ""))
    return "\n".join(lines)


__all__ = ["Row", "env_rows", "format_rows", "random_stepper", "vmas_env"]
