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
    state = {"td": td}

    def go() -> None:
        td = state["td"]
        for _ in range(steps):
            td = env.rand_action(td)
            td = env.step_and_maybe_reset(td)[1]
        state["td"] = td
    return go


def vmas_env(num_envs: int, device: str = "cpu"):
    """TorchRL's VmasEnv flocking scenario with five agents, or ``None`` without vmas."""
    try:
        from torchrl.envs import VmasEnv

        return VmasEnv("flocking", num_envs=num_envs, n_agents=5, continuous_actions=True, device=device, seed=0)
    except Exception:  # vmas is the optional `bench` extra
        return None


def env_rows(batches=(64, 1024, 4096), steps: int = 20, repeat: int = 3, device: str = "cpu",
             compile_step: bool = True) -> list[Row]:
    rows = []
    for b in batches:
        n = max(3, steps * 64 // b)
        candidates = {"eager": random_stepper(FlockingEnv("train", b, device, 0, policy_id="policy3_g"), n)}
        if compile_step:
            candidates["compiled"] = random_stepper(FlockingEnv("train", b, device, 0, policy_id="policy3_g",
                                                                compile_step=True), n)
        vmas = vmas_env(b, device)
        if vmas is not None:
            candidates["vmas"] = random_stepper(vmas, n)
        best = paired(candidates, repeat)
        base = b * n / best["vmas"] if "vmas" in best else math.nan
        note = "" if vmas is not None else "vmas not installed: pip install -e .[bench]"
        for name in ("eager", "compiled"):
            if name in best:
                rows.append(Row(f"env steps, B={b}, N=5 ({name} vs VmasEnv flocking)", b * n / best[name], base,
                                "env-steps/s", note))
        if "compiled" in best:
            rows.append(Row(f"env steps, B={b}, N=5 (compiled vs eager)", b * n / best["compiled"],
                            b * n / best["eager"], "env-steps/s"))
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
