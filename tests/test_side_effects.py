"""What the package does to the process around it: importing it changes no warning filter, no
environment variable and no logger; its own calls hold back third-party warnings only while they
run; a user's WANDB_MODE neither overrides logger.mode nor is set by a run; cudagraphs=true on a
CPU says once, in the project's words, what it does there, and tensordict says nothing."""

from __future__ import annotations

import io
import json
import logging
import os
import subprocess
import sys
import warnings

import pytest
import torch

from helpers import ROOT, run_script

# Import every module of the package in a fresh interpreter, noting every warnings filter, every
# environment variable and every logger level set on the way by the package's own code (the
# nearest caller outside the standard library is a file of flock_torchrl/; the libraries it imports
# set their own, which are theirs).
IMPORT_ALL = """
import importlib, json, logging, os, pkgutil, sys, sysconfig, warnings
STDLIB = sysconfig.get_paths()["stdlib"]
found = []

def note(what):
    frame = sys._getframe(2)
    while frame is not None and (frame.f_code.co_filename.startswith("<frozen") or (
            frame.f_code.co_filename.startswith(STDLIB) and "site-packages" not in frame.f_code.co_filename)):
        frame = frame.f_back
    if frame is not None and "/flock_torchrl/" in frame.f_code.co_filename.replace(os.sep, "/"):
        found.append(f"{what} at {frame.f_code.co_filename}:{frame.f_lineno}")

def spy(owner, name, what):
    original = getattr(owner, name)
    def call(*args, **kwargs):
        note(what(*args, **kwargs) if callable(what) else what)
        return original(*args, **kwargs)
    setattr(owner, name, call)

spy(warnings, "filterwarnings", lambda action, message="", *a, **k: f"warnings.filterwarnings({action!r}, {message!r})")
spy(warnings, "simplefilter", lambda action, *a, **k: f"warnings.simplefilter({action!r})")
spy(type(os.environ), "__setitem__", lambda self, key, value: f"os.environ[{key!r}] = {value!r}")
spy(logging.Logger, "setLevel", lambda self, level: f"logging {self.name!r} level {level}")
import flock_torchrl
names = sorted(m.name for m in pkgutil.walk_packages(flock_torchrl.__path__, "flock_torchrl.")
               if not m.name.startswith(("flock_torchrl.conf", "flock_torchrl.checkpoints")))
for name in names:
    importlib.import_module(name)
print(json.dumps({"modules": len(names), "found": found}))
"""


def module_level_calls(path) -> list[str]:
    """``name(...)`` of the calls a module makes when it is imported (its top level, outside every
    function and class body, ``if __name__ == "__main__":`` aside) that change the process:
    warnings filters, environment variables, logger levels."""
    import ast

    changing = ("warnings.filterwarnings", "warnings.simplefilter", "os.environ.setdefault", "os.environ.update",
                "os.putenv", "setLevel", "logging.basicConfig", "logging.disable")
    found = []

    def visit(node) -> None:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda)):
            return
        if isinstance(node, ast.If) and "__main__" in ast.unparse(node.test):
            return
        if isinstance(node, ast.Call) and ast.unparse(node.func).endswith(changing):
            found.append(f"{ast.unparse(node.func)}(...) at line {node.lineno}")
        if isinstance(node, (ast.Assign, ast.AugAssign)) and "os.environ[" in ast.unparse(node):
            found.append(f"{ast.unparse(node)} at line {node.lineno}")
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text()))
    return found


def test_no_module_changes_the_process_when_imported():
    """No module of the package filters warnings, sets an environment variable or a logger's level
    at import (learners.py and capture.py filtered a warning each): they do it around their own
    calls, and undo it after."""
    found = {str(p.relative_to(ROOT)): calls for p in sorted((ROOT / "flock_torchrl").rglob("*.py"))
             if (calls := module_level_calls(p))}
    assert found == {}, found


def test_the_module_level_check_sees_what_it_looks_for(tmp_path):
    (tmp_path / "noisy.py").write_text(
        "import logging, os, warnings\nwarnings.filterwarnings('ignore', message='x')\n"
        "os.environ.setdefault('SOME_MODE', 'y')\nos.environ['OTHER'] = '1'\nlogging.getLogger('t').setLevel(30)\n"
        "def f():\n    warnings.simplefilter('ignore')\n"
        "if __name__ == '__main__':\n    logging.basicConfig()\n")
    found = module_level_calls(tmp_path / "noisy.py")
    assert [f.rsplit(" at line ", 1)[1] for f in found] == ["2", "3", "4", "5"], found
    assert found[0].startswith("warnings.filterwarnings") and found[3].startswith("logging.getLogger('t').setLevel")


@pytest.mark.slow
def test_importing_the_package_changes_no_global_setting():
    """Every module of the package imported in a fresh interpreter: none adds a warnings filter,
    sets an environment variable or a logger's level on the way (what its libraries set is theirs)."""
    proc = subprocess.run([sys.executable, "-c", IMPORT_ALL], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["modules"] > 50
    assert result["found"] == [], result["found"]


def test_the_import_check_sees_a_module_level_filter(tmp_path):
    """The check above can fail: a module that filters a warning or sets a variable at import is named."""
    package = tmp_path / "flock_torchrl"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "noisy.py").write_text("import os, warnings\nwarnings.filterwarnings('ignore', message='x')\n"
                                      "os.environ.setdefault('SOME_MODE', 'y')\n")
    proc = subprocess.run([sys.executable, "-c", IMPORT_ALL.replace("> 50", "> 0")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(tmp_path)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    found = json.loads(proc.stdout.strip().splitlines()[-1])["found"]
    assert any("filterwarnings('ignore', 'x')" in f and "noisy.py" in f for f in found), found
    assert any("SOME_MODE" in f for f in found), found


def test_ppos_advantage_warning_is_held_back_only_around_its_own_loss():
    """The one warning the learners hold back (PPO normalises advantages over all UAVs on
    purpose) is filtered inside PPOLearner.update, not for the process."""
    from flock_torchrl.policies import learners

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        warnings.warn(learners.ADVANTAGE_NORMALIZATION + " and the advantage key has more dimensions")
    assert len(seen) == 1
    source = (ROOT / "flock_torchrl" / "policies" / "learners.py").read_text()
    assert 'filterwarnings("ignore", message=ADVANTAGE_NORMALIZATION)' in source.split("class PPOLearner", 1)[1]


@pytest.fixture
def tensordict_log():
    """What tensordict's own logger (it does not propagate to the root) writes meanwhile."""
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    log = logging.getLogger("tensordict")
    log.addHandler(handler)
    try:
        yield stream
    finally:
        log.removeHandler(handler)


def test_capture_on_a_cpu_says_once_what_it_does_and_tensordict_says_nothing(monkeypatch, capsys,
                                                                              tensordict_log):
    from flock_torchrl import capture

    monkeypatch.setattr(capture, "_said", set())
    cpu = torch.device("cpu")
    level = logging.getLogger("tensordict").level
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        first = capture.captured(lambda x: x * 2, cpu)
        second = capture.captured(lambda x: x + 1, cpu)
        options = capture.policy_capture("cpu", True)
    assert float(first(torch.ones(1))) == 2.0 and float(second(torch.ones(1))) == 2.0
    assert options is None                              # TorchRL's collector calls the policy as it is
    assert capture.policy_capture("cpu", False) is None
    assert [str(w.message) for w in seen] == []         # no "machine without CUDA", no "Removing TDs from PyTree"
    assert tensordict_log.getvalue() == ""              # no "Setting up CudaGraphModule ..." INFO line
    err = capsys.readouterr().err
    assert err.count("cudagraphs:") == 1 and capture.NO_GRAPHS.format(device="cpu") in err
    # Outside the capture the user's settings are untouched: tensordict's logger, warnings.
    assert logging.getLogger("tensordict").level == level
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        warnings.warn("This module is instantiated on a machine without CUDA")
    assert len(seen) == 1
    # Disabled: the function itself, and nothing said.
    monkeypatch.setattr(capture, "_said", set())
    function = lambda x: x  # noqa: E731
    assert capture.captured(function, cpu, enabled=False) is function
    assert capsys.readouterr().err == ""


def test_a_users_wandb_mode_neither_overrides_logger_mode_nor_is_set(tmp_path, monkeypatch):
    """logger.mode goes to wandb.init: WANDB_MODE=disabled in the user's environment (which
    setdefault kept, so no run was written) leaves an offline run, and the variable as it was."""
    pytest.importorskip("wandb")
    from flock_torchrl.run.run_folder import make_logger

    monkeypatch.setenv("WANDB_MODE", "disabled")
    monkeypatch.setenv("WANDB_SILENT", "true")
    logger = make_logger("wandb", "flock_torchrl", "offline", tmp_path, "run")
    try:
        logger.log_scalar("x", 1.0, step=0)
        assert logger.experiment.settings.mode == "offline"
        assert os.environ["WANDB_MODE"] == "disabled"
    finally:
        logger.experiment.finish()
    assert list((tmp_path / "wandb").glob("offline-run-*")), "no offline wandb run was written"
    monkeypatch.delenv("WANDB_MODE")
    logger = make_logger("wandb", "flock_torchrl", "offline", tmp_path / "again", "run")
    logger.experiment.finish()
    assert "WANDB_MODE" not in os.environ   # TorchRL's offline=True would have set it to "dryrun"


@pytest.mark.slow
def test_a_cpu_run_with_cudagraphs_says_what_the_switch_does_in_one_line(tmp_path):
    """cudagraphs=true on a CPU: the project's one line, and neither tensordict's INFO line nor
    its "Removing TDs from PyTree" warning (the learner's update, the env's step and the
    collector's policy all built)."""
    proc = run_script("train.py", "experiment=tiny", "experiment.max_frames=64", "experiment.eval_every_frames=0",
                      "experiment.eval_episodes=1", "scenario.max_steps=20", "progress=false", "cudagraphs=true",
                      f"hydra.run.dir={tmp_path / 'run'}", cwd=tmp_path)
    out = proc.stdout + proc.stderr
    assert out.count("cudagraphs: cpu has no CUDA graphs") == 1, out[-3000:]
    assert "[tensordict]" not in out and "PyTree" not in out and "without CUDA" not in out, out[-3000:]
    assert "checkpoint:" in out
