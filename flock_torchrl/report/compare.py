"""One table evaluated twice, side by side: a retrained set of policies against a reference.

``python scripts/reproduce.py table=3 checkpoints_dir=<your checkpoints> compare_to=results/paper_fit/table3.csv``
writes ``table3_vs_reference.md`` / ``.csv`` beside the table: per row the reference value, the
new one and their difference for each of :data:`COMPARED`, and whether the rows named in the
tolerance stay within it (``|new - reference| <= tolerance``). It answers "does my retrain of
the shipped set give policies of the same quality?" (``make check-train-all``); it changes no
exit status, the verdict is a finding, not a failure.
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
        verdicts = []
        for m in COMPARED:
            a, b = as_float(ref.get(m)), as_float(row.get(m))
            item[f"{m}_reference"], item[m], item[f"{m}_delta"] = a, b, b - a
            if m in tolerance:
                ok = bool(abs(b - a) <= tolerance[m])   # NaN compares False
                item[f"{m}_within"] = ok
                verdicts.append(ok)
        item["within"] = all(verdicts)
        out.append(item)
    return out


def _cell(m: str, value: float) -> str:
    if math.isnan(value):
        return "n/a"
    return f"{100 * value:.1f} %" if m.endswith("_rate") else f"{value:.3f}"


def _delta(m: str, value: float) -> str:
    if math.isnan(value):
        return "n/a"
    return f"{100 * value:+.1f} pp" if m.endswith("_rate") else f"{value:+.3f}"


def render_comparison(table: int, rows: Sequence[Mapping[str, Any]], tolerance: Mapping[str, float],
                      reference: str | Path, candidate: str) -> str:
    tol = ", ".join(f"{m} {_delta(m, v).lstrip('+')}" for m, v in tolerance.items()) or "none"
    n_in = sum(bool(r["within"]) for r in rows)
    lines = [f"# Table {table}: {candidate} beside {reference}", "",
             f"Per row: reference / new / Δ (new − reference). Tolerance ({tol}): {n_in} of {len(rows)} rows "
             f"within it; a cell outside it is marked ✗.", "",
             "| " + " | ".join([*KEY_COLUMNS[table], *COMPARED, "within"]) + " |",
             "|" + "---|" * (len(KEY_COLUMNS[table]) + len(COMPARED) + 1)]
    for r in rows:
        cells = [str(r[c]) for c in KEY_COLUMNS[table]]
        for m in COMPARED:
            mark = " ✗" if m in tolerance and not r[f"{m}_within"] else ""
            cells.append(f"{_cell(m, r[f'{m}_reference'])} / {_cell(m, r[m])} / {_delta(m, r[f'{m}_delta'])}{mark}")
        cells.append("yes" if r["within"] else "no")
        lines.append("| " + " | ".join(cells) + " |")
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


__all__ = ["compare_rows", "read_table", "render_comparison", "write_comparison"]
