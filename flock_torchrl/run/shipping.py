"""Shipping trained policies: slim checkpoints into ``checkpoints/<reading>/`` with a manifest.

Two collections per reading, each ``<collection>/<policy>/seed<k>.pt``: the fast recipe's
(``<checkpoints_dir>/<reading>``) and the paper recipe's (``paper_recipe_dir``, by default
``<checkpoints_dir>/<reading>/paper_recipe``), each with its ``MANIFEST.md``.
"""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace
from typing import Callable

from ..io import write_text
from ..policies.checkpoint import LAST, load_checkpoint, policy_payload, save_checkpoint
from .schedule import Schedule


# A solo run's folder, or a population's (``population=K``: seeds seed .. seed + K - 1).
_SOLO = re.compile(r"seed(\d+)")
_POPULATION = re.compile(r"seed(\d+)__population-(\d+)")


def _finished_runs(root: Path, log: Callable[[str], None] = print) -> list[tuple[Path, str, str, int | None]]:
    """``(last.pt, policy, seed<k>, member)`` of every finished run under ``<root>/<policy>/``:
    a solo run ``seed<k>/`` (``member`` None) and each member of a population
    ``seed<s>__population-<K>/``; runs with other overrides are not shipped. A run still
    training, or stopped early, is skipped with a message."""
    runs = []
    for last in sorted(root.glob(f"*/seed*/{LAST}")):
        solo, population = _SOLO.fullmatch(last.parent.name), _POPULATION.fullmatch(last.parent.name)
        if not (solo or population):
            continue
        payload = load_checkpoint(last, kind="training")
        c = payload["counters"]
        if not Schedule(SimpleNamespace(**payload["config"]["experiment"])).done(c, payload.get("evaluations", [])):
            log(f"skipped {last}: not finished ({c['frames']} frames, {c['episodes']} episodes)")
            continue
        policy = last.parent.parent.name
        if solo:
            runs.append((last, policy, last.parent.name, None))
        else:
            runs += [(last, policy, f"seed{m['seed']}", k) for k, m in enumerate(payload["members"])]
    return runs


def ship_collection(runs: list[tuple[Path, str, str, int | None]], dest: Path, reading: str, title: str,
                    source: str, log: Callable[[str], None] = print) -> list[Path]:
    """Export each run (or population member) of :func:`_finished_runs` to
    ``<dest>/<policy>/seed<k>.pt`` (files of the earlier flat layout, ``<dest>/<policy>_seed<k>.pt``,
    move to their place) and write ``<dest>/MANIFEST.md`` listing every checkpoint the collection holds."""
    shipped = []
    seen: dict[Path, Path] = {}
    exported: dict[Path, dict] = {}
    for last, policy, seed, member in runs:
        target = dest / policy / f"{seed}.pt"
        if target in seen:
            raise ValueError(f"{last} and {seen[target]} both hold {policy} {seed}: ship one of them (move the "
                             "other run folder away)")
        seen[target] = last
        slim = policy_payload(last, member)  # read once: checked, written, listed
        if slim["meta"]["reading"] != reading:
            raise ValueError(f"{last} was trained under another reading than {reading!r}")
        save_checkpoint(slim, target, kind="policy")
        log(f"{last} -> {target}" + ("" if member is None else f" (member {member})"))
        shipped.append(target)
        exported[target] = slim
    for legacy in sorted(dest.glob("*_seed*.pt")):
        policy, _, seed = legacy.stem.rpartition("_")
        target = dest / policy / f"{seed}.pt"
        if not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            legacy.replace(target)
            log(f"{legacy} -> {target} (the collection's layout)")
        else:
            legacy.unlink()
            log(f"removed {legacy} (superseded by {target})")
    held = sorted(dest.glob("*/seed*.pt"))
    if not held:
        return shipped
    lines = [f"# {title}, reading `{reading}`", "",
             f"Slim policies exported by `make ship-checkpoints` (scripts/ship.py) from `{source}`; "
             "`flock_torchrl.load_policy(path)` loads them. Minutes are the run's own training time.", "",
             "| policy | seed | experiment | frames | episodes | updates | minutes | final eval success | safe_success |",
             "|---|---|---|---|---|---|---|---|---|"]
    for path in held:
        payload = exported.get(path) or load_checkpoint(path, kind="policy")
        c, ev = payload["counters"], (payload.get("evaluations") or [{}])[-1]
        lines.append(f"| {payload['meta']['policy']} | {path.stem[4:]} | {payload['meta']['experiment']} | {c['frames']} | "
                     f"{c['episodes']} | {c['updates']} | {c['seconds'] / 60:.1f} | "
                     f"{ev.get('success', float('nan')):.3f} | {ev.get('safe_success', float('nan')):.3f} |")
    write_text(dest / "MANIFEST.md", "\n".join(lines) + "\n")
    log(f"wrote {dest / 'MANIFEST.md'} ({len(held)} checkpoints, {len(shipped)} exported now)")
    return shipped


def ship_checkpoints(reading: str, experiment: str, runs_dir: Path, checkpoints_dir: Path,
                     paper_experiment: str, paper_recipe_dir: Path,
                     log: Callable[[str], None] = print, collections: dict[str, str] | None = None) -> list[Path]:
    """Export ``<runs>/<experiment>/<reading>/<policy>/seed<k>/last.pt`` (runs without extra
    overrides only) to ``<checkpoints>/<reading>/<policy>/seed<k>.pt``, the paper recipe's
    ``<runs>/<paper_experiment>/<reading>/...`` to ``<paper_recipe_dir>/<policy>/seed<k>.pt``,
    and each further experiment of ``collections`` (experiment -> folder, e.g. ``mixed``) to
    ``<checkpoints>/<reading>/<folder>/<policy>/seed<k>.pt``."""
    fast = _finished_runs(runs_dir / experiment / reading, log)
    paper = _finished_runs(runs_dir / paper_experiment / reading, log)
    shipped = (ship_collection(fast, checkpoints_dir / reading, reading, "Shipped checkpoints",
                               f"{runs_dir}/{experiment}/{reading}/", log)
               + ship_collection(paper, paper_recipe_dir, reading, "Shipped checkpoints of the paper's recipe",
                                 f"{runs_dir}/{paper_experiment}/{reading}/", log))
    for other, folder in (collections or {}).items():
        runs = _finished_runs(runs_dir / other / reading, log)
        shipped += ship_collection(runs, checkpoints_dir / reading / folder, reading,
                                   f"Shipped checkpoints of experiment={other}", f"{runs_dir}/{other}/{reading}/", log)
    return shipped


__all__ = ["ship_checkpoints", "ship_collection"]
