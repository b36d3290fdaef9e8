"""Names made from values: a run's folder, a selection's subfolder, a contender's row, the folder
a config was read from. The composer registers them as resolvers (``${flock.run_name:...}``)."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path
from typing import Any, Mapping

from omegaconf import DictConfig, OmegaConf

from .checks import ConfigError, safe_name


def run_name(base: Any, overrides: Any = "") -> str:
    """``seed0`` or ``seed0__algo.lr_actor-0.001__scenario.tau_v-0.5``: the folder of one run.

    ``overrides`` is Hydra's ``override_dirname`` (``key-value`` pairs joined by ``__``, the
    task overrides not already in the path, sorted; conf/train.yaml sets the separators so that
    a folder name needs no quoting in a Hydra override). Anything else becomes ``_``.
    """
    overrides = str(overrides or "")
    return safe_name(str(base) + (f"__{overrides}" if overrides else ""))


def selection_dir(overrides: Any = "") -> str:
    """``""`` for a table of the whole selection, else ``/<selection>``: the reproduce app's
    subfolder for a table of some rows, contenders or other checkpoints (Hydra's
    ``override_dirname`` of those keys), so it never replaces another selection's table. A
    name over 120 characters keeps its start and a digest of the whole."""
    name = safe_name(str(overrides or ""))
    if not name:
        return ""
    if len(name) > 120:
        name = f"{name[:100]}__{hashlib.sha256(name.encode()).hexdigest()[:12]}"
    return "/" + name


def config_folder(sources: Any, config_name: Any) -> str:
    """The folder Hydra read the primary config ``<config_name>.yaml`` from: the first ``file``
    source of ``hydra.runtime.config_sources`` that holds it. A run's ``resume.yaml`` sets its
    output folder to this, so a copied or moved run folder continues where it stands now."""
    for source in sources or ():
        path = Path(str(source["path"]))
        if str(source["schema"]) == "file" and (path / f"{config_name}.yaml").is_file():
            return str(path.resolve())
    raise ConfigError("hydra.run.dir", f"no folder of the config search path holds {config_name}.yaml")


def is_file_target(text: str) -> bool:
    """``path/to/file.py:function``: a contender's factory given as a file and a function."""
    return bool(re.fullmatch(r".+\.py:[A-Za-z_][A-Za-z0-9_]*", text))


def contender_name(spec: Any) -> str:
    """A contender's row name: a mapping's ``name``, else the function's, or its module's (file's)
    for ``make`` / ``build`` / ``create`` / ``factory``; a checkpoint's file stem."""
    if isinstance(spec, Mapping):
        if spec.get("name"):
            return str(spec["name"])
        spec = spec.get("_target_", "")
    target = str(spec)
    if target.endswith(".pt"):
        return Path(target).stem
    where, _, function = target.rpartition(":" if is_file_target(target) else ".")
    if function not in ("make", "build", "create", "factory"):
        return function
    return Path(where).stem if is_file_target(target) else where.rpartition(".")[2] or function


def evaluated_name(policy_id: Any, contender: Any = None) -> str:
    """The evaluate app's folder for what it evaluates: the policy's id, or
    ``contender-<name>`` when a contender flies (``${flock.evaluated:...}`` in conf/evaluate.yaml)."""
    if contender is None or contender == "":
        return str(policy_id)
    if isinstance(contender, DictConfig):
        contender = OmegaConf.to_container(contender, resolve=True)
    return "contender-" + safe_name(contender_name(contender))


__all__ = ["config_folder", "contender_name", "evaluated_name", "is_file_target", "run_name", "selection_dir"]
