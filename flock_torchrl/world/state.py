"""The per-world state the env owns, declared once.

:data:`WORLD_STATE` names every tensor of one world's physical state (and of the step that
led to it), with its shape per world as a function of the scenario and its dtype. The env
builds empty and fresh worlds from it (:func:`empty_state`), checks what ``set_state`` and
``place`` receive against it (:func:`check_state`), and the pure step
(:func:`~flock_torchrl.world.step.advance`) returns exactly these keys (:func:`world_state`).
The running episode metrics (:func:`~flock_torchrl.world.metrics.new_accumulator`) and the
sensed quantities (:func:`~flock_torchrl.world.step.sense`) sit next to this state in the
env's world TensorDict.
"""

from __future__ import annotations

import operator
from dataclasses import dataclass
from typing import Any, Mapping

import torch
from tensordict import TensorDict, TensorDictBase

from ..config.scenario import ScenarioConfig


@dataclass(frozen=True)
class StateField:
    """One per-world tensor: ``shape`` per world, each entry an int or the name of a
    :class:`~flock_torchrl.config.ScenarioConfig` field (``"n_uavs"``, ``"n_moving"``,
    ``"random_circles"``)."""

    shape: tuple[int | str, ...]
    dtype: torch.dtype
    doc: str

    def size(self, cfg: ScenarioConfig) -> tuple[int, ...]:
        """The shape of this field for one world of ``cfg``."""
        return tuple(getattr(cfg, d) if isinstance(d, str) else d for d in self.shape)


WORLD_STATE: dict[str, StateField] = {
    "position": StateField(("n_uavs", "dims"), torch.float32, "UAV positions p_i (m)"),
    "velocity": StateField(("n_uavs", "dims"), torch.float32, "UAV velocities v_i (m/s)"),
    "heading": StateField(("n_uavs",), torch.float32, "UAV headings phi_i (rad, [-pi, pi))"),
    "climb": StateField(("n_climb",), torch.float32, "UAV flight-path angles gamma_i (rad; 3-D only, section 11)"),
    "goal": StateField(("dims",), torch.float32, "the swarm's goal p_g (m)"),
    "moving_position": StateField(("n_moving", 2), torch.float32, "centres of the moving circles (S5; m)"),
    "moving_velocity": StateField(("n_moving", 2), torch.float32, "velocities of the moving circles (m/s)"),
    "drawn_circles": StateField(("drawn_cylinders", "circle_size"), torch.float32,
                                "the episode's drawn circles, [cx, cy, radius] (the forest; m; 3-D: + z_low, z_high)"),
    "drawn_rectangles": StateField(("random_rectangles", "rectangle_size"), torch.float32,
                                   "the episode's drawn rectangles, [cx, cy, width, height] (m; 3-D: + z_low, z_high)"),
    "drawn_spheres": StateField(("drawn_spheres", 4), torch.float32,
                                "the episode's drawn spheres, [cx, cy, cz, radius] (3-D only; m)"),
    "command": StateField(("n_uavs", "dims"), torch.float32, "the velocity command executed on the last step"),
    "instinct": StateField(("n_uavs",), torch.bool, "which UAVs flew the instinct's command on the last step"),
    "prev_action": StateField(("n_uavs", "dims"), torch.float32,
                              "the last step's action (the smoothness reward's a_t-1)"),
    "has_prev_action": StateField((), torch.bool, "whether the episode has taken a step (prev_action is set)"),
    "terminated": StateField((1,), torch.bool, "the episode ended: goal reached or crash"),
    "truncated": StateField((1,), torch.bool, "the episode ran out of steps (and did not terminate)"),
}
STATE_KEYS = tuple(WORLD_STATE)


def state_shapes(cfg: ScenarioConfig, batch: int) -> dict[str, tuple[int, ...]]:
    """The shape of every state tensor for ``batch`` worlds."""
    return {key: (batch, *field.size(cfg)) for key, field in WORLD_STATE.items()}


def empty_state(cfg: ScenarioConfig, batch: int, device: torch.device | str | None = None) -> dict[str, torch.Tensor]:
    """All-zero (``False``) state tensors of ``batch`` worlds."""
    return {key: torch.zeros(shape, dtype=WORLD_STATE[key].dtype, device=device)
            for key, shape in state_shapes(cfg, batch).items()}


def world_state(**values: torch.Tensor) -> dict[str, torch.Tensor]:
    """The state mapping of exactly the keys of :data:`WORLD_STATE`, in its order (a missing
    or unknown key is an error: the step and the declaration cannot drift apart)."""
    missing, unknown = WORLD_STATE.keys() - values.keys(), values.keys() - WORLD_STATE.keys()
    if missing or unknown:
        raise KeyError(f"world state: missing {sorted(missing)}, unknown {sorted(unknown)}")
    return {key: values[key] for key in WORLD_STATE}


def fill_absent(cfg: ScenarioConfig, state: Mapping[str, Any], batch: int,
                device: torch.device | str | None = None) -> dict[str, Any]:
    """``state`` with every absent field that holds nothing in this scenario (a declared shape
    with a zero, e.g. no drawn obstacles) added empty: a state saved before that field was
    declared still restores. Other entries pass unchanged."""
    out = dict(state)
    for key, shape in state_shapes(cfg, batch).items():
        if key not in out and 0 in shape:
            out[key] = torch.zeros(shape, dtype=WORLD_STATE[key].dtype, device=device)
    return out


def check_state(cfg: ScenarioConfig, state: Mapping[str, Any], batch: int, what: str,
                keys: tuple[str, ...] = STATE_KEYS) -> None:
    """Raise a ``ValueError`` naming the key unless every ``keys`` entry of ``state`` is a tensor
    of the declared shape (for ``batch`` worlds) and dtype."""
    shapes = state_shapes(cfg, batch)
    for key in keys:
        value, dtype = state.get(key, None), WORLD_STATE[key].dtype
        if not isinstance(value, torch.Tensor):
            raise ValueError(f"{what}: {key!r} should be a {dtype} tensor of shape {list(shapes[key])}, got "
                             f"{type(value).__name__}")
        if tuple(value.shape) != shapes[key]:
            raise ValueError(f"{what}: {key!r} has shape {list(value.shape)}, expected {list(shapes[key])}")
        if value.dtype != dtype:
            raise ValueError(f"{what}: {key!r} has dtype {value.dtype}, expected {dtype}")


ACTION = ("agents", "action")


def checked_action(action: Any, cfg: ScenarioConfig, batch: int, device: torch.device,
                   done: torch.Tensor | None = None) -> torch.Tensor:
    """A step's ``action [B, N, 2]`` as float32 on ``device``, clipped to the action box;
    anything else is a ``ValueError`` naming the key and what was expected.

    ``done [B]`` (the worlds' done flags) asks for the two checks that read tensor values on
    the host (a device synchronisation): finite values, and no world done; ``None`` skips them."""
    expected = (batch, cfg.n_uavs, cfg.dims)
    if action is None:
        raise ValueError(f"FlockingEnv.step: no {ACTION} entry in the tensordict; expected a float tensor of "
                         f"shape {list(expected)}")
    if tuple(action.shape) != expected:
        raise ValueError(f"FlockingEnv.step: {ACTION} has shape {list(action.shape)}, expected {list(expected)} "
                         f"(worlds, UAVs, {cfg.dims})")
    if not action.is_floating_point():
        raise ValueError(f"FlockingEnv.step: {ACTION} has dtype {action.dtype}, expected a floating point "
                         "tensor (float32; other float types are cast)")
    action = action.to(device, torch.float32)
    limit = 1.0 if cfg.action_mode == "policy" else cfg.v_max
    if done is None:
        return action.clamp(-limit, limit)
    finite = torch.isfinite(action).all()
    if bool(finite & ~done.any()):  # one host synchronisation for both checks
        return action.clamp(-limit, limit)
    if not bool(finite):
        raise ValueError(f"FlockingEnv.step: {ACTION} contains NaN or inf; actions must be finite")
    worlds = done.nonzero().reshape(-1).tolist()
    shown = ", ".join(map(str, worlds[:8])) + (" ..." if len(worlds) > 8 else "")
    raise ValueError(f"FlockingEnv.step: world(s) {shown} are done; reset them first (TorchRL's "
                     "env.step_and_maybe_reset, rollout and collectors do this)")


def check_like(world: Any, reference: Any, parts: tuple[str, ...], what: str) -> None:
    """Every leaf of ``reference``'s ``parts`` (TensorDicts) is in ``world`` with its shape and
    dtype; a ``ValueError`` names the first that is not."""
    for part in parts:
        for key, value in reference[part].items(include_nested=True, leaves_only=True):
            key = (part, *key) if isinstance(key, tuple) else (part, key)
            got = world.get(key, None)
            if got is None or got.shape != value.shape:
                raise ValueError(f"{what} {key!r}: expected shape {list(value.shape)}, got "
                                 f"{None if got is None else list(got.shape)}")
            if got.dtype != value.dtype:
                raise ValueError(f"{what} {key!r}: has dtype {got.dtype}, expected {value.dtype}")


def checked_worlds(cfg: ScenarioConfig, saved: Any, count: int, reference: Any, what: str,
                   device: torch.device, finite: bool = False) -> TensorDict:
    """``count`` saved worlds (a mapping of a ``get_state()``'s world entries) as a TensorDict on
    ``device``: every state key of its declared shape and dtype (:func:`check_state`; fields that
    hold nothing in this scenario may be absent), its metrics and sensing cache as ``reference``'s,
    and with ``finite`` no NaN or inf in the state. Anything else is a ``ValueError`` naming the key."""
    worlds = TensorDict(fill_absent(cfg, saved, count, device), batch_size=[], device=device)
    check_state(cfg, worlds, count, what)
    if finite:  # a NaN position would give NaN observations and never end the episode
        for key in STATE_KEYS:
            value = worlds.get(key)
            if value.is_floating_point() and not bool(torch.isfinite(value).all()):
                raise ValueError(f"{what}: {key!r} contains NaN or inf; a world's state must be finite")
    check_like(worlds, reference, ("episode", "sensed"), what)
    worlds.batch_size = torch.Size([count])
    return worlds


def restored_worlds(cfg: ScenarioConfig, state: Any, count: int, reference: Any, reserve: Any, reset_pool: int,
                    device: torch.device) -> TensorDict:
    """``FlockingEnv.set_state``'s check: the ``count`` finite worlds of ``state`` (what ``get_state()``
    returns), and its reserve of fresh worlds loaded into ``reserve`` (a :class:`~.reserve.Reserve`,
    or ``None`` for ``reset_pool=0``), every part checked before anything changes; anything else is
    a ``ValueError`` naming the key."""
    world = state["world"] if isinstance(state, Mapping) and "world" in state else None
    if not isinstance(world, (Mapping, TensorDictBase)):
        raise ValueError("env state: expected a mapping with a 'world' entry (what get_state() returns)")
    world = checked_worlds(cfg, world, count, reference, "env state", device, finite=True)
    saved = state.get("reset_pool")
    if reserve is None and saved is not None:
        raise ValueError("env state: it carries a reserve of fresh worlds (saved with reset_pool > 0); this "
                         "env has reset_pool=0")
    if reserve is not None:
        reserve.load_state_dict(saved, lambda stored, n: checked_worlds(
            cfg, stored, n, reserve.worlds, f"env state's reset_pool (reset_pool={reset_pool})", device))
    return world


def spawned_state(cfg: ScenarioConfig, layout: Any, device: torch.device) -> dict[str, torch.Tensor]:
    """New episodes' state: a drawn ``layout`` (:func:`~.spawn.sample_layout`: spawns, goals, moving
    and drawn obstacles) at rest over an empty state."""
    state = empty_state(cfg, layout.position.shape[0], device)
    state.update({key: getattr(layout, key) for key in ("position", "heading", "goal", "moving_position",
                                                       "moving_velocity", "drawn_circles", "drawn_rectangles",
                                                       "drawn_spheres")})
    return state


def placed_state(cfg: ScenarioConfig, kept: Mapping[str, torch.Tensor], given: Mapping[str, Any], batch: int,
                 device: torch.device) -> dict[str, torch.Tensor]:
    """The physical state ``FlockingEnv.place`` starts from: ``given`` (the arguments not ``None``,
    as float32 on ``device``) over ``kept`` (the obstacles' entries of the current worlds) over an
    empty state; a wrong shape, a NaN / inf value or a drawn obstacle of size <= 0 is a
    ``ValueError`` naming the argument."""
    state = empty_state(cfg, batch, device)
    state.update(kept)
    state.update({key: torch.as_tensor(value, dtype=torch.float32, device=device)
                  for key, value in given.items() if value is not None})
    check_state(cfg, state, batch, "place", keys=tuple(given))
    for key, value in given.items():
        if value is not None and not bool(torch.isfinite(state[key]).all()):
            raise ValueError(f"place: {key} contains NaN or inf; positions, headings, goals and velocities "
                             "must be finite")
    for key in ("drawn_circles", "drawn_rectangles"):
        if given.get(key) is not None and not bool((state[key][..., 2:] > 0).all()):
            raise ValueError(f"place: {key} has a size <= 0; radii, widths and heights must be positive")
    return state


def checked_reset_mask(mask: Any, batch: int, device: torch.device) -> torch.Tensor:
    """A reset's ``"_reset"`` entry as a bool ``[batch]`` on ``device``; anything else is a ``ValueError``."""
    if not isinstance(mask, torch.Tensor) or mask.dtype != torch.bool:
        raise ValueError(f"FlockingEnv.reset: \"_reset\" must be a torch.bool mask of {batch} world(s) (shape "
                         f"[{batch}, 1]), got {mask.dtype if isinstance(mask, torch.Tensor) else type(mask).__name__}")
    if mask.numel() != batch:
        raise ValueError(f"FlockingEnv.reset: \"_reset\" has shape {list(mask.shape)}, expected [{batch}, 1] (one "
                         "flag per world)")
    return mask.reshape(batch).to(device)


def world_index(index: Any, batch: int, device: torch.device) -> torch.Tensor:
    """``FlockingEnv.subset``'s ``index`` (world indices, or a bool mask with one flag per world) as
    int64 world indices; an empty, float or out-of-range index is a ``ValueError``."""
    index = torch.as_tensor(index, device=device)
    if index.dtype == torch.bool:
        if index.numel() != batch:
            raise ValueError(f"subset: a boolean mask needs one flag per world ({batch}), got shape "
                             f"{list(index.shape)}")
        index = index.reshape(-1).nonzero().reshape(-1)
    elif index.is_floating_point() or index.is_complex():
        raise ValueError(f"subset: index has dtype {index.dtype}; expected world indices (integers) or a boolean mask")
    index = index.reshape(-1).long()
    if not index.numel():
        raise ValueError("subset: no world selected (an env holds at least one world)")
    outside = index[(index < -batch) | (index >= batch)].tolist()
    if outside:
        raise ValueError(f"subset: world index {outside[:8]} out of range for {batch} world(s)")
    return index


def check_counts(num_envs: Any, reset_pool: Any, per_group: int | None = None, groups: int = 1) -> None:
    """An env's ``num_envs`` (an integer >= 1) and ``reset_pool`` (an integer >= 0; with ``per_group``
    worlds per group, 0 or at least that many: one step can reset every world); else a ``ValueError``."""
    if not isinstance(num_envs, int) or isinstance(num_envs, bool) or num_envs < 1:
        raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
    if not isinstance(reset_pool, int) or isinstance(reset_pool, bool) or reset_pool < 0:
        raise ValueError(f"reset_pool must be an integer >= 0 (0: no reserve of fresh worlds), got {reset_pool!r}")
    if per_group is not None and reset_pool and reset_pool < per_group:
        worlds = "num_envs" if groups == 1 else "worlds per member"
        raise ValueError(f"reset_pool must be 0 or at least the {worlds} ({per_group}): one step can reset "
                         f"every world, got {reset_pool}")


def check_seed(seed: Any) -> None:
    """``seed``: ``None`` or an integer in [0, 2**64 - 1] (what the env's generators take)."""
    if seed is None:
        return
    try:
        value = operator.index(seed)
    except TypeError:
        value = None
    if value is None or isinstance(seed, bool) or not 0 <= value < 2**64:
        raise ValueError(f"seed must be None or an integer in [0, 2**64 - 1], got {seed!r}")


def torch_device(device: Any) -> torch.device:
    """``device`` as a torch device; one the machine lacks (CUDA without CUDA) is a ``ValueError``
    naming ``device``."""
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise ValueError(f"device {device!r} is not a torch device ({' '.join(str(exc).split())})") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {device!r}: this machine has no CUDA device (torch {torch.__version__}, "
                         f"CUDA {torch.version.cuda or 'not compiled in'}); use device='cpu'")
    return dev


__all__ = ["ACTION", "STATE_KEYS", "StateField", "WORLD_STATE", "check_counts", "check_like", "check_seed",
           "check_state", "checked_action", "checked_reset_mask", "checked_worlds", "empty_state", "fill_absent",
           "placed_state", "restored_worlds", "spawned_state", "state_shapes", "torch_device", "world_index",
           "world_state"]
