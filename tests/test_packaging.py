"""The package's declared dependencies and its quiet build: every third-party module the package
imports is one of pyproject's dependencies, and building the wheel raises no setuptools warning
about checkpoints/' data folders."""

from __future__ import annotations

import ast
import os
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


# ---------------------------------------------------------------------------- torch: the releases the tests run on
# The torch releases the tests run on, each with where: pyproject admits these minor releases and no
# other, so `pip install .` never resolves a torch nobody tested (it took 2.14.1+cu130, 5.9 GB).
TESTED_TORCH = {
    "2.13": "the whole suite, make test / make test-all (the Makefile installs torch==2.13.0, the CPU build)",
    "2.11": "tests/test_cuda.py and the GPU benchmark rows on an H200 with 2.11.0+cu130 (shared/gpu/README.md)",
}
# Releases on the registry when this was written (pip index versions torch, 2026-12-05).
TORCH_RELEASES = ["2.5.0", "2.5.1", "2.6.0", "2.7.0", "2.7.1", "2.8.0", "2.9.0", "2.9.1", "2.10.0", "2.11.0", "2.12.0",
                  "2.12.1", "2.13.0", "2.13.0+cpu", "2.14.0", "2.14.1", "2.15.0"]


def torch_requirement():
    from packaging.requirements import Requirement

    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    (torch_dep,) = [Requirement(d) for d in deps if Requirement(d).name == "torch"]
    return torch_dep


def test_the_torch_range_admits_exactly_the_releases_the_tests_run_on():
    """pyproject's torch range admits a release if and only if its minor release is one the tests
    run on: the Makefile's pin and the torch running this suite among them; 2.14 and 2.15 (which
    pip took before) and 2.12 (never tested) not."""
    import torch
    from packaging.version import Version

    spec = torch_requirement().specifier
    admitted = {v for v in TORCH_RELEASES if spec.contains(v, prereleases=False)}
    expected = {v for v in TORCH_RELEASES if f"{Version(v).major}.{Version(v).minor}" in TESTED_TORCH}
    assert admitted == expected, (str(spec), sorted(admitted ^ expected))
    pin = re.search(r"^TORCH\s*\?=\s*torch==(\S+)", (ROOT / "Makefile").read_text(), re.M).group(1)
    assert spec.contains(pin) and spec.contains(torch.__version__), (str(spec), pin, torch.__version__)
    # README says, next to `pip install .`, which releases and how to get the CPU build first.
    readme = " ".join((ROOT / "README.md").read_text().split())
    at = readme.index("`pip install .` works too")
    said = readme[at:at + 600]
    assert "2.13 and 2.11" in said and "pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu" in said
    assert "your own CUDA build" in said


# ---------------------------------------------------------------------------- the wheel
@pytest.mark.slow
def test_the_wheel_names_shipped_checkpoints_as_a_clone_does_and_requires_a_tested_torch(tmp_path):
    """From the installed wheel, in a folder of its own: flock-evaluate policy=policy3_g
    scenario=wall3d flies the five 3-D seeds (it loaded the 2-D ones and refused), a checkpoint
    is named by its path in the shipped collection (or from a clone's root), a missing one says
    where the shipped ones are; the wheel's metadata requires pyproject's torch range."""
    import zipfile

    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md", "flock_torchrl", "conf", "checkpoints"):
        (shutil.copytree if (ROOT / name).is_dir() else shutil.copy)(ROOT / name, source / name)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(tmp_path), str(source)], check=True, capture_output=True, timeout=300)
    (wheel,) = tmp_path.glob("flock_torchrl-*.whl")
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(site)
        metadata = next(n for n in archive.namelist() if n.endswith(".dist-info/METADATA"))
        requires = [line.split(": ", 1)[1] for line in archive.read(metadata).decode().splitlines()
                    if line.startswith("Requires-Dist: ")]
    from packaging.requirements import Requirement

    torch_dep = [Requirement(r).specifier for r in requires if Requirement(r).name == "torch"]
    assert torch_dep == [torch_requirement().specifier], requires
    shipped = site / "flock_torchrl" / "checkpoints"
    away = tmp_path / "elsewhere"
    away.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site), "OMP_NUM_THREADS": "1"}

    def flock_evaluate(*args: str) -> subprocess.CompletedProcess:
        code = (f"import sys; sys.argv = ['flock-evaluate', *{list(args)!r}]; "
                "from flock_torchrl.cli import evaluate_main; evaluate_main()")
        return subprocess.run([sys.executable, "-c", code], cwd=away, env=env, capture_output=True, text=True,
                              timeout=600)

    proc = flock_evaluate("policy=policy3_g", "scenario=wall3d", "episodes=1", "scenario.max_steps=20")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "pooled over 5 checkpoints" in proc.stdout and str(shipped / "paper_fit" / "threed" / "policy3_g") in proc.stdout
    for name in ("paper_fit/threed/policy3_g/seed1.pt", "checkpoints/paper_fit/threed/policy3_g/seed1.pt"):
        proc = flock_evaluate(f"checkpoint={name}", "scenario=wall3d", "episodes=1", "scenario.max_steps=20")
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert str(shipped / "paper_fit" / "threed" / "policy3_g" / "seed1.pt") in proc.stdout, proc.stdout[-2000:]
    proc = flock_evaluate("checkpoint=paper_fit/threed/policy3_g/seed99.pt", "scenario=wall3d", "episodes=1")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr[-3000:]
    assert "no checkpoint at paper_fit/threed/policy3_g/seed99.pt" in proc.stderr and str(shipped) in proc.stderr
