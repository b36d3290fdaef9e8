"""make ship-checkpoints (run/shipping.py): finished runs only, each collection in its folder
with its MANIFEST, files of the earlier flat layout moved into place."""

import shutil

import pytest

from flock_torchrl.policies.checkpoint import load_checkpoint
from flock_torchrl.run import trainer
from flock_torchrl.run.shipping import ship_checkpoints
from flock_torchrl.run.launch import train
from flock_torchrl.run.setup import make_train_config


def tiny_run(runs, experiment_folder, seed, **overrides):
    cfg = make_train_config("policy3_g", "tiny", ["scenario.max_steps=30", "progress=false", f"seed={seed}",
                                                  "experiment.eval_every_frames=0", "experiment.eval_episodes=1",
                                                  *(f"{k}={v}" for k, v in overrides.items())])
    return train(cfg, runs / experiment_folder / "paper_fit" / "policy3_g" / f"seed{seed}")


@pytest.mark.slow
def test_only_finished_runs_are_shipped_into_their_collections(tmp_path, monkeypatch):
    runs, ckpts = tmp_path / "runs", tmp_path / "checkpoints"
    tiny_run(runs, "tiny", 0, **{"experiment.max_frames": 32})
    tiny_run(runs, "mixed", 0, **{"experiment.max_frames": 32})
    # A run stopped before its budget (as a killed or interrupted run is) stays behind.
    monkeypatch.setattr(trainer.Schedule, "finished", lambda self, frames, episodes, seconds: frames >= 16)
    stopped = tiny_run(runs, "tiny", 1, **{"experiment.max_frames": 64})
    monkeypatch.undo()
    assert stopped.frames < 64
    # A file of the earlier flat layout in the paper recipe's folder moves to <policy>/seed<k>.pt.
    recipe = ckpts / "paper_fit" / "paper_recipe"
    recipe.mkdir(parents=True)
    shutil.copy(runs / "tiny" / "paper_fit" / "policy3_g" / "seed0" / "last.pt", tmp_path / "legacy.pt")
    from flock_torchrl.policies.checkpoint import export_policy
    export_policy(tmp_path / "legacy.pt", recipe / "policy3_g_seed7.pt")
    said = []
    shipped = ship_checkpoints("paper_fit", "tiny", runs, ckpts, "paper", recipe, log=said.append,
                               collections={"mixed": "mixed"})
    assert shipped == [ckpts / "paper_fit" / "policy3_g" / "seed0.pt", ckpts / "paper_fit" / "mixed" / "policy3_g" / "seed0.pt"]
    assert any(line.startswith("skipped") and "seed1" in line for line in said), said
    assert not (ckpts / "paper_fit" / "policy3_g" / "seed1.pt").exists()
    assert (recipe / "policy3_g" / "seed7.pt").is_file() and not (recipe / "policy3_g_seed7.pt").exists()
    for folder in (ckpts / "paper_fit", ckpts / "paper_fit" / "mixed", recipe):
        assert "| Policy3-G |" in (folder / "MANIFEST.md").read_text(), folder
    assert load_checkpoint(shipped[1], kind="policy")["meta"]["experiment"] == "tiny"


def test_exporting_the_same_run_twice_gives_the_same_bytes(tmp_path):
    from flock_torchrl.policies.checkpoint import export_policy

    run = tiny_run(tmp_path / "runs", "tiny", 0, **{"experiment.max_frames": 16})
    a, b = export_policy(run.checkpoint, tmp_path / "a.pt"), export_policy(run.checkpoint, tmp_path / "sub" / "b.pt")
    assert a.read_bytes() == b.read_bytes()


def test_a_policy_flies_with_its_own_camera_slots_and_older_checkpoints_with_three(tmp_path):
    """``n_cam`` is a policy scenario field: a checkpoint trained with eight camera slots records
    them and every evaluation world takes them (observation 2 + 3 x 2 + 8 x 3 = 32); a shipped
    checkpoint saved before the field existed (its ``policy_scenario`` lacks ``n_cam``) flies
    with its saved scenario's three, what it trained with."""
    from flock_torchrl import evaluate
    from flock_torchrl.config import shipped_checkpoints_dir
    from flock_torchrl.policies.checkpoint import export_policy
    from flock_torchrl.policies.registry import checkpoint_handle
    from flock_torchrl.run.rollout import policy_env

    cfg = make_train_config("policy3_g", "tiny", ["scenario.n_cam=8", "scenario.max_steps=30", "progress=false",
                                                  "seed=0", "experiment.eval_every_frames=0",
                                                  "experiment.eval_episodes=1", "experiment.max_frames=16"])
    run = train(cfg, tmp_path / "runs" / "cam8")
    path = export_policy(run.checkpoint, tmp_path / "cam8.pt")
    meta = load_checkpoint(path, kind="policy")["meta"]
    assert meta["policy_scenario"]["n_cam"] == 8 and meta["scenario"]["n_cam"] == 8
    handle = checkpoint_handle(path)
    env = policy_env(handle, "forest", "paper_fit", 2, 0, "cpu", {"n_uavs": 12})
    assert env.cfg.n_cam == 8 and env.reset()["agents", "observation"].shape[-1] == 32
    result = evaluate(path, "forest", n_episodes=2, env_overrides={"n_uavs": 12}, max_steps=5)
    assert result.episodes["success"].numel() == 2
    older = checkpoint_handle(shipped_checkpoints_dir() / "paper_fit" / "policy3_g" / "seed0.pt")
    assert "n_cam" not in load_checkpoint(older.origin, kind="policy")["meta"]["policy_scenario"]
    assert older.scenario["n_cam"] == 3
    env = policy_env(older, "forest", "paper_fit", 2, 0, "cpu", {"n_uavs": 12})
    assert env.cfg.n_cam == 3 and env.reset()["agents", "observation"].shape[-1] == 17


@pytest.mark.slow
def test_every_conflict_is_found_before_anything_is_shipped(tmp_path):
    """A solo run and a population member both hold policy3_g seed1 (and, in the mixed
    collection, seed0 twice): one line listing both conflicts, exit 2, and nothing written."""
    from helpers import run_script

    from flock_torchrl import CheckpointError

    runs, ckpts = tmp_path / "runs", tmp_path / "checkpoints"
    tiny_run(runs, "fast", 1, **{"experiment.max_frames": 16})
    tiny_run(runs, "mixed", 0, **{"experiment.max_frames": 16, "population": 2}).run_dir.rename(
        runs / "mixed" / "paper_fit" / "policy3_g" / "seed0__population-2")
    tiny_run(runs, "mixed", 0, **{"experiment.max_frames": 16})
    tiny_run(runs, "fast", 0, **{"experiment.max_frames": 16, "population": 2}).run_dir.rename(
        runs / "fast" / "paper_fit" / "policy3_g" / "seed0__population-2")
    with pytest.raises(CheckpointError) as info:
        ship_checkpoints("paper_fit", "fast", runs, ckpts, "paper", ckpts / "paper_fit" / "paper_recipe",
                         log=lambda _: None, collections={"mixed": "mixed"})
    message = str(info.value)
    assert message.startswith("nothing was shipped, 2 conflict(s): ") and "\n" not in message
    assert f"{runs}/fast/paper_fit/policy3_g/seed0__population-2/last.pt (member 1) and " \
           f"{runs}/fast/paper_fit/policy3_g/seed1/last.pt both hold policy3_g seed1" in message
    assert "both hold policy3_g seed0" in message
    assert not ckpts.exists()
    proc = run_script("ship.py", "reading=paper_fit", f"runs_dir={runs}", f"checkpoints_dir={ckpts}",
                      cwd=tmp_path, check=False)
    assert proc.returncode == 2 and proc.stderr.startswith("error: nothing was shipped, 2 conflict(s)"), proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and not ckpts.exists()
