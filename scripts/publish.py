"""The make targets that publish (results/, figures/, the documents' spliced blocks) or run several apps,
each one line of the Makefile (logic: flock_torchrl.report.publish; what each flies: conf/publish.yaml).

    python scripts/publish.py publish-threed threed.reading=paper_fit threed.episodes=500
    python scripts/publish.py docs

Targets: docs, publish, publish-tables, publish-claims, publish-paper-recipe, publish-scaling,
publish-threed, publish-benchmark, readme-demo (each lands its whole set or nothing), check-train-all,
table3-3d, scaling (into outputs/). A bad setting is one `error:` line (exit 2); Ctrl-C one line (exit 130).
"""

import signal
import sys
from pathlib import Path

from _start import STOP_SIGNALS, out_of_memory  # before anything heavy: Ctrl-C while torch loads is one line

if __name__ == "__main__":
    noted: list = []
    for _signum in STOP_SIGNALS:
        signal.signal(_signum, lambda signum, frame: noted.append(signum))
    try:
        from flock_torchrl.report.publish import main
    except (ImportError, MemoryError, OSError) as exc:
        line = out_of_memory(exc)
        if line is None:
            raise
        sys.stderr.write(line + "\n")
        raise SystemExit(2) from None
    sys.exit(main(sys.argv[1:], noted, scripts=Path(__file__).resolve().parent))
