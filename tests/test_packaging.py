"""The package's declared dependencies and its quiet build: every third-party module the package
imports is one of pyproject's dependencies, and building the wheel raises no setuptools warning
about checkpoints/' data folders."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
from importlib.metadata import packages_distributions

import pytest

from helpers import ROOT


def imported_top_modules() -> dict[str, str]:
    """Top-level module -> the first file importing it, over every absolute import of the package."""
    found: dict[str, str] = {}
    for path in sorted((ROOT / "flock_torchrl").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                found.setdefault(name.split(".")[0], str(path.relative_to(ROOT)))
    return found


def declared() -> set[str]:
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    return {re.split(r"[<>=!~\[; ]", d, maxsplit=1)[0].lower().replace("_", "-") for d in deps}


def test_every_imported_third_party_module_is_declared():
    dists = packages_distributions()
    stdlib = set(sys.stdlib_module_names) | {"flock_torchrl"}
    missing = {}
    for module, where in imported_top_modules().items():
        if module in stdlib:
            continue
        names = {d.lower().replace("_", "-") for d in dists.get(module, [module])}
        if not names & declared():
            missing[module] = where
    assert not missing, f"imported but not declared in pyproject's dependencies: {missing}"


def test_the_rule_sees_an_undeclared_import():
    """The check above can fail: scipy, which report/seeds.py imports, is found among the imports
    and maps to its distribution."""
    modules = imported_top_modules()
    assert modules.get("scipy", "").endswith("seeds.py") or "scipy" in modules
    assert "scipy" in {d.lower() for d in packages_distributions()["scipy"]}
    assert "scipy" in declared() and "not-a-package" not in declared()


@pytest.mark.slow
def test_building_the_wheel_warns_about_no_data_folder(tmp_path):
    """checkpoints/' sub-folders are data: the build takes them by package-data glob and says
    nothing about packages absent from the configuration."""
    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md", "flock_torchrl", "conf", "checkpoints"):
        (shutil.copytree if (ROOT / name).is_dir() else shutil.copy)(ROOT / name, source / name)
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w",
                           str(tmp_path), str(source)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = proc.stdout + proc.stderr
    assert "absent from the `packages` configuration" not in out, out[-2000:]
    assert list(tmp_path.glob("flock_torchrl-*.whl"))
