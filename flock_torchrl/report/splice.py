"""Program output quoted in the documents, written by the program: splicing between markers.

A document (README.md, docs/results.md) marks each quoted block with the file it comes from::

    <!-- splice: results/paper_fit/summary.md -->
    ... (replaced) ...
    <!-- end splice -->

:func:`splice_file` replaces every such block by the named file's text (its leading ``# ``
title line dropped), paths relative to ``root`` (the repository). The make targets that write
those files (``make publish``, ``make readme-demo``) run it, so no quoted number is copied by
hand; :func:`stale_blocks` says which blocks differ from their file (the tests' check).

    python -m flock_torchrl.report.splice docs/results.md README.md
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

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


def splice_text(text: str, root: str | Path, where: str = "document") -> str:
    """``text`` with every block replaced by its file's :func:`quoted` text."""
    out, last = [], 0
    for path, start, end in blocks(text):
        source = Path(root) / path
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


def machine() -> str:
    """This machine as the demo's lines depend on it: architecture, CPU model, torch build."""
    import platform

    import torch

    model = ""
    try:
        model = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                      if line.startswith("model name")), "")
    except OSError:
        pass
    return f"{platform.machine()}, {model or platform.processor() or 'unknown CPU'}, torch {torch.__version__}"


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


def write_demo(log_path: str | Path, run_dir: str | Path, out: str | Path, threads: int = 1) -> Path:
    """``out`` (docs/demo.md): the demo's quoted lines with the machine that printed them."""
    lines = demo_lines(Path(log_path).read_text(), run_dir)
    text = (f"# `make demo`, as this machine printed it\n\n"
            f"Machine: {machine()}, {threads} thread.\n\n```\n" + "\n".join(lines) + "\n```\n")
    return write_text(out, text)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args:
        print("usage: python -m flock_torchrl.report.splice DOCUMENT...\n"
              "       python -m flock_torchrl.report.splice --demo LOG RUN_DIR OUT", file=sys.stderr)
        return 2
    if args[0] == "--demo":
        try:
            print(f"wrote {write_demo(*args[1:4])}")
        except (ConfigError, OSError, TypeError) as exc:
            print(f"error: --demo: {exc}", file=sys.stderr)
            return 2
        return 0
    for document in args:
        try:
            changed = splice_file(document)
        except (ConfigError, OSError) as exc:
            print(f"error: {document}: {exc}", file=sys.stderr)
            return 2
        print(f"{document}: " + (f"spliced {', '.join(changed)}" if changed else "every block current"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = ["blocks", "demo_lines", "machine", "quoted", "splice_file", "splice_text", "stale_blocks", "write_demo"]
