"""The paper's tables as data: its rows and numbers (``reference/table<k>.csv``), what each row
evaluates, and comparison rows of ours beside the paper's.

The rows of each table come from the paper's own CSV, so our tables have exactly the paper's
rows (policy; scenario and policy; tau_v) in its order. Beside each paper column ``c`` sit
``c_paper`` and ``c_diff`` (ours minus paper); then the columns the paper lacks:
``safe_success_rate``, the Wilson bounds of both rates, the episode counts.

Example:
    >>> from flock_torchrl.report.reference import table_entries
    >>> [e.key for e in table_entries(5)][:2]
    [('0.2',), ('0.5',)]
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from ..run.results import EvaluationResult
from ..world.metrics import CELL_METRICS

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
EXTRA_COLUMNS = ("extra", "safe_success_rate", "success_rate_low", "success_rate_high", "safe_success_rate_low",
                 "safe_success_rate_high", "n_episodes", "n_reached", "n_checkpoints", "note")
TABLE5_POLICY = "Policy3-G"
PAPER_RECIPE_ROW = "Policy3-G (paper recipe)"


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
def as_float(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def comparison_row(table: int, key: tuple[str, ...], ours: Mapping[str, Any], paper: Mapping[str, Any] | None,
                   note: str = "", n_checkpoints: Any = "") -> dict[str, Any]:
    row: dict[str, Any] = dict(zip(KEY_COLUMNS[table], key))
    for c in VALUE_COLUMNS:
        mine, ref = as_float(ours.get(c)), as_float((paper or {}).get(c))
        row[c], row[f"{c}_paper"], row[f"{c}_diff"] = mine, ref, mine - ref
    for c in EXTRA_COLUMNS[1:-2]:
        row[c] = ours.get(c, math.nan if not c.startswith("n_") else "")
    row["extra"] = ""
    row["n_checkpoints"] = n_checkpoints
    row["note"] = note
    return row


def comparison_rows(table: int, results: Mapping[tuple[str, ...], EvaluationResult | Mapping[str, Any] | None],
                    notes: Mapping[tuple[str, ...], str] | None = None) -> list[dict[str, Any]]:
    """Ours, the paper's and the difference, one dict per paper row (paper order)."""
    notes = notes or {}
    _, ref_rows = load_reference(table)
    out = []
    for entry, ref in zip(table_entries(table), ref_rows):
        result = results.get(entry.key)
        ours = result.summary() if isinstance(result, EvaluationResult) else (result or {})
        n_ckpt = (len(result.parts) or 1) if isinstance(result, EvaluationResult) else ""
        out.append(comparison_row(table, entry.key, ours, ref,
                                  notes.get(entry.key, "" if result is not None else "not evaluated"), n_ckpt))
    return out


def csv_columns(table: int) -> list[str]:
    cols = list(KEY_COLUMNS[table])
    for c in VALUE_COLUMNS:
        cols += [c, f"{c}_paper", f"{c}_diff"]
    return cols + list(EXTRA_COLUMNS)


def read_table_csv(path: str | Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


__all__ = ["EXTRA_COLUMNS", "KEY_COLUMNS", "PAPER_RECIPE_ROW", "REFERENCE_DIR", "ROMAN", "TABLE_NUMBERS", "TITLES",
           "TableEntry", "VALUE_COLUMNS", "as_float", "comparison_row", "comparison_rows", "csv_columns",
           "load_reference", "read_table_csv", "reference_path", "table_entries"]
