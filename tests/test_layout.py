"""The package's layers: imports only point down config/io -> world -> policies -> run -> report -> cli;
the repository's tools above it (``benchmarks/``, ``scripts/``) use its public names and nothing
in the package imports them; no module of the whole tree, tools and tests included, imports itself
back through others."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "flock_torchrl"
ROOT = PACKAGE.parent
TOOLS = [*(ROOT / "benchmarks").rglob("*.py"), *(ROOT / "scripts").glob("*.py")]
LAYERS = ["config", "io", "world", "policies", "run", "report", "prerun", "cli"]
RANK = {"config": 0, "io": 0, "world": 1, "policies": 2, "run": 3, "report": 4, "prerun": 5, "cli": 5}


def layer_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in RANK else "package"


def imports(path: Path) -> set[str]:
    """Absolute names of the flock_torchrl modules ``path`` imports (relative imports resolved)."""
    module = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            if name.startswith("flock_torchrl"):
                found.add(name)
                found.update(f"{name}.{alias.name}" for alias in node.names if name == "flock_torchrl")
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("flock_torchrl"))
    return found


@pytest.mark.parametrize("path", sorted(p for p in PACKAGE.rglob("*.py") if p.name != "__init__.py"),
                         ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_only_point_down(path):
    own = layer_of(".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts))
    for name in imports(path):
        other = layer_of(name)
        if other == "package" or other == own:
            continue
        assert RANK[other] <= RANK[own], f"{path.relative_to(PACKAGE)} ({own}) imports {name} ({other})"


def test_no_private_name_crosses_a_module():
    """A module imports only the public names of another (no ``from .x import _y``)."""
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("flock_torchrl")):
                private = [a.name for a in node.names if a.name.startswith("_")]
                assert not private, f"{path.relative_to(PACKAGE)} imports {private} from {node.module}"


def test_the_package_never_imports_the_repositorys_tools():
    """``benchmarks/`` and ``scripts/`` are not in the wheel: a module of the package that
    imported them would work in a checkout and fail once installed."""
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            tools = [n for n in names if n.split(".")[0] in ("benchmarks", "scripts", "tests")]
            assert not tools, f"{path.relative_to(ROOT)} imports {tools}"


def test_the_tools_use_only_public_names_of_the_package():
    assert any(p.parent.name == "benchmarks" for p in TOOLS)
    for path in TOOLS:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in ("flock_torchrl", "benchmarks"):
                private = [a.name for a in node.names if a.name.startswith("_")]
                hidden = [part for part in node.module.split(".") if part.startswith("_")]
                assert not private and not hidden, f"{path.relative_to(ROOT)} imports {private or hidden}"


def test_benchmarks_are_outside_the_wheel_and_every_console_command_exists():
    """``benchmarks/`` is a tool of the repository (``make benchmark``), not a package of the
    wheel; every console command of pyproject.toml names a function the package has."""
    import importlib

    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert not [p for p in project["tool"]["setuptools"]["packages"] if "bench" in p]
    for command, target in project["project"]["scripts"].items():
        module, function = target.split(":")
        assert callable(getattr(importlib.import_module(module), function, None)), f"{command} -> {target}"
    assert "-m benchmarks.run" in (ROOT / "Makefile").read_text()


DOC_SOURCES = [*PACKAGE.rglob("*.py"), *(PACKAGE.parent / "conf").rglob("*.yaml"), *(PACKAGE.parent / "docs").glob("*.md"),
               PACKAGE.parent / "README.md", *TOOLS, *(ROOT / "benchmarks").rglob("*.yaml")]


def test_docs_name_files_and_sections_that_exist():
    """Every ``docs/<file>.md`` a file names exists, a quoted section of it is one of its headings,
    and ``docs/specification.md section N`` is one of the specification's numbered sections."""
    import re

    root = PACKAGE.parent
    for source in DOC_SOURCES:
        text = source.read_text()
        for name in set(re.findall(r"docs/([A-Za-z_]+\.md)", text)):
            assert (root / "docs" / name).is_file(), f"{source.relative_to(root)} names docs/{name}"
        for name, section in re.findall(r'docs/([A-Za-z_]+\.md),? "([^"]+)"', text):
            headings = [h.lstrip("#").strip() for h in (root / "docs" / name).read_text().splitlines()
                        if h.startswith("#")]
            assert any(h.startswith(section) for h in headings), \
                f"{source.relative_to(root)} names section {section!r} of docs/{name}"
        spec = [h for h in (root / "docs" / "specification.md").read_text().splitlines() if h.startswith("## ")]
        for number in re.findall(r"docs/specification\.md,? sections? (\d+)", text):
            assert any(h.startswith(f"## {number}.") for h in spec), f"{source.relative_to(root)}: section {number}"
        for stray in ("BASELINES.md", "SPEC.md", "STYLE.md"):
            assert stray not in text, f"{source.relative_to(root)} names {stray}, a file outside the repository"


def _marked_slow(decorators: list[ast.expr]) -> bool:
    return any(ast.unparse(d).endswith("mark.slow") for d in decorators)


def test_every_test_file_keeps_a_fast_test_and_make_test_leaves_out_only_slow_ones():
    """``make test`` (``-m "not slow"``) still runs every test file; ``make test-all`` runs the
    tests marked slow too, and CI (``.ci/run``) runs ``make test-all``."""
    for path in sorted((ROOT / "tests").glob("test_*.py")):
        tree = ast.parse(path.read_text())
        whole = [n for n in tree.body if isinstance(n, ast.Assign) and any(getattr(t, "id", "") == "pytestmark"
                                                                           for t in n.targets)]
        assert not any("slow" in ast.unparse(n.value) for n in whole), f"{path.name} is slow as a whole"
        fast = [n.name for n in tree.body if isinstance(n, ast.FunctionDef) and n.name.startswith("test_")
                and not _marked_slow(n.decorator_list)]
        assert fast, f"{path.name} has no test outside the slow tier"
    make = (ROOT / "Makefile").read_text()
    recipe = {t: make.split(f"\n{t}: ")[1].split("\n\n")[0] for t in ("test", "test-all")}
    assert '-m "not slow"' in recipe["test"] and "-m" not in recipe["test-all"].replace("-m pytest", "")
    assert "make test-all" in (ROOT / ".ci" / "run").read_text()


# Each part of the tree and the folder its modules are imported from: the package and benchmarks/
# from the repository's root (``benchmarks.gpu``), scripts/ and examples/ from their own folders
# (``from _start import start``), the tests from theirs (``from helpers import ROOT``).
IMPORT_ROOTS = {"flock_torchrl": ROOT, "benchmarks": ROOT, "scripts": ROOT / "scripts", "examples": ROOT / "examples",
                "tests": ROOT / "tests"}


def tree_modules() -> dict[str, Path]:
    """Every module of the tree by the name it is imported as (a package by its ``__init__``)."""
    modules: dict[str, Path] = {}
    for part, base in IMPORT_ROOTS.items():
        for path in sorted((ROOT / part).rglob("*.py")):
            name = ".".join(path.relative_to(base).with_suffix("").parts).removesuffix(".__init__")
            assert name not in modules, f"{path.relative_to(ROOT)} and {modules[name].relative_to(ROOT)} are both {name}"
            modules[name] = path
    return modules


def module_graph() -> dict[str, set[str]]:
    """Every module of the tree -> the tree's modules it imports, at the top or inside a function
    alike (``from x import name`` counts ``x.name`` where that is a module)."""
    modules = tree_modules()
    graph = {}
    for module, path in modules.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                stem = node.module or ""
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    stem = ".".join([p for p in base if p] + ([node.module] if node.module else []))
                found.add(stem)
                found.update(f"{stem}.{a.name}" for a in node.names)
        graph[module] = {m for m in found if m in modules and m != module}
    return graph


def import_circle(graph: dict[str, set[str]]) -> list[str]:
    """A circle of ``graph`` (``[a, b, ..., a]``), or ``[]``. A package's ``__init__`` may import its
    own modules (that is what it is for): those edges are left out."""
    graph = {m: {d for d in deps if not (d.startswith(m + ".") or m.startswith(d + "."))} for m, deps in graph.items()}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(module: str) -> list[str]:
        state[module] = 1
        stack.append(module)
        for dep in sorted(graph[module]):
            if state.get(dep) == 1:
                return stack[stack.index(dep):] + [dep]
            if dep not in state and (circle := visit(dep)):
                return circle
        stack.pop()
        state[module] = 2
        return []

    for module in sorted(graph):
        if module not in state and (circle := visit(module)):
            return circle
    return []


def test_the_graph_sees_the_whole_tree_and_imports_inside_functions():
    graph = module_graph()
    assert {"flock_torchrl.world.env", "benchmarks.gpu", "train", "goal_separation", "helpers"} <= set(graph)
    assert "_start" in graph["train"] and "helpers" in graph["test_shipped_files"]
    assert "flock_torchrl.run.launch" in graph["benchmarks.throughput"]  # imported inside loop_rows
    assert "simulated_cuda" in graph["simulated_cuda_site.sitecustomize"]
    assert import_circle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert import_circle({"a": {"a.b"}, "a.b": {"a"}}) == []  # a package and its own module


def test_no_import_circle():
    """No module of the tree (the package, benchmarks/, scripts/, examples/, the tests and their
    helpers) imports, directly or through others, a module that imports it back: an import inside
    a function does not hide a circle from this test."""
    circle = import_circle(module_graph())
    assert not circle, "import circle: " + " -> ".join(circle)


@pytest.mark.slow
def test_only_compose_touches_hydra_and_importing_the_package_registers_and_reads_nothing():
    """config/: ``compose.py`` is the one module that imports Hydra (``scenario.py``, what the world
    builds on, imports none); importing the package registers no resolver or schema and reads no
    YAML (``EVAL_SEED`` and the schemas come when first asked for or composed)."""
    import subprocess
    import sys

    for path in sorted((PACKAGE / "config").glob("*.py")):
        hydra = [n for n in ast.walk(ast.parse(path.read_text()))
                 if isinstance(n, ast.ImportFrom) and (n.module or "").split(".")[0] == "hydra"
                 or isinstance(n, ast.Import) and any(a.name.split(".")[0] == "hydra" for a in n.names)]
        assert not hydra or path.name == "compose.py", f"config/{path.name} imports Hydra"
    bare = ("import flock_torchrl, flock_torchrl.run, flock_torchrl.world, flock_torchrl.config as c; "
            "from omegaconf import OmegaConf; from hydra.core.config_store import ConfigStore; "
            "assert not OmegaConf.has_resolver('pi'); assert 'train_schema.yaml' not in ConfigStore.instance().repo; "
            "assert c.EVAL_SEED == 2024 and OmegaConf.has_resolver('pi')")
    # The command-line apps register when cli is imported: a launcher's worker unpickles its task.
    apps = "import flock_torchrl.cli; from omegaconf import OmegaConf; assert OmegaConf.has_resolver('flock.run_name')"
    proc = subprocess.run([sys.executable, "-c", f"{bare}; {apps}"], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
