"""Paper-table writer and reproduction: rows and columns as the paper's CSVs, values, end to end."""

from __future__ import annotations

import csv
import math
import runpy
import sys
from pathlib import Path

import pytest

from flock_torchrl.evaluation import goal_seeking_policy
from flock_torchrl.tables import (KEY_COLUMNS, REFERENCE_DIR, VALUE_COLUMNS, comparison_rows, load_reference,
                                  parse_key_values, reproduce, table_entries, write_table)

ROOT = Path(__file__).resolve().parent.parent
SHARED_PAPER = Path("/work/shared/paper")


def _read(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
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
    md, csv_path = write_table(table, {first: ours}, tmp_path)
    fields, rows = _read(csv_path)
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
    text = md.read_text()
    assert text.count("| paper |") == len(ref_rows) and "90.0 %" in text and "safe success" in text
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # atomic: no temp files


def test_comparison_rows_without_results_keep_paper_values():
    rows = comparison_rows(5, {})
    assert [r["tau_v"] for r in rows] == ["0.2", "0.5", "1.0", "1.5", "2.0"]
    assert rows[2]["success_rate_paper"] == 0.938 and math.isnan(rows[2]["success_rate"])
    assert rows[0]["note"] == "not evaluated"


def test_reproduce_end_to_end_with_a_scripted_policy(tmp_path):
    policy = goal_seeking_policy()
    # No instinct: straight flights end early (crash on the central circle), keeping the test short.
    policy.flock_meta = {"policy": "scripted", "env": {"instinct": False}}
    out = reproduce(3, episodes=4, checkpoint_dir=tmp_path / "none", results_dir=tmp_path / "results",
                    policies={"Policy3-G": policy}, only=["Policy3-G"], log=lambda m: None)
    assert out["failed"] == [] and out["markdown"].is_file() and out["csv"].is_file()
    fields, rows = _read(out["csv"])
    by_policy = {r["policy"]: r for r in rows}
    assert len(rows) == 12 and by_policy["Policy3-G"]["n_episodes"] == "4"
    assert by_policy["Policy3-G"]["success_rate"] != "" and by_policy["Policy1"]["success_rate"] == ""
    assert by_policy["Policy1"]["note"] == "not requested"
    _, episodes = _read(tmp_path / "results" / "table3_episodes.csv")
    assert len(episodes) == 4 and {e["policy"] for e in episodes} == {"Policy3-G"}
    _, seeds = _read(tmp_path / "results" / "table3_seeds.csv")
    assert len(seeds) == 1


def _run_script(monkeypatch, capsys, *args: str) -> tuple[int, str, str]:
    """``scripts/reproduce.py args`` in this process (runpy; spares a second torch import)."""
    monkeypatch.setattr(sys, "argv", ["reproduce.py", *args])
    with pytest.raises(SystemExit) as exit_info:
        runpy.run_path(str(ROOT / "scripts" / "reproduce.py"), run_name="__main__")
    out = capsys.readouterr()
    return exit_info.value.code, out.out, out.err


def test_reproduce_script_skips_missing_checkpoints(tmp_path, monkeypatch, capsys):
    code, out, _ = _run_script(monkeypatch, capsys, "table=5", "episodes=2", f"checkpoints={tmp_path / 'none'}",
                               f"results={tmp_path / 'results'}")
    assert code == 0 and "skipped: no checkpoint" in out
    text = (tmp_path / "results" / "table5.md").read_text()
    assert "skipped: no checkpoint" in text and text.count("| paper |") == 5
    code, _, err = _run_script(monkeypatch, capsys, "tabel=3")
    assert code == 2 and "tabel=3" in err


def test_key_value_arguments_are_typed_and_checked():
    cfg = parse_key_values(["table=4", "episodes=20", "only=Policy3-G,Policy-MA", "episodes_csv=false"])
    assert (cfg.table, cfg.episodes, cfg.only, cfg.episodes_csv) == (4, 20, "Policy3-G,Policy-MA", False)
    with pytest.raises(ValueError, match="episodes"):
        parse_key_values(["episodes=many"])
    with pytest.raises(ValueError, match="key=value"):
        parse_key_values(["table"])


def test_evaluate_config_composes():
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        cfg = compose("evaluate", overrides=["scenario=tau_v", "scenario.tau_v=0.5", "episodes=3"])
    assert cfg.episodes == 3 and cfg.scenario.tau_v == 0.5 and cfg.policy.name == "Policy3-G"
    assert cfg.seed == 2024 and cfg.checkpoint is None
