"""Shipping trained policies: slim checkpoints into ``checkpoints/<reading>/`` with a manifest.

Two collections per reading, each ``<collection>/<policy>/seed<k>.pt``: the fast recipe's
(``<checkpoints_dir>/<reading>``) and the paper recipe's (``paper_recipe_dir``, by default
``<checkpoints_dir>/<reading>/paper_recipe``), each with its ``MANIFEST.md``. A shipment lands whole
or not at all (:class:`~.publication.Publication`): stopped at any moment, the collections and
their manifests are the old ones or the new ones, never a mix.
"""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace
from typing import Callable, Sequence

from ..io import write_text
from ..policies.checkpoint import LAST, CheckpointError, load_checkpoint, save_checkpoint, slim_payload
from .publication import Publication
from .schedule import Schedule


def _folder_patterns(names: Sequence[str] = ()) -> tuple[re.Pattern, re.Pattern]:
    """A solo run's folder, or a population's (``population=K``: seeds seed .. seed + K - 1):
    ``seed<k>`` with no override in its name, or, given ``names``, ``seed<k>__<name>`` for one of them
    (``seed<k>__population-<K>__<name>``)."""
    tail = "__(?:" + "|".join(map(re.escape, names)) + ")" if names else ""
    return re.compile(rf"seed(\d+){tail}"), re.compile(rf"seed(\d+)__population-(\d+){tail}")


Run = tuple[Path, str, str, "int | None", dict]  # (last.pt, policy, seed<k>, member, slim payload)


def _finished_runs(root: Path, log: Callable[[str], None] = print, names: Sequence[str] = ()) -> list[Run]:
    """``(last.pt, policy, seed<k>, member, slim policy)`` of every finished run under ``<root>/<policy>/``:
    a solo run ``seed<k>/`` (``member`` None) and each member of a population
    ``seed<s>__population-<K>/`` (each followed by ``__<name>`` for one of ``names``, when given);
    runs with other overrides are not shipped. A run still training, or stopped early, is skipped
    with a message."""
    solo_name, population_name = _folder_patterns(names)
    runs = []
    for last in sorted(root.glob(f"*/seed*/{LAST}")):
        solo, population = solo_name.fullmatch(last.parent.name), population_name.fullmatch(last.parent.name)
        if not (solo or population):
            continue
        payload = load_checkpoint(last, kind="training")
        c = payload["counters"]
        if not Schedule(SimpleNamespace(**payload["config"]["experiment"])).done(c, payload.get("evaluations", [])):
            log(f"skipped {last}: not finished ({c['frames']} frames, {c['episodes']} episodes)")
            continue
        policy = last.parent.parent.name
        if solo:
            runs.append((last, policy, f"seed{solo.group(1)}", None, slim_payload(payload, last)))
        else:
            runs += [(last, policy, f"seed{m['seed']}", k, slim_payload(payload, last, k))
                     for k, m in enumerate(payload["members"])]
        del payload  # its replay buffer: only the slim policies are kept
    return runs


Shipment = list[tuple[Path, Path, int | None, dict]]  # (last.pt, target, member, slim payload)


def plan_collection(runs: list[Run], dest: Path, reading: str) -> tuple[Shipment, list[str]]:
    """What :func:`ship_collection` would write for ``runs`` into ``dest`` (each run's slim
    policy, read and checked), and every conflict it would meet: two runs holding the same
    ``<policy> seed<k>`` (a solo run and a population member, say), a run of another reading."""
    plan: Shipment = []
    seen: dict[Path, str] = {}
    conflicts = []
    for last, policy, seed, member, slim in runs:
        target = dest / policy / f"{seed}.pt"
        what = f"{last}" + ("" if member is None else f" (member {member})")
        if target in seen:
            conflicts.append(f"{seen[target]} and {what} both hold {policy} {seed}")
            continue
        seen[target] = what
        if slim["meta"]["reading"] != reading:
            conflicts.append(f"{what} was trained under the reading {slim['meta']['reading']!r}, not {reading!r}")
            continue
        plan.append((last, target, member, slim))
    return plan, conflicts


def ship_collection(plan: Shipment, dest: Path, reading: str, title: str, source: str,
                    log: Callable[[str], None] = print,
                    made_by: str = "`make ship-checkpoints` (scripts/ship.py)",
                    publication: Publication | None = None) -> list[Path]:
    """Write the slim policies of a :func:`plan_collection` plan (found free of conflicts) to
    ``<dest>/<policy>/seed<k>.pt`` (files of the earlier flat layout, ``<dest>/<policy>_seed<k>.pt``,
    move to their place) and ``<dest>/MANIFEST.md`` listing every checkpoint the collection holds: all
    of them land together or none does (written into ``publication``'s stage, or into one of its own)."""
    if publication is None:
        with Publication(f"the checkpoints of {dest}", [dest], log=log) as pub:
            return ship_collection(plan, dest, reading, title, source, log, made_by, pub)
    staged = publication.staged
    shipped = []
    exported: dict[Path, dict] = {}
    for last, target, member, slim in plan:
        save_checkpoint(slim, staged(target), kind="policy")
        log(f"{last} -> {target}" + ("" if member is None else f" (member {member})"))
        shipped.append(target)
        exported[staged(target)] = slim
    for legacy in sorted(staged(dest).glob("*_seed*.pt")):
        policy, _, seed = legacy.stem.rpartition("_")
        target = legacy.parent / policy / f"{seed}.pt"
        if not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            legacy.replace(target)
            log(f"{dest / legacy.name} -> {dest / policy / target.name} (the collection's layout)")
        else:
            legacy.unlink()
            log(f"removed {dest / legacy.name} (superseded by {dest / policy / target.name})")
    held = sorted(staged(dest).glob("*/seed*.pt"))
    if not held:
        return shipped
    lines = [f"# {title}, reading `{reading}`", "",
             f"Slim policies exported by {made_by} from `{source}`; "
             "`flock_torchrl.load_policy(path)` loads them. Minutes are the run's own training time.", "",
             "| policy | seed | experiment | frames | episodes | updates | minutes | final eval success | safe_success |",
             "|---|---|---|---|---|---|---|---|---|"]
    for path in held:
        payload = exported.get(path) or load_checkpoint(path, kind="policy")
        c, ev = payload["counters"], (payload.get("evaluations") or [{}])[-1]
        lines.append(f"| {payload['meta']['policy']} | {path.stem[4:]} | {payload['meta']['experiment']} | {c['frames']} | "
                     f"{c['episodes']} | {c['updates']} | {c['seconds'] / 60:.1f} | "
                     f"{ev.get('success', float('nan')):.3f} | {ev.get('safe_success', float('nan')):.3f} |")
    write_text(staged(dest) / "MANIFEST.md", "\n".join(lines) + "\n")
    log(f"wrote {dest / 'MANIFEST.md'} ({len(held)} checkpoints, {len(shipped)} exported now)")
    return shipped


def ship_scenario_collection(reading: str, runs_dir: Path, experiment: str, names: Sequence[str], dest: Path,
                             log: Callable[[str], None] = print, target: str | None = None) -> list[Path]:
    """Export the finished runs ``<runs_dir>/<experiment>/<reading>/<policy>/seed<k>__<name>/last.pt``
    (``name`` one of ``names``: the scenario's overrides, e.g. ``scenario-train3d``) to
    ``<dest>/<policy>/seed<k>.pt`` with its ``MANIFEST.md``; two folders holding one policy's seed
    are a conflict (:class:`CheckpointError`), found before the first file is written. The MANIFEST
    names ``make <target>`` where a make target ships the collection (conf/ship.yaml)."""
    source = runs_dir / experiment / reading
    plan, conflicts = plan_collection(_finished_runs(source, log, names), dest, reading)
    if conflicts:
        raise CheckpointError(refusal(conflicts))
    command = f"scripts/ship.py only={dest.name}"
    made_by = f"`make {target}` ({command})" if target else f"`python {command}`"
    return ship_collection(plan, dest, reading, f"Shipped checkpoints: {dest.name}", f"{source}/", log,
                           made_by=made_by)


def refusal(conflicts: list[str]) -> str:
    """One line: every conflict, and that nothing was written."""
    return (f"nothing was shipped, {len(conflicts)} conflict(s): " + "; ".join(conflicts)
            + " (ship one run of each: move the others' folders away)")


def ship_checkpoints(reading: str, experiment: str, runs_dir: Path, checkpoints_dir: Path,
                     paper_experiment: str, paper_recipe_dir: Path,
                     log: Callable[[str], None] = print, collections: dict[str, str] | None = None) -> list[Path]:
    """Export ``<runs>/<experiment>/<reading>/<policy>/seed<k>/last.pt`` (runs without extra
    overrides only) to ``<checkpoints>/<reading>/<policy>/seed<k>.pt``, the paper recipe's
    ``<runs>/<paper_experiment>/<reading>/...`` to ``<paper_recipe_dir>/<policy>/seed<k>.pt``,
    and each further experiment of ``collections`` (experiment -> folder, e.g. ``mixed``) to
    ``<checkpoints>/<reading>/<folder>/<policy>/seed<k>.pt``. Every run is read and every
    conflict found (:func:`plan_collection`) before the first file is written: a conflict is one
    :class:`CheckpointError` listing them all, and ``checkpoints/`` is left as it was."""
    collections_ = [(experiment, checkpoints_dir / reading, "Shipped checkpoints"),
                    (paper_experiment, paper_recipe_dir, "Shipped checkpoints of the paper's recipe"),
                    *((other, checkpoints_dir / reading / folder, f"Shipped checkpoints of experiment={other}")
                      for other, folder in (collections or {}).items())]
    plans, conflicts = [], []
    for name, dest, title in collections_:
        plan, found = plan_collection(_finished_runs(runs_dir / name / reading, log), dest, reading)
        plans.append((plan, dest, title, f"{runs_dir}/{name}/{reading}/"))
        conflicts += found
    if conflicts:
        raise CheckpointError(refusal(conflicts))
    shipped = []
    with Publication(f"the shipped checkpoints ({reading})", [dest for _, dest, _ in collections_], log=log) as pub:
        for plan, dest, title, source in plans:
            shipped += ship_collection(plan, dest, reading, title, source, log, publication=pub)
    return shipped


__all__ = ["plan_collection", "ship_checkpoints", "ship_collection", "ship_scenario_collection"]
