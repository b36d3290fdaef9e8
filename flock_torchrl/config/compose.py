"""The one module that touches Hydra: the composer, the schemas' registration as Hydra root
configs and the resolvers the YAMLs use. Nothing happens when it is imported: :func:`register`
runs when a config is composed (:func:`compose`, and the apps' ``main`` before ``hydra.main``).

:func:`compose` is Hydra's compose API on the package's ``conf/`` for Python callers
(``make_train_config``, :func:`scenario_config`, :func:`app_config`); the scripts use
``hydra.main`` on the same folder, with the user's ``--config-dir`` and ``hydra.searchpath``
added by Hydra itself. ``docs/specification.md`` says what every scenario field means.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

from hydra import compose as hydra_compose
from hydra import initialize_config_dir
from hydra.core.config_store import ConfigStore
from hydra.core.global_hydra import GlobalHydra
from hydra.errors import HydraException
from hydra.initialize import get_gh_backup, restore_gh_from_backup
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from .apps import APP_SCHEMAS, EvaluateConfig, TrainConfig
from .checks import ConfigError, Schema, config_error, safe_name
from .groups import ExperimentConfig, LoggerConfig, PolicyConfig
from .learners import ALGO_SCHEMAS, sac_target_entropy
from .names import config_folder, evaluated_name, run_name, selection_dir
from .paths import CONF_DIR, shipped_checkpoints_dir
from .scenario import FIELDS_BEFORE, SCENARIO_FIELDS, ScenarioConfig, check_booleans

# The resolvers the YAMLs use, by name.
RESOLVERS = {
    "pi": lambda k=1.0: float(k) * math.pi,   # ``${pi:0.5}`` = 0.5 pi: angles written as the paper writes them
    "flock.run_name": run_name,
    "flock.target_entropy": sac_target_entropy,   # ``${flock.target_entropy:${scenario.dims}}``: -|A|
    "flock.shipped_checkpoints": lambda: str(shipped_checkpoints_dir()),
    "flock.evaluated": lambda policy, contender=None: evaluated_name(policy, contender),
    "flock.selection": selection_dir,
    "flock.safe_name": safe_name,
    # ``${flock.concat:[a,b],${some_list}}``: lists joined (one list written once, used twice).
    "flock.concat": lambda *lists: [x for items in lists for x in items],
    # ``${flock.config_folder:${hydra.runtime.config_sources},${hydra.job.config_name}}``: where
    # the primary config was read (a run folder's resume.yaml is its own output folder).
    "flock.config_folder": config_folder,
}


# As Hydra root configs, the apps' ``algo`` is left untyped: the learner's own YAML types it
# (``/sac_schema@_here_`` in conf/algo/sac.yaml), and a run's resume.yaml, which saves it as plain
# values, composes too; :meth:`WorldApp.structured` types it when the config is checked.
@dataclasses.dataclass
class _TrainRoot(TrainConfig):
    algo: Any = None


@dataclasses.dataclass
class _EvaluateRoot(EvaluateConfig):
    algo: Any = None


HYDRA_ROOTS: dict[str, type] = {**APP_SCHEMAS, "train": _TrainRoot, "evaluate": _EvaluateRoot}


def register() -> None:
    """The resolvers, and every schema in Hydra's ConfigStore as a root config (``<name>_schema``):
    the YAMLs name them in their defaults lists (a group's file as ``/scenario_schema@_here_``), so
    they type the composition without appearing among a group's choices. Safe to call again: what is
    stored already stays."""
    for name, resolver in RESOLVERS.items():
        if not OmegaConf.has_resolver(name):
            OmegaConf.register_new_resolver(name, resolver)
    cs = ConfigStore.instance()
    schemas: dict[str, type] = {"scenario": ScenarioConfig, "policy": PolicyConfig, "experiment": ExperimentConfig,
                                "logger": LoggerConfig, **ALGO_SCHEMAS, **HYDRA_ROOTS}
    for name, schema in schemas.items():
        if f"{name}_schema.yaml" not in cs.repo:  # storing converts the dataclass: a quarter of a compose
            cs.store(name=f"{name}_schema", node=schema)


def compose(config_name: str, overrides: Sequence[str] = (), return_hydra_config: bool = False) -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with Hydra's compose API and command-line style
    ``overrides``, as ``hydra.main`` does for the scripts.

    Safe inside a running Hydra app: the app's global Hydra state is put back afterwards.
    Errors become :class:`ConfigError` (Hydra's message, the key where there is one).
    """
    register()
    backup = get_gh_backup()
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
            cfg = hydra_compose(config_name, overrides=list(overrides), return_hydra_config=return_hydra_config)
        check_boolean_overrides(cfg, overrides)
        return cfg
    except OmegaConfBaseException as exc:
        raise config_error(exc) from exc
    except HydraException as exc:
        cause = exc.__cause__
        if isinstance(cause, OmegaConfBaseException):
            raise config_error(cause) from exc
        # Hydra's message up to its (long) listing of the config search path.
        raise ConfigError(hydra_key(exc), " ".join(str(exc).split("Config search path")[0].split())) from exc
    finally:
        restore_gh_from_backup(backup)


def check_boolean_overrides(cfg: DictConfig, overrides: Sequence[str]) -> None:
    """A command-line value of a boolean key is ``true`` or ``false``: OmegaConf would take ``2``,
    ``yes`` or ``on`` as true, and a typo (``instinct=2``) would pass unseen. Sweeps are checked
    job by job (each job's overrides are plain values)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    try:
        parsed = OverridesParser.create().parse_overrides([str(o) for o in overrides])
    except HydraException:  # Hydra has already named a malformed override
        return
    for override in parsed:
        if override.is_hydra_override() or override.is_delete() or override.is_sweep_override():
            continue
        key = override.key_or_group
        try:
            composed = OmegaConf.select(cfg, key, throw_on_missing=False)
        except OmegaConfBaseException:
            continue
        if isinstance(composed, bool) and not isinstance(override.value(), bool):
            raise ConfigError(key, f"must be true or false, got {override.get_value_element_as_str()}")


def hydra_key(exc: BaseException) -> str:
    """The config group or key a Hydra error is about, from its attributes."""
    missing = getattr(exc, "missing_cfg_file", None)
    if missing:
        return str(missing).rpartition("/")[0] or str(missing)
    return ""


# The config groups an app's Python call selects by name (the rest are values).
GROUPS = ("scenario", "reading", "policy", "experiment", "logger", "algo")


def app_config(app: str, overrides: Sequence[str] = (), **values: Any) -> Schema:
    """``conf/<app>.yaml`` composed and checked: the one object an app's function takes.

    Args:
        app: ``train``, ``evaluate``, ``reproduce``, ``figures``, ``scaling``, ``tune_baselines``, ``ship``.
        overrides: command-line style overrides, e.g. ``["episodes=100", "only=[Policy3-G]"]``.
        **values: group choices by name (``reading="literal"``, ``scenario="s2"``) and any field's
            value, as Python values (``episodes=6``, ``checkpoints_dir=Path(...)``,
            ``contenders=[{"_target_": ...}]``), set after the composition.

    Example:
        >>> cfg = app_config("reproduce", table=3, reading="paper_fit", episodes=100, only=["Policy-MA"])
    """
    choices = [f"{k}={v}" for k, v in values.items() if k in GROUPS]
    node = compose(app, [*choices, *overrides])
    try:
        for key, value in values.items():
            if key not in GROUPS:
                OmegaConf.update(node, key, str(value) if isinstance(value, Path) else value, merge=False)
    except OmegaConfBaseException as exc:
        raise config_error(exc) from exc
    return APP_SCHEMAS[app].from_config(node)


@functools.lru_cache(maxsize=1)
def world_values() -> DictConfig:
    """``conf/world.yaml``'s own values (the shared ones), read when first asked for."""
    register()
    return OmegaConf.load(CONF_DIR / "world.yaml")


def eval_seed() -> int:
    """The evaluation seed every policy shares (docs/specification.md section 5): conf/world.yaml."""
    return int(world_values().eval_seed)


def default_checkpoints_dir() -> Path:
    """Where the shipped checkpoints are (``checkpoints_dir`` of conf/world.yaml)."""
    return Path(str(world_values().checkpoints_dir))


# ---------------------------------------------------------------------------- scenarios
def scenario_overrides(scenario: str = "train", reading: str | None = None, policy: str | None = None) -> list[str]:
    """The override strings that select a scenario, a reading and (optionally) a policy."""
    chosen = {"scenario": scenario, "reading": reading, "policy": policy}
    return [f"{group}={name}" for group, name in chosen.items() if name is not None]


def compose_world(scenario: str = "train", reading: str | None = None, policy: str | None = None,
                  overrides: Sequence[str] = ()) -> DictConfig:
    """``conf/world.yaml``: a scenario, a reading and optionally a policy, composed by Hydra."""
    return compose("world", [*scenario_overrides(scenario, reading, policy), *overrides])


def scenario_config(scenario: str | Mapping[str, Any] | DictConfig | ScenarioConfig = "train",
                    reading: str | None = None, policy: str | None = None, **fields: Any) -> ScenarioConfig:
    """A checked :class:`ScenarioConfig`: the one helper that resolves a scenario's name.

    Args:
        scenario: a name under ``conf/scenario/`` (composed with the reading and policy by
            Hydra), or a complete scenario (mapping, DictConfig or ScenarioConfig).
        reading: ``literal`` or ``paper_fit`` (default: the one ``conf/world.yaml`` selects).
        policy: a policy id whose scenario fields (``fov``, ``instinct`` ...) apply.
        **fields: any scenario field, applied last.
    """
    unknown = sorted(set(fields) - SCENARIO_FIELDS)
    if unknown:
        raise ConfigError(f"scenario.{unknown[0]}", f"unknown field; known: {', '.join(sorted(SCENARIO_FIELDS))}")
    if isinstance(scenario, str):
        node: Any = compose_world(scenario.lower(), reading, policy).scenario
    else:
        if reading is not None or policy is not None:
            raise ConfigError("scenario", "reading= and policy= select YAMLs; pass them with a scenario name")
        if isinstance(scenario, ScenarioConfig) and not fields:
            return ScenarioConfig.from_config(scenario)
        node = dataclasses.asdict(scenario) if isinstance(scenario, ScenarioConfig) else scenario
    check_booleans(fields)
    if isinstance(node, Mapping):
        check_booleans(node)
    try:
        node = OmegaConf.merge(OmegaConf.structured(ScenarioConfig), node)
        for name, value in fields.items():
            OmegaConf.update(node, name, value, merge=False)
    except OmegaConfBaseException as exc:
        raise config_error(exc, "scenario") from exc
    return ScenarioConfig.from_config(node)


def saved_scenario(saved: Mapping[str, Any]) -> dict[str, Any]:
    """A scenario a checkpoint or a run folder saved, as this version's fields: fields added
    since (e.g. the drawn obstacles) take the training scenario's values of its reading
    (conf/scenario/train.yaml), which mean "as it was", or, where today's default changed what a
    world does (``FIELDS_BEFORE``: the 3-D instinct's taper, the laser's vertical pair), the
    value that does what it did."""
    missing = SCENARIO_FIELDS - set(saved)
    if not missing:
        return dict(saved)
    base = OmegaConf.to_container(compose_world("train", str(saved.get("reading", "paper_fit"))).scenario, resolve=True)
    return {**{k: FIELDS_BEFORE.get(k, base[k]) for k in missing}, **dict(saved)}


def plain(cfg: Any) -> Any:
    """A config as plain, resolved Python containers (for saving and logging)."""
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)
    if dataclasses.is_dataclass(cfg) and not isinstance(cfg, type):
        return dataclasses.asdict(cfg)
    return cfg


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}`` (lists stay values): hyperparameters for loggers."""
    out: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten(value, f"{name}."))
        else:
            out[name] = value
    return out


__all__ = ["GROUPS", "HYDRA_ROOTS", "RESOLVERS", "app_config", "compose", "compose_world", "default_checkpoints_dir",
           "eval_seed", "flatten", "hydra_key", "plain", "register", "saved_scenario", "scenario_config",
           "scenario_overrides", "world_values"]
