"""A user's own controllers as rows of the paper's tables (reproduce contenders=, evaluate
contender=): a factory from a file, from an import path with keyword arguments, a checkpoint;
marked as not the paper's, outside the fidelity score; bad ones named before anything runs."""

from __future__ import annotations

import csv
import os

import pytest

from helpers import ROOT, first_fast, run_script

EXAMPLE = f"{ROOT / 'examples' / 'goal_separation.py'}:make"
CHECKPOINT = ROOT / "checkpoints" / "paper_fit" / "policy3_g" / "seed0.pt"


def rows_of(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_contenders_are_rows_of_table_3_beside_the_papers_and_outside_its_score(tmp_path):
    base = ["table=3", "episodes=3", "only=[Policy-MA]", "episodes_csv=false"]
    run_script("reproduce.py", *base, f"hydra.run.dir={tmp_path / 'plain'}", cwd=tmp_path)
    run_script("reproduce.py", *base, f"contenders=[{EXAMPLE},{CHECKPOINT}]", f"hydra.run.dir={tmp_path / 'with'}",
               cwd=tmp_path)
    rows = {r["policy"]: r for r in rows_of(tmp_path / "with" / "table3.csv")}
    assert {"Policy-MA", "goal_separation", "Policy3-G (seed0)"} <= set(rows)
    assert rows["Policy-MA"]["extra"] == ""
    assert rows["goal_separation"]["extra"] == f"contender: {EXAMPLE}; world: fov 0.50 pi, instinct off"
    assert rows["Policy3-G (seed0)"]["extra"].startswith("contender: ") and float(rows["goal_separation"]["success_rate"]) > 0
    # same protocol: Policy-MA's row is the same with or without contenders; the score ignores them
    plain = {r["policy"]: r for r in rows_of(tmp_path / "plain" / "table3.csv")}
    assert plain["Policy-MA"] == rows["Policy-MA"]
    fidelity = [(tmp_path / d / "table3.md").read_text().splitlines()[2] for d in ("plain", "with")]
    assert fidelity[0] == fidelity[1]
    assert "goal_separation" in (tmp_path / "with" / "table3.md").read_text()


@pytest.mark.slow
def test_a_contender_from_an_import_path_with_arguments_is_evaluated_and_in_table_4(tmp_path):
    package = tmp_path / "lab" / "mylab"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "ctl.py").write_text((ROOT / "examples" / "goal_separation.py").read_text())
    env = {"PYTHONPATH": f"{ROOT}{os.pathsep}{tmp_path / 'lab'}"}
    proc = run_script("evaluate.py", "+contender={_target_: mylab.ctl.make, name: Cautious, near: 0.8}",
                      "scenario=s2", "episodes=2", f"hydra.run.dir={tmp_path / 'ev'}", cwd=tmp_path, **env)
    assert "Cautious on s2" in proc.stdout
    # Table IV (every scenario) and Table III, an import path and a checkpoint each.
    for table, only, expect in ((4, "Policy-MA", ["S1", "S2", "S3", "S4", "S5"]), (3, "Policy-OP", [None])):
        out = tmp_path / f"t{table}"
        run_script("reproduce.py", f"table={table}", "episodes=2", f"only=[{only}]", "episodes_csv=false",
                   f"contenders=[mylab.ctl.make,{CHECKPOINT}]", f"hydra.run.dir={out}", cwd=tmp_path, **env)
        rows = rows_of(out / f"table{table}.csv")
        for name in ("ctl", "Policy3-G (seed0)"):
            mine = [r for r in rows if r["policy"] == name]
            assert sorted(r.get("scenario") for r in mine) == expect and all(r["extra"] for r in mine), (table, name)


@pytest.mark.parametrize("spec, words", first_fast([
    ("examples/nowhere.py:make", "no file"),
    (f"{ROOT / 'examples' / 'goal_separation.py'}:build", "defines no function 'build'"),
    ("mylab_missing.make", "cannot import the factory 'mylab_missing.make'"),
    ("{name: x}", "a mapping with _target_"),
]))
def test_a_bad_contender_is_named_before_anything_runs(tmp_path, spec, words):
    proc = run_script("reproduce.py", "table=3", "episodes=2", "only=[Policy-MA]", f"contenders=[{spec}]",
                      f"hydra.run.dir={tmp_path / 'out'}", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "contenders" in proc.stderr and words in proc.stderr, proc.stderr
    assert not (tmp_path / "out" / "table3.csv").exists()
