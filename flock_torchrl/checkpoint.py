"""Checkpoints: atomic writes, safe loads, and the shipped policy loader.

A checkpoint is a plain ``dict`` of tensors, numbers, strings, lists and dicts, saved with
``torch.save`` and read back with ``torch.load(..., weights_only=True)``: opening someone
else's file never runs code. Writes go to a temporary file in the same folder, are flushed
to disk, then renamed over the target, so a kill leaves either the old or the new file.
"""

from __future__ import annotations

import os
import pickle
import tempfile
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from .models import ACTION, OBS, make_actor

FORMAT = "flock_torchrl/checkpoint-v1"
LAST = "last.pt"


class CheckpointError(RuntimeError):
    """A checkpoint is missing, unreadable, or does not fit the run."""


def atomic_save(obj: Any, path: str | os.PathLike) -> Path:
    """``torch.save`` to ``path`` through a temporary file and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            torch.save(obj, handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Read a checkpoint safely (``weights_only=True``); raise :class:`CheckpointError` on any problem."""
    path = Path(path)
    if path.is_dir():
        path = path / LAST
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, OSError) as exc:
        raise CheckpointError(f"checkpoint {path} is corrupted or not a flock_torchrl checkpoint: {exc}") from exc
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a flock_torchrl checkpoint (format {FORMAT!r} expected)")
    return payload


def export_policy(checkpoint: str | os.PathLike, destination: str | os.PathLike) -> Path:
    """Write the slim, shippable part of a training checkpoint: the actor, its metadata, the
    run's config, counters and evaluations (no optimiser, replay buffer or env state)."""
    payload = load_checkpoint(checkpoint)
    slim = {key: payload[key] for key in ("format", "meta", "actor", "config", "counters", "evaluations")
            if key in payload}
    return atomic_save(slim, destination)


class SharedPolicy(TensorDictModuleBase):
    """A trained shared actor that runs with any number of UAVs.

    The actor's parameters are shared across UAVs, hence independent of N; the TorchRL
    multi-agent module is rebuilt (once per N) for the N of the tensordict it receives.
    ``flock_meta`` carries the policy's name and the scenario overrides it implies.
    """

    def __init__(self, actor_state: dict, meta: dict[str, Any], device: str | torch.device = "cpu") -> None:
        super().__init__()
        self.in_keys = [OBS]
        self.out_keys = [ACTION]
        self.flock_meta = meta
        self._actor_state = actor_state
        self._device = torch.device(device)
        self._actors = torch.nn.ModuleDict()
        self.actor_for(int(meta["n_agents"]))

    def actor_for(self, n_agents: int) -> TensorDictModuleBase:
        key = str(n_agents)
        if key not in self._actors:
            from .env import FlockingEnv

            scenario = dict(self.flock_meta["scenario"])
            scenario["n_uavs"] = n_agents
            env = FlockingEnv(scenario, num_envs=1, device=self._device, seed=None)
            actor = make_actor(env, stochastic=self.flock_meta["stochastic"], hidden=self.flock_meta["hidden"],
                               depth=self.flock_meta["depth"])
            actor.load_state_dict(self._actor_state)
            self._actors[key] = actor
        return self._actors[key]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self.actor_for(tensordict.get(OBS).shape[-2])(tensordict)


def load_policy(path: str | os.PathLike, device: str | torch.device = "cpu") -> SharedPolicy:
    """Load a trained policy from a checkpoint file or run folder, ready for ``env.rollout``.

    Build the env with the policy's overrides (``policy.flock_meta["env"]``) so that it sees
    what it was trained with, e.g.::

        policy = load_policy("checkpoints/policy3_g/seed0.pt")
        env = FlockingEnv("s2", num_envs=8, **policy.flock_meta["env"])
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            td = env.rollout(500, policy)
    """
    payload = load_checkpoint(path)
    meta = dict(payload["meta"])
    return SharedPolicy(payload["actor"], meta, device=device)
