"""The one trainer writes what the solo trainer wrote before the solo and population trainers
became one (tests/data/solo_runs.json, recorded by tests/data/make_solo_reference.py from main
before the change): SAC, SAC captured, DDPG and mixed sizes, each whole and resumed from its
checkpoint at half the budget; checkpoints, episode logs and scalars, bit for bit.

Float round-off is bitwise only on a machine of the recorded fingerprint (docs/decisions.md,
"Reproducibility"); on another one the runs' structure (every key, shape and dtype, the counters
and the episodes' count) is compared, and the values are left to the tests that compare paths of
the one trainer with each other."""

import json
from pathlib import Path

import pytest
import torch

from flock_torchrl.run.launch import train
from flock_torchrl.run.setup import make_train_config

DATA = Path(__file__).parent / "data"
spec = __import__("importlib.util").util.spec_from_file_location("make_solo_reference",
                                                                   DATA / "make_solo_reference.py")
reference = __import__("importlib.util").util.module_from_spec(spec)
spec.loader.exec_module(reference)
RECORDED = json.loads((DATA / "solo_runs.json").read_text())
SAME_MACHINE = RECORDED["fingerprint"] == reference.fingerprint()


# Changed since the recording, on purpose: the evaluation's success and safe success were logged twice
# (as eval/success_rate and eval/success), now once; the training scalars gained the episodes' length,
# the gradients' norms and the learning rates.
DROPPED = {"scalars.eval/success", "scalars.eval/safe_success"}
ADDED = {"scalars.train/episode_length", "scalars.train/grad_norm_actor", "scalars.train/grad_norm_critic",
         "scalars.train/lr_actor", "scalars.train/lr_critic", "scalars.train/lr_alpha"}


def compare(name: str, got: dict[str, str]) -> None:
    want = {key: value for key, value in RECORDED["runs"][name].items() if key not in DROPPED}
    got = {key: value for key, value in got.items() if key not in ADDED}
    assert sorted(got) == sorted(want), (name, sorted(set(got) - set(want)), sorted(set(want) - set(got)))
    if SAME_MACHINE:
        differ = [key for key in want if got[key] != want[key]]
        assert not differ, (name, differ[:10])


@pytest.mark.parametrize("name", ["sac", pytest.param("sac_captured", marks=pytest.mark.slow),
                                  pytest.param("ddpg", marks=pytest.mark.slow),
                                  pytest.param("mixed", marks=pytest.mark.slow)])
def test_the_trainer_writes_what_the_solo_trainer_wrote(name, tmp_path):
    torch.set_num_threads(1)
    policy, extra = reference.RUNS[name]
    torch.manual_seed(0)
    whole = train(make_train_config(policy, "tiny", [*reference.BASE, *extra]), tmp_path / "whole")
    compare(name, reference.run_digest(whole.run_dir))
    half = [o for o in reference.BASE if not o.startswith("experiment.max_frames")]
    train(make_train_config(policy, "tiny", [*half, "experiment.max_frames=96", *extra]), tmp_path / "resumed")
    resumed = train(make_train_config(policy, "tiny", [*reference.BASE, *extra, "resume=true"]), tmp_path / "resumed")
    compare(f"{name}_resumed", reference.run_digest(resumed.run_dir))
