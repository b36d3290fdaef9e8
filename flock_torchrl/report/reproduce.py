"""Reproduce one of the paper's tables: evaluate every row, write ours beside the paper's.

:func:`reproduce` evaluates the rows of Table III, IV or V under one reading (the section 5
protocol: ``episodes`` per checkpoint, the evaluation seed, deterministic actions; a learned
policy pools its shipped seeds) and writes ``table<k>.md`` / ``.csv``, ``table<k>_seeds.csv``
(one row per checkpoint), ``table<k>_episodes.csv.gz`` (one row per episode) and, through
:func:`~flock_torchrl.report.markdown.render_tables`, ``fidelity.md`` and ``summary.md``.

Two recipes: ``fast`` reads the shipped checkpoints ``<checkpoints_dir>/<reading>/<id>/seed<k>.pt``;
``paper`` (Table III only) reads the paper recipe's ``<paper_recipe_dir>/<id>/seed<k>.pt`` and
writes ``table3_paper_recipe.*``. Besides the paper's rows sit extra rows, marked in the
``extra`` column and never part of the fidelity score or the claims: Table III's paper-recipe
Policy3-G, and any *contenders* (a checkpoint file, or the import path of a factory
``f(env) -> TensorDict module``), evaluated under the same protocol in every row's scenario.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from ..config import ConfigError, ReproduceConfig, check_tolerance
from ..io import shown, write_csv
from ..policies.checkpoint import CheckpointError, load_checkpoint
from ..policies.registry import (PolicyHandle, contender_handle, policy_config_of, resolve, shipped_checkpoints,
                                 world_label)
from ..run.results import EvaluationResult
from ..run.rollout import evaluate_handle, try_contender
from .compare import counts, read_table, tolerance_text, verdict_lines, write_comparison
from .markdown import render_tables
from .reference import (KEY_COLUMNS, PAPER_RECIPE_ROW, TABLE_NUMBERS, TableEntry, comparison_row, comparison_rows,
                        csv_columns, table_entries)

RECIPES = ("fast", "paper")


def table_stem(table: int, recipe: str = "fast") -> str:
    """``table3`` or ``table3_paper_recipe``: the files of one table."""
    return f"table{table}" if recipe == "fast" else f"table{table}_paper_recipe"


@dataclass
class Row:
    """What one row of a table evaluates: its key, its scenario, the policies it pools."""

    entry: TableEntry
    handles: list[PolicyHandle]
    extra: str = ""          # "" for the paper's rows; else what the row is (paper recipe, a contender)


def _collection(recipe: str, reading: str, checkpoints_dir: str | Path, paper_recipe_dir: str | Path | None) -> Path:
    if recipe == "paper":
        if paper_recipe_dir is None:
            raise ConfigError("paper_recipe_dir", "the paper recipe's table needs its checkpoints folder")
        return Path(paper_recipe_dir)
    return Path(checkpoints_dir) / reading


def plan(table: int, reading: str, checkpoints_dir: str | Path = "checkpoints", paper_recipe_dir: str | Path | None = None,
         only: Sequence[str] | None = None, recipe: str = "fast", contenders: Sequence[Any] = (),
         device: str = "cpu", policies: Mapping[str, Any] | None = None) -> tuple[list[Row], dict[tuple, str]]:
    """The rows to evaluate, every checkpoint among them opened and digest-checked now (before
    the first episode), every contender tried on a small batch (:func:`try_contender`: a bad
    one is one line naming it), and the notes of the rows left out. A learned policy without
    checkpoints is an error under the fast recipe (the shipped set is complete) and a noted,
    empty row under the paper recipe (not every policy was trained with it)."""
    if table not in TABLE_NUMBERS:
        raise ConfigError("table", f"must be one of {', '.join(map(str, TABLE_NUMBERS))}, got {table}")
    if recipe not in RECIPES:
        raise ConfigError("recipe", f"must be one of {', '.join(RECIPES)}, got {recipe!r}")
    if recipe == "paper" and table != 3:
        raise ConfigError("recipe", "the paper recipe trained the policies of Table III only (table=3)")
    entries = table_entries(table)
    names = {e.policy for e in entries}
    unknown = sorted(set(only or ()) - names)
    if unknown:
        raise ConfigError("only", f"{unknown} are not rows of Table {table}; rows: {sorted(names)}")
    folder = _collection(recipe, reading, checkpoints_dir, paper_recipe_dir)
    rows, notes, cache = [], {}, {}
    for entry in entries:
        if only and entry.policy not in only:
            notes[entry.key] = "not requested"
            continue
        if entry.policy not in cache:
            cache[entry.policy] = _handles(entry.policy, reading, folder, recipe, device, (policies or {}))
        handles = cache[entry.policy]
        if not handles:
            notes[entry.key] = "not trained with the paper recipe"
            continue
        rows.append(Row(entry, handles))
    if table == 3 and recipe == "fast" and paper_recipe_dir is not None and (not only or "Policy3-G" in only):
        paper = shipped_checkpoints("policy3_g", Path(paper_recipe_dir))
        if paper:
            rows.append(Row(TableEntry((PAPER_RECIPE_ROW,), "Policy3-G", "train"),
                            [resolve(p, reading, device=device)[0] for p in paper], extra="paper recipe"))
    for spec in contenders:
        handle = contender_handle(spec, device=device)
        handle.check_reading(reading)
        evaluations = _contender_entries(table, entries)
        # one small batch of its first evaluation, before any row: a bad contender is one line now
        try_contender(handle, evaluations[0].scenario, reading, device, evaluations[0].env_overrides)
        extra = f"contender: {handle.origin}; world: {world_label(handle.scenario)}"
        for entry in evaluations:
            rows.append(Row(TableEntry(_contender_key(table, entry, handle.name), handle.name, entry.scenario,
                                       dict(entry.env_overrides)), [handle], extra=extra))
    return rows, notes


def _handles(name: str, reading: str, folder: Path, recipe: str, device: str,
             given: Mapping[str, Any]) -> list[PolicyHandle]:
    if name in given:  # tests: a module, a checkpoint, or a list of them
        items = given[name] if isinstance(given[name], (list, tuple)) else [given[name]]
        return [h for item in items for h in resolve(item, reading, device=device)]
    config, _ = policy_config_of(name, reading)
    if config.kind == "rule":
        return resolve(name, reading, device=device)
    paths = shipped_checkpoints(config.id, folder)
    if not paths and recipe == "fast":
        raise CheckpointError(f"{config.name}: {folder / config.id} holds no seed*.pt; point checkpoints_dir= at the "
                              f"shipped checkpoints, or evaluate the other rows with only=[...]")
    for path in paths:
        load_checkpoint(path)  # a corrupted or foreign file fails now, naming itself
    return [h for p in paths for h in resolve(p, reading, device=device)]


def _contender_entries(table: int, entries: Sequence[TableEntry]) -> list[TableEntry]:
    """One entry per distinct evaluation of a table (its scenarios; Table V's tau_v values)."""
    seen, out = set(), []
    for entry in entries:
        what = (entry.scenario, tuple(sorted(entry.env_overrides.items())))
        if what not in seen:
            seen.add(what)
            out.append(entry)
    return out


def _contender_key(table: int, entry: TableEntry, name: str) -> tuple[str, ...]:
    if table == 3:
        return (name,)
    if table == 4:
        return (entry.key[0], name)
    return (f"{entry.key[0]} ({name})",)


def check_table_inputs(table: int, reading: str, checkpoints_dir: str | Path, paper_recipe_dir: str | Path | None,
                       only: Sequence[str] = (), recipe: str = "fast", contenders: Sequence[Any] = (),
                       compare_to: str | Path | None = None) -> None:
    """Everything a table needs, checked before anything runs (:func:`plan`; the reference
    table of ``compare_to`` read)."""
    if compare_to is not None:
        read_table(compare_to, table)
    plan(table, reading, checkpoints_dir, paper_recipe_dir, only, recipe, contenders)


def reproduce(cfg: ReproduceConfig, out_dir: str | Path = ".", log: Callable[[str], None] = print,
              policies: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Evaluate everything the paper table ``cfg.table`` needs under ``cfg.scenario.reading`` and
    write it to ``out_dir``: ``conf/reproduce.yaml``'s app, taking its checked config (build it with
    :func:`flock_torchrl.config.app_config`, e.g. ``app_config("reproduce", table=3, episodes=100)``).
    ``cfg.only``: the paper names of the rows to evaluate (empty: all); ``recipe``: as the module says;
    ``contenders``: checkpoint paths, factory import paths (``pkg.module.make``) or mappings with
    ``_target_``, ``name``, ``scenario`` and ``extras``; ``compare_to``: a table CSV written before
    (e.g. ``results/<reading>/table3.csv``), the rows both hold also written side by side
    (:mod:`~flock_torchrl.report.compare`, ``compare_tolerance`` deciding each row's ``within``).
    ``policies``: policy name -> a module / checkpoint (or a list) used instead (tests)."""
    table, reading, recipe, compare_to = cfg.table, cfg.scenario.reading, cfg.recipe, cfg.compare_to
    tolerance = check_tolerance(cfg.compare_tolerance)
    if compare_to is not None:
        read_table(compare_to, table)   # a missing or foreign reference is refused before the first episode
    rows_to_run, notes = plan(table, reading, cfg.checkpoints_dir, cfg.paper_recipe_dir, list(cfg.only) or None,
                              recipe, cfg.contenders, cfg.device, policies)
    results: dict[tuple[str, ...], EvaluationResult] = {}
    extra_rows, seed_rows, episode_rows = [], [], []
    t0 = time.perf_counter()
    # contenders first: one that fails mid-episode costs no evaluated paper row; written in plan order
    order = sorted(range(len(rows_to_run)), key=lambda k: not rows_to_run[k].extra.startswith("contender"))
    evaluated: dict[int, EvaluationResult] = {}
    for i, k in enumerate(order, 1):
        entry = rows_to_run[k].entry
        parts = [evaluate_handle(h, entry.scenario, reading, cfg.episodes, cfg.seed, cfg.device, entry.env_overrides)
                 for h in rows_to_run[k].handles]
        evaluated[k] = result = EvaluationResult.pooled(parts)
        result.policy = entry.policy
        log(f"[table {table}, {i}/{len(rows_to_run)}, {time.perf_counter() - t0:.0f} s] {' / '.join(entry.key)}: "
            f"{result}")
    for k, row in enumerate(rows_to_run):
        entry, result = row.entry, evaluated[k]
        parts = result.parts or [result]
        note = f"{len(parts)} checkpoints pooled ({result.n_episodes} episodes)" if len(parts) > 1 else ""
        if row.extra:
            extra = comparison_row(table, entry.key, result.summary(), None, "; ".join(x for x in (row.extra, note) if x),
                                   len(parts))
            extra["extra"] = row.extra
            extra_rows.append(extra)
        else:
            results[entry.key] = result
            if note:
                notes[entry.key] = note
        key_cols = dict(zip(KEY_COLUMNS[table], entry.key))
        for part in result.parts or [result]:
            seed_rows.append({**key_cols, "extra": row.extra, "checkpoint": shown(part.source), **part.summary(),
                              "rollout_steps": part.rollout_steps, "wall_time_s": round(part.wall_time_s, 2)})
            if cfg.episodes_csv:
                episode_rows += [{**key_cols, "extra": row.extra, "checkpoint": shown(part.source), **rec}
                                 for rec in part.records()]
    rows = comparison_rows(table, results, notes) + extra_rows
    out_dir = Path(out_dir)
    stem = table_stem(table, recipe)
    csv_path = write_csv(out_dir / f"{stem}.csv", csv_columns(table), rows)
    if seed_rows:
        write_csv(out_dir / f"{stem}_seeds.csv", list(seed_rows[0]), seed_rows)
    if episode_rows:
        write_csv(out_dir / f"{stem}_episodes.csv.gz", list(episode_rows[0]), episode_rows)
    score = render_tables(out_dir, reading, cfg.episodes, cfg.seed)
    log(f"[table {table}] {reading}, {recipe} recipe: wrote {out_dir / f'{stem}.md'} and {csv_path} "
        f"({len(rows_to_run)} rows evaluated, {time.perf_counter() - t0:.1f} s); {score}")
    compared = None
    if compare_to is not None:
        source = _collection(recipe, reading, cfg.checkpoints_dir, cfg.paper_recipe_dir)
        _, md_path, compared = write_comparison(table, stem, out_dir, compare_to, rows, tolerance, str(source))
        n_in, cells_in, cells = counts(compared, tolerance)
        for line in verdict_lines(table, compared, tolerance):
            log(f"[table {table}] {line}")
        log(f"[table {table}] beside {compare_to}: {n_in} of {len(compared)} rows, {cells_in} of {cells} cells within "
            f"the tolerance ({tolerance_text(tolerance)}); wrote {md_path}")
    return {"rows": rows, "markdown": out_dir / f"{stem}.md", "csv": csv_path, "failed": [], "fidelity": score,
            "comparison": compared}


__all__ = ["RECIPES", "Row", "check_table_inputs", "plan", "reproduce", "table_stem"]
