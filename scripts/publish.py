"""The make targets that publish (results/, figures/, the documents' spliced blocks) or run several apps,
each one line of the Makefile (logic: flock_torchrl.report.publish; what each flies: conf/publish.yaml).

    python scripts/publish.py publish-threed threed.reading=paper_fit threed.episodes=500
    python scripts/publish.py docs

Targets: docs, publish, publish-tables, publish-claims, publish-paper-recipe, publish-scaling,
publish-threed, publish-benchmark, readme-demo (each lands its whole set or nothing), check-train-all,
table3-3d, scaling (into outputs/). A bad setting is one `error:` line (exit 2); Ctrl-C one line (exit 130).
"""

import sys
from pathlib import Path

from _start import load, noting  # before anything heavy: Ctrl-C while torch loads is one line

if __name__ == "__main__":
    noted = noting()
    main = load("flock_torchrl.report.publish", "main")
    sys.exit(main(sys.argv[1:], noted, scripts=Path(__file__).resolve().parent))
