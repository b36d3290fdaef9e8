"""The make targets that publish, and those that run several apps, as Python: ``scripts/publish.py <target>``.

Each publication (``docs``, ``publish``, ``publish-tables``, ``publish-claims``, ``publish-paper-recipe``,
``publish-scaling``, ``publish-threed``, ``publish-benchmark``, ``readme-demo``) runs the apps' own
functions in this process, writing into a :class:`~flock_torchrl.run.publication.Publication`'s stage,
then refreshes results/standing.md and the documents' spliced blocks from what it wrote, and lands the
whole set or nothing. ``check-train-all``, ``table3-3d`` and ``scaling`` write under outputs/.
What each flies (checkpoints, scenarios, swarm sizes, episodes) is data: conf/publish.yaml, any value
of which the command line sets::

    python scripts/publish.py publish-threed threed.reading=paper_fit threed.episodes=500
    python scripts/publish.py publish-scaling 'scaling.readings=[paper_fit]' scaling.episodes=100

A bad setting or input is one ``error:`` line (exit status 2) before anything is evaluated; a stop
signal is one line (128 + the signal), the set then either landed whole or not at all.
"""

from __future__ import annotations

import dataclasses
import glob
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence

from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from ..config import CONF_DIR, app_config, compose
from ..run.publication import Publication, PublishError, entry, held_signals
from ..run.signals import STOP_SIGNALS, Stopped

SETTINGS = CONF_DIR / "publish.yaml"
Log = Callable[[str], None]


def _say(line: str) -> None:
    print(line, flush=True)


# ---------------------------------------------------------------------------- settings
def settings(overrides: Sequence[str] = ()) -> DictConfig:
    """conf/publish.yaml with ``key=value`` overrides (a list also as ``"a b"`` or ``a,b``; an empty
    value is null); an unknown key or a bad value is a :class:`PublishError`."""
    cfg = OmegaConf.load(SETTINGS)
    OmegaConf.set_struct(cfg, True)
    for override in overrides:
        key, sep, text = override.partition("=")
        if not sep or not key:
            raise PublishError(f"{override!r}: expected key=value (the keys: conf/publish.yaml)")
        try:
            listed = key in LISTS or isinstance(OmegaConf.select(cfg, key, throw_on_missing=False), ListConfig)
            if listed and text and not text.lstrip().startswith("["):
                text = "[" + ",".join(text.replace(",", " ").split()) + "]"
            parsed = OmegaConf.from_dotlist([f"x={text}"]).x if text else None
            _check_kind(key, OmegaConf.select(cfg, key, throw_on_missing=False), parsed, text)
            OmegaConf.update(cfg, key, parsed, merge=False)
        except OmegaConfBaseException as exc:
            raise PublishError(f"{key}: {str(exc).splitlines()[0]} (the keys: conf/publish.yaml)") from None
    return cfg


def _whole(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _check_kind(key: str, default: Any, given: Any, text: str) -> None:
    """A value of the kind the key holds: a whole number (at least 1 for a count of episodes or
    threads) for a number, a list for a list."""
    least = 1 if key.endswith(("episodes", "threads")) else 0
    if _whole(default) and not (_whole(given) and given >= least):
        raise PublishError(f"{key}: must be a whole number{' >= 1' if least else ''}, got {text!r}")
    if isinstance(default, ListConfig) and not isinstance(given, ListConfig):
        raise PublishError(f"{key}: must be a list, got {text!r}")


# Keys whose value is a list though the YAML leaves it to the command line (``???``).
LISTS = ("check_train_all.policies", "check_train_all.rows")


def value(cfg: DictConfig, key: str) -> Any:
    """``cfg.<key>`` resolved to Python values; a missing one is a :class:`PublishError`."""
    try:
        node = OmegaConf.select(cfg, key, throw_on_missing=True)
        return (OmegaConf.to_container(node, resolve=True, throw_on_missing=True) if OmegaConf.is_config(node)
                else node)
    except OmegaConfBaseException as exc:
        name = getattr(exc, "full_key", None) or key
        raise PublishError(f"{name}: {str(exc).splitlines()[0]} (set it: {name}=...)") from None


def paths(patterns: Sequence[str], reading: str) -> list[str]:
    """Each of ``patterns`` with ``<reading>`` filled in: a pattern with ``*``, every file it matches
    (sorted); a path (a ``/`` or ``.pt`` in it), itself where it exists; anything else (a policy id
    such as ``policy_ma``) as it is."""
    out: list[str] = []
    for pattern in patterns:
        path = str(pattern).replace("<reading>", reading)
        if any(c in path for c in "*?["):
            out += sorted(glob.glob(path))
        elif "/" in path or path.endswith(".pt"):
            out += [path] if Path(path).exists() else []
        else:
            out.append(path)
    return out


def _app(cfg: DictConfig, app: str, **values: Any) -> Any:
    """The app's checked config (:func:`~flock_torchrl.config.app_config`), reading ``checkpoints_dir``
    where the settings name one."""
    if value(cfg, "checkpoints_dir"):
        values["checkpoints_dir"] = value(cfg, "checkpoints_dir")
    return app_config(app, **values)


def _threads(cfg: DictConfig) -> None:
    import torch

    if value(cfg, "threads"):
        torch.set_num_threads(int(value(cfg, "threads")))


# ---------------------------------------------------------------------------- the documents
def refresh(publication: Publication) -> None:
    """A publication's last step: results/standing.md (README's table) and the pooled scaling table
    from the staged results (where it covers results/), then every document's spliced blocks."""
    from .splice import splice_staged
    from .standing import write_standing

    if publication.covers("results"):
        write_standing(publication.staged("results"))
    splice_staged(publication)


def publication(cfg: DictConfig, name: str, areas: Sequence[str] = ("results", "figures"), log: Log = _say) -> Publication:
    return Publication(name, areas, documents=value(cfg, "documents"), refresh=refresh, log=log)


def staged_log(pub: Publication, log: Log) -> Log:
    """``log`` with the stage's folder left out of the paths the apps say they wrote (``wrote
    results/paper_fit/table3.md``: where it lands, with the rest of the set, at the end)."""
    prefix = f"{pub.stage}{os.sep}"
    return lambda line: log(line.replace(prefix, ""))


def _land(cfg: DictConfig, name: str, log: Log, *steps: Callable[[Publication, Log], None],
          areas: Sequence[str] = ("results", "figures")) -> None:
    """Run ``steps`` (each ``step(pub, log)``) into one :func:`publication`: the set lands whole or not at all."""
    with publication(cfg, name, areas, log=log) as pub:
        for step in steps:
            step(pub, staged_log(pub, log))


# ---------------------------------------------------------------------------- Tables III-V and the figures
def _table_configs(cfg: DictConfig) -> list[tuple[str, str, Any]]:
    """(reading, what, app config) of every table and figure set publish-tables writes, each checked now."""
    from ..world.memory import check_episodes_memory
    from .figures import check_figure_inputs
    from .reproduce import check_table_inputs

    episodes = int(value(cfg, "episodes"))
    out = []
    for reading in value(cfg, "readings"):
        for table in value(cfg, "tables"):
            out.append((reading, f"Table {table}", _app(cfg, "reproduce", table=table, reading=reading, episodes=episodes)))
        if value(cfg, "figures"):
            out.append((reading, "figures", _app(cfg, "figures", reading=reading, figs=value(cfg, "figures"))))
        if paths([value(cfg, "paper_recipe")], reading):
            out.append((reading, "Table 3, paper recipe",
                        _app(cfg, "reproduce", table=3, recipe="paper", reading=reading, episodes=episodes)))
    for reading, what, c in out:
        if what == "figures":
            check_figure_inputs(reading, c.figs, c.checkpoints_dir)
        else:
            check_episodes_memory(c.scenario, c.episodes)
            check_table_inputs(c.table, reading, c.checkpoints_dir, c.paper_recipe_dir, c.only, recipe=c.recipe)
    return out


def _write_tables(pub: Publication, configs: Sequence[tuple[str, str, Any]], log: Log) -> None:
    from .figures import make_figures
    from .reproduce import reproduce

    for reading, what, c in configs:
        log(f"[{reading}] {what}")
        if what == "figures":
            make_figures(c, pub.staged(f"figures/{reading}"), log=log)
        else:   # reproduce evaluates every row or raises
            reproduce(c, pub.staged(f"results/{reading}"), log=log)


# ---------------------------------------------------------------------------- the claims over seeds
def _write_claims(cfg: DictConfig, pub: Publication, log: Log) -> None:
    from .seeds import plot_profiles, write_claims, write_overview

    claims = value(cfg, "claims")
    results = pub.staged("results")
    for folder in sorted(p for p in results.iterdir() if p.is_dir()):
        reading = folder.name
        for stem in claims["tables"]:
            seeds = folder / f"{stem}_seeds.csv"
            if seeds.is_file():
                write_claims(seeds, folder / f"{stem}_claims.md")
                plot_profiles(seeds, pub.staged(f"figures/{reading}/{stem}_performance_profile.png"))
                log(f"[{reading}] the claims over the seeds of {stem}")
        if any((folder / f).is_file() for f in claims["overview"].values()):
            write_overview({title: folder / f for title, f in claims["overview"].items()}, folder / "claims_overview.md")


# ---------------------------------------------------------------------------- swarm sizes
def _scaling_configs(cfg: DictConfig, runs: Sequence[dict], reading: str, episodes: int | None,
                     scenarios: Sequence[str] | None = None) -> list:
    """The scaling app's config of each run (its scenario among ``scenarios``), each policy resolved now."""
    from ..policies.registry import resolve
    from ..world.memory import check_episodes_memory

    out = []
    for run in runs:
        if scenarios is not None and run["scenario"] not in scenarios:
            continue
        c = _app(cfg, "scaling", reading=reading, scenario=run["scenario"], policy_name=run["policy"],
                       others=paths(run["others"], reading), sizes=list(run["sizes"]),
                       episodes=int(run.get("episodes") or episodes))
        check_episodes_memory(dataclasses.replace(c.scenario, n_uavs=max(c.sizes)), c.episodes)
        for policy in (c.policy_name, *c.others):
            resolve(policy, reading, c.checkpoints_dir, device=c.device)
        out.append(c)
    return out


def _write_scaling(pub: Publication, configs: Sequence[Any], log: Log) -> None:
    from .scaling import scaling

    for c in configs:
        log(f"[{c.scenario.reading}] swarm sizes on {c.scenario.name}: {c.policy_name}, {', '.join(c.others)}")
        scaling(c, pub.staged(f"results/{c.scenario.reading}"), log=log)


def _scaling_plan(cfg: DictConfig) -> list:
    s = value(cfg, "scaling")
    return [c for reading in s["readings"] for c in _scaling_configs(cfg, s["runs"], reading, s["episodes"], s["scenarios"])]


# ---------------------------------------------------------------------------- three dimensions
def _threed_plan(cfg: DictConfig) -> tuple[list[str], list]:
    from ..policies.checkpoint import load_checkpoint

    t = value(cfg, "threed")
    checkpoints = paths(t["policies"], t["reading"])
    if not [c for c in checkpoints if c.endswith(".pt")]:
        raise PublishError(f"no 3-D checkpoint matches {', '.join(t['policies'])} (reading {t['reading']}): "
                           "make ship-threed ships them")
    for path in checkpoints:
        if path.endswith(".pt"):
            load_checkpoint(path)   # a truncated or foreign file is one line now, before any episode
    return checkpoints, _scaling_configs(cfg, t["scaling"], t["reading"], t["scaling_episodes"])


def _figure_settings(t: dict) -> dict[str, Any]:   # threed.publish's settings, from conf/publish.yaml's threed
    return dict(baselines=t["baselines"], scenarios=t["scenarios"], gif_size=tuple(t["gif_size"]),
                gif_stride=int(t["gif_stride"]), shown=t["shown"], frames=t["frames"])


def _write_threed(cfg: DictConfig, pub: Publication, plan: tuple[list[str], list], log: Log) -> None:
    from .threed import publish

    t = value(cfg, "threed")
    reading = t["reading"]
    publish(plan[0], pub.staged(f"results/{reading}"), pub.staged(f"figures/{reading}"), reading, int(t["episodes"]),
            "make publish-threed", log=log, **_figure_settings(t))
    _write_scaling(pub, plan[1], log)


# ---------------------------------------------------------------------------- the targets
def docs(cfg: DictConfig, log: Log = _say) -> None:
    """``make docs``: results/standing.md and every document's spliced blocks, from results/."""
    _land(cfg, "the documents' copies of results/", log, areas=("results",))


def publish_tables(cfg: DictConfig, log: Log = _say) -> None:
    """``make publish-tables``: Tables III-V, Fig. 4-6 and the paper recipe's Table III of each reading."""
    configs = _table_configs(cfg)
    _threads(cfg)
    _land(cfg, "Tables III-V and the figures", log, lambda pub, log: _write_tables(pub, configs, log))


def publish_claims(cfg: DictConfig, log: Log = _say) -> None:
    """``make publish-claims``: the claims over the seeds of every published table, and the overview."""
    _land(cfg, "the claims over seeds", log, lambda pub, log: _write_claims(cfg, pub, log))


def _paper_recipe_configs(cfg: DictConfig) -> list[tuple[str, str, Any]]:
    """publish-paper-recipe's tables and figure (paper_fit), each checked now."""
    from .reproduce import check_table_inputs

    episodes = int(value(cfg, "episodes"))
    configs = [("paper_fit", "Table 3", _app(cfg, "reproduce", table=3, reading="paper_fit", episodes=episodes)),
               ("paper_fit", "Table 3, paper recipe",
                _app(cfg, "reproduce", table=3, recipe="paper", reading="paper_fit", episodes=episodes)),
               ("paper_fit", "figures", _app(cfg, "figures", reading="paper_fit", figs=[4]))]
    for _, what, c in configs[:2]:
        check_table_inputs(3, "paper_fit", c.checkpoints_dir, c.paper_recipe_dir, c.only, recipe=c.recipe)
    return configs


def publish_paper_recipe(cfg: DictConfig, log: Log = _say) -> None:
    """``make publish-paper-recipe``: under paper_fit, the fast Table III (its paper-recipe row pools the
    shipped seeds), the paper recipe's Table III, Fig. 4 and the claims."""
    configs = _paper_recipe_configs(cfg)
    _threads(cfg)
    _land(cfg, "the paper recipe's tables", log, lambda pub, log: _write_tables(pub, configs, log),
          lambda pub, log: _write_claims(cfg, pub, log))


def publish_scaling(cfg: DictConfig, log: Log = _say) -> None:
    """``make publish-scaling``: each run of ``scaling.runs`` under each reading of ``scaling.readings``."""
    configs = _scaling_plan(cfg)
    _threads(cfg)
    _land(cfg, "the swarm-size tables", log, lambda pub, log: _write_scaling(pub, configs, log))


def publish_threed(cfg: DictConfig, log: Log = _say) -> None:
    """``make publish-threed``: the 3-D table, its verdicts, figures and scaling rows (conf/publish.yaml's ``threed``)."""
    plan = _threed_plan(cfg)
    _threads(cfg)
    _land(cfg, "the 3-D results", log, lambda pub, log: _write_threed(cfg, pub, plan, log))


def publish_all(cfg: DictConfig, log: Log = _say) -> None:
    """``make publish``: publish-tables, publish-scaling and publish-claims as one set."""
    tables, scaling = _table_configs(cfg), _scaling_plan(cfg)
    _threads(cfg)
    _land(cfg, "every table and figure", log, lambda pub, log: _write_tables(pub, tables, log),
          lambda pub, log: _write_scaling(pub, scaling, log), lambda pub, log: _write_claims(cfg, pub, log))


def publish_benchmark(cfg: DictConfig, log: Log = _say) -> None:
    """``make publish-benchmark``: the page ``python -m benchmarks.run`` wrote, as results/benchmark.md,
    spliced into docs/throughput.md."""
    source = Path(value(cfg, "benchmark"))
    if not source.is_file():
        raise PublishError(f"no benchmark page at {source} (python -m benchmarks.run writes it)")
    _land(cfg, "the benchmark", log, lambda pub, log: shutil.copyfile(source, pub.staged("results/benchmark.md")),
          areas=("results/benchmark.md",))


# ---------------------------------------------------------------------------- targets that run apps in child processes
def run_app(command: Sequence[str], log: Log = _say, stdout: Any = None) -> int:
    """Run ``command`` (an app) in a child process of this process group, single-threaded: a
    terminal's Ctrl-C reaches it, and it stops as it does alone (a training writes its checkpoint).
    A stop signal waits for the child, then stops this process; returns the child's exit status."""
    log("$ " + " ".join(command))
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    with held_signals() as noted:
        rc = subprocess.run(list(command), env=env, stdout=stdout).returncode
    if noted:
        raise Stopped(noted[0])
    for signum in STOP_SIGNALS:   # the child was stopped by a signal that did not reach this process
        if rc in (-signum, 128 + signum):
            raise Stopped(signum)
    return rc


def readme_demo(cfg: DictConfig, scripts: Path, log: Log = _say) -> None:
    """``make readme-demo``: the demo trained from nothing (as a fresh clone's ``make demo``), its
    checkpoint and evaluation lines with this machine's name in docs/demo.md, spliced into README.md."""
    from .splice import demo_lines, write_demo

    folder = Path(value(cfg, "demo"))
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    with (folder / "demo.log").open("w") as handle:
        rc = run_app([sys.executable, str(scripts / "train.py"), "experiment=demo", "progress=false",
                      f"hydra.run.dir={folder / 'run'}"], log, stdout=handle)
    text = (folder / "demo.log").read_text()
    print(text, end="", flush=True)
    if rc:
        raise PublishError(f"the demo's training failed (exit status {rc}; its output: {folder / 'demo.log'})")
    demo_lines(text, folder / "run")   # both lines are there, before anything is staged
    with Publication("the demo's lines", ["docs/demo.md"], documents=["README.md"], refresh=refresh, log=log) as pub:
        write_demo(folder / "demo.log", folder / "run", pub.staged("docs/demo.md"))


def check_train_all(cfg: DictConfig, scripts: Path, log: Log = _say) -> None:
    """``make check-train-all``: ``make train-all`` timed from nothing into a folder of its own, its
    policies shipped there, its Table III beside the shipped one (``table3_vs_reference.md``)."""
    c = value(cfg, "check_train_all")
    reading, seeds = c["reading"], ",".join(map(str, c["seeds"]))
    folder = Path(str(c["folder"]).replace("<reading>", reading))
    if folder.exists():
        raise PublishError(f"{folder} exists; move it away for a timing from nothing")
    python = sys.executable
    start = time.perf_counter()
    rc = run_app([python, str(scripts / "train.py"), "-m", "hydra/launcher=local", "experiment=fast", "progress=false",
                  "resume=auto", f"seed={seeds}", f"policy={','.join(c['policies'])}", f"hydra.sweep.dir={folder / 'runs'}",
                  f"reading={reading}"], log)
    if rc:
        raise PublishError(f"the training sweep failed (exit status {rc}); its runs are in {folder / 'runs'}")
    line = f"make train-all READING={reading} SEEDS={seeds}: {time.perf_counter() - start:.0f} s wall"
    log(line)
    (folder / "wall.txt").write_text(line + "\n")
    for command in ([python, str(scripts / "ship.py"), f"reading={reading}", f"runs_dir={folder / 'runs'}",
                     f"checkpoints_dir={folder / 'checkpoints'}"],
                    [python, str(scripts / "reproduce.py"), "table=3", f"episodes={c['episodes']}", f"reading={reading}",
                     f"checkpoints_dir={folder / 'checkpoints'}", f"only=[{','.join(c['rows'])}]",
                     f"compare_to=results/{reading}/table3.csv", f"hydra.run.dir={folder / 'table3'}"]):
        rc = run_app(command, log)
        if rc:
            raise PublishError(f"{Path(command[1]).name} failed (exit status {rc})")


def table3_3d(cfg: DictConfig, log: Log = _say) -> None:
    """``make table3-3d``: the finished 3-D runs of ``make train-3d``, before they are shipped, and the
    baselines, as publish-threed's table and figures, into outputs/ (no scaling rows)."""
    from .threed import publish

    t, s = value(cfg, "threed"), value(cfg, "table3_3d")
    reading = s["reading"]
    checkpoints = paths([s["runs"]], reading)
    if not checkpoints:
        raise PublishError(f"no finished 3-D run matches {s['runs'].replace('<reading>', reading)} (make train-3d)")
    out = Path(s["out"].replace("<reading>", reading))
    _threads(cfg)
    publish(checkpoints, out, out, reading, int(s["episodes"]), "make table3-3d", log=log, **_figure_settings(t))


def scaling_outputs(cfg: DictConfig, scripts: Path, log: Log = _say) -> None:
    """``make scaling``: scripts/scaling.py into outputs/scaling/{reading}/, with the mixed-size policy where shipped."""
    s = value(cfg, "scaling_outputs")
    given = [f"reading={s['reading']}"] if s["reading"] else []
    reading = str(compose("scaling", given).scenario.reading)
    others = paths(s["others"], reading)
    rc = run_app([sys.executable, str(scripts / "scaling.py"), *given, *([f"others=[{','.join(others)}]"] if others else [])],
                 log)
    if rc:
        raise PublishError(f"scripts/scaling.py failed (exit status {rc})")


# ---------------------------------------------------------------------------- the command line
TARGETS: dict[str, Callable[..., None]] = {
    "docs": docs, "publish": publish_all, "publish-tables": publish_tables, "publish-claims": publish_claims,
    "publish-paper-recipe": publish_paper_recipe, "publish-scaling": publish_scaling, "publish-threed": publish_threed,
    "publish-benchmark": publish_benchmark, "readme-demo": readme_demo, "check-train-all": check_train_all,
    "table3-3d": table3_3d, "scaling": scaling_outputs,
}
WITH_SCRIPTS = ("readme-demo", "check-train-all", "scaling")


def main(argv: Sequence[str] | None = None, noted: Sequence[int] = (), scripts: str | os.PathLike | None = None) -> int:
    """``scripts/publish.py <target> [key=value ...]``: run one target; its exit status."""
    args = list(sys.argv[1:] if argv is None else argv)

    def run() -> None:
        if not args or args[0] not in TARGETS:
            raise PublishError(f"usage: scripts/publish.py <target> [key=value ...]; targets: {', '.join(TARGETS)}"
                               + (f" (not {args[0]!r})" if args else ""))
        cfg = settings(args[1:])
        target = TARGETS[args[0]]
        if args[0] in WITH_SCRIPTS:
            target(cfg, Path(scripts) if scripts is not None else Path(__file__).resolve().parents[2] / "scripts")
        else:
            target(cfg)

    return entry(run, noted)


__all__ = ["TARGETS", "check_train_all", "docs", "main", "paths", "publication", "publish_all", "publish_benchmark",
           "publish_claims", "publish_paper_recipe", "publish_scaling", "publish_tables", "publish_threed", "readme_demo",
           "refresh", "run_app", "scaling_outputs", "settings", "table3_3d", "value"]
