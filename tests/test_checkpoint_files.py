"""Checkpoint files: empty, truncated, corrupted (a flipped byte fails the SHA-256 digest), a text
file, a foreign or a newer format, the wrong kind, a pickle carrying code, a digest-valid one
crafted to hold a wrong field: each refused in one line naming the file, never by unsafe loading.
A checkpoint's write is atomic: a full disk or a file-size limit keeps the last good one."""

from __future__ import annotations

import errno
import hashlib
import os
import pickle
from pathlib import Path

import pytest
import torch
from helpers import SHIPPED, TINY, frames_at, one_line, run_script, script, tiny

from flock_torchrl import CheckpointError, load_policy
from flock_torchrl.policies.checkpoint import export_policy, load_checkpoint, save_checkpoint
from flock_torchrl.run import parts
from flock_torchrl.run.launch import train
from flock_torchrl.run.setup import make_train_config


# ---------------------------------------------------------------------------- refused in one line, never loaded unsafely
def test_corrupted_checkpoint_is_refused(tmp_path):
    path = tmp_path / "last.pt"
    path.write_bytes(b"\x80\x04not a checkpoint")
    with pytest.raises(CheckpointError, match="corrupted"):
        load_policy(path)


class _Boom:
    def __reduce__(self):
        return (print, ("this must never run",))


def test_checkpoint_with_code_never_runs(tmp_path, capsys):
    path = tmp_path / "evil.pt"
    torch.save({"format": "flock_torchrl/checkpoint-v2", "payload": _Boom()}, path)
    with pytest.raises(CheckpointError):
        load_checkpoint(path)
    assert "this must never run" not in capsys.readouterr().out


def test_unpicklable_junk_in_checkpoint_dir_is_a_clear_error(tmp_path):
    (tmp_path / "last.pt").write_bytes(pickle.dumps({"format": "something else"}))
    with pytest.raises(CheckpointError):
        load_checkpoint(tmp_path)


def test_a_checkpoint_of_a_newer_format_says_newer(tmp_path):
    torch.save({"format": "flock_torchrl/checkpoint-v3"}, tmp_path / "new.pt")
    with pytest.raises(CheckpointError, match="newer flock_torchrl"):
        load_checkpoint(tmp_path / "new.pt")


def test_corrupted_foreign_and_wrong_kind_checkpoints_say_which(tmp_path):
    result = train(tiny("experiment.max_frames=48"), tmp_path / "run")
    data = bytearray(result.checkpoint.read_bytes())
    actor = load_checkpoint(result.checkpoint)["actor"]
    weights = next(v for v in actor.values() if v.numel() > 100).numpy().tobytes()
    at = bytes(data).find(weights[:64])
    assert at > 0
    data[at + 40:at + 56] = bytes(255 - b for b in data[at + 40:at + 56])  # 16 bytes inside a weight tensor
    flipped = tmp_path / "flipped.pt"
    flipped.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match="corrupted: its payload does not match its SHA-256"):
        load_checkpoint(flipped)
    text = tmp_path / "notes.pt"
    text.write_text("these are my notes\n")
    with pytest.raises(CheckpointError, match="not a readable checkpoint"):
        load_checkpoint(text)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(CheckpointError, match="foreign"):
        load_checkpoint(foreign)
    slim = export_policy(result.checkpoint, tmp_path / "slim.pt")
    with pytest.raises(CheckpointError, match="slim shipped policy"):
        load_checkpoint(slim, kind="training")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "last.pt").write_bytes(slim.read_bytes())
    with pytest.raises(CheckpointError, match="slim shipped policy"):
        train(tiny("resume=true"), tmp_path / "other")
    # Digest-valid, but not what a kind holds : refused naming the missing keys.
    save_checkpoint({"x": 1}, tmp_path / "odd.pt", kind="policy")
    with pytest.raises(CheckpointError, match="policy checkpoint without meta, actor"):
        load_checkpoint(tmp_path / "odd.pt")


def _malicious(path: Path) -> None:
    class Payload:
        def __reduce__(self):
            return (os.system, ("echo this-must-never-run",))

    with path.open("wb") as handle:
        pickle.dump({"payload": Payload()}, handle)


@pytest.mark.parametrize("make, words", [
    (lambda p: p.write_bytes(b""), "is empty"),
    (lambda p: p.write_text("my notes\n"), "not a readable checkpoint"),
    (_malicious, "holds Python objects a checkpoint never contains"),
])
@pytest.mark.slow
def test_a_bad_checkpoint_is_one_line_naming_it_and_never_suggests_unsafe_loading(tmp_path, make, words):
    bad = tmp_path / "bad.pt"
    make(bad)
    proc = run_script("evaluate.py", f"checkpoint={bad}", "episodes=2", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert str(bad) in proc.stderr and words in proc.stderr
    assert "weights_only" not in proc.stderr and "this-must-never-run" not in proc.stdout


@pytest.mark.slow
def test_a_corrupted_paper_recipe_checkpoint_is_found_before_the_first_row(tmp_path):
    recipe = tmp_path / "recipe" / "policy3_g"
    recipe.mkdir(parents=True)
    (recipe / "seed0.pt").write_text("truncated")
    proc = run_script("reproduce.py", "table=3", "episodes=2", f"paper_recipe_dir={tmp_path / 'recipe'}",
                      f"hydra.run.dir={tmp_path / 'out'}", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and str(recipe / "seed0.pt") in proc.stderr
    assert not (tmp_path / "out").exists() and "[table 3," not in proc.stdout  # no row evaluated


# ---------------------------------------------------------------------------- crafted: digest-valid, one field wrong
def crafted(path: Path, how: str) -> Path:
    """A digest-valid checkpoint of the shipped Policy3-G, changed in one field."""
    from flock_torchrl.policies import checkpoint as ck

    payload = ck.load_checkpoint(SHIPPED)
    kind = payload.pop("kind")
    first = next(iter(payload["actor"]))
    if how == "kind":
        kind = "weird"
    elif how == "shape":
        payload["actor"][first] = torch.zeros(3, 3)
    elif how == "nan":
        payload["actor"][first] = payload["actor"][first].clone().fill_(float("nan"))
    elif how == "reading":
        payload["meta"]["reading"] = "weird"
    data = ck._serialise(payload)
    envelope = {"format": ck.FORMAT, "kind": kind, "sha256": hashlib.sha256(data).hexdigest(),
                "payload": torch.frombuffer(bytearray(data), dtype=torch.uint8)}
    path.write_bytes(ck._serialise(envelope))
    return path


CRAFTED = {"kind": "kind 'weird' is not a checkpoint kind (training, policy)",
           "shape": "actor.{first} is [3, 3], but the network its meta describes",
           "nan": "actor.{first} holds NaN or infinite weights",
           "reading": "meta.reading is 'weird', not one of literal, paper_fit"}


@pytest.mark.parametrize("how", sorted(CRAFTED))
def test_a_crafted_digest_valid_checkpoint_is_refused_naming_the_field(tmp_path, how):
    bad = crafted(tmp_path / "bad.pt", how)
    first = next(iter(load_checkpoint(SHIPPED)["actor"]))
    with pytest.raises(CheckpointError) as info:
        load_policy(bad)
    message = str(info.value)
    assert message.startswith(f"{bad}: {CRAFTED[how].format(first=first)}") and "\n" not in message
    assert "pass reading=weird" not in message


@pytest.mark.parametrize("how", ["kind", "nan"])
@pytest.mark.slow
def test_evaluate_refuses_a_crafted_checkpoint_in_one_line(tmp_path, how):
    bad = crafted(tmp_path / "bad.pt", how)
    proc = script("evaluate.py", f"checkpoint={bad}", "policy=policy3_g", "episodes=2",
                  f"hydra.run.dir={tmp_path / 'out'}", cwd=tmp_path, timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    one_line(proc.stderr, f"{bad}: {CRAFTED[how].split('{')[0]}")
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------------------- writes: a full disk, a file-size limit
def test_a_full_disk_says_so_in_one_line_and_keeps_the_last_checkpoint(tmp_path, monkeypatch):
    cfg = make_train_config("policy3_g", "tiny", [*TINY, "experiment.max_frames=160",
                                                  "experiment.checkpoint_every_frames=64"])
    real, calls = parts.save_checkpoint, {"n": 0}

    def full_after_one(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] > 1:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(*args, **kwargs)

    monkeypatch.setattr(parts, "save_checkpoint", full_after_one)
    with pytest.raises(CheckpointError) as info:
        train(cfg, tmp_path / "run")
    message = str(info.value)
    assert "no space left on the device" in message and "the last good checkpoint is" in message
    assert "\n" not in message and frames_at(tmp_path / "run" / "last.pt") == 64


def limit_file_size(size: int):
    def limit() -> None:
        import resource

        resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))
    return limit


@pytest.mark.slow
def test_a_file_size_limit_at_checkpoint_time_is_one_line_naming_the_checkpoint(tmp_path):
    run = tmp_path / "run"
    proc = script("train.py", *TINY, f"hydra.run.dir={run}", cwd=tmp_path, preexec=limit_file_size(100_000))
    assert proc.returncode == 2, proc.stderr[-3000:]
    one_line(proc.stderr, f"cannot write {run / 'last.pt'}: it would pass this process's file-size limit (ulimit -f)")
    assert "no checkpoint yet" in proc.stderr
    assert not (run / "last.pt").exists() and not list(run.glob(".*.tmp"))
