"""Paper-table writer and reproduction: rows and columns as the paper's CSVs, values, end to end."""

from __future__ import annotations

import csv
import gzip
import io
import math
from pathlib import Path

import pytest

from flock_torchrl.config import app_config
from flock_torchrl.io import shown, write_csv
from flock_torchrl.policies.scripted import goal_seeking_policy
from flock_torchrl.report.claims import CLAIMS, LEARNED, claim_verdicts, fidelity, fidelity_terms
from flock_torchrl.report.markdown import claims_markdown, render_tables
from flock_torchrl.report.reference import (KEY_COLUMNS, REFERENCE_DIR, VALUE_COLUMNS, comparison_rows, csv_columns,
                                            load_reference, table_entries)
from flock_torchrl.report.reproduce import reproduce
from helpers import run_script
from flock_torchrl.world.metrics import CELL_METRICS

ROOT = Path(__file__).resolve().parent.parent
SHARED_PAPER = Path("/work/shared/paper")


def _read(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    text = gzip.decompress(path.read_bytes()).decode() if path.suffix == ".gz" else path.read_text()
    reader = csv.DictReader(io.StringIO(text))
    return list(reader.fieldnames or []), list(reader)


@pytest.mark.parametrize("table", [3, 4, 5])
def test_reference_copies_are_the_papers_tables(table):
    fields, rows = load_reference(table)
    assert fields[: len(KEY_COLUMNS[table])] == list(KEY_COLUMNS[table])
    assert fields[len(KEY_COLUMNS[table]):] == list(VALUE_COLUMNS)
    assert len(rows) == {3: 12, 4: 25, 5: 5}[table]
    assert (REFERENCE_DIR / "README.md").read_text().count("Bai") >= 1
    shared = SHARED_PAPER / f"table{table}.csv"
    if shared.is_file():  # the brief's copy, where this checkout has it
        assert (REFERENCE_DIR / f"table{table}.csv").read_bytes() == shared.read_bytes()


def test_entries_follow_the_paper_rows():
    t3, t4, t5 = table_entries(3), table_entries(4), table_entries(5)
    assert [e.policy for e in t3][:2] == ["Policy1", "Policy1-G"] and t3[-1].policy == "Policy-OP"
    assert all(e.scenario == "train" and not e.env_overrides for e in t3)
    assert t4[0].key == ("S1", "Policy3-G") and t4[0].scenario == "s1" and t4[-1].key == ("S5", "Policy-OP")
    assert [e.env_overrides["tau_v"] for e in t5] == [0.2, 0.5, 1.0, 1.5, 2.0]
    assert all(e.policy == "Policy3-G" and e.scenario == "tau_v" for e in t5)


@pytest.mark.parametrize("table", [3, 4, 5])
def test_written_table_has_the_papers_rows_and_columns(tmp_path, table):
    ref_fields, ref_rows = load_reference(table)
    first = table_entries(table)[0].key
    ours = {c: 1.0 for c in VALUE_COLUMNS}
    ours.update(success_rate=0.9, safe_success_rate=0.8, n_episodes=500)
    write_csv(tmp_path / f"table{table}.csv", csv_columns(table), comparison_rows(table, {first: ours}))
    render_tables(tmp_path, "literal", 500, 2024)
    fields, rows = _read(tmp_path / f"table{table}.csv")
    assert set(ref_fields) <= set(fields)  # every paper column, holding our value
    assert "safe_success_rate" in fields
    for c in VALUE_COLUMNS:
        assert f"{c}_paper" in fields and f"{c}_diff" in fields
    keys = KEY_COLUMNS[table]
    assert [tuple(r[k] for k in keys) for r in rows] == [tuple(r[k] for k in keys) for r in ref_rows]
    row, ref = rows[0], ref_rows[0]
    assert float(row["success_rate"]) == 0.9 and float(row["safe_success_rate"]) == 0.8
    assert float(row["d_c_paper"]) == float(ref["d_c"])
    assert float(row["d_c_diff"]) == pytest.approx(1.0 - float(ref["d_c"]), abs=1e-5)
    assert rows[1]["d_c"] == "" and float(rows[1]["d_c_paper"]) == float(ref_rows[1]["d_c"])
    text = (tmp_path / f"table{table}.md").read_text()
    assert text.count("| paper |") == len(ref_rows) and "90.0 %" in text and "safe success" in text
    assert "Reading **literal**" in text and "fidelity score" in text
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # atomic: no temp files


def test_comparison_rows_without_results_keep_paper_values():
    rows = comparison_rows(5, {})
    assert [r["tau_v"] for r in rows] == ["0.2", "0.5", "1.0", "1.5", "2.0"]
    assert rows[2]["success_rate_paper"] == 0.938 and math.isnan(rows[2]["success_rate"])
    assert rows[0]["note"] == "not evaluated"


def test_fidelity_score_by_hand():
    # Table III, Policy3-G (paper: d_min_obs 3.549 +- 0.937, d_min_uav 1.627 +- 0.276, d_c 3.393 +- 0.610,
    # v_error 0.268 +- 0.067, phi_error 0.159 +- 0.219, speed 2.052 +- 0.076, t_goal 36.709 +- 1.434).
    paper = {r["policy"]: r for r in load_reference(3)[1]}["Policy3-G"]
    ours = {m: float(paper[m]) for m in CELL_METRICS}
    ours["d_min_uav"] = 1.627 - 2 * 0.276          # two paper stds off: term 2
    ours["v_error"] = 0.268 + 0.134                # denominator max(0.067, 0.0268, 0.05) = 0.067: term 2
    ours["t_goal"] = 36.709 + 36.709 * 0.1 * 3     # max(1.434, 3.6709, 0.05) = 3.6709: term 3
    ours["phi_error"] = 0.159 + 0.219 / 2          # term 0.5
    rows = comparison_rows(3, {("Policy3-G",): ours})
    terms = fidelity_terms([r for r in rows if r["policy"] == "Policy3-G"])
    assert sorted(terms) == pytest.approx(sorted([0, 2, 0, 2, 0.5, 0, 3]), abs=1e-9)
    score = fidelity({3: rows})
    assert score.score == pytest.approx(7.5 / 7) and score.terms == 7 and not score.complete
    assert score.expected == (12 + 25) * 7
    # Per metric, the same terms one by one (one row: each metric's mean is its term).
    assert score.per_metric == pytest.approx({"d_min_obs": 0, "d_min_uav": 2, "d_c": 0, "v_error": 2,
                                              "phi_error": 0.5, "speed": 0, "t_goal": 3}, abs=1e-9)
    assert score.metric_line().startswith("mean term per metric: t_goal 3.00, ")
    # A row the paper lacks (the paper recipe's own) counts nothing; a missing value counts nothing.
    extra = dict(rows[0], policy="Policy3-G (paper recipe)", d_c_paper=math.nan)
    assert fidelity({3: [*rows, extra]}).terms == 7
    # 0.05 floor: paper 0.002 +- 0.002 (Table IV, S1 Policy-OP v_error), ours 0.052: term 1.
    assert fidelity_terms([{"v_error": 0.052, "v_error_paper": 0.002, "v_error_std_paper": 0.002}]) == \
        pytest.approx([1.0])


def test_claims_by_hand():
    # The paper's own Table III: every claim holds (d_min_uav 1.581-1.742 instinct vs <= 0.190 without;
    # success 88.8 < 93.6, 87.2 < 97.0, 87.6 < 93.8; Policy4-G 65.4 lowest; 93.8 > 88.6; d_c 1.112 < 2.945,
    # 0.804 < 1.275).
    paper_rows = comparison_rows(3, {})
    verdicts = claim_verdicts(paper_rows)
    assert len(verdicts) == len(CLAIMS) == 6
    assert all(v["paper"] is not None and v["paper"][0] == v["paper"][1] for v in verdicts)
    assert all(v["ours"] is None for v in verdicts)          # nothing evaluated: no verdict
    # Ours: success saturated at 1.0 for Policy1 and Policy1-G (not greater), Policy2-G 0.99 < Policy2's 1.0.
    ours = {name: {"success_rate": 1.0, "d_min_uav": 0.5, "d_c": 3.0} for name in LEARNED}
    ours["Policy2-G"]["success_rate"] = 0.99
    ours["Policy3-G"]["success_rate"] = 1.0
    ours["Policy3"]["success_rate"] = 0.9                  # one pair of three: 1.0 > 0.9
    ours["Policy4-G"]["success_rate"] = 0.95               # above Policy3's 0.9: not the lowest
    ours["Policy3"]["d_min_uav"], ours["Policy5-G"]["d_min_uav"] = 1.2, 1.1   # Policy3-G 0.5 <= 1 m
    ours["Policy1"]["d_min_uav"] = 0.6                     # above Policy3-G's 0.5: instinct not above all
    ours["Policy1"]["d_c"], ours["Policy2"]["d_c"] = 2.0, 4.0   # 1 of 2 (Policy1-G 3.0 = Policy2-G 3.0)
    rows = comparison_rows(3, {(n,): v for n, v in ours.items()})
    got = {v["claim"].split(" (")[0]: v["ours"] for v in claim_verdicts(rows)}
    assert list(got.values()) == [(0, 1), (2, 3), (1, 3), (0, 1), (0, 1), (1, 2)]
    table = "\n".join(claims_markdown(rows))
    assert "| 2 of 3 |" in table and "Policy4-G 95.0 / 65.4" in table
    # A table of some policies (the paper recipe's): ours counts what it can. Policy1 0.984 above
    # Policy1-G 0.95 (0 of the 1 pair left); Policy3-G's 1.727 m above both 0.001 m (holds, and
    # above 1 m); Policy4-G, Policy5-G and Policy2 missing: no verdict.
    some = {"Policy1": {"success_rate": 0.984, "d_min_uav": 0.001, "d_c": 0.9},
            "Policy1-G": {"success_rate": 0.95, "d_min_uav": 0.001, "d_c": 0.5},
            "Policy3-G": {"success_rate": 0.99, "d_min_uav": 1.727, "d_c": 3.6}}
    verdicts = claim_verdicts(comparison_rows(3, {(n,): v for n, v in some.items()}))
    assert [v["ours"] for v in verdicts] == [(1, 1), (1, 1), (0, 1), None, None, None]
    assert [v["ours_partial"] for v in verdicts] == [True, True, True, False, False, False]
    assert all(v["paper"][0] == v["paper"][1] for v in verdicts)   # the paper's side as stated
    assert "| 0 of 1 (of those evaluated) |" in "\n".join(claims_markdown(comparison_rows(3, {(n,): v for n, v in
                                                                                              some.items()})))


def test_reproduce_end_to_end_with_a_scripted_policy(tmp_path):
    policy = goal_seeking_policy()
    cfg = app_config("reproduce", table=3, reading="literal", episodes=4, checkpoints_dir=tmp_path / "none",
                     only=["Policy3-G"])
    out = reproduce(cfg, tmp_path / "results", policies={"Policy3-G": policy}, log=lambda m: None)
    assert out["failed"] == [] and out["markdown"].is_file() and out["csv"].is_file()
    fields, rows = _read(out["csv"])
    by_policy = {r["policy"]: r for r in rows}
    assert len(rows) == 12 and by_policy["Policy3-G"]["n_episodes"] == "4"
    assert by_policy["Policy3-G"]["success_rate"] != "" and by_policy["Policy1"]["success_rate"] == ""
    assert by_policy["Policy1"]["note"] == "not requested"
    _, episodes = _read(tmp_path / "results" / "table3_episodes.csv.gz")
    assert len(episodes) == 4 and {e["policy"] for e in episodes} == {"Policy3-G"}
    _, seeds = _read(tmp_path / "results" / "table3_seeds.csv")
    assert len(seeds) == 1
    assert "INCOMPLETE" in (tmp_path / "results" / "fidelity.md").read_text()


@pytest.mark.slow  # a whole reproduce run over shipped checkpoints (~10 s)
def test_tables_name_a_checkpoint_by_its_path_in_the_working_directory(tmp_path, monkeypatch):
    # A shipped table must not carry this machine's absolute path (checkpoints/ is inside the
    # repository; the seed and episode rows name it from there).
    monkeypatch.chdir(ROOT)
    assert shown(str(ROOT / "checkpoints" / "literal" / "policy3_g" / "seed0.pt")) == "checkpoints/literal/policy3_g/seed0.pt"
    assert shown("/elsewhere/seed0.pt") == "/elsewhere/seed0.pt" and shown("baseline:policy_ma") == "baseline:policy_ma"
    cfg = app_config("reproduce", table=3, reading="literal", episodes=2, checkpoints_dir=ROOT / "checkpoints",
                     only=["Policy3-G"])
    reproduce(cfg, tmp_path / "results", log=lambda m: None)
    _, seeds = _read(tmp_path / "results" / "table3_seeds.csv")
    _, episodes = _read(tmp_path / "results" / "table3_episodes.csv.gz")
    assert len(seeds) >= 3 and len(episodes) == 2 * len(seeds)
    assert {r["checkpoint"] for r in seeds} == {r["checkpoint"] for r in episodes}
    assert all(r["checkpoint"].startswith("checkpoints/literal/policy3_g/seed") for r in seeds)


@pytest.mark.slow
def test_reproduce_app_checks_every_checkpoint_before_the_first_row(tmp_path):
    # Nothing shipped where checkpoints_dir points: refused at once, naming the setting, nothing written.
    out = tmp_path / "out"
    proc = run_script("reproduce.py", "table=5", "episodes=2", f"checkpoints_dir={tmp_path / 'none'}",
                      f"hydra.run.dir={out}", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "checkpoints_dir=" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not out.exists()
    # A corrupted checkpoint among the shipped ones: refused before any row is evaluated.
    shipped = tmp_path / "ckpt" / "paper_fit" / "policy3_g"
    shipped.mkdir(parents=True)
    (shipped / "seed0.pt").write_bytes(b"not a checkpoint")
    proc = run_script("reproduce.py", "table=5", "episodes=2", "reading=paper_fit", f"checkpoints_dir={tmp_path / 'ckpt'}",
                      f"hydra.run.dir={out}", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "seed0.pt" in proc.stderr and "weights_only=False" not in proc.stderr
    assert not out.exists()
    # Unknown keys are Hydra's own errors (exit 1); a bad table number is ours (exit 2).
    bad_key = run_script("reproduce.py", "tabel=3", cwd=tmp_path, check=False)
    assert bad_key.returncode == 1 and "tabel" in bad_key.stderr
    bad_value = run_script("reproduce.py", "table=7", cwd=tmp_path, check=False)
    assert bad_value.returncode == 2 and bad_value.stderr.startswith("error: table: must be one of 3, 4, 5")


def test_comparison_by_hand(tmp_path):
    from flock_torchrl.config import COMPARED
    from flock_torchrl.report.compare import compare_rows, read_table, render_comparison

    # A reference table: two rows and an extra row (never compared).
    ref = [{"policy": "Policy1", "extra": "", **{m: 1.0 for m in COMPARED}, "success_rate": 0.950, "d_min_uav": 0.50},
           {"policy": "Policy3-G", "extra": "", **{m: 1.0 for m in COMPARED}, "success_rate": 0.990, "d_min_uav": 1.50},
           {"policy": "Policy3-G (paper recipe)", "extra": "paper recipe", **{m: 1.0 for m in COMPARED}}]
    path = write_csv(tmp_path / "table3.csv", ["policy", "extra", *COMPARED], ref)
    reference = read_table(path, 3)
    assert sorted(reference) == [("Policy1",), ("Policy3-G",)]
    new = [{"policy": "Policy1", "extra": "", "n_episodes": 500, **{m: 1.0 for m in COMPARED},
            "success_rate": 0.958, "d_min_uav": 0.65},           # +0.8 pp within; +0.15 m outside 0.1 m
           {"policy": "Policy3-G", "extra": "", "n_episodes": 500, **{m: 1.0 for m in COMPARED},
            "success_rate": 0.975, "d_min_uav": 1.45},           # -1.5 pp outside 1 pp; -0.05 m within
           {"policy": "Policy2", "extra": "", "n_episodes": 500, **{m: 1.0 for m in COMPARED}},  # not in the reference
           {"policy": "Policy4-G", "extra": "", "n_episodes": ""}]                               # not evaluated
    rows = compare_rows(3, reference, new, {"success_rate": 0.01, "d_min_uav": 0.1})
    assert [r["policy"] for r in rows] == ["Policy1", "Policy3-G"]
    p1, p3 = rows
    assert p1["success_rate_delta"] == pytest.approx(0.008) and p1["success_rate_within"]
    assert p1["d_min_uav_delta"] == pytest.approx(0.15) and not p1["d_min_uav_within"] and not p1["within"]
    assert p3["success_rate_delta"] == pytest.approx(-0.015) and not p3["success_rate_within"]
    assert p3["d_min_uav_within"] and not p3["within"]
    assert compare_rows(3, reference, new, {"success_rate": 0.02, "d_min_uav": 0.2})[0]["within"]
    text = render_comparison(3, rows, {"success_rate": 0.01, "d_min_uav": 0.1}, path, "new")
    assert "0 of 2 rows within it" in text and "95.0 % / 95.8 % / +0.8 pp" in text and "0.500 / 0.650 / +0.150 ✗" in text


@pytest.mark.slow
def test_reproduce_writes_the_comparison_and_checks_its_inputs_first(tmp_path):
    policy = goal_seeking_policy()
    values = dict(table=3, reading="literal", episodes=3, checkpoints_dir=tmp_path / "none", only=["Policy3-G"],
                  episodes_csv=False)
    first = reproduce(app_config("reproduce", **values), tmp_path / "a", policies={"Policy3-G": policy},
                      log=lambda m: None)
    again = reproduce(app_config("reproduce", **values, compare_to=first["csv"],
                                 compare_tolerance={"success_rate": 0.0, "d_min_uav": 1e-5}),
                      tmp_path / "b", policies={"Policy3-G": policy}, log=lambda m: None)
    (row,) = again["comparison"]     # the same policy, episodes and seed: the same, up to the CSV's 6 digits
    assert row["policy"] == "Policy3-G" and row["within"] and row["success_rate_delta"] == 0.0
    assert abs(row["d_min_uav_delta"]) <= 1e-5 * abs(row["d_min_uav"])
    assert (tmp_path / "b" / "table3_vs_reference.md").is_file() and (tmp_path / "b" / "table3_vs_reference.csv").is_file()
    # A missing reference or an unknown column is refused before anything is evaluated.
    out = tmp_path / "out"
    proc = run_script("reproduce.py", "table=3", f"compare_to={tmp_path / 'nope.csv'}", f"hydra.run.dir={out}",
                      cwd=tmp_path, check=False)
    assert proc.returncode == 2 and proc.stderr.startswith("error: compare_to:") and not out.exists()
    proc = run_script("reproduce.py", "table=3", "+compare_tolerance.speedy=1", f"hydra.run.dir={out}",
                      cwd=tmp_path, check=False)
    assert proc.returncode == 2 and proc.stderr.startswith("error: compare_tolerance.speedy:") and not out.exists()


@pytest.mark.slow
def test_scaling_table_flies_a_policy_at_each_size(tmp_path):
    """report/scaling.py (make scaling) in the fast tier: one row per policy and size, the spawn
    radius by the reading's rule (literal: 3 m up to N = 9, docs/specification.md section 9),
    dashes for a rule-based policy's training, and the CSV, Markdown and plot written."""
    from flock_torchrl.report.scaling import scaling

    cfg = app_config("scaling", reading="literal", policy_name="policy_ma", sizes=[3], episodes=1)
    rows = scaling(cfg, tmp_path, log=lambda message: None)
    assert [(r["policy"], r["trained_sizes"], r["n_uavs"], r["n_episodes"]) for r in rows] == [("Policy-MA", "—", 3, 1)]
    assert rows[0]["spawn_radius"] == pytest.approx(3.0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scaling.csv", "scaling.md", "scaling.png"]
    assert "| Policy-MA | — | 3 | 3.00 | " in (tmp_path / "scaling.md").read_text()


@pytest.mark.slow
def test_scaling_table_puts_the_baselines_beside_a_learned_policy_on_forest(tmp_path, monkeypatch):
    """``others`` takes the rule-based baselines (rows named as in the paper, no
    training seed), and ``scenario="forest"`` flies every row in the forest, into scaling_forest.*
    (the training scenario's scaling.* stay as they are). The header names the shipped checkpoint
    relative to the working directory, never by this machine's absolute path."""
    from flock_torchrl.report.scaling import scaling

    monkeypatch.chdir(ROOT)
    cfg = app_config("scaling", reading="paper_fit", scenario="forest", policy_name="policy3_g", sizes=[3],
                     episodes=1, others=["policy_ma", "policy_op"])
    rows = scaling(cfg, tmp_path, log=lambda message: None)
    assert [(r["policy"], r["trained_sizes"], r["n_uavs"]) for r in rows] == [
        ("Policy3-G", "5", 3), ("Policy-MA", "—", 3), ("Policy-OP", "—", 3)]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scaling_forest.csv", "scaling_forest.md",
                                                          "scaling_forest.png"]
    text = (tmp_path / "scaling_forest.md").read_text()
    assert "(reading `paper_fit`, forest)" in text and "Scenario `forest`" in text
    assert "| Policy-OP | — | 3 |" in text
    assert "`checkpoints/paper_fit/policy3_g/seed0.pt`, `baseline:policy_ma`" in text and str(ROOT) not in text
