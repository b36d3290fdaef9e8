"""What a policy name, a checkpoint or a module means: the one place that answers it.

Training, evaluation, the tables and the figures all ask :func:`resolve`, which turns

* a policy id (``policy3_g``, ``Policy3-G``, ``policy_ma``) into its composed config
  (``conf/policy/<id>.yaml``): a rule-based controller, or the shipped checkpoints of a
  learned policy under a reading (``checkpoints/<reading>/<id>/seed<k>.pt``; for a 3-D world
  ``checkpoints/<reading>/threed/<id>/seed<k>.pt``);
* a checkpoint path into the policy it holds, with the reading it was trained under (a path
  relative to the shipped checkpoints names one of them from any folder);
* a TensorDict module into itself;

into :class:`PolicyHandle` s: the policy's name, the scenario fields it sets, the reading it
belongs to, the env keys it reads, and how to build its module for a given env.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from ..config import (POLICY_SCENARIO_FIELDS, ConfigError, PolicyConfig, available, compose_world, contender_name,
                      default_checkpoints_dir, is_file_target)
from ..config.paths import DIMS_FOLDER, seeds_dir, shipped_checkpoints_dir
from .checkpoint import (CheckpointError, SharedPolicy, load_checkpoint, members_of, no_checkpoint, policy_of,
                         resolve_path)

Module = Callable[[Any], Any]


@dataclass
class PolicyHandle:
    """A policy before it meets an env.

    Attributes:
        id: the policy's config id (``policy3_g``), or ``"module"``.
        name: the paper's name (``Policy3-G``).
        kind: ``learned``, ``rule`` or ``module``.
        reading: the reading a checkpoint was trained under (``None``: it fits either).
        scenario: the scenario fields the policy sets (``fov``, ``instinct``, ...).
        extras: env keys it reads beyond the observation (``FlockingEnv(extras=...)``).
        origin: a checkpoint path, ``baseline:<id>`` or ``module``.
        seed: the training seed of a checkpoint (``None`` otherwise).
        member: the member of a population's checkpoint it is (``None``: not a population's).
    """

    id: str
    name: str
    kind: str
    reading: str | None
    scenario: dict[str, Any]
    extras: tuple[str, ...]
    origin: str
    build_for: Callable[[Any], Module] = field(repr=False)
    seed: int | None = None
    member: int | None = None      # which member of a population's checkpoint (``None``: one run's)

    def build(self, env: Any) -> Module:
        """The TensorDict module that acts in ``env`` (a :class:`~flock_torchrl.FlockingEnv`);
        ``ValueError`` naming them when the env does not emit the extra keys the policy reads."""
        missing = [e for e in self.extras if e not in tuple(getattr(env, "extras", ()) or ())]
        if missing:
            raise ValueError(f"{self.name} reads the env's extra keys {tuple(self.extras)}, and this env does not emit "
                             f"{tuple(missing)}: build it with FlockingEnv(..., extras={tuple(self.extras)!r})")
        return self.build_for(env)

    @property
    def source(self) -> str:
        """Where it comes from, in words: its origin, and which member of a population it is."""
        return self.origin if self.member is None else f"{self.origin} member={self.member} (seed {self.seed})"

    def check_reading(self, reading: str) -> None:
        """Refuse to act in a world of another reading than the one it was trained under."""
        if self.reading is not None and reading != self.reading:
            raise ConfigError("reading", f"{self.origin} was trained under the reading {self.reading!r}; it cannot "
                                         f"be evaluated under {reading!r} (pass reading={self.reading})")


def policy_id(name: str) -> str:
    """``"Policy3-G"`` / ``"policy3_g"`` / ``"Policy-MA"`` -> the config id ``policy3_g`` / ``policy_ma``."""
    return re.sub(r"[-\s]+", "_", str(name).strip()).lower()


def policy_config_of(name: str, reading: str | None = None) -> tuple[PolicyConfig, dict[str, Any]]:
    """A policy's composed config and the scenario fields it sets (``conf/policy/<id>.yaml``)."""
    pid = policy_id(name)
    if pid not in available("policy"):
        raise ConfigError("policy", f"unknown policy {name!r}; available: {', '.join(available('policy'))} "
                                    "or a checkpoint path")
    cfg = compose_world("train", reading, pid)
    policy = PolicyConfig.from_config(cfg.policy)
    scenario = {k: cfg.scenario[k] for k in POLICY_SCENARIO_FIELDS}
    return policy, scenario


def shipped_checkpoints(name: str, folder: str | os.PathLike) -> list[Path]:
    """``<folder>/<id>/seed<k>.pt`` of a policy, ordered by ``k`` (empty if none). ``folder`` is
    a collection of shipped policies: ``<checkpoints_dir>/<reading>`` (the fast recipe) or the
    paper recipe's ``<checkpoints_dir>/<reading>/paper_recipe``."""
    def seed_of(p: Path) -> tuple[int, str]:
        m = re.fullmatch(r"seed(\d+)", p.stem)
        return (int(m.group(1)) if m else 1 << 30, p.name)

    return sorted((Path(folder) / policy_id(name)).glob("seed*.pt"), key=seed_of)


def checkpoint_handle(path: str | os.PathLike, device: str = "cpu", member: int | None = None,
                      payload: dict[str, Any] | None = None) -> PolicyHandle:
    """The policy a checkpoint holds (slim or training); of a population's, member ``member``'s
    (which must be given: the error lists them). ``payload``: the checkpoint, already read."""
    origin = str(resolve_path(path))
    one = policy_of(payload if payload is not None else load_checkpoint(path), origin, member)
    meta = dict(one["meta"])
    where = origin if member is None else f"{origin} member={member}"
    module = SharedPolicy(one["actor"], meta, device=device, origin=where)
    return PolicyHandle(
        id=meta["policy_id"], name=meta["policy"], kind="learned", reading=meta["reading"],
        scenario=dict(module.flock_meta["policy_scenario"]), extras=(), origin=origin,
        build_for=lambda env: same_dims(module, env, where), seed=meta.get("seed"), member=member)


def same_dims(module: Any, env: Any, origin: str) -> Any:
    """``module``, if it was trained in ``env``'s dimension (docs/specification.md section 11);
    else a :class:`ConfigError` naming ``scenario.dims`` and, for a shipped policy, where its
    seeds of the env's dimension are."""
    if module.dims != env.cfg.dims:
        policy, reading = module.flock_meta["policy_id"], module.flock_meta["reading"]
        folder = seeds_dir(shipped_checkpoints_dir(), reading, env.cfg.dims) / policy
        shipped = f"; its shipped {env.cfg.dims}-D seeds are {folder}/seed<k>.pt" if shipped_checkpoints(
            policy, folder.parent) else ""
        raise ConfigError("scenario.dims", f"is {env.cfg.dims} here, but {origin} was trained in a world with dims "
                                           f"{module.dims}: evaluate it on a {module.dims}-D scenario{shipped}")
    return module


def checkpoint_handles(path: str | os.PathLike, device: str = "cpu", member: int | None = None) -> list[PolicyHandle]:
    """Every policy a checkpoint holds: its one policy, a population's every member (as a learned
    policy's name stands for every shipped seed), or the member ``member``."""
    payload = load_checkpoint(path)
    members = members_of(payload)
    chosen = [member] if member is not None or not members else list(range(len(members)))
    return [checkpoint_handle(path, device, k, payload) for k in chosen]


def rule_handle(policy: PolicyConfig, scenario: Mapping[str, Any]) -> PolicyHandle:
    from .baselines import REQUIRED_EXTRAS, controller_params, make_baseline

    controller_params(policy)  # a bad parameter fails now, naming it
    return PolicyHandle(
        id=policy.id, name=policy.name, kind="rule", reading=None, scenario=dict(scenario), extras=REQUIRED_EXTRAS,
        origin=f"baseline:{policy.id}", build_for=lambda env: make_baseline(policy, env.cfg))


def module_device(module: Any, default: str = "cpu") -> str:
    """Where a module's parameters (else buffers) live; ``default`` for anything without either."""
    for tensors in ("parameters", "buffers"):
        found = getattr(module, tensors, None)
        if callable(found):
            first = next(iter(found()), None)
            if first is not None:
                return str(first.device)
    return default


def module_handle(module: Any) -> PolicyHandle:
    meta = dict(getattr(module, "flock_meta", None) or {})
    name = str(meta.get("policy") or getattr(module, "name", None) or type(module).__name__)
    return PolicyHandle(
        id=str(meta.get("policy_id", "module")), name=name, kind="module", reading=meta.get("reading"),
        scenario=dict(meta.get("policy_scenario") or {}), extras=tuple(meta.get("extras", ())), origin="module",
        build_for=lambda env: module)


def contender_handle(spec: Any, device: str = "cpu", key: str = "contenders") -> PolicyHandle:
    """A controller of the user's, as a row beside the paper's policies: a checkpoint file, or a
    factory ``f(env, **kwargs)`` returning a TensorDict module, given by its import path
    (``"mypkg.controllers.make"``), by a Python file and a function in it
    (``"examples/goal_separation.py:make"``), or as a mapping for Hydra's ``instantiate``
    (``_target_`` — either form — plus its keyword arguments, and optionally ``name``,
    ``scenario`` — the policy scenario fields it needs, e.g. ``{instinct: true}`` — and
    ``extras``, the env keys it reads). A factory may also carry those fields as its
    ``scenario`` attribute (the mapping's win). The world it flies in is
    :func:`contender_world` of them; a checkpoint flies in the world it was trained in.
    Errors name ``key``, the setting that gave ``spec``."""
    from hydra.utils import instantiate
    from omegaconf import DictConfig, OmegaConf

    if isinstance(spec, DictConfig):
        spec = OmegaConf.to_container(spec, resolve=True)
    if isinstance(spec, (str, os.PathLike)) and not is_file_target(str(spec)) and _is_path(spec):
        handle = checkpoint_handle(resolve_path(spec), device)
        handle.kind, handle.name = "contender", f"{handle.name} ({Path(spec).stem})"
        return handle
    options = {"_target_": str(spec)} if isinstance(spec, str) else dict(spec)
    if not isinstance(options.get("_target_"), str) or not options["_target_"]:
        raise ConfigError(key, f"a checkpoint path, a factory's import path or a mapping with _target_; got {spec!r}")
    target = options["_target_"]
    factory = _factory(target, key)
    del options["_target_"]
    name = str(options.pop("name", contender_name(target)))
    scenario = dict(options.pop("scenario", {}) or {})
    declared = getattr(factory, "scenario", None)
    if declared is not None and not isinstance(declared, Mapping):
        raise ConfigError(key, f"{name}: the factory's scenario attribute must be a mapping of "
                               f"{', '.join(POLICY_SCENARIO_FIELDS)}; got {type(declared).__name__}")
    scenario = {**dict(declared or {}), **scenario}
    unknown = sorted(set(scenario) - set(POLICY_SCENARIO_FIELDS))
    if unknown:
        raise ConfigError(key, f"{name}: scenario may set only {', '.join(POLICY_SCENARIO_FIELDS)}; got {unknown}")
    extras = tuple(options.pop("extras", ()) or ())
    # keyword arguments as given; a nested mapping with its own _target_ is built by Hydra
    kwargs = {k: instantiate(v) if isinstance(v, Mapping) and "_target_" in v else v for k, v in options.items()}

    def build(env: Any) -> Module:
        try:
            module = factory(env=env, **kwargs)
        except Exception as exc:
            raise ConfigError(key, f"{name}: its factory {target} raised {type(exc).__name__}: {exc}") from None
        if not callable(module) or isinstance(module, (str, bytes)):
            raise ConfigError(key, f"{name}: its factory {target} returned {describe(module)}, not a TensorDict "
                                   "module writing ('agents', 'action')")
        return module

    return PolicyHandle(id="contender", name=name, kind="contender", reading=None,
                        scenario=contender_world(scenario), extras=extras, origin=target, build_for=build)


def contender_world(declared: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The world a contender flies in, the same through every door (``evaluate contender=``,
    ``reproduce contenders=``): every policy scenario field (``POLICY_SCENARIO_FIELDS``: the field of
    view, camera slots, instinct, reward variants, action mode) at the scenarios' own value
    (``conf/scenario/train.yaml``: the field of view 0.5 pi, the instinct off), but those the
    contender declares."""
    base = compose_world("train").scenario
    return {**{k: base[k] for k in POLICY_SCENARIO_FIELDS}, **dict(declared or {})}


def world_label(fields: Mapping[str, Any]) -> str:
    """``fov 0.50 pi, instinct off``: a policy world in words (the fields that name it)."""
    import math

    parts = []
    if "fov" in fields:
        parts.append(f"fov {float(fields['fov']) / math.pi:.2f} pi")
    if "instinct" in fields:
        parts.append("instinct " + ("on" + ("" if fields.get("tangential", True) else ", no tangential term")
                                    if fields["instinct"] else "off"))
    for key, usual in (("collision_reward_source", "scan"), ("action_mode", "policy")):
        if key in fields and fields[key] != usual:
            parts.append(f"{key} {fields[key]}")
    return ", ".join(parts) or "the scenario's own"


def describe(value: Any) -> str:
    """What a contender returned, in a few words: ``None``, ``a str ('abc')``, ``a Tensor``."""
    if value is None:
        return "None"
    text = repr(value)
    text = text if len(text) <= 40 else text[:37] + "..."
    return f"a {type(value).__name__} ({text})" if isinstance(value, (str, bytes, int, float)) else \
        f"a {type(value).__name__}"


def _factory(target: str, key: str) -> Callable[..., Any]:
    """The callable ``target`` names: ``pkg.module.function`` (importable from ``sys.path``)
    or ``path/to/file.py:function`` (loaded from that file, relative to the working folder)."""
    import importlib.util

    from hydra.utils import get_method

    if not is_file_target(target):
        try:
            return get_method(target)
        except Exception as exc:
            raise ConfigError(key, f"cannot import the factory {target!r}: {exc} (an import path needs its package "
                                   "on PYTHONPATH; a file can be given as path/to/file.py:function)") from None
    file, _, function = target.rpartition(":")
    path = Path(file).expanduser().resolve()
    if not path.is_file():
        raise ConfigError(key, f"{target}: no file {path}")
    spec = importlib.util.spec_from_file_location(f"flock_contender_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Exception as exc:
        raise ConfigError(key, f"{target}: loading {path} failed: {type(exc).__name__}: {exc}") from None
    found = getattr(module, function, None)
    if not callable(found):
        raise ConfigError(key, f"{target}: {path.name} defines no function {function!r}")
    return found


def _is_path(policy: Any) -> bool:
    if isinstance(policy, os.PathLike):
        return True
    text = str(policy)
    return text.endswith(".pt") or "/" in text or os.sep in text or Path(text).is_file()


def resolve(policy: Any, reading: str | None = None, checkpoints_dir: str | os.PathLike | None = None,
            device: str = "cpu", policy_config: PolicyConfig | None = None,
            member: int | None = None, dims: int = 2) -> list[PolicyHandle]:
    """Every policy ``policy`` stands for (one per shipped seed for a learned name).

    Args:
        policy: a policy id or paper name, a checkpoint file or run folder, a TensorDict
            module, or a :class:`PolicyHandle`.
        reading: the world's reading (default: the composed default). A checkpoint of another
            reading is refused; a learned name looks under ``<checkpoints_dir>/<reading>/``.
        checkpoints_dir: the shipped checkpoints' root (default: ``checkpoints_dir`` of
            conf/world.yaml).
        policy_config: the policy's composed config, when the caller has it (an app composed
            with the user's config folders); otherwise ``conf/policy/<id>.yaml`` is composed.
        member: of a population's checkpoint, the member to take (``None``: every member, each
            named by its member and seed); refused for anything else.
        dims: the world's dimension: a learned name's seeds for a 3-D world are those under
            ``<checkpoints_dir>/<reading>/threed/`` (``make ship-threed``).
    """
    if member is not None and not _is_path(policy):
        raise ConfigError("member", f"chooses a member of a population's checkpoint; {policy!r} is not a checkpoint")
    if isinstance(policy, PolicyHandle):
        handles = [policy]
    elif callable(policy) and not isinstance(policy, (str, os.PathLike)):
        handles = [module_handle(policy)]
    elif _is_path(policy):
        path = resolve_path(policy)
        if not path.is_file():
            raise no_checkpoint(path)
        handles = checkpoint_handles(path, device, member)
    else:
        config, scenario = (policy_config, {}) if policy_config is not None else policy_config_of(str(policy), reading)
        if config.kind == "rule":
            handles = [rule_handle(config, scenario)]
        else:
            reading = reading or compose_world().scenario.reading
            root = Path(checkpoints_dir if checkpoints_dir is not None else default_checkpoints_dir())
            folder = seeds_dir(root, reading, dims)
            paths = shipped_checkpoints(config.id, folder)
            if not paths:
                raise CheckpointError(
                    f"{config.name} is a learned policy and {folder / config.id} holds no seed*.pt"
                    f"{_shipped_for(folder, dims)}; point checkpoints_dir= at the shipped checkpoints, train it "
                    f"(scripts/train.py policy={config.id} reading={reading}) or pass a checkpoint path")
            handles = [checkpoint_handle(p, device) for p in paths]
    if reading is not None:
        for handle in handles:
            handle.check_reading(reading)
    return handles


def _shipped_for(folder: Path, dims: int) -> str:
    """`` (the N-D policies there: a, b)``: what the folder holds for that dimension, if anything."""
    held = sorted(p.name for p in folder.glob("*") if p.is_dir() and any(p.glob("seed*.pt"))
                  and p.name not in DIMS_FOLDER.values()) if folder.is_dir() else []
    return f" (the {dims}-D policies there: {', '.join(held)})" if held else ""


def make_policy(policy: Any, env: Any, device: str | None = None) -> Module:
    """A TensorDict module for ``env``: a checkpoint's or module's policy, a rule-based
    controller, or, for a learned policy's id, a freshly initialised shared actor sized from
    the env's specs (to script your own training). On ``device``, by default the env's.

    The env should be built in the policy's world: ``FlockingEnv(..., policy_id=<id>)``, and
    for the rule-based ones with ``extras=("physics", "laser")``.
    """
    if isinstance(policy, str) and not _is_path(policy):
        config, _ = policy_config_of(policy, env.cfg.reading)
        if config.kind == "learned":
            from .models import make_actor

            algo = compose_world("train", env.cfg.reading, config.id).algo
            return make_actor(env, stochastic=algo.name != "ddpg", hidden=algo.hidden, depth=algo.depth)
    (handle,) = resolve(policy, env.cfg.reading, device=str(env.device if device is None else device))[:1]
    return handle.build(env)


__all__ = ["PolicyHandle", "checkpoint_handle", "checkpoint_handles", "module_device",
           "contender_handle", "contender_world", "describe", "world_label", "make_policy", "module_handle", "policy_config_of",
           "policy_id", "resolve", "rule_handle", "shipped_checkpoints"]
