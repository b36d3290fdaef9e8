"""One table evaluated twice, side by side: a retrained set of policies against a reference.

``python scripts/reproduce.py table=3 checkpoints_dir=<your checkpoints> compare_to=results/paper_fit/table3.csv``
writes ``table3_vs_reference.md`` / ``.csv`` beside the table: per row the reference value, the
new one and their difference for each of :data:`COMPARED`, and whether the rows named in the
tolerance stay within it (``|new - reference| <= tolerance``). It answers "does my retrain of
the shipped set give policies of the same quality?" (``make check-train-all``, at the retrain's
tolerance) and "does this machine reproduce the shipped table?" (``make reproduce-table3``, every
column at the Makefile's ``REPRODUCE_TOLERANCE``); it changes no exit status, the verdict is a
finding, not a failure. A row evaluated with another number of episodes per checkpoint than
the reference's is not comparable: its cells are never within.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..config import COMPARED, ConfigError
from ..io import write_csv, write_text
from .reference import KEY_COLUMNS, as_float, read_table_csv


def read_table(path: str | Path, table: int) -> dict[tuple[str, ...], dict[str, str]]:
    """The paper's rows of a table CSV written by :func:`~flock_torchrl.report.reproduce.reproduce`
    (extra rows left out), by row key."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError("compare_to", f"{path} is not a file; give a table{table}.csv written by "
                                        "scripts/reproduce.py")
    rows = read_table_csv(path)
    missing = [c for c in (*KEY_COLUMNS[table], *COMPARED, "extra") if rows and c not in rows[0]]
    if not rows or missing:
        raise ConfigError("compare_to", f"{path} is not a Table {table} CSV of scripts/reproduce.py: "
                                        f"{'it lacks the columns ' + str(missing) if missing else 'it has no rows'}")
    rows = [r for r in rows if not r.get("extra")]
    return {tuple(r[c] for c in KEY_COLUMNS[table]): r for r in rows}


def compare_rows(table: int, reference: Mapping[tuple[str, ...], Mapping[str, Any]],
                 candidate: Sequence[Mapping[str, Any]], tolerance: Mapping[str, float]) -> list[dict[str, Any]]:
    """One row per evaluated candidate row that the reference also has: ``<m>_reference``,
    ``<m>``, ``<m>_delta`` for each compared column, ``<m>_within`` for each toleranced one and
    ``within`` (all of them). A missing value (NaN) on either side is never within."""
    out = []
    for row in candidate:
        if row.get("extra") or not as_float(row.get("n_episodes")) > 0:   # an extra row, or one not evaluated
            continue
        key = tuple(str(row[c]) for c in KEY_COLUMNS[table])
        if key not in reference:
            continue
        ref = reference[key]
        item: dict[str, Any] = dict(zip(KEY_COLUMNS[table], key))
        item["episodes_reference"], item["episodes"] = episodes_per_checkpoint(ref), episodes_per_checkpoint(row)
        comparable = not (item["episodes_reference"] > 0 and item["episodes"] > 0) or \
            item["episodes_reference"] == item["episodes"]    # unknown on either side: compared
        item["comparable"] = comparable
        verdicts = []
        for m in COMPARED:
            a, b = as_float(ref.get(m)), as_float(row.get(m))
            item[f"{m}_reference"], item[m], item[f"{m}_delta"] = a, b, b - a
            if m in tolerance:
                ok = comparable and bool(abs(b - a) <= tolerance[m])   # NaN compares False
                item[f"{m}_within"] = ok
                verdicts.append(ok)
        item["within"] = comparable and all(verdicts)
        out.append(item)
    return out


def episodes_per_checkpoint(row: Mapping[str, Any]) -> float:
    """A table row's episodes per evaluated checkpoint (NaN where the row does not say)."""
    n, k = as_float(row.get("n_episodes")), as_float(row.get("n_checkpoints"))
    return n / k if k > 0 else n


def _cell(m: str, value: float, sign: str = "", points: str = "%") -> str:
    if math.isnan(value):
        return "n/a"
    return f"{100 * value:{sign}.1f} {points}" if m.endswith("_rate") else f"{value:{sign}.3f}"


def _delta(m: str, value: float) -> str:
    return _cell(m, value, "+", "pp")


def tolerance_text(tolerance: Mapping[str, float]) -> str:
    """``success_rate 1.0 pp, d_min_uav 0.100`` (``none`` when empty)."""
    return ", ".join(f"{m} {_delta(m, v).lstrip('+')}" for m, v in tolerance.items()) or "none"


def counts(rows: Sequence[Mapping[str, Any]], tolerance: Mapping[str, float]) -> tuple[int, int, int]:
    """Rows within, toleranced cells within, toleranced cells."""
    cells = [bool(r[f"{m}_within"]) for r in rows for m in COMPARED if m in tolerance]
    return sum(bool(r["within"]) for r in rows), sum(cells), len(cells)


def not_comparable(row: Mapping[str, Any]) -> str:
    return (f"not comparable: {row['episodes']:g} episodes per checkpoint here, {row['episodes_reference']:g} "
            "in the reference")


def verdict_lines(table: int, rows: Sequence[Mapping[str, Any]], tolerance: Mapping[str, float]) -> list[str]:
    """One line per compared row: each toleranced cell ✓ (within) or ✗ (outside, with its
    difference), or why the row is not comparable."""
    lines = []
    for r in rows:
        name = " / ".join(str(r[c]) for c in KEY_COLUMNS[table])
        if not r.get("comparable", True):
            lines.append(f"{name}: {not_comparable(r)}")
            continue
        cells = [f"{m} ✓" if r[f"{m}_within"] else f"{m} ✗ ({_delta(m, r[f'{m}_delta'])})"
                 for m in COMPARED if m in tolerance]
        lines.append(f"{name}: {'within tolerance' if r['within'] else 'OUTSIDE tolerance'}: {', '.join(cells)}")
    return lines


def render_comparison(table: int, rows: Sequence[Mapping[str, Any]], tolerance: Mapping[str, float],
                      reference: str | Path, candidate: str) -> str:
    n_in, cells_in, cells = counts(rows, tolerance)
    lines = [f"# Table {table}: {candidate} beside {reference}", "",
             f"Per row: reference / new / Δ (new − reference). Tolerance ({tolerance_text(tolerance)}): {n_in} of "
             f"{len(rows)} rows within it ({cells_in} of {cells} cells); a cell within it is marked ✓, one outside "
             "✗.", "",
             "| " + " | ".join([*KEY_COLUMNS[table], *COMPARED, "within"]) + " |",
             "|" + "---|" * (len(KEY_COLUMNS[table]) + len(COMPARED) + 1)]
    for r in rows:
        cells_text = [str(r[c]) for c in KEY_COLUMNS[table]]
        for m in COMPARED:
            mark = "" if m not in tolerance or not r.get("comparable", True) else \
                " ✓" if r[f"{m}_within"] else " ✗"
            ref, new, delta = _cell(m, r[f"{m}_reference"]), _cell(m, r[m]), _delta(m, r[f"{m}_delta"])
            cells_text.append(f"{ref} / {new} / {delta}{mark}")
        cells_text.append("yes" if r["within"] else "no" if r.get("comparable", True) else not_comparable(r))
        lines.append("| " + " | ".join(cells_text) + " |")
    return "\n".join(lines) + "\n"


def write_comparison(table: int, stem: str, out_dir: str | Path, reference: str | Path,
                     candidate_rows: Sequence[Mapping[str, Any]], tolerance: Mapping[str, float],
                     candidate: str) -> tuple[Path, Path, list[dict[str, Any]]]:
    """Write ``<stem>_vs_reference.csv`` and ``.md``; returns their paths and the rows."""
    rows = compare_rows(table, read_table(reference, table), candidate_rows, tolerance)
    out_dir = Path(out_dir)
    fields = list(rows[0]) if rows else [*KEY_COLUMNS[table], "within"]
    csv_path = write_csv(out_dir / f"{stem}_vs_reference.csv", fields, rows)
    md_path = write_text(out_dir / f"{stem}_vs_reference.md",
                         render_comparison(table, rows, tolerance, reference, candidate))
    return csv_path, md_path, rows


__all__ = ["compare_rows", "counts", "episodes_per_checkpoint", "read_table",
           "render_comparison", "tolerance_text", "verdict_lines", "write_comparison"]
