"""The tables as markdown: the full tables (ours, the paper's, the difference), their headers,
the README-sized summary and the claims, all (re)written from the CSVs by :func:`render_tables`."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..io import write_text
from ..world.metrics import CELL_METRICS, METRIC_BY_KEY
from .claims import Fidelity, claim_verdicts, fidelity, is_extra_row
from .reference import KEY_COLUMNS, ROMAN, TABLE_NUMBERS, TITLES, as_float, read_table_csv


def claims_markdown(rows: Sequence[Mapping[str, Any]], recipe: str = "") -> list[str]:
    """The claims as a markdown table: holds in k of n comparisons, paper and ours, with values."""
    def fmt(v: Any, partial: bool = False) -> str:
        if v is None:
            return "—"
        return ("holds" if v[0] == v[1] else f"{v[0]} of {v[1]}") + (" (of those evaluated)" if partial else "")

    where = f", {recipe}" if recipe else ""
    lines = [f"**The paper's claims, on Table III{where}** (comparisons that hold, paper / ours; values ours / paper; "
             "— where no comparison can be made; \"of those evaluated\": among the policies this table has):", "",
             "| claim | paper | ours | values |", "|---|---|---|---|"]
    for v in claim_verdicts(rows):
        scale, digits = (100, 1) if v["metric"] == "success_rate" else (1, 3)
        def num(x: float) -> str:
            return "—" if math.isnan(x) else f"{scale * x:.{digits}f}"

        values = ", ".join(f"{n} {num(v['ours_values'][n])} / {num(v['paper_values'][n])}" for n in v["ours_values"])
        lines.append(f"| {v['claim']} | {fmt(v['paper'])} | {fmt(v['ours'], v['ours_partial'])} | "
                     f"{v['metric']}: {values} |")
    return lines + [""]


def _pm(mean: float, std: float) -> str:
    return "—" if math.isnan(mean) else f"{mean:.3f} ± {std:.3f}"


def _pct(rate: float) -> str:
    return "—" if math.isnan(rate) else f"{100 * rate:.1f} %"


def markdown_table(table: int, rows: Sequence[Mapping[str, Any]], header: str = "") -> str:
    """Three lines per row: ours (mean ± std, success with its 95 % Wilson interval, safe
    success), the paper's, and the difference of the means (rates in percentage points)."""
    keys = KEY_COLUMNS[table]
    labels = [f"{METRIC_BY_KEY[m].label} ({METRIC_BY_KEY[m].unit})" for m in CELL_METRICS]
    cols = [*keys, "", *labels, "success", "safe success"]
    lines = [f"# Table {ROMAN[table]} — {TITLES[table]}", ""]
    if header:
        lines += [header, ""]
    lines += ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for row in rows:
        label = [str(row[k]) + (" †" if is_extra_row(row) else "") for k in keys[:1]] + [str(row[k]) for k in keys[1:]]
        blank = [""] * len(keys)
        success = _pct(as_float(row["success_rate"]))
        low, high = as_float(row.get("success_rate_low")), as_float(row.get("success_rate_high"))
        if not math.isnan(low):
            success += f" [{100 * low:.1f}, {100 * high:.1f}]"
        ours = [_pm(as_float(row[m]), as_float(row[f"{m}_std"])) for m in CELL_METRICS]
        paper = [_pm(as_float(row[f"{m}_paper"]), as_float(row[f"{m}_std_paper"])) for m in CELL_METRICS]
        diff = ["—" if math.isnan(as_float(row[f"{m}_diff"])) else f"{as_float(row[f'{m}_diff']):+.3f}"
                for m in CELL_METRICS]
        lines.append("| " + " | ".join([*label, "ours", *ours, success,
                                         _pct(as_float(row.get("safe_success_rate")))]) + " |")
        if not math.isnan(as_float(row["success_rate_paper"])):
            lines.append("| " + " | ".join([*blank, "paper", *paper, _pct(as_float(row["success_rate_paper"])),
                                             "n/a"]) + " |")
            diff_rate = as_float(row["success_rate_diff"])
            lines.append("| " + " | ".join([*blank, "Δ", *diff, "—" if math.isnan(diff_rate)
                                             else f"{100 * diff_rate:+.1f} pp", ""]) + " |")
    notes = [(tuple(str(r[k]) for k in keys), r.get("note")) for r in rows if r.get("note")]
    if any(is_extra_row(r) for r in rows):
        lines += ["", f"† {EXTRA_NOTE}"]
    if notes:
        lines += ["", "Notes:", ""]
        lines += [f"- {' / '.join(k)}: {n}" for k, n in notes]
    return "\n".join(lines) + "\n"


EXTRA_NOTE = ("not one of the paper's rows (the paper recipe's run or a contender): evaluated under the same "
              "protocol, outside the fidelity score and the claims.")
TABLE3_COLUMNS = "success % | safe_success % | d_min_uav (m) | d_min_obs (m) | d_c (m) | t_goal (s) |"


def table_header(table: int, reading: str, episodes: int, seed: int, score: Fidelity) -> str:
    return (f"Reading **{reading}** (docs/specification.md section 9); {score}. Ours: {episodes} episodes per "
            f"checkpoint, evaluation seed {seed}, deterministic actions; learned policies pool all their shipped "
            f"seeds. Paper: Bai et al., IEEE Trans. Cybern. 54(1) 2024, Table {ROMAN[table]} (500 episodes). "
            "Δ = ours − paper. Success: goal reached without obstacle collision, with its 95 % Wilson interval; "
            "safe success also needs no UAV pair closer than d_min^b (the paper does not report it).")


def _pair(row: Mapping[str, Any], metric: str, digits: int = 3, scale: float = 1.0) -> str:
    ours, paper = as_float(row.get(metric)), as_float(row.get(f"{metric}_paper"))
    mine = "—" if math.isnan(ours) else f"{scale * ours:.{digits}f}"
    return mine if math.isnan(paper) else f"{mine} / {scale * paper:.{digits}f}"


def _percent(value: Any) -> str:
    value = as_float(value)
    return "—" if math.isnan(value) else f"{100 * value:.1f}"


def _table3_cells(r: Mapping[str, Any]) -> str:
    """The summary's Table III cells of one row: success, safe success, d_min_uav, d_min_obs, d_c, t_goal."""
    return (f"{_pair(r, 'success_rate', 1, 100)} | {_percent(r.get('safe_success_rate'))} | {_pair(r, 'd_min_uav')} | "
            f"{_pair(r, 'd_min_obs')} | {_pair(r, 'd_c')} | {_pair(r, 't_goal', 1)}")


def summary_markdown(rows: Mapping[int, Sequence[Mapping[str, Any]]], reading: str, score: Fidelity,
                     paper_recipe: Sequence[Mapping[str, Any]] | None = None,
                     paper_score: Fidelity | None = None) -> str:
    """README-sized views of the tables present: ours / paper for the columns that tell most,
    and the claims under each recipe."""
    lines = [f"# Summary, reading `{reading}`", "", f"{score}.", ""]
    if 3 in rows:
        lines += ["**Table III, training scenario** (ours / paper):", "", f"| policy | {TABLE3_COLUMNS}",
                  "|---|---|---|---|---|---|---|"]
        for r in rows[3]:
            lines.append(f"| {r['policy']}{' †' if is_extra_row(r) else ''} | {_table3_cells(r)} |")
        lines.append("")
        if any(is_extra_row(r) for r in rows[3]):
            lines += [f"† {EXTRA_NOTE}", ""]
        lines += claims_markdown(rows[3])
    if paper_recipe:
        lines += ["**Table III under the paper's own recipe** (Table I: one env, one SAC update per step, 5000 "
                  f"episodes; seeds pooled; ours / paper); {paper_score}:", "", f"| policy | seeds | {TABLE3_COLUMNS}",
                  "|---|---|---|---|---|---|---|---|"]
        for r in paper_recipe:
            if str(r.get("note", "")).startswith("not trained"):
                continue
            lines.append(f"| {r['policy']} | {r.get('n_checkpoints') or 1} | {_table3_cells(r)} |")
        lines.append("")
        lines += claims_markdown(paper_recipe, "under the paper's recipe")
    if 4 in rows:
        policies = list(dict.fromkeys(r["policy"] for r in rows[4]))
        lines += ["**Table IV, S1-S5**: success % ours / paper (our safe_success %); d_min_uav m ours / paper:", "",
                  "| scenario | " + " | ".join(policies) + " |", "|---|" + "---|" * len(policies)]
        for scenario in dict.fromkeys(r["scenario"] for r in rows[4]):
            cells = []
            for policy in policies:
                r = next(x for x in rows[4] if x["scenario"] == scenario and x["policy"] == policy)
                cells.append(f"{_pair(r, 'success_rate', 1, 100)} ({_percent(r.get('safe_success_rate'))}); "
                             f"{_pair(r, 'd_min_uav', 2)}")
            lines.append(f"| {scenario} | " + " | ".join(cells) + " |")
        lines.append("")
    if 5 in rows:
        lines += ["**Table V, Policy3-G by tau_v** (ours / paper):", "",
                  "| tau_v (s) | success % | safe_success % | d_min_uav (m) | speed (m/s) | t_goal (s) |",
                  "|---|---|---|---|---|---|"]
        for r in rows[5]:
            lines.append(f"| {r['tau_v']} | {_pair(r, 'success_rate', 1, 100)} | "
                         f"{_percent(r.get('safe_success_rate'))} | {_pair(r, 'd_min_uav')} | "
                         f"{_pair(r, 'speed')} | {_pair(r, 't_goal', 1)} |")
        lines.append("")
    return "\n".join(lines)


def render_tables(out_dir: str | Path, reading: str, episodes: int, seed: int) -> Fidelity:
    """(Re)write every table's markdown in ``out_dir`` from its CSV, headed by the reading's
    fidelity score over the Tables III and IV found there (the paper recipe's Table III,
    ``table3_paper_recipe``, with its own); write ``fidelity.md`` and ``summary.md`` (the
    README's compact views, the claims under each recipe). Returns the reading's score."""
    out_dir = Path(out_dir)
    rows = {t: read_table_csv(out_dir / f"table{t}.csv") for t in TABLE_NUMBERS if (out_dir / f"table{t}.csv").is_file()}
    score = fidelity(rows)
    for t, table_rows in rows.items():
        write_text(out_dir / f"table{t}.md", markdown_table(t, table_rows, table_header(t, reading, episodes, seed,
                                                                                         score)))
    paper_path = out_dir / "table3_paper_recipe.csv"
    paper = read_table_csv(paper_path) if paper_path.is_file() else None
    paper_score = fidelity({3: paper}) if paper else None
    if paper:
        header = table_header(3, reading, episodes, seed, paper_score).replace(
            "learned policies pool all their shipped seeds", "learned policies trained with the paper's own recipe "
            "(Table I: one env, one update per step, 5000 episodes), their seeds pooled")
        write_text(out_dir / "table3_paper_recipe.md", markdown_table(3, paper, header).replace(
            "# Table III —", "# Table III, the paper's recipe —", 1))
    write_text(out_dir / "summary.md", summary_markdown(rows, reading, score, paper, paper_score))
    lines = [f"# Fidelity of the reading `{reading}`", "", f"{score}.", ""]
    if score.per_metric:
        lines += [f"Tables III and IV, {score.metric_line()}.", ""]
    if paper_score is not None:
        lines += [f"The paper's own recipe (Table III only): {paper_score}.", ""]
        if paper_score.per_metric:
            lines += [f"The paper's own recipe, {paper_score.metric_line()}.", ""]
    lines += ["Definition (fixed before any result was seen, docs/specification.md section 9): the mean over Table "
              "III's twelve policies and Table IV's 25 cells of |ours - paper| / max(paper std, 0.1 |paper|, 0.05) "
              "over d_min_obs, d_min_uav, d_c, v_error, phi_error, speed and t_goal. Rows that are not the paper's "
              "(the paper recipe's run in the fast table, contenders) are not counted."]
    write_text(out_dir / "fidelity.md", "\n".join(lines) + "\n")
    return score


__all__ = ["claims_markdown", "markdown_table", "render_tables", "summary_markdown", "table_header"]
