"""Writes tests/data/composed_train_configs.json: what conf/train.yaml composes for every policy x
experiment x reading, generated once from main before configuration became a package,
so that tests/test_config_compose.py can show every composition kept its values.

    .venv/bin/python tests/data/make_composed_reference.py

Each composition is stored as its top-level nodes, each node once in a table of distinct values
(a node's key is a digest of its canonical JSON); the shipped checkpoints' folder, which depends on
where the repository sits, is written as ``<checkpoints>``.
"""

import hashlib
import json
from pathlib import Path

from flock_torchrl.config import available, compose, shipped_checkpoints_dir

OUT = Path(__file__).with_name("composed_train_configs.json")


def canonical(value):
    return json.dumps(value, sort_keys=True, separators=(",", ":"))


def main():
    from omegaconf import OmegaConf

    shipped = str(shipped_checkpoints_dir())
    nodes, compositions = {}, {}
    for policy in available("policy"):
        for experiment in available("experiment"):
            for reading in available("reading"):
                cfg = compose("train", [f"policy={policy}", f"experiment={experiment}", f"reading={reading}"])
                tree = json.loads(canonical(OmegaConf.to_container(cfg, resolve=True)).replace(shipped, "<checkpoints>"))
                entry = {}
                for key, value in tree.items():
                    digest = hashlib.sha256(canonical(value).encode()).hexdigest()[:16]
                    nodes[digest] = value
                    entry[key] = digest
                compositions[f"{policy}/{experiment}/{reading}"] = entry
    OUT.write_text(json.dumps({"nodes": nodes, "compositions": compositions}, sort_keys=True, indent=0) + "\n")
    print(f"{OUT}: {len(compositions)} compositions, {len(nodes)} distinct nodes")


if __name__ == "__main__":
    main()
