"""Writes tests/data/solo_runs.json: digests of what today's solo training writes, recorded from
main before the solo and population trainers became one, so that
tests/test_solo_reference.py can show the one trainer writes the same, bit for bit.

    .venv/bin/python tests/data/make_solo_reference.py [OUT]      (from the repository's root)

Each run (SAC, SAC captured, DDPG, mixed sizes; each also resumed after its checkpoint at half
the budget) is stored as digests of its checkpoint's tensors and values (not its seconds), its
episode log and its training and evaluation scalars (not the speeds), beside the machine's
fingerprint: float round-off is bitwise only on a machine of the same fingerprint.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import sys
import tempfile
from pathlib import Path

import torch

OUT = Path(__file__).with_name("solo_runs.json")
BASE = ["scenario.max_steps=40", "progress=false", "experiment.max_frames=192", "experiment.eval_every_frames=96",
        "experiment.checkpoint_every_frames=96"]
RUNS = {
    "sac": ("policy3_g", []),
    "sac_captured": ("policy3_g", ["cudagraphs=true"]),
    "ddpg": ("policyd_g", []),
    "mixed": ("policy3_g", ["experiment.swarm_sizes=[3,6]"]),
}


def digest(value) -> str:
    """A tensor's dtype, shape and bytes, or a value's canonical JSON, as a short sha256."""
    if isinstance(value, torch.Tensor):
        t = value.detach().cpu().contiguous().reshape(-1)
        data = f"{value.dtype}{list(value.shape)}".encode() + (t.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    else:
        data = json.dumps(value, sort_keys=True, default=str).encode()
    return hashlib.sha256(data).hexdigest()[:20]


def leaves(tree, prefix: str = "") -> dict[str, str]:
    """Every leaf of a checkpoint's nested dicts and lists by its dotted path, digested."""
    out: dict[str, str] = {}
    if isinstance(tree, dict):
        for key in sorted(tree, key=str):
            out.update(leaves(tree[key], f"{prefix}{key}."))
    elif isinstance(tree, (list, tuple)) and any(isinstance(v, (dict, list, tuple, torch.Tensor)) for v in tree):
        for i, value in enumerate(tree):
            out.update(leaves(value, f"{prefix}{i}."))
    else:
        out[prefix[:-1]] = digest(tree)
    return out


def run_digest(run_dir: Path) -> dict[str, str]:
    """What a finished run wrote, digested: the checkpoint (but its seconds), the episode log and
    the scalars of training and evaluation (but the loop's speeds)."""
    from flock_torchrl.policies.checkpoint import load_checkpoint

    ckpt = load_checkpoint(run_dir / "last.pt")
    ckpt["counters"] = {k: v for k, v in ckpt["counters"].items() if k != "seconds"}
    ckpt.pop("config", None)  # holds the run's folder
    out = {f"checkpoint.{k}": v for k, v in leaves(ckpt).items()}
    out["episodes.csv"] = digest((run_dir / "episodes.csv").read_text())
    for path in sorted((run_dir / "logs" / "scalars").glob("*/*.csv")):
        group = path.parent.name
        if group in ("train", "eval"):
            rows = list(csv.reader(io.StringIO(path.read_text())))
            out[f"scalars.{group}/{path.stem}"] = digest(rows)
    return out


def record(folder: Path) -> dict:
    from flock_torchrl.run.launch import train
    from flock_torchrl.run.setup import make_train_config

    runs = {}
    for name, (policy, extra) in RUNS.items():
        torch.manual_seed(0)
        whole = train(make_train_config(policy, "tiny", [*BASE, *extra]), folder / name)
        runs[name] = run_digest(whole.run_dir)
        half = [o for o in BASE if not o.startswith("experiment.max_frames")]
        train(make_train_config(policy, "tiny", [*half, "experiment.max_frames=96", *extra]), folder / f"{name}_r")
        resumed = train(make_train_config(policy, "tiny", [*BASE, *extra, "resume=true"]), folder / f"{name}_r")
        runs[f"{name}_resumed"] = run_digest(resumed.run_dir)
    return runs


def fingerprint() -> str:
    from flock_torchrl.report.splice import machine

    return machine(1)


def main() -> None:
    torch.set_num_threads(1)
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else OUT
    with tempfile.TemporaryDirectory() as folder:
        runs = record(Path(folder))
    out.write_text(json.dumps({"fingerprint": fingerprint(), "base": BASE, "runs": runs}, indent=1, sort_keys=True)
                   + "\n")
    print(f"wrote {out}: {len(runs)} runs")


if __name__ == "__main__":
    main()
