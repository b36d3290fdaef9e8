"""Where the package's ``conf/`` and shipped checkpoints are, and a config group's choices (a file
listing: no composition, no Hydra)."""

from __future__ import annotations

import importlib.util
from pathlib import Path


def _packaged(name: str, marker: str = "") -> Path:
    """``flock_torchrl.<name>`` in an installed wheel (mapped to the repository's folder by an
    editable install), else the source checkout's ``<name>/``."""
    spec = importlib.util.find_spec(f"flock_torchrl.{name}")
    if spec is not None and spec.submodule_search_locations:
        for location in spec.submodule_search_locations:
            if (Path(location) / marker).exists() if marker else Path(location).is_dir():
                return Path(location)
    return Path(__file__).resolve().parent.parent.parent / name


def config_dir() -> Path:
    """The ``conf/`` folder: packaged as ``flock_torchrl.conf`` in an installed wheel (and
    mapped to the repository's ``conf/`` by an editable install), else the source checkout's."""
    return _packaged("conf", "train.yaml")


def shipped_checkpoints_dir() -> Path:
    """The shipped checkpoints: packaged as ``flock_torchrl.checkpoints`` in a wheel (the
    repository's ``checkpoints/`` in an editable install), else the source checkout's. It is the
    default of ``checkpoints_dir`` (conf/world.yaml), so the apps find them from any folder."""
    return _packaged("checkpoints")


CONF_DIR = config_dir()


def available(group: str) -> list[str]:
    """The choices of a config group in the package's ``conf/`` (YAML stems)."""
    folder = CONF_DIR / group
    return sorted(p.stem for p in folder.glob("*.yaml")) if group and folder.is_dir() else []


__all__ = ["CONF_DIR", "available", "config_dir", "shipped_checkpoints_dir"]
