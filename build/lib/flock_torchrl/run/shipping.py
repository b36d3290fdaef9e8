"""Shipping trained policies: slim checkpoints into ``checkpoints/<reading>/`` with a manifest."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Callable

from ..io import write_text
from ..policies.checkpoint import LAST, export_policy, load_checkpoint


def ship_checkpoints(reading: str, experiment: str, runs_dir: Path, checkpoints_dir: Path,
                     paper_experiment: str = "paper", log: Callable[[str], None] = print) -> list[Path]:
    """Export ``<runs>/<experiment>/<reading>/<policy>/seed<k>/last.pt`` (runs without extra
    overrides only) to ``<checkpoints>/<reading>/<policy>/seed<k>.pt``, the paper recipe's
    Policy3-G run to ``<checkpoints>/<reading>/paper_recipe/policy3_g_seed<k>.pt``, and write
    ``<checkpoints>/<reading>/MANIFEST.md`` (frames, episodes, time, final evaluation)."""
    dest_root = checkpoints_dir / reading
    shipped = []
    sources = sorted((runs_dir / experiment / reading).glob(f"*/seed*/{LAST}"))
    sources = [s for s in sources if re.fullmatch(r"seed\d+", s.parent.name)]
    paper = sorted((runs_dir / paper_experiment / reading / "policy3_g").glob(f"seed*/{LAST}"))
    lines = [f"# Shipped checkpoints, reading `{reading}`", "",
             f"Slim policies exported by `make ship-checkpoints` (scripts/ship.py) from `{runs_dir}/{experiment}/"
             f"{reading}/` and the paper recipe's `{runs_dir}/{paper_experiment}/{reading}/policy3_g/`; "
             "`flock_torchrl.load_policy(path)` loads them. Minutes are the run's own training time.", "",
             "| policy | seed | experiment | frames | episodes | updates | minutes | final eval success | safe_success |",
             "|---|---|---|---|---|---|---|---|---|"]
    for last in [*sources, *paper]:
        policy, seed = last.parent.parent.name, last.parent.name
        is_paper = last in paper
        dest = dest_root / ("paper_recipe" if is_paper else policy) / (f"{policy}_{seed}.pt" if is_paper else f"{seed}.pt")
        export_policy(last, dest)
        payload = load_checkpoint(dest, kind="policy")
        if payload["meta"]["reading"] != reading:
            raise ValueError(f"{last} was trained under {payload['meta']['reading']!r}, not {reading!r}")
        c, ev = payload["counters"], (payload.get("evaluations") or [{}])[-1]
        lines.append(f"| {payload['meta']['policy']} | {seed[4:]} | {payload['meta']['experiment']} | {c['frames']} | "
                     f"{c['episodes']} | {c['updates']} | {c['seconds'] / 60:.1f} | "
                     f"{ev.get('success', float('nan')):.3f} | {ev.get('safe_success', float('nan')):.3f} |")
        log(f"{last} -> {dest}")
        shipped.append(dest)
    write_text(dest_root / "MANIFEST.md", "\n".join(lines) + "\n")
    log(f"wrote {dest_root / 'MANIFEST.md'} ({len(shipped)} checkpoints)")
    return shipped
