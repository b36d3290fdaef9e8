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

# The shipped collection's layout: <checkpoints_dir>/<reading>/<policy>/seed<k>.pt for the 2-D
# policies, and the 3-D ones (docs/specification.md section 11; `make ship-threed`) in their own
# folder beside them, <checkpoints_dir>/<reading>/threed/<policy>/seed<k>.pt.
DIMS_FOLDER = {2: "", 3: "threed"}
# A path from a clone's root (checkpoints/paper_fit/...) names the same file as one relative to the
# collection (paper_fit/...).
CLONE_FOLDER = "checkpoints"


def seeds_dir(root: str | Path, reading: str, dims: int = 2) -> Path:
    """Where a learned policy's shipped seeds lie, by policy id, under ``root`` (the shipped
    checkpoints, or a ``checkpoints_dir`` of yours laid out the same): ``<root>/<reading>`` for a
    2-D world, ``<root>/<reading>/threed`` for a 3-D one."""
    folder = Path(root) / reading
    return folder / DIMS_FOLDER[dims] if DIMS_FOLDER.get(dims) else folder


def shipped_path(path: str | Path) -> Path:
    """``path`` as given, unless it is relative, names nothing from the working folder and names a
    shipped checkpoint: then that one. Relative to the shipped collection
    (``paper_fit/threed/policy3_g/seed0.pt``) or as from a clone's root
    (``checkpoints/paper_fit/policy3_g/seed0.pt``), a shipped checkpoint is named the same way from
    any folder, in a clone or from the wheel."""
    path = Path(path)
    if path.is_absolute() or path.exists():
        return path
    root = shipped_checkpoints_dir()
    parts = path.parts
    candidates = [root / path]
    if len(parts) > 1 and parts[0] == CLONE_FOLDER:
        candidates.append(root.joinpath(*parts[1:]))
    return next((c for c in candidates if c.exists()), path)


def where_shipped() -> str:
    """Where the shipped checkpoints are and how to name one, in words (for an error's end)."""
    return (f"the shipped checkpoints are in {shipped_checkpoints_dir()} (<reading>/<policy>/seed<k>.pt; 3-D: "
            f"<reading>/threed/<policy>/seed<k>.pt), and a path relative to that folder names one from any "
            "folder, e.g. paper_fit/threed/policy3_g/seed0.pt")


def available(group: str) -> list[str]:
    """The choices of a config group in the package's ``conf/`` (YAML stems)."""
    folder = CONF_DIR / group
    return sorted(p.stem for p in folder.glob("*.yaml")) if group and folder.is_dir() else []


__all__ = ["CLONE_FOLDER", "CONF_DIR", "DIMS_FOLDER", "available", "config_dir", "seeds_dir", "shipped_checkpoints_dir",
           "shipped_path", "where_shipped"]
