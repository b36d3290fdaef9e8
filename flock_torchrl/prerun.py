"""What the command-line apps check before Hydra creates anything, beyond a config's schema:
the output folder can be written, a resumed run folder is where its ``resume.yaml`` says, the
sweep's jobs (enumerated with Hydra's public override parser), its launcher and its direction,
the YAML files of the folders a command line adds that the composition reads; and where a bad
value came from (:func:`blame`), so that an error names the command line's override or the file
that set it.
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import re
import shutil
import tempfile
from importlib.resources import files
from pathlib import Path
from typing import Any

import yaml
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import DictConfig, OmegaConf, read_write

from .config import ConfigError, config_folder
from .io import write_failure
from .run.run_folder import RESUME_CONFIG


class AppError(Exception):
    """An error a job reports as one line (exit status 2)."""


def check_writable(folder: Path, key: str) -> None:
    """Refuse an output folder that cannot be made or written, before Hydra creates it: a file
    tried in its nearest existing folder (and removed at once) must be writable."""
    probe = Path(folder).absolute()
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise ConfigError(key, f"{folder} cannot be made: {probe} is a file, not a folder")
    try:
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as exc:
        why = (write_failure(OSError(exc.errno, exc.strerror, str(probe))) or
               f"cannot write {probe}: {exc.strerror}")
        raise ConfigError(key, f"{folder} cannot be written ({why})") from None


def covers(a: str, b: str) -> bool:
    """Dotted keys ``a`` and ``b`` are the same, or one holds the other (``x.y`` and ``x.y[0]``, ``x.y.z``)."""
    return a == b or any(b.startswith(a + sep) or a.startswith(b + sep) for sep in ".[")


def blame(config: DictConfig, key: str, also: tuple[str, ...] = ()) -> tuple[str, str | None]:
    """The key to name for an error about ``key`` (or, when the user set one of them on the
    command line, one of ``also``) and where its value came from: the command line's override,
    the YAML file of its group that sets it, or ``None`` (a default, or not known)."""
    hydra = config.get("hydra") if isinstance(config, DictConfig) else None
    if hydra is None:
        return key, None
    choices = set(hydra.runtime.choices)
    for candidate in (key, *also):
        for override in hydra.overrides.task:
            name = str(override).lstrip("+~").split("=")[0]
            if name == candidate or (name not in choices and covers(name, candidate)):  # not a group's choice
                return candidate, f"the command line's {override}"
    return key, source_of(hydra, key)


def sets(text: str, path: list[str]) -> bool:
    """The YAML ``text`` sets the nested key ``path``."""
    try:
        node: Any = yaml.safe_load(text)
    except yaml.YAMLError:
        return False
    for part in path:
        if not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def source_of(hydra: DictConfig, key: str) -> str | None:
    """The YAML file behind the group a dotted ``key`` belongs to (``scenario.n_uavs`` ->
    ``.../scenario/corridor.yaml``) when that file sets it, from the composed config's own
    record (``hydra``) of its choices and search path; ``None`` when it is not a file."""
    group = key.split(".")[0]
    choice = hydra.runtime.choices.get(group) if group else None
    if not choice:
        return None
    inner = [p for p in re.sub(r"\[\d+\]", "", key).split(".")[1:] if p]
    for source in hydra.runtime.config_sources:
        path, schema = str(source.path), str(source.schema)
        try:
            if schema == "file":
                candidate = Path(path) / group / f"{choice}.yaml"
                if candidate.is_file():
                    return str(candidate) if sets(candidate.read_text(), inner) else None
            elif schema == "pkg":
                candidate = files(path) / group / f"{choice}.yaml"
                if candidate.is_file():
                    return f"pkg://{path}/{group}/{choice}.yaml" if sets(candidate.read_text(), inner) else None
        except (ModuleNotFoundError, TypeError, ValueError):
            continue
    return None


def check_trained_dims(handles: Any, scenario: Any, key: str = "scenario.dims", where: str = "") -> None:
    """Each checkpoint of ``handles`` flies in ``scenario``'s dimension (docs/specification.md
    section 11), checked before any folder exists: the registry's own check, the one building a
    checkpoint's module for an env makes, asked of a stand-in env that has only the scenario.
    Rule-based policies and a contender's factory fit either dimension; ``key`` and ``where`` name
    the setting that chose the scenario when it is not ``scenario`` itself."""
    from types import SimpleNamespace

    env = SimpleNamespace(cfg=scenario)
    for handle in handles:
        if handle.kind == "learned" or (handle.kind == "contender" and Path(handle.origin).is_file()):
            try:
                handle.build_for(env)
            except ConfigError as exc:
                if exc.key == key:
                    raise
                raise ConfigError(key, f"{where}{exc.key} {exc.message}") from None


def check_resume_folder(config: DictConfig) -> None:
    """A ``resume.yaml`` written before run folders could move names its folder by its absolute
    path: read from a copy or a moved folder, it would continue (or miss) the original."""
    if str(config.hydra.job.config_name) != RESUME_CONFIG:
        return
    folder = Path(config_folder(config.hydra.runtime.config_sources, RESUME_CONFIG))
    out = Path(str(config.hydra.run.dir)).resolve()
    chosen = any(str(o).startswith("hydra.run.dir=") for o in config.hydra.overrides.hydra)
    if out != folder and not chosen:
        raise ConfigError("hydra.run.dir", f"{folder / (RESUME_CONFIG + '.yaml')} names another run folder, {out} "
                                           f"(it was copied or moved); pass hydra.run.dir={folder} to continue "
                                           "this one (nothing was changed)")


def sweep_jobs(config: DictConfig) -> list[list[str]] | None:
    """The task overrides of every job of a sweep whose values are lists or ranges (the
    cartesian product, as Hydra's basic sweeper makes it); ``None`` for another sweeper or a
    sweep it cannot enumerate. Only Hydra's public override parser is used."""
    sweeper = str(config.hydra.sweeper.get("_target_", ""))
    if not sweeper.endswith("BasicSweeper"):
        return None
    parsed = OverridesParser.create().parse_overrides([str(o) for o in config.hydra.overrides.task])
    axes = []
    for override in parsed:
        if override.is_hydra_override():
            continue
        if not override.is_sweep_override():
            axes.append([override.input_line])
        elif override.is_discrete_sweep() and not override.value_type.name.startswith("GLOB"):
            key = override.get_key_element()
            axes.append([f"{key}={value}" for value in override.sweep_string_iterator()])
        else:
            return None
    return [list(job) for job in itertools.product(*axes)]


LAUNCHER_EXTRAS = {"hydra_plugins.hydra_submitit_launcher": "slurm", "hydra_plugins.hydra_joblib_launcher": "",
                    "hydra_plugins.hydra_optuna_sweeper": "optuna"}


def check_launcher(config: DictConfig) -> None:
    """A launcher or sweeper that cannot start: its plugin not installed (say which extra
    installs it), or Slurm's launcher where no ``srun`` is on the PATH (submitit would raise
    only after Hydra wrote the sweep's ``multirun.yaml``)."""
    for node in ("launcher", "sweeper"):
        target = str(config.hydra[node].get("_target_", ""))
        module = ".".join(target.split(".")[:2])
        if module.startswith("hydra_plugins.") and importlib.util.find_spec(module) is None:
            extra = LAUNCHER_EXTRAS.get(module)
            hint = f"pip install 'flock_torchrl[{extra}]'" if extra else f"pip install {module.split('.')[1]}"
            raise AppError(f"hydra/{node}: the plugin {module} is not installed ({hint})")
    launcher = str(config.hydra.launcher.get("_target_", ""))
    if launcher.endswith(".SlurmLauncher") and shutil.which("srun") is None:
        raise AppError("hydra/launcher=slurm: this machine has no Slurm (no srun on the PATH); run the sweep on a "
                       "Slurm login node, or locally with hydra/launcher=local")


# What each train objective asks of a sweeper (every one is a rate or a return: larger is better).
OBJECTIVE_DIRECTIONS = {"success_rate": "maximize", "safe_success_rate": "maximize", "return": "maximize"}


def direction_names(value: Any) -> list[str]:
    """``maximize`` / ``Direction.maximize`` / a list of them -> their names."""
    values = list(value) if isinstance(value, (list, tuple)) or OmegaConf.is_list(value) else [value]
    return [str(getattr(v, "name", v)).split(".")[-1].lower() for v in values]


def sweep_direction(config: DictConfig) -> None:
    """Optuna's ``direction`` follows the train app's ``objective`` (the plugin's default,
    ``minimize``, would minimise success): set from the objective unless the command line sets
    it; one set there that contradicts the objective is a config error. Runs before Hydra
    instantiates the sweeper (``on_multirun_start``)."""
    sweeper = config.hydra.sweeper
    if not str(sweeper.get("_target_", "")).endswith("OptunaSweeper") or "objective" not in config:
        return
    want = OBJECTIVE_DIRECTIONS.get(str(config.objective))
    if want is None:
        return
    given = [str(o) for o in config.hydra.overrides.hydra
             if str(o).lstrip("+~").split("=")[0] == "hydra.sweeper.direction"]
    if given:
        wrong = [d for d in direction_names(sweeper.direction) if d != want]
        if wrong:
            raise ConfigError("hydra.sweeper.direction", f"{given[-1]} contradicts objective={config.objective}, "
                                                         f"which is to {want}; pass hydra.sweeper.direction={want} "
                                                         "or leave it out (it follows the objective)")
        return
    with read_write(sweeper):
        sweeper.direction = want


def config_folders(argv: list[str]) -> list[Path]:
    """The folders a command line adds to Hydra's search path: ``--config-dir`` / ``-cd`` and the
    ``file://`` (or plain) entries of ``hydra.searchpath=[...]`` (parsed by Hydra's public
    override parser)."""
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    parser.add_argument("--config-dir", "-cd")
    known, rest = parser.parse_known_args(argv)
    folders = [Path(known.config_dir)] if known.config_dir else []
    for arg in rest:
        if arg.lstrip("+~").startswith("hydra.searchpath="):
            try:
                value = OverridesParser.create().parse_overrides([arg])[0].value()
            except Exception:  # Hydra names a malformed override itself
                continue
            for entry in value if isinstance(value, list) else [value]:
                entry = str(entry)
                if entry.startswith("file://") or "://" not in entry:
                    folders.append(Path(entry.removeprefix("file://")))
    return folders


DEFAULTS_KEY = re.compile(r"^(?P<override>override\s+)?(?:optional\s+)?(?P<path>[^@\s]+)(?:@\S+)?$")
CHOICE_REF = re.compile(r"\$\{([\w/]+)\}")


def _command_line(argv: list[str], app: str) -> tuple[str, dict[str, list[str]]]:
    """The primary config's name (``-cn``, else the app's) and the command line's group
    choices, group -> names (a choice sweep: each; a glob: ``*``), parsed with Hydra's public
    override parser."""
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    for flag in (("--config-dir", "-cd"), ("--config-name", "-cn"), ("--config-path", "-cp"), ("--cfg", "-c"),
                 ("--package", "-p"), ("--experimental-rerun",)):
        parser.add_argument(*flag)
    known, rest = parser.parse_known_args(argv)
    choices: dict[str, list[str]] = {}
    for arg in rest:
        if arg.startswith("-") or "=" not in arg:
            continue
        try:
            override = OverridesParser.create().parse_overrides([arg])[0]
        except Exception:  # Hydra names a malformed override itself
            continue
        if override.is_delete() or "." in override.key_or_group:
            continue
        if override.is_sweep_override():
            names = ["*"] if not override.is_discrete_sweep() or override.value_type.name.startswith("GLOB") else \
                list(override.sweep_string_iterator())
        else:
            value = override.value()
            names = [str(v) for v in value] if isinstance(value, list) else [str(value)]
        choices[override.key_or_group] = names
    return known.config_name or app, choices


def _defaults(node: Any) -> list[tuple[bool, str | None, Any]]:
    """A config's defaults list as ``(override, group, value)``; a config named without a group
    (``- world``) is ``(False, None, name)``; ``_self_`` and malformed entries are left out."""
    out: list[tuple[bool, str | None, Any]] = []
    for item in (node.get("defaults") or []) if isinstance(node, dict) else []:
        if isinstance(item, str) and item.strip() != "_self_":
            m = DEFAULTS_KEY.match(item.strip())
            if m:
                out.append((False, None, m["path"]))
        elif isinstance(item, dict) and len(item) == 1:
            ((key, value),) = item.items()
            m = DEFAULTS_KEY.match(str(key).strip())
            if m:
                out.append((bool(m["override"]), m["path"], value))
    return out


def _within(group: str, path: str) -> str:
    """A defaults entry's path as Hydra reads it: absolute with a leading ``/``, else relative to
    the group of the config that lists it."""
    return path[1:] if path.startswith("/") else f"{group}/{path}" if group else path


def composed_yaml_files(folders: list[Path], app: str, argv: list[str]) -> list[Path]:
    """The YAML files of ``folders`` (the ones a command line adds to the search path) that
    composing ``app`` with ``argv`` reads: the primary config and, through the defaults lists of
    the package's and the user's configs, each group's chosen option (the command line's choice,
    else a defaults list's ``override``, else its first default; ``${group}`` in a choice read as
    that group's choice). A file of those folders that no choice names is not read, as Hydra does
    not read it. Where a choice cannot be known (a glob, an unresolved interpolation), every
    file of that group in ``folders`` counts as read."""
    from .config import CONF_DIR

    primary, command = _command_line(argv, app)
    sources = [Path(f) for f in folders if Path(f).is_dir()] + [Path(CONF_DIR)]
    if len(sources) == 1:
        return []
    forced: dict[str, Any] = {}
    for _ in range(8):   # until the defaults lists' overrides are all known
        used: list[Path] = []
        chosen: dict[str, list[str]] = dict(command)   # also a group no defaults list names (hydra/launcher=...)
        found_overrides: dict[str, Any] = {}
        queue = [primary, *(f"{group}/{name}" for group, names in command.items() for name in names)]
        seen: set[str] = set()
        deferred: list[tuple[str, list[str]]] = []

        def choose(group: str, value: Any) -> None:
            value = command.get(group, forced.get(group, value))
            names = value if isinstance(value, list) else [] if value in (None, "???") else [value]
            names = [str(n) for n in names]
            if any(CHOICE_REF.search(n) for n in names):
                deferred.append((group, names))
                return
            chosen.setdefault(group, names)
            queue.extend(f"{group}/{n}" for n in chosen[group])

        while queue or deferred:
            if not queue:   # interpolated choices, once what they name is known (else: every file of the group)
                group, names = deferred.pop(0)
                known = [CHOICE_REF.sub(lambda m: (chosen.get(m[1]) or ["*"])[0], n) for n in names]
                chosen.setdefault(group, known)
                queue.extend(f"{group}/{n}" for n in chosen[group])
                continue
            path = queue.pop(0)
            if path in seen:
                continue
            seen.add(path)
            node, group = None, path.rpartition("/")[0]
            for source in sources:
                for file in sorted(source.glob(f"{path}.yaml")) if "*" in path else [source / f"{path}.yaml"]:
                    if not file.is_file():
                        continue
                    if source != sources[-1]:
                        used.append(file)
                    if node is None:
                        try:
                            node = yaml.safe_load(file.read_text())
                        except (yaml.YAMLError, OSError, UnicodeDecodeError):
                            node = {}   # the check names it
            for override, entry_group, value in _defaults(node):
                if entry_group is None:
                    queue.append(_within(group, str(value)))
                elif override:
                    found_overrides[_within(group, entry_group)] = value
                else:
                    choose(_within(group, entry_group), value)
        if found_overrides == forced:
            break
        forced = found_overrides
    return list(dict.fromkeys(used))


def check_yaml_files(paths: list[Path]) -> None:
    """Refuse a YAML file that does not parse among ``paths`` (the files of the folders a
    command line adds to the search path that the composition reads, :func:`composed_yaml_files`;
    Hydra would fail on it with a long ``yaml.parser`` traceback), naming the file and the line."""
    for path in paths:
        try:
            yaml.safe_load(Path(path).read_text())
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f" (line {mark.line + 1}, column {mark.column + 1}: {exc.problem})" if mark else ""
            raise AppError(f"{path} is not valid YAML{where}") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise AppError(f"{path} cannot be read ({type(exc).__name__}: {exc})") from None


__all__ = ["AppError", "OBJECTIVE_DIRECTIONS", "blame", "check_launcher", "check_resume_folder", "check_trained_dims",
           "check_writable", "check_yaml_files", "composed_yaml_files", "config_folders", "sweep_direction",
           "sweep_jobs"]
