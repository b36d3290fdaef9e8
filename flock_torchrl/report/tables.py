"""The paper's Tables III-V next to ours, per reading, with the fidelity score.

The rows of each table come from the paper's own CSV (``reference/``), so our tables have
exactly the paper's rows (policy; scenario and policy; tau_v) in its order. Beside each
paper column ``c`` sit ``c_paper`` and ``c_diff`` (ours minus paper); then the columns the
paper lacks: ``safe_success_rate``, the Wilson bounds of both rates, the episode counts.

The **fidelity score** of a reading (docs/specification.md section 9), fixed before any result
was seen: the mean over Table III's twelve policies and Table IV's 25 cells of
``|ours - paper| / max(paper std, 0.1 |paper|, 0.05)`` over d_min_obs, d_min_uav, d_c,
v_error, phi_error, speed and t_goal (success excluded). Lower is closer to the paper.

Example:
    >>> from flock_torchrl.report.tables import table_entries
    >>> [e.key for e in table_entries(5)][:2]
    [('0.2',), ('0.5',)]
"""

from __future__ import annotations

import csv
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from ..io import write_csv, write_text
from ..run.evaluation import EVAL_SEED, EvaluationResult, evaluate
from ..world.metrics import CELL_METRICS, METRIC_BY_KEY

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
EXTRA_COLUMNS = ("safe_success_rate", "success_rate_low", "success_rate_high", "safe_success_rate_low",
                 "safe_success_rate_high", "n_episodes", "n_reached", "n_checkpoints", "note")
TABLE5_POLICY = "Policy3-G"
# The fidelity score's terms (docs/specification.md section 9): every table cell metric.
FIDELITY_METRICS = CELL_METRICS
FIDELITY_TABLES = (3, 4)
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
def _float(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def comparison_row(table: int, key: tuple[str, ...], ours: Mapping[str, Any], paper: Mapping[str, Any] | None,
                   note: str = "", n_checkpoints: Any = "") -> dict[str, Any]:
    row: dict[str, Any] = dict(zip(KEY_COLUMNS[table], key))
    for c in VALUE_COLUMNS:
        mine, ref = _float(ours.get(c)), _float((paper or {}).get(c))
        row[c], row[f"{c}_paper"], row[f"{c}_diff"] = mine, ref, mine - ref
    for c in EXTRA_COLUMNS[:-2]:
        row[c] = ours.get(c, math.nan if not c.startswith("n_") else "")
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


# ---------------------------------------------------------------------------- fidelity
def fidelity_terms(rows: Sequence[Mapping[str, Any]]) -> list[float]:
    """``|ours - paper| / max(paper std, 0.1 |paper|, 0.05)`` for every metric of every row
    that has both values (rows without a paper value, e.g. the paper-recipe row, count nothing)."""
    terms = []
    for row in rows:
        for m in FIDELITY_METRICS:
            ours, paper, std = _float(row.get(m)), _float(row.get(f"{m}_paper")), _float(row.get(f"{m}_std_paper"))
            if math.isnan(ours) or math.isnan(paper):
                continue
            terms.append(abs(ours - paper) / max(std if not math.isnan(std) else 0.0, 0.1 * abs(paper), 0.05))
    return terms


@dataclass
class Fidelity:
    """A reading's fidelity score, from the Table III and IV rows evaluated so far."""

    score: float
    terms: int
    expected: int
    parts: dict[int, float]

    @property
    def complete(self) -> bool:
        return self.terms == self.expected

    def __str__(self) -> str:
        if not self.terms:
            return "fidelity score: not available (Tables III and IV not evaluated)"
        parts = ", ".join(f"Table {ROMAN[t]} alone {v:.3f}" for t, v in self.parts.items())
        state = "" if self.complete else f", INCOMPLETE: {self.terms} of {self.expected} terms"
        return f"fidelity score {self.score:.3f} (lower is closer to the paper; {parts}{state})"


def fidelity(tables: Mapping[int, Sequence[Mapping[str, Any]]]) -> Fidelity:
    """The score over the rows of Tables III and IV given (docs/specification.md section 9)."""
    terms, parts = [], {}
    for t in FIDELITY_TABLES:
        rows = [r for r in tables.get(t, []) if not str(r.get("policy", "")).endswith("(paper recipe)")]
        part = fidelity_terms(rows)
        if part:
            parts[t] = sum(part) / len(part)
        terms += part
    expected = sum(len(load_reference(t)[1]) for t in FIDELITY_TABLES) * len(FIDELITY_METRICS)
    return Fidelity(sum(terms) / len(terms) if terms else math.nan, len(terms), expected, parts)


# ---------------------------------------------------------------------------- the paper's claims
@dataclass(frozen=True)
class Claim:
    """One of the paper's qualitative claims, tested on Table III's rows. ``groups`` are lists
    of paper policy names; ``compare(groups, value)`` says whether the claim holds for the
    values of ``metric`` (``value(name)`` reads one row: ours or the paper's)."""

    text: str
    metric: str
    groups: tuple[tuple[str, ...], ...]
    compare: Callable[[tuple[tuple[str, ...], ...], Callable[[str], float]], tuple[int, int]]


def _pairs_below(groups, value):
    """The pairs ``(a, b)`` of ``groups[0]`` and ``groups[1]``, position by position: how many
    have ``value(a) < value(b)``."""
    pairs = list(zip(*groups))
    return sum(value(a) < value(b) for a, b in pairs), len(pairs)


def _all_above(groups, value):
    """Every policy of ``groups[0]`` above every policy of ``groups[1]``: 1 of 1, else 0 of 1."""
    return int(min(value(n) for n in groups[0]) > max(value(n) for n in groups[1])), 1


def _all_above_1m(groups, value):
    """Every policy of ``groups[0]`` keeps its mean closest pair above 1 m (half of d_safe)."""
    return sum(value(n) > 1.0 for n in groups[0]), len(groups[0])


def _lowest(groups, value):
    """``groups[0][0]`` has the lowest value of all of ``groups[1]``."""
    target = value(groups[0][0])
    return int(all(target < value(n) for n in groups[1] if n != groups[0][0])), 1


LEARNED = ("Policy1", "Policy1-G", "Policy2", "Policy2-G", "Policy3", "Policy3-G", "Policy4-G", "Policy5-G",
           "PolicyD-G", "PolicyP-G")
CLAIMS = (
    Claim("the instinct keeps UAVs apart (closest pair of every instinct policy above every SAC policy without it)",
          "d_min_uav", (("Policy3", "Policy3-G", "Policy5-G"), ("Policy1", "Policy1-G", "Policy2", "Policy2-G")),
          _all_above),
    Claim("... and by a safe margin: every instinct policy's mean closest pair above 1 m (half of d_safe)",
          "d_min_uav", (("Policy3", "Policy3-G", "Policy5-G"),), _all_above_1m),
    Claim("the centralised critic (-G) beats its plain twin (success)", "success_rate",
          (("Policy1", "Policy2", "Policy3"), ("Policy1-G", "Policy2-G", "Policy3-G")), _pairs_below),
    Claim("Policy4-G (instinct as a reward term) has the lowest success of the learned policies", "success_rate",
          (("Policy4-G",), LEARNED), _lowest),
    Claim("the tangential term helps (Policy3-G above Policy5-G, success)", "success_rate",
          (("Policy5-G",), ("Policy3-G",)), _pairs_below),
    Claim("a wider field of view gives more compact flocks (d_c, 2 pi below 0.5 pi, without instinct)", "d_c",
          (("Policy1", "Policy1-G"), ("Policy2", "Policy2-G")), _pairs_below),
)


def claim_verdicts(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """For each of :data:`CLAIMS`: how many of its comparisons hold in the paper's Table III and
    in ours, with the values compared. Rows missing a policy give ``None`` for that side."""
    by_name = {r["policy"]: r for r in rows}
    out = []
    for claim in CLAIMS:
        names = list(dict.fromkeys(n for g in claim.groups for n in g))
        verdict: dict[str, Any] = {"claim": claim.text, "metric": claim.metric}
        for side, column in (("paper", f"{claim.metric}_paper"), ("ours", claim.metric)):
            values = {n: _float(by_name[n].get(column)) if n in by_name else math.nan for n in names}
            if any(math.isnan(v) for v in values.values()):
                verdict[side], verdict[f"{side}_values"] = None, values
                continue
            verdict[side] = claim.compare(claim.groups, values.__getitem__)
            verdict[f"{side}_values"] = values
        out.append(verdict)
    return out


def claims_markdown(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The claims as a markdown table: holds in k of n comparisons, paper and ours, with values."""
    def fmt(v: Any) -> str:
        return "—" if v is None else ("holds" if v[0] == v[1] else f"{v[0]} of {v[1]}")

    lines = ["**The paper's claims, on Table III** (comparisons that hold, paper / ours; values ours / paper):", "",
             "| claim | paper | ours | values |", "|---|---|---|---|"]
    for v in claim_verdicts(rows):
        scale, digits = (100, 1) if v["metric"] == "success_rate" else (1, 3)
        values = ", ".join(
            f"{n} {scale * v['ours_values'][n]:.{digits}f} / {scale * v['paper_values'][n]:.{digits}f}"
            for n in v["ours_values"])
        lines.append(f"| {v['claim']} | {fmt(v['paper'])} | {fmt(v['ours'])} | {v['metric']}: {values} |")
    return lines + [""]


# ---------------------------------------------------------------------------- markdown
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
        label = [str(row[k]) for k in keys]
        blank = [""] * len(keys)
        success = _pct(_float(row["success_rate"]))
        low, high = _float(row.get("success_rate_low")), _float(row.get("success_rate_high"))
        if not math.isnan(low):
            success += f" [{100 * low:.1f}, {100 * high:.1f}]"
        ours = [_pm(_float(row[m]), _float(row[f"{m}_std"])) for m in CELL_METRICS]
        paper = [_pm(_float(row[f"{m}_paper"]), _float(row[f"{m}_std_paper"])) for m in CELL_METRICS]
        diff = ["—" if math.isnan(_float(row[f"{m}_diff"])) else f"{_float(row[f'{m}_diff']):+.3f}"
                for m in CELL_METRICS]
        lines.append("| " + " | ".join([*label, "ours", *ours, success,
                                         _pct(_float(row.get("safe_success_rate")))]) + " |")
        if not math.isnan(_float(row["success_rate_paper"])):
            lines.append("| " + " | ".join([*blank, "paper", *paper, _pct(_float(row["success_rate_paper"])),
                                             "n/a"]) + " |")
            diff_rate = _float(row["success_rate_diff"])
            lines.append("| " + " | ".join([*blank, "Δ", *diff, "—" if math.isnan(diff_rate)
                                             else f"{100 * diff_rate:+.1f} pp", ""]) + " |")
    notes = [(tuple(str(r[k]) for k in keys), r.get("note")) for r in rows if r.get("note")]
    if notes:
        lines += ["", "Notes:", ""]
        lines += [f"- {' / '.join(k)}: {n}" for k, n in notes]
    return "\n".join(lines) + "\n"


def table_header(table: int, reading: str, episodes: int, seed: int, score: Fidelity) -> str:
    return (f"Reading **{reading}** (docs/specification.md section 9); {score}. Ours: {episodes} episodes per "
            f"checkpoint, evaluation seed {seed}, deterministic actions; learned policies pool all their shipped "
            f"seeds. Paper: Bai et al., IEEE Trans. Cybern. 54(1) 2024, Table {ROMAN[table]} (500 episodes). "
            "Δ = ours − paper. Success: goal reached without obstacle collision, with its 95 % Wilson interval; "
            "safe success also needs no UAV pair closer than d_min^b (the paper does not report it).")


def _pair(row: Mapping[str, Any], metric: str, digits: int = 3, scale: float = 1.0) -> str:
    ours, paper = _float(row.get(metric)), _float(row.get(f"{metric}_paper"))
    mine = "—" if math.isnan(ours) else f"{scale * ours:.{digits}f}"
    return mine if math.isnan(paper) else f"{mine} / {scale * paper:.{digits}f}"


def _percent(value: Any) -> str:
    value = _float(value)
    return "—" if math.isnan(value) else f"{100 * value:.1f}"


def summary_markdown(rows: Mapping[int, Sequence[Mapping[str, Any]]], reading: str, score: Fidelity) -> str:
    """README-sized views of the tables present: ours / paper for the columns that tell most."""
    lines = [f"# Summary, reading `{reading}`", "", f"{score}.", ""]
    if 3 in rows:
        lines += ["**Table III, training scenario** (ours / paper):", "",
                  "| policy | success % | safe_success % | d_min_uav (m) | d_min_obs (m) | d_c (m) | t_goal (s) |",
                  "|---|---|---|---|---|---|---|"]
        for r in rows[3]:
            lines.append(f"| {r['policy']} | {_pair(r, 'success_rate', 1, 100)} | "
                         f"{_percent(r.get('safe_success_rate'))} | {_pair(r, 'd_min_uav')} | "
                         f"{_pair(r, 'd_min_obs')} | {_pair(r, 'd_c')} | {_pair(r, 't_goal', 1)} |")
        lines.append("")
        lines += claims_markdown(rows[3])
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
    """(Re)write every ``table<k>.md`` in ``out_dir`` from its CSV, headed by the reading's
    fidelity score over the Tables III and IV found there; write ``fidelity.md`` and
    ``summary.md`` (the README's compact views)."""
    out_dir = Path(out_dir)
    rows = {t: read_table_csv(out_dir / f"table{t}.csv") for t in TABLE_NUMBERS if (out_dir / f"table{t}.csv").is_file()}
    score = fidelity(rows)
    for t, table_rows in rows.items():
        write_text(out_dir / f"table{t}.md", markdown_table(t, table_rows, table_header(t, reading, episodes, seed,
                                                                                         score)))
    write_text(out_dir / "summary.md", summary_markdown(rows, reading, score))
    write_text(out_dir / "fidelity.md", f"# Fidelity of the reading `{reading}`\n\n{score}.\n\n"
               "Definition (fixed before any result was seen, docs/specification.md section 9): the mean over Table "
               "III's twelve policies and Table IV's 25 cells of |ours - paper| / max(paper std, 0.1 |paper|, 0.05) "
               "over d_min_obs, d_min_uav, d_c, v_error, phi_error, speed and t_goal.\n")
    return score


# ---------------------------------------------------------------------------- reproduction
def reproduce(table: int, reading: str, episodes: int = 500, seed: int = EVAL_SEED, device: str = "cpu",
              checkpoints_dir: str | Path = "checkpoints", out_dir: str | Path = ".",
              policies: Mapping[str, Any] | None = None, only: Sequence[str] | None = None,
              episodes_csv: bool = True, paper_run: str | Path | None = None,
              log: Callable[[str], None] = print) -> dict[str, Any]:
    """Evaluate everything a paper table needs under ``reading`` and write ``table<k>.md`` /
    ``.csv`` (plus ``table<k>_seeds.csv``, ``table<k>_episodes.csv``, ``fidelity.md``) to ``out_dir``.

    Learned policies pool their shipped seeds (``<checkpoints_dir>/<reading>/<id>/seed<k>.pt``),
    each on the same seeded episodes; rule-based ones run their controller. A policy with
    nothing to evaluate keeps an empty row with a note. ``paper_run``: a checkpoint of the
    paper's own recipe, added to Table III as its own row.

    Args:
        policies: policy name -> a module / checkpoint (or a list) used instead (tests).
        only: evaluate only these policy names.
    """
    entries = table_entries(table)
    wanted = set(only) if only else None
    results: dict[tuple[str, ...], EvaluationResult] = {}
    notes: dict[tuple[str, ...], str] = {}
    seed_rows, episode_rows, failed = [], [], []
    t0 = time.perf_counter()
    for entry in entries:
        if wanted is not None and entry.policy not in wanted:
            notes[entry.key] = "not requested"
            continue
        given = (policies or {}).get(entry.policy)
        try:
            if isinstance(given, (list, tuple)):
                result = EvaluationResult.pooled([evaluate(g, entry.scenario, reading, episodes, seed, device,
                                                           entry.env_overrides) for g in given])
            else:
                result = evaluate(given if given is not None else entry.policy, entry.scenario, reading, episodes,
                                  seed, device, entry.env_overrides, checkpoints_dir=checkpoints_dir)
        except Exception as exc:  # one missing checkpoint must not cost the whole table
            log(f"[table {table}] {' / '.join(entry.key)}: skipped: {exc}")
            notes[entry.key] = f"not evaluated: {exc}"
            failed.append(" / ".join(entry.key))
            continue
        result.policy = entry.policy
        results[entry.key] = result
        if len(result.parts) > 1:
            notes[entry.key] = f"{len(result.parts)} checkpoints pooled ({result.n_episodes} episodes)"
        log(f"[table {table}] {' / '.join(entry.key)}: {result}")
        key_cols = dict(zip(KEY_COLUMNS[table], entry.key))
        for part in result.parts or [result]:
            seed_rows.append({**key_cols, "checkpoint": part.source, **part.summary(),
                              "rollout_steps": part.rollout_steps, "wall_time_s": round(part.wall_time_s, 2)})
            if episodes_csv:
                episode_rows += [{**key_cols, "checkpoint": part.source, **rec} for rec in part.records()]
    rows = comparison_rows(table, results, notes)
    if table == 3 and paper_run is not None:
        if Path(paper_run).is_file():
            extra = evaluate(paper_run, "train", reading, episodes, seed, device)
            log(f"[table 3] {PAPER_RECIPE_ROW}: {extra}")
            counters = _counters(paper_run)
            rows.append(comparison_row(3, (PAPER_RECIPE_ROW,), extra.summary(), None,
                                       f"experiment=paper, {counters}", 1))
        else:
            log(f"[table 3] {PAPER_RECIPE_ROW}: skipped, no checkpoint at {paper_run}")
    out_dir = Path(out_dir)
    csv_path = write_csv(out_dir / f"table{table}.csv", csv_columns(table), rows)
    if seed_rows:
        write_csv(out_dir / f"table{table}_seeds.csv", list(seed_rows[0]), seed_rows)
    if episode_rows:
        write_csv(out_dir / f"table{table}_episodes.csv", list(episode_rows[0]), episode_rows)
    score = render_tables(out_dir, reading, episodes, seed)
    log(f"[table {table}] {reading}: wrote {out_dir / f'table{table}.md'} and {csv_path} "
        f"({len(results)}/{len(entries)} rows, {time.perf_counter() - t0:.1f} s); {score}"
        + (f"; not evaluated: {failed}" if failed else ""))
    return {"rows": rows, "markdown": out_dir / f"table{table}.md", "csv": csv_path, "failed": failed,
            "fidelity": score}


def _counters(path: str | Path) -> str:
    from ..policies.checkpoint import load_checkpoint

    c = load_checkpoint(path)["counters"]
    return f"{c['episodes']} episodes, {c['updates']} updates, {c['seconds'] / 3600:.1f} h"


__all__ = ["CLAIMS", "Claim", "FIDELITY_METRICS", "Fidelity", "KEY_COLUMNS", "LEARNED", "PAPER_RECIPE_ROW",
           "REFERENCE_DIR", "TABLE_NUMBERS", "TableEntry", "VALUE_COLUMNS", "claim_verdicts", "claims_markdown",
           "comparison_rows", "csv_columns", "fidelity", "fidelity_terms", "load_reference",
           "markdown_table", "render_tables", "reproduce", "table_entries"]
