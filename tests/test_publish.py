"""Publishing (flock_torchrl/run/publication.py, flock_torchrl/report/publish.py, scripts/publish.py): every
make target that writes results/, figures/, checkpoints/ or the documents lands its whole set or nothing,
whatever moment a stop signal comes; each is one line of the Makefile; its entry points answer as the apps
do (one ``error:`` line, exit status 2; a stop signal, one line).

A publication is stopped at its k-th file landed with ``FLOCK_TORCHRL_PUBLISH_FAULT`` (``raise@k`` in this
process, ``SIGINT@k`` / ``SIGKILL@k`` in a child): afterwards the files that differ from the old set are
none of them, or all those that an uninterrupted run changes, never some.
"""

from __future__ import annotations

import csv
import hashlib
import json
import re
import shutil
import signal
import subprocess
from pathlib import Path

import pytest

from helpers import ROOT, first_fast, run_script

from flock_torchrl.run.publication import FAULT, FOLDER, Publication, PublishError, entry, recover


# ---------------------------------------------------------------------------- snapshots of a tree
def snapshot(root: Path) -> dict[str, str]:
    """Every file under ``root`` (the publication's folder and a step's inputs in outputs/ aside) and the
    digest of its bytes."""
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and not {FOLDER, "outputs"} & set(p.relative_to(root).parts)}


def differing(old: dict[str, str], now: dict[str, str]) -> set[str]:
    return {k for k in old.keys() | now.keys() if old.get(k) != now.get(k)}


def assert_whole_or_nothing(old: dict[str, str], new_set: set[str], now: dict[str, str], where: str) -> str:
    """The files that differ from ``old`` are none of them ("old") or exactly ``new_set`` ("new")."""
    changed = differing(old, now)
    assert changed in (set(), new_set), (f"{where}: a mix, {len(changed)} of {len(new_set)} files of the new set: "
                                         f"{sorted(changed)[:8]} against {sorted(new_set)[:8]}")
    return "old" if not changed else "new"


# ---------------------------------------------------------------------------- the mechanism, on made-up files
def make_tree(root: Path) -> None:
    (root / "results" / "r").mkdir(parents=True)
    (root / "figures" / "r").mkdir(parents=True)
    (root / "results" / "r" / "table.md").write_text("# Table\n\nold table\n")
    (root / "results" / "r" / "kept.md").write_text("# Kept\n\nuntouched\n")
    (root / "results" / "r" / "gone.csv").write_text("a\n1\n")
    (root / "figures" / "r" / "fig.png").write_bytes(b"old picture")
    (root / "doc.md").write_text("intro\n<!-- splice: results/r/table.md -->\nold table\n<!-- end splice -->\nend\n")


def publish_made_up(root: Path) -> Publication:
    """A step that rewrites a table and a figure, adds two files, removes one; the document is spliced."""
    from flock_torchrl.io import write_bytes, write_text
    from flock_torchrl.report.splice import splice_staged

    with Publication("made-up", [root / "results", root / "figures"], documents=[root / "doc.md"],
                     refresh=splice_staged, log=lambda line: None) as pub:
        write_text(pub.staged(root / "results/r/table.md"), "# Table\n\nnew table\n")
        write_text(pub.staged(root / "results/r/new.md"), "new file\n")
        write_bytes(pub.staged(root / "figures/r/fig.png"), b"new picture")
        write_bytes(pub.staged(root / "figures/r/new.png"), b"another")
        pub.staged(root / "results/r/gone.csv").unlink()
        write_text(pub.staged(root / "results/r/kept.md"), "# Kept\n\nuntouched\n")   # same bytes: not moved
    return pub


def test_a_publication_lands_whole_or_not_at_all_whatever_write_it_is_stopped_at(tmp_path, monkeypatch):
    clean = tmp_path / "clean"
    make_tree(clean)
    old = snapshot(clean)
    pub = publish_made_up(clean)
    assert sorted(pub.landed) == ["doc.md", "figures/r/fig.png", "figures/r/new.png", "results/r/new.md",
                                  "results/r/table.md"]
    assert pub.removed == ["results/r/gone.csv"]
    assert (clean / "doc.md").read_text() == ("intro\n<!-- splice: results/r/table.md -->\nnew table\n"
                                              "<!-- end splice -->\nend\n")
    new_set = differing(old, snapshot(clean))
    assert new_set == {*pub.landed, "results/r/gone.csv"} and not (clean / FOLDER).exists()
    # Five staged writes, the document, the journal, five moves: stopped at each, then past the last.
    outcomes = []
    for k in range(1, 14):
        root = tmp_path / f"k{k}"
        make_tree(root)
        monkeypatch.setenv(FAULT, f"raise@{k}")
        if k <= 12:
            with pytest.raises(KeyboardInterrupt):
                publish_made_up(root)
        else:
            publish_made_up(root)
        outcomes.append(assert_whole_or_nothing(old, new_set, snapshot(root), f"stopped at write {k}"))
        assert not (root / FOLDER).exists(), f"k={k}: the stage, the journal or the lock was left"
    # Stopped before the journal: the old set; once it is written, the landing is finished.
    assert outcomes == ["old"] * 7 + ["new"] * 6, outcomes


def test_a_landing_cut_short_is_finished_by_the_next_publication(tmp_path):
    """What a process killed while moving leaves (the journal, two of three files moved) is finished
    by the next publication under that root, before its own step."""
    root = tmp_path
    make_tree(root)
    stage = root / FOLDER / "stage"
    (stage / "results" / "r").mkdir(parents=True)
    (stage / "results" / "r" / "table.md").write_text("new table\n")
    (root / "results" / "r" / "new.md").write_text("moved already\n")   # the first move had happened
    (root / FOLDER / "journal.json").write_text(json.dumps({"name": "cut", "moves": ["results/r/new.md",
                                                                                       "results/r/table.md"],
                                                            "removes": ["results/r/gone.csv"]}))
    said = []
    with Publication("next", [root / "results" / "r", root / "figures"], log=said.append):
        assert (root / "results/r/table.md").read_text() == "new table\n"
    assert not (root / "results/r/gone.csv").exists() and (root / "results/r/new.md").read_text() == "moved already\n"
    assert any("finished the publication 'cut'" in line for line in said), said
    assert not (root / FOLDER).exists()
    # A stage without a journal never landed: it is discarded, the files stay as they are.
    (root / FOLDER / "stage" / "results").mkdir(parents=True)
    (root / FOLDER / "stage" / "results" / "x.md").write_text("half")
    said.clear()
    assert recover(root, said.append) == 0
    assert not (root / "results" / "x.md").exists() and "discarded" in said[0]


def test_one_publication_at_a_time_and_one_inside_another_joins_it(tmp_path):
    make_tree(tmp_path)
    with Publication("outer", [tmp_path / "results", tmp_path / "figures"], log=lambda line: None) as outer:
        with pytest.raises(PublishError, match="another publication is under way"):
            Publication("beside", [tmp_path / "figures"], documents=[tmp_path / "doc.md"], log=lambda line: None).__enter__()
        with Publication("inner", [tmp_path / "results" / "r"], log=lambda line: None) as inner:
            (inner.staged(tmp_path / "results/r/table.md")).write_text("inner's\n")
        assert (tmp_path / "results/r/table.md").read_text() == "# Table\n\nold table\n"   # lands with the outer
        with pytest.raises(PublishError, match="not part of the publication"):
            outer.staged(tmp_path / "doc.md")
    assert (tmp_path / "results/r/table.md").read_text() == "inner's\n"


def test_a_stopped_or_failed_publishing_command_is_one_line(capsys):
    from flock_torchrl.run.signals import Stopped

    def stopped() -> None:
        raise Stopped(signal.SIGTERM)

    assert entry(stopped) == 128 + signal.SIGTERM
    assert entry(lambda: (_ for _ in ()).throw(KeyboardInterrupt())) == 130
    assert entry(lambda: (_ for _ in ()).throw(PublishError("a bad\n input"))) == 2
    assert entry(lambda: None, noted=[signal.SIGINT]) == 130
    err = capsys.readouterr().err.splitlines()
    assert err == ["stopped by SIGTERM before anything was published", "stopped by SIGINT before anything was published",
                   "error: a bad input", "stopped by SIGINT before anything was published"]


# ---------------------------------------------------------------------------- the Makefile: targets a user types
def recipes() -> dict[str, list[str]]:
    """Each rule of the Makefile and its recipe lines."""
    out, target = {}, None
    for line in (ROOT / "Makefile").read_text().splitlines():
        m = re.match(r"^([a-z0-9%][\w%-]*|\$\(STAMP\)):(?!=)", line)
        if m:
            target = m.group(1)
            out[target] = []
        elif line.startswith("\t") and target:
            out[target].append(line)
        elif not line.strip() or line.startswith("#"):
            target = None if not line.strip() else target
    return out


def test_every_recipe_is_at_most_three_lines_and_no_shell_program():
    for target, lines in recipes().items():
        assert len(lines) <= 3, f"{target}: {len(lines)} recipe lines"
        for line in lines:
            assert not line.rstrip().endswith("\\"), f"{target}: a continued line"
            for program in (" for ", "; do", "xargs", "python -c", "$$(", "if [", "set -e"):
                if target == "reproduce-table3" and program == "$$(":   # the time estimate's arithmetic
                    continue
                assert program not in line, f"{target}: {program!r} in {line!r}"


def test_publish_targets_are_one_line_each_and_refresh_the_documents():
    from flock_torchrl.report.publish import TARGETS, settings, value

    rules = recipes()
    for target in ("docs", "readme-demo", "publish", "publish-tables", "publish-claims", "publish-paper-recipe",
                   "publish-scaling", "publish-threed", "publish-benchmark", "table3-3d", "scaling", "check-train-all"):
        assert target in TARGETS, target
        assert [line for line in rules[target] if "$(PUBLISH) " + target in line] == rules[target][-1:], target
    documents = value(settings(), "documents")
    for document in ("docs/results.md", "README.md", "docs/threed.md", "docs/scaling.md", "docs/throughput.md"):
        assert document in documents and (ROOT / document).is_file()
    makefile = (ROOT / "Makefile").read_text()
    assert "5, 20 and 50 UAVs" in makefile and "5, 9 and 20 UAVs" not in makefile
    assert "about two minutes" not in (ROOT / "conf" / "experiment" / "demo.yaml").read_text()
    import inspect

    from flock_torchrl.report import publish

    demo = inspect.getsource(publish.readme_demo)
    assert "experiment=demo" in demo and "write_demo" in demo and '"README.md"' in demo


@pytest.mark.parametrize("command, shown", [
    ("train-fast-populations READING=literal POPULATION=7 POP_SEED=3", ["seed=3 population=7", "reading=literal"]),
    ("train-paper-all", ["policy=policy1,policy1_g,policy2,policy2_g,policy3,policy3_g,policy4_g,policy5_g seed=0",
                         "policy=policy3_g,policy4_g,policy5_g seed=1,2", "reading=paper_fit", "compile=true"]),
    ("reproduce-table4 READING=literal", ["scripts/reproduce.py table=4 episodes=500 reading=literal"]),
    ("publish-threed READING=paper_fit EPISODES=7", ["publish.py publish-threed threed.reading=paper_fit threed.episodes=7"]),
    ("publish PUBLISH_READINGS=paper_fit", ['publish.py publish "readings=paper_fit" episodes=500']),
])
def test_make_targets_compose_their_commands(command, shown):
    proc = subprocess.run(["make", "-n", *command.split()], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    for text in shown:
        assert text in proc.stdout, f"{command}: {text!r} not in {proc.stdout}"


# ---------------------------------------------------------------------------- settings are data
def test_what_a_publication_flies_is_data(tmp_path, monkeypatch):
    from flock_torchrl.report.publish import _scaling_configs, paths, settings, value

    cfg = settings(["readings=paper_fit", "threed.policies=a/*.pt b/seed0.pt", "scaling.episodes=3",
                    "check_train_all.policies=policy1,policy3_g", "scaling_outputs.reading="])
    assert value(cfg, "readings") == ["paper_fit"] and value(cfg, "scaling.readings") == ["paper_fit"]
    assert value(cfg, "threed.policies") == ["a/*.pt", "b/seed0.pt"] and value(cfg, "scaling.episodes") == 3
    assert value(cfg, "check_train_all.policies") == ["policy1", "policy3_g"] and value(cfg, "scaling_outputs.reading") is None
    for bad, words in (("threed.nope=1", "threed.nope"), ("episodes=0", "whole number >= 1"), ("tables=3", None),
                       ("threed.scenarios=wall3d", None), ("nothing", "key=value")):
        if words is None:   # a single value for a list is a list of one
            settings([bad])
            continue
        with pytest.raises(PublishError, match=re.escape(words)):
            settings([bad])
    with pytest.raises(PublishError, match="check_train_all.policies"):
        value(settings(), "check_train_all")
    monkeypatch.chdir(tmp_path)
    for name in ("seed1.pt", "seed0.pt"):
        (tmp_path / "ck" / "paper_fit").mkdir(parents=True, exist_ok=True)
        (tmp_path / "ck" / "paper_fit" / name).write_bytes(b"")
    assert paths(["ck/<reading>/seed*.pt", "ck/<reading>/seed7.pt", "ck/<reading>/seed0.pt", "policy_op"], "paper_fit") == \
        ["ck/paper_fit/seed0.pt", "ck/paper_fit/seed1.pt", "ck/paper_fit/seed0.pt", "policy_op"]
    # A scaling run on another 3-D scenario is a row of data: its app config, checked.
    (config,) = _scaling_configs(settings(), [{"scenario": "forest3d", "policy": "policy_ma", "sizes": [5, 10], "episodes": 2,
                                   "others": ["policy_op"]}], "paper_fit", 200)
    assert (config.scenario.name, config.sizes, config.episodes, config.others) == ("forest3d", [5, 10], 2, ["policy_op"])


# ---------------------------------------------------------------------------- the 3-D figures show a typical seed
def test_the_3d_figures_show_the_seed_of_median_success():
    from flock_torchrl.report.threed import figures_markdown, representative

    def row(seed, success, scenario="wall3d", policy="Policy3-G"):
        return {"policy": policy, "scenario": scenario, "seed": seed, "success_rate": success,
                "checkpoint": f"checkpoints/paper_fit/threed/policy3_g/seed{seed}.pt"}

    rows = [row(0, 0.192), row(1, 0.99), row(2, 0.81), row(3, 0.95), row(4, 0.86), row(0, 1.0, "train3d")]
    assert representative(rows, "Policy3-G", "wall3d")["seed"] == 4          # 0.192 0.81 [0.86] 0.95 0.99
    assert representative(rows[:4], "Policy3-G", "wall3d")["seed"] == 2      # even: the lower middle, 0.81
    assert representative([row(3, 0.5), row(1, 0.5), row(2, 0.5)], "Policy3-G", "wall3d")["seed"] == 2   # ties: by seed
    assert representative(rows, "Policy2-G", "wall3d") is None
    text = figures_markdown(rows, {"wall3d": representative(rows, "Policy3-G", "wall3d")}, "Policy-OP", "wall3d")
    assert "| wall3d | 4 | 86.0 % | 0: 19.2 %, 1: 99.0 %, 2: 81.0 %, 3: 95.0 %, 4: 86.0 % |" in text
    assert "median" in text and "`threed_wall3d_frames.png`" in text
    # On the published table, the seed shown on wall3d is one of median success there.
    with (ROOT / "results" / "paper_fit" / "table3_3d_seeds.csv").open() as handle:
        published = [dict(r, seed=int(re.search(r"seed(\d+)\.pt", r["checkpoint"]).group(1)))
                     for r in csv.DictReader(handle) if r["policy"] == "Policy3-G"]
    wall = sorted(float(r["success_rate"]) for r in published if r["scenario"] == "wall3d")
    chosen = representative(published, "Policy3-G", "wall3d")
    assert float(chosen["success_rate"]) == wall[(len(wall) - 1) // 2]


# ---------------------------------------------------------------------------- the app answers in one line
def test_the_publish_app_answers_a_bad_input_in_one_line(tmp_path, capsys):
    from flock_torchrl.report.publish import main

    shipped = ROOT / "checkpoints" / "paper_fit" / "threed" / "policy3_g" / "seed0.pt"
    truncated = tmp_path / "seed0.pt"
    truncated.write_bytes(shipped.read_bytes()[: shipped.stat().st_size // 2])
    cases = [(["publish-threed", "threed.episodes=two"], "error: threed.episodes: must be a whole number"),
             (["publish-threed", f"threed.policies=[{truncated}]"], "error: "),
             (["publish-threed", f"threed.policies=[{tmp_path}/none/*.pt]"], "error: no 3-D checkpoint matches")]
    for args, line in cases:
        assert main(args) == 2, args
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(line), (args, err)


# ---------------------------------------------------------------------------- each pipeline, stopped at several writes
def sandbox(root: Path, checkpoints: dict[str, list[str]] | None = None) -> Path:
    """A copy of the repository's published files (results/, figures/, the documents) and of the checkpoints
    named (folder under checkpoints/<reading>/ -> seed files), to publish into."""
    root.mkdir(parents=True)
    for folder in ("results", "figures"):
        shutil.copytree(ROOT / folder, root / folder)
    (root / "docs").mkdir()
    for doc in (ROOT / "docs").glob("*.md"):
        shutil.copy2(doc, root / "docs" / doc.name)
    shutil.copy2(ROOT / "README.md", root / "README.md")
    for folder, names in (checkpoints or {}).items():
        (root / "checkpoints" / folder).mkdir(parents=True, exist_ok=True)
        for name in names:
            shutil.copy2(ROOT / "checkpoints" / folder / name, root / "checkpoints" / folder / name)
    return root


def stopped_at_several_writes(tmp_path, monkeypatch, capsys, make, publish, points=("first", "middle", "staged", "landing")):
    """Publish once whole in one sandbox (counting the files it lands), then in a fresh sandbox per
    point stop it there; each ends with the old set or the whole new one. Returns the outcomes."""
    clean = make(tmp_path / "clean")
    old = snapshot(clean)
    monkeypatch.chdir(clean)
    monkeypatch.setenv(FAULT, "count")
    publish()
    err = capsys.readouterr()
    total = int(re.findall(rf"{FAULT}: (\d+) file", err.err)[-1])
    moved = int(re.findall(r"published .*: (\d+) file\(s\) changed", err.out + err.err)[-1])
    new_set = differing(old, snapshot(clean))
    assert new_set and moved <= len(new_set)
    staged = total - moved - 1                      # the stage's writes (the documents among them), the journal, the moves
    at = {"first": 1, "middle": max(1, staged // 2), "staged": staged, "journal": staged + 1, "landing": staged + 2}
    outcomes = {}
    for point in points:
        root = make(tmp_path / point)
        monkeypatch.chdir(root)
        monkeypatch.setenv(FAULT, f"raise@{at[point]}")
        with pytest.raises(KeyboardInterrupt):
            publish()
        outcomes[point] = assert_whole_or_nothing(old, new_set, snapshot(root), f"stopped at {point} ({at[point]})")
        assert not (root / FOLDER).exists()
    monkeypatch.delenv(FAULT)
    # raise@k aborts the k-th rename: one of the journal leaves no journal (the old set); one of a move
    # is an error while landing, and the landing is finished at once
    expected = {"first": "old", "middle": "old", "staged": "old", "journal": "old", "landing": "new"}
    assert outcomes == {p: expected[p] for p in points}
    return outcomes


@pytest.mark.slow   # one 3-D checkpoint and one baseline, one episode on wall3d, tiny GIFs, one swarm size (~60 s a run)
def test_publish_threed_lands_whole_or_not_at_all(tmp_path, monkeypatch, capsys):
    from flock_torchrl.report.publish import publish_threed, settings

    tiny = ["checkpoints_dir=checkpoints", "threed.episodes=1", "threed.scenarios=[wall3d]", "threed.baselines=[policy_op]", "threed.gif_size=[40,80]",
            "threed.gif_stride=250", "threed.policies=[checkpoints/<reading>/threed/policy3_g/seed0.pt]",
            *(f"threed.scaling.{k}.{key}" for k in (0, 1)   # both scaling runs (train3d, forest3d), tiny
              for key in ("sizes=[5]", "episodes=1", "policy=policy_op", "others=[]"))]
    stopped_at_several_writes(tmp_path, monkeypatch, capsys,
                              lambda root: sandbox(root, {"paper_fit/threed/policy3_g": ["seed0.pt"]}),
                              lambda: publish_threed(settings(tiny)), points=("middle", "staged"))


@pytest.mark.slow   # Table V from one seed, Fig. 4, one swarm size, the claims (~40 s a run)
def test_publish_lands_tables_scaling_and_claims_whole_or_not_at_all(tmp_path, monkeypatch, capsys):
    from flock_torchrl.report.publish import publish_all, settings

    tiny = ["checkpoints_dir=checkpoints", "readings=[paper_fit]", "episodes=1", "tables=[5]", "figures=[4]", "paper_recipe=none/*.pt",
            "scaling.readings=[literal]", "scaling.scenarios=[train]", "scaling.episodes=1", "scaling.runs.0.sizes=[5]",
            "scaling.runs.0.others=[policy_op]"]   # literal's swarm sizes: README's table reads paper_fit's
    stopped_at_several_writes(tmp_path, monkeypatch, capsys,
                              lambda root: sandbox(root, {"paper_fit/policy3_g": ["seed0.pt"], "literal/policy3_g": ["seed0.pt"]}),
                              lambda: publish_all(settings(tiny)), points=("middle", "staged", "landing"))


@pytest.mark.slow   # the claims of the published seeds tables, no evaluation
def test_publish_claims_lands_whole_or_not_at_all(tmp_path, monkeypatch, capsys):
    from flock_torchrl.report.publish import publish_claims, settings

    def make(root):
        sandbox(root)
        seeds = root / "results" / "literal" / "table3_seeds.csv"
        lines = seeds.read_text().splitlines()
        seeds.write_text("\n".join(lines[:1] + lines[1:][::-1]) + "\n")   # the same seeds in another order
        (root / "results" / "literal" / "claims_overview.md").write_text("# stale\n")
        return root

    stopped_at_several_writes(tmp_path, monkeypatch, capsys, make, lambda: publish_claims(settings()),
                              points=("middle", "staged", "landing"))


def test_publish_benchmark_lands_whole_or_not_at_all(tmp_path, monkeypatch, capsys):
    from flock_torchrl.report.publish import publish_benchmark, settings

    def make(root):
        sandbox(root)
        page = root / "outputs" / "benchmark" / "benchmark.md"
        page.parent.mkdir(parents=True)
        page.write_text((ROOT / "results" / "benchmark.md").read_text().replace("load average was", "load average was then"))
        return root

    stopped_at_several_writes(tmp_path, monkeypatch, capsys, make, lambda: publish_benchmark(settings()),
                              points=("first", "staged", "landing"))


def test_the_demos_lines_and_readme_land_together(tmp_path, monkeypatch, capsys):
    """readme-demo's publication, on a made-up log: docs/demo.md and README.md land together."""
    from flock_torchrl.report.publish import refresh
    from flock_torchrl.report.splice import write_demo

    def make(root):
        sandbox(root)
        run = root / "outputs" / "readme_demo" / "run"
        run.mkdir(parents=True)
        (run.parent / "demo.log").write_text(
            f"checkpoint: {run.resolve()}/last.pt (64000 frames, 9 episodes, 7 updates, 3 s)\n"
            "evaluation (100 episodes, seed 2024, deterministic): success 0.123, d_c 1.000\n")
        return root

    def publish():
        folder = Path("outputs/readme_demo")
        with Publication("the demo's lines", ["docs/demo.md"], documents=["README.md"], refresh=refresh,
                         log=print) as pub:
            write_demo(folder / "demo.log", folder / "run", pub.staged("docs/demo.md"))

    stopped_at_several_writes(tmp_path, monkeypatch, capsys, make, publish, points=("first", "staged", "landing"))


@pytest.mark.slow   # two tiny trainings, then their shipments (ship-checkpoints', ship-threed's) stopped at several writes
def test_ship_lands_the_collection_and_its_manifest_whole_or_not_at_all(tmp_path, monkeypatch, capsys):
    from flock_torchrl.run.launch import train
    from flock_torchrl.run.shipping import ship_checkpoints
    from flock_torchrl.run.setup import make_train_config

    runs = tmp_path / "runs"
    for seed in (0, 1):
        cfg = make_train_config("policy3_g", "tiny", ["scenario.max_steps=30", "progress=false", f"seed={seed}",
                                                      "experiment.eval_every_frames=0", "experiment.eval_episodes=1",
                                                      "experiment.max_frames=32"])
        train(cfg, runs / "tiny" / "paper_fit" / "policy3_g" / f"seed{seed}")

    def make(root):
        dest = root / "checkpoints" / "paper_fit"
        (dest / "policy3_g").mkdir(parents=True)
        for seed in (0, 1, 5):
            shutil.copy2(ROOT / "checkpoints" / "paper_fit" / "policy3_g" / f"seed{seed}.pt", dest / "policy3_g" / f"seed{seed}.pt")
        shutil.copy2(ROOT / "checkpoints" / "paper_fit" / "MANIFEST.md", dest / "MANIFEST.md")
        return root

    def ship():
        ship_checkpoints("paper_fit", "tiny", runs, Path("checkpoints"), "paper", Path("checkpoints/paper_fit/paper_recipe"),
                         log=print)

    stopped_at_several_writes(tmp_path / "ship", monkeypatch, capsys, make, ship, points=("first", "staged", "landing"))
    # make ship-threed's collection (runs of another scenario, named by their override), alone
    from flock_torchrl.run.shipping import ship_scenario_collection

    for seed in (0, 1):
        shutil.copytree(runs / "tiny" / "paper_fit" / "policy3_g" / f"seed{seed}",
                        tmp_path / "runs3" / "tiny" / "paper_fit" / "policy3_g" / f"seed{seed}__scenario-train")

    def make3(root):
        dest = root / "checkpoints" / "paper_fit" / "threed"
        shutil.copytree(ROOT / "checkpoints" / "paper_fit" / "threed", dest)
        return root

    def ship3():
        ship_scenario_collection("paper_fit", tmp_path / "runs3", "tiny", ["scenario-train"],
                                 Path("checkpoints/paper_fit/threed"), log=print)

    stopped_at_several_writes(tmp_path / "ship3", monkeypatch, capsys, make3, ship3, points=("middle", "staged", "landing"))


# ---------------------------------------------------------------------------- the process: Ctrl-C and a kill
@pytest.mark.slow   # scripts/publish.py stopped by SIGINT at three writes, then killed while landing and finished
def test_a_signal_stops_a_publication_in_one_line_and_a_kill_is_finished_next_time(tmp_path):
    def make(root):
        sandbox(root)
        brief = root / "results" / "paper_fit" / "table3_3d_brief.md"
        brief.write_text(brief.read_text().replace("| wall3d |", "| wall3d (changed) |"))
        return root

    clean = make(tmp_path / "clean")
    old = snapshot(clean)
    proc = run_script("publish.py", "docs", cwd=clean, **{FAULT: "count"})
    total = int(re.search(rf"{FAULT}: (\d+) file", proc.stderr).group(1))
    new_set = differing(old, snapshot(clean))
    assert new_set == {"README.md"}, new_set
    for k, outcome in ((1, "old"), (total - 1, "new"), (total, "new")):   # a staged write, the journal, the move
        root = make(tmp_path / f"sigint{k}")
        proc = run_script("publish.py", "docs", cwd=root, check=False, **{FAULT: f"SIGINT@{k}"})
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 130 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
        assert lines[0].startswith("stopped by SIGINT: ") and ("had landed whole" if outcome == "new" else
                                                               "nothing of the publication") in lines[0], lines
        assert assert_whole_or_nothing(old, new_set, snapshot(root), f"SIGINT at {k}") == outcome
    # Killed between the journal and the move: half landed until the next publication finishes it.
    root = make(tmp_path / "killed")
    proc = run_script("publish.py", "docs", cwd=root, check=False, **{FAULT: f"SIGKILL@{total}"})
    assert proc.returncode == -signal.SIGKILL and (root / FOLDER / "journal.json").is_file()
    proc = run_script("publish.py", "docs", cwd=root)
    assert "finished the publication" in proc.stdout + proc.stderr
    assert assert_whole_or_nothing(old, new_set, snapshot(root), "after the kill") == "new"


# ---------------------------------------------------------------------------- every target's set, its steps stubbed
STEPS = {"publish": ("_write_tables", "_write_scaling", "_write_claims"), "publish-tables": ("_write_tables",),
         "publish-claims": ("_write_claims",), "publish-paper-recipe": ("_write_tables", "_write_claims"),
         "publish-scaling": ("_write_scaling",), "publish-threed": ("_write_threed",), "docs": ()}


@pytest.mark.parametrize("target", first_fast(list(STEPS)))   # ~5 s each (copies of results/ and figures/)
def test_every_publication_target_is_one_set(target, tmp_path, monkeypatch, capsys):
    """Each target's steps (stubbed: each rewrites a table and adds a figure, as the apps would) and the
    documents' refresh land as one set, stopped at any of its writes."""
    from flock_torchrl.io import write_text
    from flock_torchrl.report import publish

    def step(name):
        def write(*args, **kwargs):
            pub = next(a for a in args if isinstance(a, Publication))
            brief = pub.staged("results/paper_fit/table3_3d_brief.md")
            write_text(brief, brief.read_text().replace("| wall3d |", f"| wall3d ({name}) |"))
            write_text(pub.staged(f"figures/paper_fit/{name}.png"), name)
        return write

    for name in ("_write_tables", "_write_scaling", "_write_claims", "_write_threed"):
        monkeypatch.setattr(publish, name, step(name) if name in STEPS[target] else None)
    for name in ("_table_configs", "_paper_recipe_configs", "_scaling_plan", "_threed_plan"):
        monkeypatch.setattr(publish, name, lambda cfg: ([], []))
    monkeypatch.setattr(publish, "_threads", lambda cfg: None)

    def make(root):
        sandbox(root)
        (root / "results" / "paper_fit" / "scaling_pooled.md").write_text("# stale\n")   # the refresh rewrites it
        return root

    def run():
        publish.TARGETS[target](publish.settings())

    points = ("first", "staged", "journal", "landing") if STEPS[target] else ("first", "landing")
    stopped_at_several_writes(tmp_path, monkeypatch, capsys, make, run, points=points)


def test_the_targets_that_run_apps_compose_their_commands(tmp_path, monkeypatch):
    from flock_torchrl.report import publish

    ran = []
    monkeypatch.setattr(publish, "run_app", lambda command, log=None, stdout=None: ran.append(list(command)) or 0)
    monkeypatch.chdir(ROOT)
    scripts = ROOT / "scripts"
    publish.scaling_outputs(publish.settings(["scaling_outputs.reading=paper_fit"]), scripts)
    publish.scaling_outputs(publish.settings(["scaling_outputs.reading=literal"]), scripts)
    assert ran[0][1:] == [str(scripts / "scaling.py"), "reading=paper_fit", "others=[checkpoints/paper_fit/mixed/policy3_g/seed0.pt]"]
    assert ran[1][1:] == [str(scripts / "scaling.py"), "reading=literal"]   # no mixed-size policy shipped there
    ran.clear()
    folder = tmp_path / "check"
    cfg = publish.settings([f"check_train_all.folder={folder}", "check_train_all.policies=policy1,policy3_g",
                            "check_train_all.rows=Policy1,Policy3-G", "check_train_all.seeds=0,1", "episodes=7"])
    folder.mkdir()
    with pytest.raises(PublishError, match="exists; move it away"):
        publish.check_train_all(cfg, scripts)
    assert not ran
    folder.rmdir()
    monkeypatch.setattr(publish, "run_app", lambda command, log=None, stdout=None: (ran.append(list(command)),
                                                                                    folder.mkdir(exist_ok=True))[0] and 0)
    publish.check_train_all(cfg, scripts)
    sweep, ship, table = (" ".join(c[1:]) for c in ran)
    assert "train.py -m hydra/launcher=local experiment=fast progress=false resume=auto seed=0,1 policy=policy1,policy3_g" in sweep
    assert f"hydra.sweep.dir={folder / 'runs'} reading=paper_fit" in sweep
    assert f"ship.py reading=paper_fit runs_dir={folder / 'runs'} checkpoints_dir={folder / 'checkpoints'}" in ship
    assert "episodes=7" in table and "only=[Policy1,Policy3-G]" in table and "compare_to=results/paper_fit/table3.csv" in table
    assert (folder / "wall.txt").read_text().startswith("make train-all READING=paper_fit SEEDS=0,1: ")
