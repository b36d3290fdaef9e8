"""README's "Where it stands", written from ``results/``: every number of that table comes from the
published tables, so it cannot drift from them (``make docs`` writes ``results/standing.md`` and
splices it into README.md; the tests compare the file with what this module makes of ``results/``).

It reads each reading's ``fidelity.md`` (the score), ``table3.csv`` (ours beside the paper's),
``table3_seeds.csv`` and ``table3_paper_recipe_seeds.csv`` (the verdicts over seeds), the paper
recipe's ``table3_paper_recipe.csv``, and ``paper_fit``'s ``scaling.csv`` and ``scaling_forest.csv``
(the scaling policy's seeds pooled, beside Olfati-Saber's Policy-MA); it also writes that pooled
comparison per scenario and size, ``results/paper_fit/scaling_pooled.md`` (docs/scaling.md quotes it).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Iterable, Sequence

from ..io import write_text
from ..run.results import wilson_interval
from .claims import CLAIMS, LEARNED
from .reference import read_table_csv
from .seeds import claim_verdict, comparisons_of, read_seed_scores

READINGS = ("paper_fit", "literal")
SCALING_POLICY = "Policy3-G-crowd-ramp-allround-radial"
PAPER_CAMERA_POLICY = "Policy3-G-crowd-ramp-radial"  # its twin with the paper's camera
BASELINE = "Policy-MA"                      # Olfati-Saber's flocking, the scaling tables' yardstick
INSTINCT_CLAIM, *_ = (c for c in CLAIMS if c.metric == "d_min_uav" and c.compare.__name__ == "_all_above")
SUCCESS_CLAIMS = [c for c in CLAIMS if c.metric == "success_rate"]


def _rows(path: Path) -> dict[str, dict[str, str]]:
    return {row["policy"]: row for row in read_table_csv(path)}


def _fidelity(results: Path, reading: str) -> str:
    text = (results / reading / "fidelity.md").read_text()
    found = re.search(r"^fidelity score (\d+\.\d{3}) ", text, re.M)
    if not found:
        raise ValueError(f"{results / reading / 'fidelity.md'} states no fidelity score")
    return found.group(1)


def _pct(value: float) -> str:
    return f"{100 * value:.1f}"


def _range(values: Sequence[float]) -> str:
    low, high = _pct(min(values)), _pct(max(values))
    return f"{low} %" if low == high else f"{low}-{high} %"


def _seeds(results: Path, reading: str, stem: str = "table3") -> list[int]:
    scores = read_seed_scores(results / reading / f"{stem}_seeds.csv", "success_rate")
    return sorted({len(v) for k, v in scores.items() if k in LEARNED})


def _count(seeds: list[int]) -> str:
    return str(seeds[0]) if len(seeds) == 1 else f"{seeds[0]}-{seeds[-1]}"


def _verdicts(seeds_csv: Path, claims) -> list[str]:
    out = []
    for claim in claims:
        found = comparisons_of(claim, read_seed_scores(seeds_csv, claim.metric))
        out.append(claim_verdict(found) if found else "no comparison")
    return out


def _learned(rows: dict[str, dict[str, str]], key: str) -> dict[str, float]:
    return {p: float(rows[p][key]) for p in LEARNED if p in rows and rows[p].get(key) not in (None, "")}


def instinct_row(results: Path) -> str:
    rows = _rows(results / "paper_fit" / "table3.csv")
    p3g = rows["Policy3-G"]
    without = [float(rows[p]["d_min_uav"]) for p in INSTINCT_CLAIM.groups[1]]
    (verdict,) = _verdicts(results / "paper_fit" / "table3_seeds.csv", [INSTINCT_CLAIM])
    return (f"| the instinct keeps UAVs apart (the paper's central claim) | {verdict} over seeds under `paper_fit`: "
            f"Policy3-G's closest pair {float(p3g['d_min_uav']):.3f} m (paper {float(p3g['d_min_uav_paper']):.3f} m), "
            f"safe success {_pct(float(p3g['safe_success_rate']))} % (the goal reached with no pair ever within 0.5 m); "
            f"without the instinct {min(without):.3f}-{max(without):.3f} m |")


def fidelity_row(results: Path) -> str:
    cells = []
    for reading in READINGS:
        note = "the default reading; " if reading == "paper_fit" else ""
        cells.append(f"`{reading}` {_fidelity(results, reading)} ({note}{_count(_seeds(results, reading))} seeds "
                     "pooled per learned policy)")
    return "| fidelity score (1.0: one paper std off on average; lower is closer) | " + ", ".join(cells) + " |"


def success_row(results: Path) -> str:
    cells = []
    for reading in READINGS:
        rows = _rows(results / reading / "table3.csv")
        ours, paper = _learned(rows, "success_rate"), _learned(rows, "success_rate_paper")
        cells.append(f"`{reading}` {_range(list(ours.values()))} (paper {_range(list(paper.values()))})")
    held = _verdicts(results / "paper_fit" / "table3_seeds.csv", SUCCESS_CLAIMS).count("holds")
    seeds = _count(_seeds(results, "paper_fit"))
    return (f"| success of the learned policies, fast recipe ({seeds} seeds each) | " + "; ".join(cells)
            + f": saturated, so {held} of the paper's {len(SUCCESS_CLAIMS)} claims on success differences hold "
            "over seeds (`paper_fit`) |")


def paper_recipe_row(results: Path) -> str:
    rows = _rows(results / "paper_fit" / "table3_paper_recipe.csv")
    trained = {p: float(r["success_rate"]) for p, r in rows.items()
               if p in LEARNED and r.get("success_rate") not in (None, "") and int(float(r["n_checkpoints"] or 0))}
    seeds = _seeds(results, "paper_fit", "table3_paper_recipe")
    held = _verdicts(results / "paper_fit" / "table3_paper_recipe_seeds.csv", SUCCESS_CLAIMS).count("holds")
    return (f"| the paper's own recipe (5000 episodes; {len(trained)} policies, {_count(seeds)} seeds each; "
            f"`paper_fit`) | {_range(list(trained.values()))}; {held} of the {len(SUCCESS_CLAIMS)} success claims "
            "hold over seeds |")


def baseline_row(results: Path) -> str:
    cells = []
    for reading in READINGS:
        rows = _rows(results / reading / "table3.csv")
        cells.append(f"`{reading}` Policy-MA {_pct(float(rows['Policy-MA']['success_rate']))} %, "
                     f"Policy-OP {_pct(float(rows['Policy-OP']['success_rate']))} %")
    return "| rule-based baselines (retuned per reading), success | " + "; ".join(cells) + " |"


def _pooled(rows: list[dict[str, str]], size: int, key: str) -> tuple[float, float, float, int]:
    """The seeds' rows at one swarm size pooled: rate, Wilson interval, episodes."""
    cells = [r for r in rows if int(r["n_uavs"]) == size]
    n = sum(int(r["n_episodes"]) for r in cells)
    k = round(sum(float(r[key]) * int(r["n_episodes"]) for r in cells))
    return (k / n, *wilson_interval(k, n), n)


def scaling_cells(path: Path, policy: str = SCALING_POLICY) -> list[dict]:
    """Per swarm size: ``policy``'s seeds pooled beside Policy-MA (safe success, success)."""
    rows = read_table_csv(path)
    mine = [r for r in rows if r["policy"].startswith(f"{policy} [")]
    base = {int(r["n_uavs"]): r for r in rows if r["policy"] == BASELINE}
    if not mine or not base:
        raise ValueError(f"{path} holds no rows of {policy} or {BASELINE}")
    cells = []
    for size in sorted({int(r["n_uavs"]) for r in mine}):
        safe, low, high, n = _pooled(mine, size, "safe_success_rate")
        b = base[size]
        cells.append({"n_uavs": size, "safe": safe, "low": low, "high": high, "episodes": n,
                      "seeds": sum(int(r["n_uavs"]) == size for r in mine),
                      "success": _pooled(mine, size, "success_rate")[0],
                      "base": float(b["safe_success_rate"]), "base_low": float(b["safe_success_rate_low"]),
                      "base_high": float(b["safe_success_rate_high"]), "base_episodes": int(b["n_episodes"])})
    return cells


def scaling_row(results: Path) -> str:
    scenarios = {"on the training scenario": results / "paper_fit" / "scaling.csv",
                 "in the forest": results / "paper_fit" / "scaling_forest.csv"}
    cells = {name: scaling_cells(path) for name, path in scenarios.items()}
    every = [c for found in cells.values() for c in found]
    above = sum(c["safe"] >= c["base"] for c in every)
    tied = sum(c["safe"] < c["base"] and c["high"] >= c["base_low"] for c in every)
    below = len(every) - above - tied
    sizes = sorted({c["n_uavs"] for c in every})
    largest = [(name, next(c for c in found if c["n_uavs"] == sizes[-1])) for name, found in cells.items()]
    at_largest = ", ".join(f"{_pct(c['safe'])} % against {_pct(c['base'])} % {name}" for name, c in largest)
    episodes = sorted({c["base_episodes"] for c in every})
    seeds = sorted({c["seeds"] for c in every})
    beyond = sum(c["low"] > c["base_high"] for c in every)
    judged = (f"at or above Olfati-Saber's (Policy-MA) in {above} of {len(every)} cells ({beyond} beyond both 95 % "
              f"intervals, {above - beyond} with the intervals overlapping)")
    if tied:
        judged += f", below it within the 95 % intervals in {tied}"
    if below:
        judged += f", below it beyond the intervals in {below}"
    twin = _cells_met(scenarios.values(), PAPER_CAMERA_POLICY)
    camera = f"; its twin with the paper's 0.5 pi camera ({PAPER_CAMERA_POLICY}) meets it in {twin}" if twin else ""
    space = [results / "paper_fit" / name for name in ("scaling_train3d.csv", "scaling_forest3d.csv")]
    flocks = [(name, _cells_met(space, policy)) for name, policy in (("the all-round flock", SCALING_POLICY),
                                                                      ("its paper's-camera twin", PAPER_CAMERA_POLICY))]
    flocks = [f"{name} in {met}" for name, met in flocks if met]
    space_clause = (f"; in space (`experiment=mixed_cluttered3d`, docs/threed.md) Policy-MA is met by "
                    f"{' and '.join(flocks)}" if flocks else "")
    return (f"| beyond the paper: flocks of {sizes[0]}-{sizes[-1]} UAVs (`paper_fit`) | your scenarios and "
            f"controllers through Hydra; {SCALING_POLICY} (`experiment=mixed_cluttered`, {_count(seeds)} seeds pooled, "
            f"{_count(episodes)} episodes per seed and cell; its actor sees all round): success "
            f"{_range([c['success'] for c in every])} at every size on both scenarios; safe success {judged}; "
            f"at {sizes[-1]} UAVs {at_largest}{camera} (docs/scaling.md){space_clause} |")


def _cells_met(tables: Iterable[Path], policy: str) -> str:
    """``"m of n cells (a above beyond both intervals)"``: section 11's count of ``policy``'s pooled cells
    beside Policy-MA over the scaling tables that hold its rows; ``""`` where none does."""
    cells = [c for path in tables if path.exists() and _has_rows(path, policy) for c in scaling_cells(path, policy)]
    met, above = _met_and_above([_verdict(c) for c in cells])
    return f"{met} of {len(cells)} cells ({above} above beyond both intervals)" if cells else ""


def _met_and_above(verdicts: Sequence[str]) -> tuple[int, int]:
    """Section 11's count: the cells met (not below Policy-MA beyond both intervals), and those above it
    beyond both intervals."""
    return (sum(v != "below, beyond both intervals" for v in verdicts),
            sum(v == "above, beyond both intervals" for v in verdicts))


def _verdict(c: dict) -> str:
    if c["low"] > c["base_high"]:
        return "above, beyond both intervals"
    if c["safe"] >= c["base"]:
        return "at or above, the intervals overlapping"
    if c["high"] >= c["base_low"]:
        return "below, the intervals overlapping"
    return "below, beyond both intervals"


# The pooled comparisons with Policy-MA (docs/specification.md section 11): file -> (policy, its
# scenarios' scaling tables, the make target that publishes them). Written where their rows are.
PLANE = {"train": "scaling.csv", "forest": "scaling_forest.csv"}, "`make publish-scaling`"
SPACE = {"train3d": "scaling_train3d.csv", "forest3d": "scaling_forest3d.csv"}, "`make publish-threed`"
POOLED = {"scaling_pooled.md": (SCALING_POLICY, *PLANE),
          "scaling_pooled_paper_camera.md": (PAPER_CAMERA_POLICY, *PLANE),
          "scaling3d_pooled.md": (SCALING_POLICY, *SPACE),
          "scaling3d_pooled_paper_camera.md": (PAPER_CAMERA_POLICY, *SPACE)}


def scaling_summary(reading_dir: str | Path, name: str = "scaling_pooled.md") -> str | None:
    """Markdown: a policy's seeds pooled beside Policy-MA, per scenario and swarm size (safe success
    with 95 % Wilson intervals, success, the verdict of docs/specification.md section 11), from the
    scaling tables of one reading's results (:data:`POOLED`); ``None`` where none holds its rows."""
    reading_dir = Path(reading_dir)
    policy, tables, made_by = POOLED[name]
    found = {scenario: reading_dir / table for scenario, table in tables.items()
             if (reading_dir / table).exists() and _has_rows(reading_dir / table, policy)}
    if not found:
        return None
    files = " and ".join(f"`{path.name}`" for path in found.values())
    lines = [f"# {policy} beside {BASELINE} (reading `{reading_dir.name}`)", "",
             f"{policy}'s shipped seeds pooled (the same episodes per seed), beside Olfati-Saber's "
             f"{BASELINE}, from {files} ({made_by}); rates in %, safe success with its 95 % Wilson interval. "
             "Written by `make docs`.", "",
             "| scenario | N | episodes (pooled / Policy-MA) | success: pooled / Policy-MA | safe success, pooled | "
             "safe success, Policy-MA | safe success against Policy-MA |",
             "|---|---|---|---|---|---|---|"]
    verdicts = []
    for scenario, path in found.items():
        base = {int(r["n_uavs"]): float(r["success_rate"]) for r in read_table_csv(path) if r["policy"] == BASELINE}
        for c in scaling_cells(path, policy):
            verdict = _verdict(c)
            verdicts.append(verdict)
            lines.append(f"| {scenario} | {c['n_uavs']} | {c['episodes']} / {c['base_episodes']} | "
                         f"{_pct(c['success'])} / {_pct(base[c['n_uavs']])} | {_pct(c['safe'])} "
                         f"[{_pct(c['low'])}, {_pct(c['high'])}] | {_pct(c['base'])} [{_pct(c['base_low'])}, "
                         f"{_pct(c['base_high'])}] | {verdict} |")
    if name != "scaling_pooled.md":  # the rule's count (the first table is quoted as it always was)
        (met, above), total = _met_and_above(verdicts), len(verdicts)
        lines += ["", f"Cells met (not below Policy-MA beyond both intervals): {met} of {total}; above it beyond "
                      f"both intervals: {above} of {total}."]
    return "\n".join(lines) + "\n"


def _has_rows(path: Path, policy: str) -> bool:
    return any(r["policy"].startswith(f"{policy} [") for r in read_table_csv(path))


def standing(results: str | Path = "results") -> str:
    """The markdown of README's "Where it stands" table (a title line first, dropped when spliced)."""
    results = Path(results)
    rows = [instinct_row(results), fidelity_row(results), success_row(results), paper_recipe_row(results),
            baseline_row(results), scaling_row(results)]
    return ("# Where it stands\n\n| question | answer |\n|---|---|\n" + "\n".join(rows) + "\n")


def write_standing(results: str | Path = "results", out: str | Path | None = None) -> list[Path]:
    """``results/standing.md`` (README's table) and the pooled comparisons with Policy-MA of
    :data:`POOLED` whose rows are published (``results/paper_fit/scaling*_pooled*.md``; docs/scaling.md
    and docs/threed.md quote them)."""
    results = Path(results)
    written = [write_text(Path(out) if out is not None else results / "standing.md", standing(results))]
    for name in POOLED:
        table = scaling_summary(results / "paper_fit", name)
        if table is not None:
            written.append(write_text(results / "paper_fit" / name, table))
    return written


__all__ = ["scaling_cells", "scaling_summary", "standing", "write_standing"]
