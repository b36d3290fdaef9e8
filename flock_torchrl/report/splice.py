"""Program output quoted in the documents, written by the program: splicing between markers.

A document (README.md, docs/results.md) marks each quoted block with the file it comes from::

    <!-- splice: results/paper_fit/summary.md -->
    ... (replaced) ...
    <!-- end splice -->

:func:`splice_file` replaces every such block by the named file's text (its leading ``# ``
title line dropped), paths relative to ``root`` (the repository). The make targets that write
those files (``make publish``, ``make readme-demo``) run it, so no quoted number is copied by
hand; :func:`stale_blocks` says which blocks differ from their file (the tests' check).
"""

from __future__ import annotations

import re
import textwrap
from pathlib import Path
from typing import Sequence

from ..config import ConfigError
from ..io import write_text

BEGIN = re.compile(r"^<!-- splice: (?P<path>\S+) -->\n", re.M)
END = "<!-- end splice -->\n"


def quoted(path: str | Path) -> str:
    """The text a block quotes of ``path``: the file without its leading ``# `` title line
    (and the blank lines after it), ending with one newline."""
    text = Path(path).read_text()
    if text.startswith("# "):
        text = text.split("\n", 1)[1] if "\n" in text else ""
    return text.strip("\n") + "\n"


def blocks(text: str) -> list[tuple[str, int, int]]:
    """``(path, start, end)`` of every block: ``text[start:end]`` is what sits between its
    markers. ``ConfigError`` naming the marker when one has no end."""
    found = []
    for m in BEGIN.finditer(text):
        end = text.find(END, m.end())
        nested = BEGIN.search(text, m.end())
        if end < 0 or (nested is not None and nested.start() < end):
            line = text.count("\n", 0, m.start()) + 1
            raise ConfigError("splice", f"line {line}: '<!-- splice: {m['path']} -->' has no '{END.strip()}' "
                                        "before the next block or the end")
        found.append((m["path"], m.end(), end))
    return found


def _source(path: str, roots: str | Path | Sequence[str | Path]) -> Path:
    """``path`` under the first of ``roots`` that holds it (a publication's stage, then the repository)."""
    roots = [roots] if isinstance(roots, (str, Path)) else list(roots)
    return next((Path(r) / path for r in roots if (Path(r) / path).is_file()), Path(roots[-1]) / path)


def splice_text(text: str, root: str | Path | Sequence[str | Path], where: str = "document") -> str:
    """``text`` with every block replaced by its file's :func:`quoted` text; ``root``: the folder the
    blocks' paths are relative to, or several, the first that holds a file giving it."""
    out, last = [], 0
    for path, start, end in blocks(text):
        source = _source(path, root)
        if not source.is_file():
            raise ConfigError("splice", f"{where}: the block '<!-- splice: {path} -->' names {source}, which does not "
                                        "exist (run the make target that writes it first)")
        out += [text[last:start], quoted(source)]
        last = end
    return "".join(out) + text[last:]


def splice_file(document: str | Path, root: str | Path | None = None) -> list[str]:
    """Rewrite ``document`` (atomically) with its blocks spliced; ``root``: the folder the
    blocks' paths are relative to (default: the document's repository, the folder holding
    ``pyproject.toml`` above it). Returns the paths of the blocks that changed."""
    document = Path(document)
    root = Path(root) if root is not None else _repository(document)
    text = document.read_text()
    new = splice_text(text, root, str(document))
    changed = stale_blocks(document, root) if new != text else []
    if new != text:
        write_text(document, new)
    return changed


def splice_staged(publication) -> list[str]:
    """A publication's ``refresh``: each of its documents read from the repository as it is now,
    its blocks spliced from the staged files (those the publication did not write from the
    repository), written into the stage where that changes it. Returns the documents that change."""
    changed = []
    for document in publication.documents:
        live = Path(document).absolute()
        text = live.read_text()
        new = splice_text(text, [publication.stage, publication.root], str(live.relative_to(publication.root)))
        if new != text:
            write_text(publication.staged(live), new)
            changed.append(live.relative_to(publication.root).as_posix())
    return changed


def stale_blocks(document: str | Path, root: str | Path | None = None) -> list[str]:
    """The paths of ``document``'s blocks whose text differs from their file's."""
    document = Path(document)
    root = Path(root) if root is not None else _repository(document)
    text = document.read_text()
    return [path for path, start, end in blocks(text)
            if not (Path(root) / path).is_file() or text[start:end] != quoted(Path(root) / path)]


def _repository(document: Path) -> Path:
    for folder in document.resolve().parents:
        if (folder / "pyproject.toml").is_file():
            return folder
    return document.resolve().parent


def cpu() -> str:
    """This CPU as float round-off depends on it: vendor, family and model (``/proc/cpuinfo``,
    Linux; elsewhere the platform's processor string), then the model name."""
    import platform

    fields: dict[str, str] = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, sep, value = line.partition(":")
            if sep and key.strip() in ("vendor_id", "cpu family", "model", "model name"):
                fields.setdefault(key.strip(), value.strip())
            if not line.strip() and fields:   # the first processor's block is enough
                break
    except OSError:
        pass
    if "vendor_id" in fields and "cpu family" in fields and "model" in fields:
        name = f" ({fields['model name']})" if fields.get("model name") else ""
        return f"{fields['vendor_id']} family {fields['cpu family']} model {fields['model']}{name}"
    return platform.processor() or "unknown CPU"


def machine(threads: int = 1) -> str:
    """The demo's fingerprint: what decides its float round-off, so that two machines with the
    same fingerprint print the same demo lines. The architecture, the CPU (vendor, family,
    model), the instruction set torch dispatches its kernels to
    (``torch.backends.cpu.get_cpu_capability()``), the torch build and the thread count (the
    demo runs ``threads=1``)."""
    import platform

    import torch

    return (f"{platform.machine()}, {cpu()}, {torch.backends.cpu.get_cpu_capability()}, torch {torch.__version__}, "
            f"{threads} thread{'s' if threads != 1 else ''}")


DEMO_LINES = ("checkpoint: ", "evaluation (")


def demo_lines(log: str, run_dir: str | Path) -> list[str]:
    """The lines of a demo run's output that README quotes (its checkpoint and its final
    evaluation), the run folder shown as ``...``. ``ConfigError`` when the log lacks one."""
    found = {}
    for line in log.splitlines():
        for start in DEMO_LINES:
            if line.startswith(start):
                found[start] = line.replace(str(Path(run_dir).resolve()), "...").rstrip()
    missing = [s.strip() for s in DEMO_LINES if s not in found]
    if missing:
        raise ConfigError("demo", f"the demo's output has no {' / '.join(missing)} line: did it finish?")
    return [found[s] for s in DEMO_LINES]


# How far the demo's numbers may land from the quoted ones on a machine of another fingerprint,
# where training takes another float path from the first update on and ends as another seed
# would (docs/decisions.md, "Reproducibility": the spread measured over seeds and machines).
# The frame budget and the update count follow from the configuration, not from round-off: equal.
DEMO_TOLERANCE = {"episodes": 0.15, "success": 0.10, "safe_success": 0.10, "d_min_uav": 0.25, "d_c": 1.5,
                  "t_goal": 5.0}
DEMO_EXACT = ("frames", "updates")
DEMO_NUMBER = re.compile(r"(?:(?P<count>\d+) (?P<what>frames|episodes|updates)\b)|"
                         r"(?:(?P<key>success|safe_success|d_min_uav|d_c|t_goal) (?P<value>[-\d.]+|nan))")


def demo_numbers(lines: list[str]) -> dict[str, float]:
    """The numbers of the demo's two lines: ``frames``, ``episodes``, ``updates`` (the
    checkpoint line, its seconds left out) and the evaluation's metrics."""
    out: dict[str, float] = {}
    for m in DEMO_NUMBER.finditer("\n".join(lines)):
        key = m["what"] or m["key"]
        out.setdefault(key, float(m["count"] or m["value"]))
    return out


def tolerance_text() -> str:
    """:data:`DEMO_TOLERANCE` in words (rates of equal tolerance named together)."""
    t = DEMO_TOLERANCE
    rates: dict[float, list[str]] = {}
    for key in ("success", "safe_success"):
        rates.setdefault(t[key], []).append(key)
    return ", ".join([" and ".join(DEMO_EXACT) + " equal", f"episodes within {100 * t['episodes']:.0f} %",
                      *(f"{' and '.join(keys)} within {100 * value:.0f} points" for value, keys in rates.items()),
                      *(f"{key} within {value:g} {'s' if key == 't_goal' else 'm'}" for key, value in t.items()
                        if key not in ("episodes", "success", "safe_success"))])


def demo_differences(printed: list[str], quoted: list[str], recorded: str,
                     this: str | None = None) -> tuple[str, list[str]]:
    """Compare a demo's printed lines with the quoted ones: on the machine of the quoted lines'
    fingerprint (``recorded`` equal to ``this``, default :func:`machine`) every number but the
    seconds must be equal ("exact"); elsewhere each within :data:`DEMO_TOLERANCE` ("tolerance").
    Returns the mode and what lies outside (empty: the demo keeps README's promise)."""
    this = machine() if this is None else this
    got, want = demo_numbers(printed), demo_numbers(quoted)
    missing = [k for k in want if k not in got]
    if missing:
        return ("exact" if recorded == this else "tolerance"), [f"{k}: not printed" for k in missing]
    if recorded == this:
        seconds = re.compile(r", \d+ s\)$")
        if [seconds.sub("", line) for line in printed] == [seconds.sub("", line) for line in quoted]:
            return "exact", []
        return "exact", [f"{k}: {got[k]:g}, quoted {want[k]:g}" for k in want if got[k] != want[k]] or \
            ["the lines differ (not in their numbers)"]
    off = []
    for key, value in want.items():
        if key in DEMO_EXACT:
            ok = got[key] == value
        elif key == "episodes":
            ok = abs(got[key] - value) <= DEMO_TOLERANCE[key] * value
        elif key in DEMO_TOLERANCE:
            ok = abs(got[key] - value) <= DEMO_TOLERANCE[key]
        else:
            continue
        if not ok:
            off.append(f"{key}: {got[key]:g}, quoted {value:g}")
    return "tolerance", off


def write_demo(log_path: str | Path, run_dir: str | Path, out: str | Path, threads: int = 1) -> Path:
    """``out`` (docs/demo.md): the demo's quoted lines with the fingerprint of the machine that
    printed them, and how near another machine's lines land."""
    lines = demo_lines(Path(log_path).read_text(), run_dir)
    note = textwrap.fill(f"On a machine of another fingerprint the numbers land nearby: {tolerance_text()} "
                         "(`tests/test_front_door.py` checks which applies).", 100)
    text = (f"# `make demo`, as this machine printed it\n\n"
            f"Machine: {machine(int(threads))}.\n\n```\n" + "\n".join(lines) + "\n```\n\n" + note + "\n")
    return write_text(out, text)


__all__ = ["DEMO_TOLERANCE", "blocks", "cpu", "demo_differences", "demo_lines", "demo_numbers", "machine", "quoted",
           "splice_file", "splice_text", "stale_blocks", "tolerance_text", "write_demo"]
