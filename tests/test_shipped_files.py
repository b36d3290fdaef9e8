"""What the repository ships names no folder of the machine that wrote it: results/, figures/'
text, docs/, README.md and the checkpoints' MANIFEST.md files name checkpoints relative to the
repository (report/reproduce.py and report/scaling.py write them so, through io.shown)."""

from __future__ import annotations

import gzip
import re
from pathlib import Path

import pytest

from helpers import ROOT

# An absolute path under a folder where a checkout, a home or a scratch space lives.
ABSOLUTE = re.compile(r"(?<![\w.~$-])/(?:work|home|tmp|root|Users|mnt|scratch|var|opt|srv|data|private)/[\w.-]")
TEXT = {".md", ".csv", ".txt", ".json", ".yaml", ".gz"}


def shipped_files() -> list[Path]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")),
             *sorted((ROOT / "checkpoints").rglob("MANIFEST.md"))]
    for folder in ("results", "figures"):
        files += [p for p in sorted((ROOT / folder).rglob("*")) if p.is_file() and p.suffix in TEXT]
    return files


def text_of(path: Path) -> str:
    return gzip.decompress(path.read_bytes()).decode() if path.suffix == ".gz" else path.read_text()


def absolute_paths(text: str) -> list[str]:
    return [text[max(0, m.start() - 40):m.end() + 40] for m in ABSOLUTE.finditer(text)]


def test_no_shipped_file_names_a_machine_path():
    found = {str(p.relative_to(ROOT)): hits[:2] for p in shipped_files() if (hits := absolute_paths(text_of(p)))}
    assert not found, f"absolute paths in shipped files (republish through the make targets): {found}"


def test_the_rule_finds_what_it_must_and_spares_the_rest():
    assert absolute_paths("checkpoint,/work/main/checkpoints/paper_fit/policy3_g/seed0.pt")
    assert absolute_paths("see /home/ann/runs and /tmp/x")
    assert absolute_paths("| `/root/flock/checkpoints/literal/policy3_g/seed0.pt` |")
    for fine in ("checkpoints/paper_fit/policy3_g/seed0.pt", "runs/fast/paper_fit/policy3_g/seed0",
                 "~/my_conf/scenario", "$HOME/my_conf/scenario", "baseline:policy_ma", "0.5 m / 2 m",
                 "https://hydra.cc/docs/advanced/override_grammar/basic/", "results/paper_fit/table3.md"):
        assert not absolute_paths(fine), fine


@pytest.mark.parametrize("name", ["results", "docs", "figures"])
def test_the_scan_reads_every_folder(name):
    assert any(p.is_relative_to(ROOT / name) for p in shipped_files())


def test_docs_pages_read_in_minutes():
    """No docs page over about 400 lines but the specification, the project's reference."""
    long = {p.name: n for p in sorted((ROOT / "docs").glob("*.md"))
            if p.name != "specification.md" and (n := len(p.read_text().splitlines())) > 400}
    assert not long, f"docs pages over 400 lines: {long}"


# How the work was organised is not the product's business (git history keeps it): no issue
# numbers, no dated audit files, none of these words, in code, tests, conf or docs.
ORGANISATION = re.compile(r"\bissues? \d+|\bissue item\b|\bsessions?\b|\bmoonshot\b|\blent\b|\bhelpers? session"
                          r"|cells_moved_|scaling_diagnosis", re.I)


def project_text_files() -> list[Path]:
    files = [ROOT / "README.md", ROOT / "Makefile", ROOT / "pyproject.toml"]
    for folder, suffixes in (("docs", {".md"}), ("flock_torchrl", {".py"}), ("tests", {".py"}), ("conf", {".yaml"}),
                             ("scripts", {".py"}), ("benchmarks", {".py"}), ("examples", {".py"})):
        files += [p for p in sorted((ROOT / folder).rglob("*")) if p.suffix in suffixes and p.is_file()]
    return [p for p in files if p != Path(__file__).resolve()]


def test_no_issue_numbers_or_words_about_the_work():
    found = {}
    for path in project_text_files():
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if ORGANISATION.search(line):
                found.setdefault(str(path.relative_to(ROOT)), []).append(number)
    assert not found, f"issue numbers or words about how the work was organised, by file and line: {found}"
    assert ORGANISATION.search("fixed in issue 31") and ORGANISATION.search("this session's merges")
    assert not ORGANISATION.search("a test process; the training loop; rounds of rejection sampling")
