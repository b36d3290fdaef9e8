"""Checkpoints: a digest-checked file format, and the shipped policy they load as.

A checkpoint file is ``torch.save`` of a small envelope::

    {"format": FORMAT, "kind": "training" | "policy", "sha256": <hex>, "payload": <uint8 tensor>}

where ``payload`` holds the bytes of ``torch.save(payload_dict)`` and ``sha256`` their digest.
Both levels are read with ``torch.load(weights_only=True)``: opening a file never runs code.
A flipped byte, a truncated file, a foreign file or the wrong kind is a
:class:`CheckpointError` that says which. ``training`` checkpoints hold everything a run
needs to continue bit for bit (networks, optimisers, replay buffer, counters, env state, RNG
states); ``policy`` checkpoints are what ``checkpoints/`` ships: the actor, its metadata (the
policy, the reading and scenario it was trained in), the run's config, counters,
evaluations and training curve. Every write goes through :func:`flock_torchrl.io.atomic_write`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import os
import pickle
import warnings
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Iterator

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from ..config import POLICY_SCENARIO_FIELDS, ScenarioConfig, saved_scenario
from ..config.paths import shipped_path, where_shipped
from ..io import atomic_write
from ..world.sensors import observation_size
from ..world.state import torch_device
from .models import ACTION, OBS, actor_of_sizes

FORMAT_VERSION = 2
FORMAT = f"flock_torchrl/checkpoint-v{FORMAT_VERSION}"
KINDS = ("training", "policy")
LAST = "last.pt"
# What each kind must hold (a digest-valid file without them is refused, naming the keys).
REQUIRED = {"training": ("meta", "config", "counters", "actor", "learner", "rng", "evaluations"),
            "policy": ("meta", "actor")}


class CheckpointError(RuntimeError):
    """A checkpoint is missing, unreadable, corrupted, of the wrong kind, or does not fit."""


def _serialise(obj: Any) -> bytes:
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    return buffer.getvalue()


def save_checkpoint(payload: dict[str, Any], path: str | os.PathLike, kind: str) -> Path:
    """Write ``payload`` as a ``kind`` checkpoint, atomically, with its digest.

    Memory: the payload is serialised once into memory (its digest is taken there); the
    envelope around it is streamed to the temporary file through an open handle, without
    another copy of those bytes (torch names the archive inside after a file *path*, so the
    handle, like a buffer, keeps every export's bytes the same wherever it is written)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    buffer = io.BytesIO()
    _save(payload, buffer)
    view = buffer.getbuffer()  # the bytes in place, no copy
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # torch warns that the tensor shares a writable buffer: it is only read
        data = torch.frombuffer(view, dtype=torch.uint8)
    envelope = {"format": FORMAT, "kind": kind, "sha256": hashlib.sha256(view).hexdigest(), "payload": data}

    def write(tmp: str) -> None:
        with open(tmp, "wb") as handle:
            _save(envelope, handle)

    return atomic_write(path, write)


def _save(obj: Any, handle: Any) -> None:
    """``torch.save`` into an open handle; a write or an allocation that fails inside it comes
    out as itself (``OSError``: a full disk, a file-size limit; ``MemoryError``), not as the
    ``RuntimeError`` torch's archive writer raises when it is closed after it."""
    try:
        torch.save(obj, handle)
    except RuntimeError as exc:
        cause, seen = exc.__context__, 0
        while cause is not None and seen < 8:
            if isinstance(cause, (OSError, MemoryError)):
                raise cause from None
            cause, seen = cause.__cause__ or cause.__context__, seen + 1
        raise


def resolve_path(path: str | os.PathLike) -> Path:
    """A checkpoint file, or a run folder's ``last.pt``; a relative path that names nothing from
    the working folder but a shipped checkpoint is that one (:func:`~flock_torchrl.config.paths.shipped_path`:
    ``paper_fit/threed/policy3_g/seed0.pt`` from any folder, a clone's or the wheel's)."""
    path = shipped_path(path)
    return path / LAST if path.is_dir() else path


def no_checkpoint(path: str | os.PathLike) -> CheckpointError:
    """``no checkpoint at <path>``, and where the shipped ones are and how to name them."""
    return CheckpointError(f"no checkpoint at {path}; {where_shipped()}")


def load_checkpoint(path: str | os.PathLike, kind: str | None = None) -> dict[str, Any]:
    """Read a checkpoint; raise :class:`CheckpointError` unless it is intact and of ``kind``."""
    path = resolve_path(path)
    if not path.is_file():
        raise no_checkpoint(path)
    if path.stat().st_size == 0:
        raise CheckpointError(f"{path} is empty (0 bytes): not a checkpoint (a copy or a write that did not finish?)")
    try:
        with warnings.catch_warnings():  # torch warns about foreign pickle protocols; the error says it all
            warnings.simplefilter("ignore")
            envelope = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        # torch's own message suggests weights_only=False: never do that with a file you did not write.
        with path.open("rb") as handle:
            head = handle.read(4)
        if not (head.startswith(b"PK\x03\x04") or head[:1] == b"\x80"):  # neither a torch zip nor a pickle
            raise CheckpointError(f"{path} is not a readable checkpoint (not a torch file)") from None
        raise CheckpointError(f"{path} is not a {FORMAT} checkpoint: it holds Python objects a checkpoint "
                              "never contains, so it was not opened (opening it could run code)") from None
    except (RuntimeError, EOFError, ValueError, OSError, KeyError, AttributeError, TypeError, IndexError,
            UnicodeDecodeError) as exc:
        raise CheckpointError(f"{path} is not a readable checkpoint (corrupted, truncated or not a torch file; "
                              f"{type(exc).__name__})") from None
    if not isinstance(envelope, dict) or envelope.get("format") != FORMAT:
        found = envelope.get("format") if isinstance(envelope, dict) else type(envelope).__name__
        raise CheckpointError(f"{path} is not a {FORMAT} checkpoint (found {found!r}); {_version_hint(found)}")
    payload_bytes = envelope.get("payload")
    if not isinstance(payload_bytes, torch.Tensor) or payload_bytes.dtype != torch.uint8:
        raise CheckpointError(f"{path}: malformed checkpoint (no payload)")
    data = payload_bytes.numpy().tobytes()
    if hashlib.sha256(data).hexdigest() != envelope.get("sha256"):
        raise CheckpointError(f"{path} is corrupted: its payload does not match its SHA-256 digest")
    if envelope.get("kind") not in KINDS:
        raise CheckpointError(f"{path}: kind {envelope.get('kind')!r} is not a checkpoint kind "
                              f"({', '.join(KINDS)}); it was not written by flock_torchrl")
    if kind is not None and envelope.get("kind") != kind:
        what = {"training": "a full training state (resume)", "policy": "a slim shipped policy"}
        raise CheckpointError(f"{path} is {what.get(envelope.get('kind'), repr(envelope.get('kind')))}, but "
                              f"{what[kind]} is needed here")
    try:
        payload = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as exc:  # digest matched: only a writer bug gets here
        raise CheckpointError(f"{path}: payload unreadable ({type(exc).__name__})") from None
    missing = [k for k in REQUIRED.get(envelope.get("kind"), ()) if not isinstance(payload, dict) or k not in payload]
    if missing:
        raise CheckpointError(f"{path} is a {envelope.get('kind')} checkpoint without {', '.join(missing)}: it "
                              "cannot be used (written by something else than flock_torchrl's trainer?)")
    if envelope["kind"] == "training":
        check_training_fields(payload, path)
    check_policy_fields(payload, path)
    payload["kind"] = envelope["kind"]
    return payload


# The metadata a policy is rebuilt from (:class:`SharedPolicy`), with the types it must have.
META_FIELDS = {"policy": str, "policy_id": str, "reading": str, "scenario": dict, "policy_scenario": dict,
               "stochastic": bool, "hidden": int, "depth": int}


def check_policy_fields(payload: dict[str, Any], path: str | os.PathLike) -> None:
    """Refuse, naming the field, a digest-valid checkpoint whose metadata or actor weights are
    wrong: a missing or mistyped ``meta`` field, a reading this version does not know, actor
    weights that are not tensors or are not finite."""
    from ..config import READINGS

    meta = payload.get("meta")
    if not isinstance(meta, dict):
        raise CheckpointError(f"{path}: meta is {type(meta).__name__}, not a dict")
    for name, kind in META_FIELDS.items():
        value = meta.get(name)
        if not isinstance(value, kind) or (kind is int and isinstance(value, bool)) or (kind is int and value < 1):
            raise CheckpointError(f"{path}: meta.{name} is {value!r}, not a valid {kind.__name__}")
    if meta["reading"] not in READINGS:
        raise CheckpointError(f"{path}: meta.reading is {meta['reading']!r}, not one of {', '.join(READINGS)}")
    actor = payload.get("actor")
    if not isinstance(actor, dict) or not actor:
        raise CheckpointError(f"{path}: actor is {type(actor).__name__}, not a dict of weights")
    for name, value in actor.items():
        if not isinstance(value, torch.Tensor):
            raise CheckpointError(f"{path}: actor.{name} is {type(value).__name__}, not a tensor")
        if value.is_floating_point() and not bool(torch.isfinite(value).all()):
            raise CheckpointError(f"{path}: actor.{name} holds NaN or infinite weights")


def _non_finite(tree: Any, name: str) -> Iterator[tuple[str, torch.Tensor]]:
    """``(dotted name, tensor)`` of every floating tensor in ``tree`` (dicts, lists) that holds
    NaN or an infinity."""
    if isinstance(tree, torch.Tensor):
        if tree.is_floating_point() and not bool(torch.isfinite(tree).all()):
            yield name, tree
    elif isinstance(tree, dict):
        for key, value in tree.items():
            yield from _non_finite(value, f"{name}.{key}")
    elif isinstance(tree, (list, tuple)):
        for i, value in enumerate(tree):
            yield from _non_finite(value, f"{name}[{i}]")


def check_training_fields(payload: dict[str, Any], path: str | os.PathLike) -> None:
    """Refuse, naming the field (and, of a population's, the member and its seed), a training
    checkpoint whose learner (networks, optimiser state) or members' actors are not finite: a
    run resumed from it would fail in its first step, far from the cause."""
    members = members_of(payload)
    seeds = [m.get("seed", "?") if isinstance(m, dict) else "?" for m in members]
    for k, member in enumerate(members):
        actor = member.get("actor") if isinstance(member, dict) else None
        for name, _ in _non_finite(actor, f"members[{k}].actor"):
            raise CheckpointError(f"{path}: {name} (member {k}, seed {seeds[k]}) holds NaN or infinite weights")
    for name, tensor in _non_finite(payload.get("learner"), "learner"):
        if members and tensor.dim() and tensor.shape[0] == len(members):  # stacked: one row per member
            bad = [k for k in range(len(members)) if not bool(torch.isfinite(tensor[k]).all())]
            who = ", ".join(f"member {k} (seed {seeds[k]})" for k in bad)
            raise CheckpointError(f"{path}: {name} holds NaN or infinite values for {who}")
        raise CheckpointError(f"{path}: {name} holds NaN or infinite values")


def _version_hint(found: object) -> str:
    """Whether a checkpoint of another format is older or newer than this version reads."""
    import re

    match = re.fullmatch(r"flock_torchrl/checkpoint-v(\d+)", str(found))
    if not match:
        return "it is foreign (not a flock_torchrl checkpoint)"
    version = int(match.group(1))
    if version > FORMAT_VERSION:
        return f"it was written by a newer flock_torchrl (format v{version}; this one reads v{FORMAT_VERSION}): upgrade"
    return f"it was written by an older flock_torchrl (format v{version}; this one reads v{FORMAT_VERSION})"


def members_of(payload: dict[str, Any]) -> list[dict[str, Any]]:
    """A population checkpoint's members (each a policy: ``meta``, ``actor``, ...); empty for one run's."""
    members = payload.get("members")
    return list(members) if isinstance(members, list) else []


def member_list(payload: dict[str, Any]) -> str:
    """``member=0 (seed 4), member=1 (seed 5)``: how to choose a population's members."""
    return ", ".join(f"member={k} (seed {m.get('seed', '?')})" for k, m in enumerate(members_of(payload)))


def policy_of(payload: dict[str, Any], path: str | os.PathLike, member: int | None = None) -> dict[str, Any]:
    """The policy a checkpoint holds (its ``meta`` and ``actor``, ...): of a population's,
    member ``member``'s, which must then be given (a :class:`CheckpointError` lists them);
    ``member`` of a single run's checkpoint is refused."""
    members = members_of(payload)
    if not members:
        if member is not None:
            raise CheckpointError(f"{path} holds one run's policy, not a population's: member={member} does not "
                                  "apply (leave it out)")
        return payload
    if member is None:
        raise CheckpointError(f"{path} holds a population of {len(members)} policies: choose one with "
                              f"{member_list(payload)}")
    if isinstance(member, bool) or not isinstance(member, int) or not 0 <= member < len(members):
        raise CheckpointError(f"{path} holds {len(members)} population members, not member={member!r}: choose "
                              f"one of {member_list(payload)}")
    return members[member]


def export_policy(checkpoint: str | os.PathLike, destination: str | os.PathLike, member: int | None = None) -> Path:
    """Write the slim, shippable part of a training checkpoint (:func:`policy_payload`)."""
    return save_checkpoint(policy_payload(checkpoint, member), destination, kind="policy")


def policy_payload(checkpoint: str | os.PathLike, member: int | None = None) -> dict[str, Any]:
    """The slim, shippable part of a training checkpoint (actor, metadata, config, counters,
    evaluations, training curve; no optimiser, replay buffer or env state); of a population's
    checkpoint, member ``member``'s (each member holds those keys itself)."""
    return slim_payload(load_checkpoint(checkpoint, kind="training"), checkpoint, member)


def slim_payload(payload: dict[str, Any], checkpoint: str | os.PathLike, member: int | None = None) -> dict[str, Any]:
    """:func:`policy_payload` of a training checkpoint already read (``checkpoint``: its path, for errors)."""
    if member is not None:
        payload = policy_of(payload, checkpoint, member)
    return {key: payload[key] for key in ("meta", "actor", "config", "counters", "evaluations", "curve")
            if key in payload}


def policy_fields(meta: dict[str, Any], scenario: ScenarioConfig | None = None) -> dict[str, Any]:
    """The policy scenario fields (``POLICY_SCENARIO_FIELDS``) a checkpoint's policy flies with: those
    its meta records, and for a field added since it was written, its saved scenario's value
    (``scenario``, if already built), which is what it trained with (:func:`saved_scenario`)."""
    saved = dataclasses.asdict(scenario) if scenario is not None else saved_scenario(meta["scenario"])
    return {**{k: saved[k] for k in POLICY_SCENARIO_FIELDS}, **dict(meta["policy_scenario"])}


class SharedPolicy(TensorDictModuleBase):
    """A trained shared actor, ready for ``env.rollout`` with any number of UAVs.

    ``flock_meta`` carries the policy's id and name, the reading and scenario it was trained
    in, and the scenario fields it sets (``policy_scenario``); ``dims`` is the dimension of its
    world (2, or 3: docs/specification.md section 11), and observations of another world's size
    are refused in one line naming it.

    Its parameters do not require gradients: a policy loaded to act builds no autograd graph
    through the env's differentiable step. To train it further, ask for them:
    ``policy.requires_grad_(True)`` (before building its optimiser).
    """

    def __init__(self, actor_state: dict, meta: dict[str, Any], device: str | torch.device | None = None,
                 origin: str = "the checkpoint") -> None:
        super().__init__()
        device = torch_device("cpu" if device is None else device)  # CUDA without CUDA: FlockingEnv's one line
        self.in_keys = [OBS]
        self.out_keys = [ACTION]
        try:
            scenario = ScenarioConfig(**saved_scenario(meta["scenario"]))
        except (TypeError, ValueError) as exc:
            raise CheckpointError(f"{origin}: meta.scenario is not a scenario ({' '.join(str(exc).split())})"
                                  ) from None
        self.flock_meta = {**meta, "policy_scenario": policy_fields(meta, scenario)}
        # Sized from what the checkpoint stores (no world is built): its scenario's observation and action box.
        limit = 1.0 if scenario.action_mode == "policy" else float(scenario.v_max)
        self.dims = scenario.dims
        self._sizes = (observation_size(scenario), limit)
        self.actor = self._build(device)
        expected = self.actor.state_dict()
        for name in sorted(set(expected) | set(actor_state)):
            want, got = expected.get(name), actor_state.get(name)
            if want is None or got is None or tuple(want.shape) != tuple(got.shape):
                shape = lambda t: "absent" if t is None else list(t.shape)  # noqa: E731
                raise CheckpointError(f"{origin}: actor.{name} is {shape(got)}, but the network its meta describes "
                                      f"(obs {observation_size(scenario)}, hidden {meta['hidden']}, depth "
                                      f"{meta['depth']}) needs {shape(want)}")
        self.actor.load_state_dict(actor_state)
        self.actor.requires_grad_(False)  # acting: no autograd graph (requires_grad_(True) to train it)
        self._device = device  # where the actor and its action box are
        self._origin = origin
        fields = dataclasses.asdict(scenario)
        # The observation's length in either dimension, to name a world of the other one.
        self._observation_sizes = {dims: observation_size(SimpleNamespace(**{**fields, "dims": dims}))
                                   for dims in (2, 3)}

    def _build(self, device: torch.device) -> Any:
        """A fresh actor of this policy's sizes on ``device``, with its action box there too."""
        n_obs, limit = self._sizes
        box = torch.full((self.dims,), limit, device=device)
        meta = self.flock_meta
        return actor_of_sizes(n_obs, -box, box, device=device, stochastic=meta["stochastic"],
                              hidden=meta["hidden"], depth=meta["depth"])

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation = tensordict.get(OBS, None)
        if observation is not None:
            if observation.shape[-1] != self._sizes[0]:
                self._refuse(observation.shape[-1])
            if observation.device != self._device:
                self.follow(observation.device)
        return self.actor(tensordict)

    def _refuse(self, size: int) -> None:
        """One line for observations of another length than the policy's: another dimension's
        world (a 2-D policy in a 3-D env, or the reverse), else another sensing."""
        n_obs = self._sizes[0]
        other = next((d for d, n in self._observation_sizes.items() if n == size and d != self.dims), None)
        if other is not None:
            raise ValueError(f"{self._origin} was trained in a {self.dims}-D world (observations of {n_obs}) and is "
                             f"given a {other}-D world's (observations of {size}): fly it in a {self.dims}-D "
                             f"scenario (scenario.dims={self.dims})")
        raise ValueError(f"{self._origin} reads observations of {n_obs} (its scenario's n_scan and n_cam) and is "
                         f"given observations of {size}: build its env with FlockingEnv(..., "
                         f"policy_id={self.flock_meta['policy_id']!r}) in its own world")

    def follow(self, device: str | torch.device) -> "SharedPolicy":
        """Move the actor, and the action box its distribution reads, to ``device`` (what a
        call with observations on another device does by itself: the policy follows its env);
        whether its parameters require gradients stays as it was."""
        device = torch_device(device)
        grad = any(p.requires_grad for p in self.actor.parameters())
        state = {k: v.to(device) for k, v in self.actor.state_dict().items()}
        self.actor = self._build(device)
        self.actor.load_state_dict(state)
        self.actor.requires_grad_(grad)
        self._device = device
        return self


def load_policy(path: str | os.PathLike, device: str | torch.device | None = None, member: int | None = None
                ) -> SharedPolicy:
    """A trained policy from a checkpoint (slim or training, or a run folder), ready for
    ``env.rollout``: on ``device`` (default: the CPU) until it is called with observations on
    another device, then on theirs (it follows its env). Build its env in its own world::

        policy = load_policy("checkpoints/paper_fit/policy3_g/seed0.pt")
        env = FlockingEnv("s2", num_envs=8, reading=policy.flock_meta["reading"],
                          policy_id=policy.flock_meta["policy_id"])

    A population's checkpoint (``population=K``) holds K policies: ``member=k`` chooses one
    (``load_policy(run, member=1)``: seed ``seed + 1``); without it the error lists them.

    ``path`` is a file or run folder, or a shipped checkpoint named by its path in the shipped
    collection (``paper_fit/threed/policy3_g/seed0.pt``; ``checkpoints/...`` as from a clone's
    root), the same from any folder, a clone or the wheel. Its parameters do not require
    gradients (acting builds no autograd graph); ``policy.requires_grad_(True)`` to train it further.
    """
    origin = str(resolve_path(path))
    payload = policy_of(load_checkpoint(path), origin, member)
    return SharedPolicy(payload["actor"], dict(payload["meta"]), device=device, origin=origin)


__all__ = ["CheckpointError", "FORMAT", "LAST", "SharedPolicy", "export_policy", "load_checkpoint", "load_policy",
           "member_list", "members_of", "no_checkpoint", "policy_fields", "policy_of", "policy_payload",
           "slim_payload", "resolve_path", "save_checkpoint"]
