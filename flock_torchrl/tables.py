"""The paper's Tables III-V next to ours: reference data, comparison rows, writers, reproduction.

The rows of each table come from the paper's own CSV (``flock_torchrl/reference/``), so our
tables have exactly the paper's rows (policy; scenario and policy; tau_v) in its order, and
every column of the paper's CSV, holding *our* value. Beside each paper column ``c`` sit
``c_paper`` and ``c_diff`` (ours minus paper); then the columns the paper lacks:
``safe_success_rate``, the Wilson bounds of both rates, and the episode counts.

Example:
    >>> from flock_torchrl.tables import table_entries, write_table
    >>> [e.key for e in table_entries(5)][:2]
    [('0.2',), ('0.5',)]
    >>> md, csv_path = write_table(5, {}, "results")   # no results yet: paper values only
"""

from __future__ import annotations

import csv
import dataclasses
import math
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from .evaluation import (CELL_METRICS, EVAL_SEED, EvaluationResult, PolicySource, evaluate, load_policy_config,
                         policy_runs, policy_source, write_csv_atomic, write_text_atomic)

REFERENCE_DIR = Path(__file__).resolve().parent / "reference"
TABLE_NUMBERS = (3, 4, 5)
ROMAN = {3: "III", 4: "IV", 5: "V"}
TITLES = {
    3: "Comparison results of different policies in the training environment",
    4: "Comparison results of five policies under five different scenarios",
    5: "Generalization test results of Policy3-G under different values of tau_v in the training scenario",
}
KEY_COLUMNS = {3: ("policy",), 4: ("scenario", "policy"), 5: ("tau_v",)}
# Paper value columns, in the paper's CSV order.
VALUE_COLUMNS = tuple(c for m in CELL_METRICS for c in (m, f"{m}_std")) + ("success_rate",)
# Columns the paper does not report.
EXTRA_COLUMNS = ("safe_success_rate", "success_rate_low", "success_rate_high", "safe_success_rate_low",
                 "safe_success_rate_high", "n_episodes", "n_reached", "n_checkpoints", "note")
LABELS = {
    "d_min_obs": "d_min^obs (m)", "d_min_uav": "d_min^uav (m)", "d_c": "d_c (m)",
    "v_error": "V_error^c (m/s)", "phi_error": "phi_error^c (rad)", "speed": "V (m/s)", "t_goal": "t^g (s)",
}
TABLE5_POLICY = "Policy3-G"


# ---------------------------------------------------------------------------- reference data
def reference_path(table: int) -> Path:
    if table not in TABLE_NUMBERS:
        raise ValueError(f"table must be one of {TABLE_NUMBERS}, got {table!r}")
    return REFERENCE_DIR / f"table{table}.csv"


def load_reference(table: int) -> tuple[list[str], list[dict[str, str]]]:
    """The paper's CSV of a table: ``(column names, rows as dicts of strings)``."""
    with open(reference_path(table), newline="") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


@dataclass(frozen=True)
class TableEntry:
    """One row of a table: its key (the paper's strings) and what to evaluate for it."""

    key: tuple[str, ...]
    policy: str
    scenario: str
    env_overrides: dict[str, Any] = field(default_factory=dict)


def table_entries(table: int) -> list[TableEntry]:
    """The rows of a table, in the paper's order, with the evaluation each one needs."""
    _, rows = load_reference(table)
    entries = []
    for row in rows:
        key = tuple(row[k] for k in KEY_COLUMNS[table])
        if table == 3:
            entries.append(TableEntry(key, row["policy"], "train"))
        elif table == 4:
            entries.append(TableEntry(key, row["policy"], row["scenario"].lower()))
        else:
            entries.append(TableEntry(key, TABLE5_POLICY, "tau_v", {"tau_v": float(row["tau_v"])}))
    return entries


# ---------------------------------------------------------------------------- comparison rows
def _float(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def comparison_rows(table: int, results: Mapping[tuple[str, ...], EvaluationResult | Mapping[str, Any] | None],
                    notes: Mapping[tuple[str, ...], str] | None = None) -> list[dict[str, Any]]:
    """Ours, the paper's and the difference, one dict per paper row (paper order).

    Args:
        results: row key (e.g. ``("Policy3-G",)``, ``("S1", "Policy-MA")``, ``("0.2",)``) ->
            an :class:`EvaluationResult` or its :meth:`~EvaluationResult.summary` dict; rows
            without a result keep empty values of ours.
        notes: row key -> a note (why a row is empty, which checkpoints were pooled).
    """
    notes = notes or {}
    _, ref_rows = load_reference(table)
    out = []
    for entry, ref in zip(table_entries(table), ref_rows):
        result = results.get(entry.key)
        ours: Mapping[str, Any] = result.summary() if isinstance(result, EvaluationResult) else (result or {})
        row: dict[str, Any] = {k: v for k, v in zip(KEY_COLUMNS[table], entry.key)}
        for c in VALUE_COLUMNS:
            mine, paper = _float(ours.get(c)), _float(ref[c])
            row[c], row[f"{c}_paper"], row[f"{c}_diff"] = mine, paper, mine - paper
        for c in EXTRA_COLUMNS[:-1]:
            row[c] = ours.get(c, math.nan if not c.startswith("n_") else "")
        if isinstance(result, EvaluationResult):
            row["n_checkpoints"] = result.extra.get("pooled", 1)
        row["note"] = notes.get(entry.key, "" if result is not None else "not evaluated")
        out.append(row)
    return out


def csv_columns(table: int) -> list[str]:
    cols = list(KEY_COLUMNS[table])
    for c in VALUE_COLUMNS:
        cols += [c, f"{c}_paper", f"{c}_diff"]
    return cols + list(EXTRA_COLUMNS)


def _pm(mean: float, std: float) -> str:
    return "—" if math.isnan(mean) else f"{mean:.3f} ± {std:.3f}"


def _pct(rate: float) -> str:
    return "—" if math.isnan(rate) else f"{100 * rate:.1f} %"


def _signed(x: float, scale: float = 1.0, digits: int = 3) -> str:
    return "—" if math.isnan(x) else f"{scale * x:+.{digits}f}"


def markdown_table(table: int, rows: Sequence[Mapping[str, Any]], header: str = "") -> str:
    """Three lines per paper row: ours (mean ± std, success with its 95 % Wilson interval),
    the paper's, and the difference of the means (rates in percentage points)."""
    keys = KEY_COLUMNS[table]
    cols = [*keys, "", *(LABELS[m] for m in CELL_METRICS), "success", "safe success"]
    lines = [f"# Table {ROMAN[table]} — {TITLES[table]}", ""]
    if header:
        lines += [header, ""]
    lines += ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for row in rows:
        label = [str(row[k]) for k in keys]
        blank = [""] * len(keys)
        success = _pct(_float(row["success_rate"]))
        low, high = _float(row.get("success_rate_low")), _float(row.get("success_rate_high"))
        if not math.isnan(low):
            success += f" [{100 * low:.1f}, {100 * high:.1f}]"
        ours = [_pm(_float(row[m]), _float(row[f"{m}_std"])) for m in CELL_METRICS]
        paper = [_pm(_float(row[f"{m}_paper"]), _float(row[f"{m}_std_paper"])) for m in CELL_METRICS]
        diff = [_signed(_float(row[f"{m}_diff"])) for m in CELL_METRICS]
        lines.append("| " + " | ".join([*label, "ours", *ours, success,
                                         _pct(_float(row.get("safe_success_rate")))]) + " |")
        lines.append("| " + " | ".join([*blank, "paper", *paper, _pct(_float(row["success_rate_paper"])), "n/a"]) + " |")
        diff_rate = _float(row["success_rate_diff"])
        lines.append("| " + " | ".join([*blank, "Δ", *diff,
                                         "—" if math.isnan(diff_rate) else f"{100 * diff_rate:+.1f} pp", ""]) + " |")
    notes = [(tuple(str(r[k]) for k in keys), r.get("note")) for r in rows if r.get("note")]
    if notes:
        lines += ["", "Notes:", ""]
        lines += [f"- {' / '.join(k)}: {n}" for k, n in notes]
    return "\n".join(lines) + "\n"


def write_table(table: int, results: Mapping[tuple[str, ...], EvaluationResult | Mapping[str, Any] | None],
                out_dir: str | Path = "results", notes: Mapping[tuple[str, ...], str] | None = None,
                header: str = "") -> tuple[Path, Path]:
    """Write ``<out_dir>/table<k>.md`` and ``.csv`` (each atomically); returns both paths."""
    rows = comparison_rows(table, results, notes)
    out_dir = Path(out_dir)
    csv_path = write_csv_atomic(out_dir / f"table{table}.csv", csv_columns(table), rows)
    md_path = write_text_atomic(out_dir / f"table{table}.md", markdown_table(table, rows, header))
    return md_path, csv_path


# ---------------------------------------------------------------------------- reproduction
@dataclass
class ReproduceConfig:
    """Options of ``scripts/reproduce.py`` (``key=value`` on its command line)."""

    table: int = 3
    episodes: int = 500
    seed: int = EVAL_SEED
    device: str = "cpu"
    checkpoints: str = "checkpoints"
    results: str = "results"
    only: str = ""            # comma-separated policy names to run (others stay empty)
    threads: int = 1          # torch threads (0: torch's default; 1 suits a shared 2-core machine)
    episodes_csv: bool = True  # also write every episode's metrics (<results>/table<k>_episodes.csv)


def parse_key_values(argv: Sequence[str], config_type: type = ReproduceConfig):
    """``["table=3", "episodes=500"]`` -> a ``config_type`` instance; unknown keys or bad
    values raise ``ValueError`` naming the key."""
    fields = {f.name: f for f in dataclasses.fields(config_type)}
    values: dict[str, Any] = {}
    for arg in argv:
        key, sep, raw = arg.lstrip("-").partition("=")
        key = key.replace("-", "_")
        if not sep or key not in fields:
            raise ValueError(f"expected key=value with key in {sorted(fields)}, got {arg!r}")
        kind = type(fields[key].default)
        try:
            if kind is bool:
                if raw.lower() not in ("true", "false", "1", "0", "yes", "no"):
                    raise ValueError(raw)
                values[key] = raw.lower() in ("true", "1", "yes")
            else:
                values[key] = kind(raw)
        except ValueError:
            raise ValueError(f"{key}: expected a {kind.__name__}, got {raw!r}") from None
    return config_type(**values)


def _policy_env(name: str) -> dict[str, Any]:
    try:
        return dict(load_policy_config(name)["env"])
    except Exception:  # no YAML for this name
        return {}


def reproduce(table: int, episodes: int = 500, seed: int = EVAL_SEED, device: str = "cpu",
              checkpoint_dir: str | Path = "checkpoints", results_dir: str | Path = "results",
              policies: Mapping[str, Any] | None = None, only: Sequence[str] | None = None,
              episodes_csv: bool = True, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Evaluate everything a paper table needs and write ``<results_dir>/table<k>.md`` / ``.csv``.

    Learned policies: every ``<checkpoint_dir>/<stem>/seed<k>.pt``, each on the same
    ``episodes`` seeded episodes, pooled into one cell (``n_checkpoints`` says how many; the
    per-checkpoint summaries go to ``table<k>_seeds.csv``). Rule-based ones: their baseline
    controller. A policy with nothing to evaluate is skipped with a message and keeps an empty
    row (the paper's values still shown).

    Args:
        policies: policy name -> a module / checkpoint path (or a list of them) used instead of
            the shipped checkpoints (tests, ad-hoc comparisons).
        only: evaluate only these policy names.

    Returns:
        ``{"rows", "markdown", "csv", "failed", "skipped"}``.
    """
    entries = table_entries(table)
    overrides = dict(policies or {})
    wanted = set(only) if only else None
    results: dict[tuple[str, ...], EvaluationResult] = {}
    notes: dict[tuple[str, ...], str] = {}
    seed_rows: list[dict[str, Any]] = []
    episode_rows: list[dict[str, Any]] = []
    failed: list[str] = []
    skipped: list[str] = []
    sources: dict[str, list[tuple[str, PolicySource]]] = {}
    policy_notes: dict[str, str] = {}
    t0 = time.perf_counter()
    for entry in entries:
        if wanted is not None and entry.policy not in wanted:
            notes[entry.key] = "not requested"
            continue
        if entry.policy not in sources:
            runs, note = policy_runs(entry.policy, checkpoint_dir, overrides)
            resolved = []
            for label, p in runs:
                try:
                    source = policy_source(p, device=device, checkpoint_dir=checkpoint_dir)
                    # The row's policy defines the scenario fields (fov, instinct, ...); what the
                    # module or checkpoint states itself wins.
                    source.env = {**_policy_env(entry.policy), **source.env}
                    resolved.append((label, source))
                except Exception as exc:
                    log(f"[table {table}] {entry.policy}: cannot load {label}: {exc}")
                    failed.append(f"{entry.policy} ({label})")
                    note = note or f"cannot load {label}: {exc}"
            sources[entry.policy], policy_notes[entry.policy] = resolved, note
            if not resolved:
                log(f"[table {table}] {entry.policy}: {note}")
                skipped.append(entry.policy)
        runs = sources[entry.policy]
        if not runs:
            notes[entry.key] = policy_notes[entry.policy]
            continue
        per_run = []
        for label, source in runs:
            try:
                r = evaluate(source, scenario=entry.scenario, n_episodes=episodes, seed=seed, device=device,
                             env_overrides=entry.env_overrides, checkpoint_dir=checkpoint_dir)
            except Exception as exc:
                log(f"[table {table}] {' / '.join(entry.key)} {label}: FAILED: {exc}\n{traceback.format_exc()}")
                failed.append(f"{' / '.join(entry.key)} ({label})")
                continue
            r.policy = entry.policy
            log(f"[table {table}] {' / '.join(entry.key)} [{label}]: {r}")
            per_run.append(r)
            key_cols = dict(zip(KEY_COLUMNS[table], entry.key))
            seed_rows.append({**key_cols, "checkpoint": label, **r.summary(),
                              "rollout_steps": r.rollout_steps, "wall_time_s": round(r.wall_time_s, 2)})
            if episodes_csv:
                episode_rows += [{**key_cols, "checkpoint": label, **rec} for rec in r.records()]
        if per_run:
            results[entry.key] = EvaluationResult.pooled(per_run)
            notes[entry.key] = (f"{len(per_run)} checkpoints pooled ({len(per_run) * episodes} episodes)"
                                if len(per_run) > 1 else "")
        else:
            notes[entry.key] = "evaluation failed (see log)"
    header = (f"Ours: {episodes} episodes per checkpoint, evaluation seed {seed}, deterministic actions; "
              f"learned policies pool all their checkpoints. Paper: Bai et al., IEEE Trans. Cybern. 54(1) "
              f"2024, Table {ROMAN[table]} (500 episodes). Δ = ours − paper. Success: goal reached without "
              f"obstacle collision, with its 95 % Wilson interval; safe success also needs no UAV pair "
              f"closer than d_min^b (not reported by the paper). Metrics: SPEC section 5.")
    md_path, csv_path = write_table(table, results, results_dir, notes, header)
    if seed_rows:
        write_csv_atomic(Path(results_dir) / f"table{table}_seeds.csv", list(seed_rows[0]), seed_rows)
    if episode_rows:
        write_csv_atomic(Path(results_dir) / f"table{table}_episodes.csv", list(episode_rows[0]), episode_rows)
    log(f"[table {table}] wrote {md_path} and {csv_path} ({len(results)}/{len(entries)} rows evaluated, "
        f"{time.perf_counter() - t0:.1f} s)" + (f"; FAILED: {failed}" if failed else ""))
    return {"rows": comparison_rows(table, results, notes), "markdown": md_path, "csv": csv_path,
            "failed": failed, "skipped": skipped}



def reproduce_main(argv: Sequence[str]) -> int:
    """``scripts/reproduce.py``: parse ``key=value`` arguments, run :func:`reproduce`, return the
    exit status (1 if an evaluation failed, 2 for bad arguments)."""
    if any(a in ("-h", "--help", "help") for a in argv):
        print("usage: python scripts/reproduce.py table=3|4|5 [episodes=500] [key=value ...]\n"
              "Evaluates what the table needs (checkpoints/<policy>/seed*.pt, the baselines) and writes\n"
              "<results>/table<k>.md and .csv: ours, the paper's and the difference per metric.\n"
              "keys (defaults): " + ", ".join(f"{f.name}={f.default!r}" for f in dataclasses.fields(ReproduceConfig)))
        return 0
    try:
        cfg = parse_key_values(argv, ReproduceConfig)
        if cfg.table not in TABLE_NUMBERS:
            raise ValueError(f"table: must be one of {TABLE_NUMBERS}, got {cfg.table}")
        if cfg.episodes < 1:
            raise ValueError(f"episodes: must be >= 1, got {cfg.episodes}")
    except ValueError as exc:
        print(f"reproduce.py: {exc}", file=sys.stderr)
        return 2
    if cfg.threads > 0:
        import torch

        torch.set_num_threads(cfg.threads)
    only = [s.strip() for s in cfg.only.split(",") if s.strip()] or None
    out = reproduce(cfg.table, episodes=cfg.episodes, seed=cfg.seed, device=cfg.device,
                    checkpoint_dir=cfg.checkpoints, results_dir=cfg.results, only=only,
                    episodes_csv=cfg.episodes_csv, log=lambda m: print(m, flush=True))
    return 1 if out["failed"] else 0
