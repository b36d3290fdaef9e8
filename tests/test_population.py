"""Populations (``population=K``): K seeds trained as one, each member as independent as K runs."""

from __future__ import annotations

import copy
import math

import pytest
import torch
from tensordict import TensorDict

from flock_torchrl import FlockingEnv
from flock_torchrl.config import ConfigError, TrainConfig
from flock_torchrl.policies.checkpoint import load_checkpoint, load_policy
from flock_torchrl.policies.learners import OffPolicyLearner, make_learner
from flock_torchrl.policies.members import MemberSampler
from flock_torchrl.run.launch import train
from flock_torchrl.run.shipping import ship_checkpoints
from flock_torchrl.run.batches import TRANSITION_KEYS, agentwise_done
from flock_torchrl.run.setup import make_train_config
from flock_torchrl.world.population import PopulationEnv

# Short episodes, so that worlds end (and reset) inside a few hundred frames.
QUICK = ["progress=false", "logger=none", "scenario.max_steps=30", "experiment.eval_episodes=3"]


def quick_config(population: int, policy: str = "policy3_g", *extra: str) -> TrainConfig:
    return TrainConfig.from_config(make_train_config(policy, "tiny", [f"population={population}", *QUICK, *extra]))


def transitions(policy: str = "policy3_g", steps: int = 120) -> tuple[FlockingEnv, TrainConfig, TensorDict]:
    cfg = quick_config(1, policy)
    env = FlockingEnv(cfg.train_scenario, num_envs=1, seed=3)
    td = env.rollout(steps, break_when_any_done=False)
    return env, cfg, agentwise_done(td, env.n_agents).select(*TRANSITION_KEYS, strict=False).reshape(-1)


def same_rows(a: list[dict], b: list[dict]) -> bool:
    """Evaluation rows equal to the last bit (NaN, e.g. ``t_goal`` without a success, equals NaN)."""
    return len(a) == len(b) and all(
        x.keys() == y.keys() and all(x[k] == y[k] or (math.isnan(x[k]) and math.isnan(y[k])) for k in x)
        for x, y in zip(a, b))


# ---------------------------------------------------------------------------- config
@pytest.mark.parametrize("override, message", [
    (["policy=policyp_g"], "off-policy"),
    (["experiment.workers=2", "experiment.num_envs=4"], "workers must be 1"),
    (["compile=loss"], "eagerly"),
    (["population=0"], "population"),
])
def test_a_population_refuses_what_it_cannot_train(override, message):
    items = ["population=3", *override] if override[0] != "population=0" else override
    with pytest.raises(ConfigError, match=message):
        TrainConfig.from_config(make_train_config("policy3_g", "tiny", items))


def test_population_seeds_are_consecutive():
    assert quick_config(4, "policy3_g", "seed=7").seeds == [7, 8, 9, 10]


# ---------------------------------------------------------------------------- env
def test_member_worlds_spawn_as_a_solo_env_seeded_alike():
    """The same starts and goals, bit for bit; the sensing of them agrees up to float round-off
    (a batch of 6 worlds is computed with other vector widths than one of 2)."""
    scenario = quick_config(1).train_scenario
    start = PopulationEnv(scenario, 3, 2, [10, 20, 30], extras=("physics",)).reset()
    for k, seed in enumerate((10, 20, 30)):
        solo = FlockingEnv(scenario, num_envs=2, seed=seed, extras=("physics",)).reset()
        mine = start[2 * k:2 * k + 2]
        assert torch.equal(mine["agents", "position"], solo["agents", "position"])
        assert torch.equal(mine["goal"], solo["goal"])
        torch.testing.assert_close(mine["agents", "observation"], solo["agents", "observation"])


def test_a_members_resets_leave_the_other_members_worlds_alone():
    """Member 0 resets its worlds again and again in one run only: member 1's next spawns are
    the same in both runs (its own generator)."""
    scenario = quick_config(1).train_scenario
    a, b = PopulationEnv(scenario, 2, 2, [1, 2]), PopulationEnv(scenario, 2, 2, [1, 2])
    a.reset()
    b.reset()
    only_member0 = TensorDict({"_reset": torch.tensor([True, False, False, False])[:, None]}, [4])
    for _ in range(5):
        a.reset(only_member0.clone())
    member1 = TensorDict({"_reset": torch.tensor([False, False, True, True])[:, None]}, [4])
    a.reset(member1.clone())
    b.reset(member1.clone())
    for key in ("position", "heading", "goal"):
        assert torch.equal(a.world[key][2:], b.world[key][2:]), key
    assert not torch.equal(a.world["position"][:1], b.world["position"][:1])


def test_population_env_state_round_trips_every_generator():
    scenario = quick_config(1).train_scenario
    env = PopulationEnv(scenario, 2, 2, [1, 2])
    env.reset()
    state = copy.deepcopy(env.get_state())
    after = env.reset(TensorDict({"_reset": torch.ones(4, 1, dtype=torch.bool)}, [4]))
    other = PopulationEnv(scenario, 2, 2, [5, 6])
    other.set_state(state)
    again = other.reset(TensorDict({"_reset": torch.ones(4, 1, dtype=torch.bool)}, [4]))
    assert torch.equal(after["agents", "observation"], again["agents", "observation"])


# ---------------------------------------------------------------------------- learner
def test_member_sampler_draws_each_members_rows_apart():
    from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer

    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(50), sampler=MemberSampler(3), batch_size=400)
    rows = torch.arange(50.0)[:, None] * 10 + torch.arange(3.0)        # row r, member k: 10 r + k
    buffer.extend(TensorDict({"x": rows}, [50, 3]))
    torch.manual_seed(0)
    x = buffer.sample()["x"]
    assert x.shape == (400, 3)
    assert torch.equal(x.remainder(10), torch.arange(3.0).expand(400, 3))  # column k holds member k's rows
    assert not torch.equal(x[:, 0] - 0, x[:, 1] - 1)                        # drawn independently


@pytest.mark.parametrize("policy", ["policy3_g", "policyd_g"])
def test_members_take_the_update_k_solo_learners_take(policy, monkeypatch):
    """Three members fed the batches three solo learners get, with the same draws (here none:
    the actor's noise is zero on both sides), take the same updates up to float round-off
    (vmap's batched kernels round differently)."""
    monkeypatch.setattr(torch, "randn_like", lambda x, **kwargs: torch.zeros_like(x))
    env, cfg, td = transitions(policy)
    seeds = [0, 1, 2]
    torch.manual_seed(0)
    pop = OffPolicyLearner(env, cfg.algo, cfg.policy.critic_input, seeds)
    solos = []
    for seed in seeds:
        torch.manual_seed(seed)
        solos.append(make_learner(env, cfg.algo, cfg.policy.critic_input))
    for k, solo in enumerate(solos):  # same initial weights: member k is a solo learner seeded k
        assert all(torch.equal(v, pop.actor_state(k)[n]) for n, v in solo.actor_state(0).items())
    for step in range(3):
        batches = [td[(step * 3 + k) * 13:(step * 3 + k + 1) * 13] for k in range(3)]
        got = pop.update(torch.stack(batches, 1))
        for k, solo in enumerate(solos):
            want = solo.update(batches[k])
            for key in want:
                torch.testing.assert_close(got[key][k], want[key][0], rtol=1e-4, atol=1e-5)
    for k, solo in enumerate(solos):
        for name, value in solo.actor_state(0).items():
            torch.testing.assert_close(pop.actor_state(k)[name], value, rtol=1e-4, atol=1e-5)


def test_a_population_of_one_updates_exactly_as_its_solo_learner():
    env, cfg, td = transitions()
    torch.manual_seed(0)
    one = OffPolicyLearner(env, cfg.algo, cfg.policy.critic_input, [0])
    torch.manual_seed(0)
    solo = make_learner(env, cfg.algo, cfg.policy.critic_input)
    for step in range(3):
        batch = td[step * 26:(step + 1) * 26]
        torch.manual_seed(100 + step)
        got = one.update(batch.unsqueeze(1))
        torch.manual_seed(100 + step)
        want = solo.update(batch)
        assert all(torch.equal(got[k][0], want[k][0]) for k in want)
    assert all(torch.equal(v, one.actor_state(0)[n]) for n, v in solo.actor_state(0).items())


def test_perturbing_one_member_leaves_the_others_update_unchanged():
    env, cfg, td = transitions()
    batch = torch.stack([td[k * 26:(k + 1) * 26] for k in range(3)], 1)
    torch.manual_seed(0)
    a = OffPolicyLearner(env, cfg.algo, cfg.policy.critic_input, [0, 1, 2])
    torch.manual_seed(0)
    b = OffPolicyLearner(env, cfg.algo, cfg.policy.critic_input, [0, 1, 2])
    with torch.no_grad():  # member 1's weights and data changed in b only
        for value in b.params.get("actor_network_params").values(True, True):
            value[1].add_(0.05)
    changed = batch.clone()
    changed["agents", "observation"][:, 1] += 0.3
    torch.manual_seed(5)
    got_a = a.update(batch)
    torch.manual_seed(5)
    got_b = b.update(changed)
    for k in (0, 2):
        assert all(torch.equal(got_a[key][k], got_b[key][k]) for key in got_a)
        assert all(torch.equal(v, b.actor_state(k)[n]) for n, v in a.actor_state(k).items())
    assert not torch.equal(got_a["loss_qvalue"][1], got_b["loss_qvalue"][1])


# ---------------------------------------------------------------------------- runs
# A population of one is the solo run: the one trainer writes the solo run's files for it, which
# tests/test_solo_reference.py holds to what the solo trainer wrote before the two became one.
MIXED = ["+experiment.swarm_sizes=[2,3]", "experiment.num_envs=4", "experiment.max_frames=192"]


@pytest.mark.slow
def test_a_mixed_size_population_resumes_bitwise(tmp_path):
    whole = train(quick_config(2, "policy3_g", *MIXED), tmp_path / "whole")
    assert whole.updates > 0
    train(quick_config(2, "policy3_g", *MIXED[:-1], "experiment.max_frames=96"), tmp_path / "resumed")
    train(quick_config(2, "policy3_g", *MIXED, "resume=true"), tmp_path / "resumed")
    a = load_checkpoint(tmp_path / "whole" / "last.pt")
    b = load_checkpoint(tmp_path / "resumed" / "last.pt")
    assert [m["meta"]["trained_sizes"] for m in a["members"]] == [[2, 3], [2, 3]]
    for ma, mb in zip(a["members"], b["members"]):
        assert all(torch.equal(v, mb["actor"][k]) for k, v in ma["actor"].items())
    assert not all(torch.equal(v, a["members"][1]["actor"][k]) for k, v in a["members"][0]["actor"].items())


@pytest.mark.slow
def test_a_population_trains_ships_and_resumes_bitwise(tmp_path):
    """population=2 under the tiny recipe: each member's policy ships as seed<k>.pt; a run stopped
    at its first checkpoint and resumed ends bit-identical to the uninterrupted one."""
    runs = tmp_path / "runs" / "tiny" / "paper_fit" / "policy3_g"
    cfg = quick_config(2, "policy3_g", "seed=4", "reading=paper_fit")
    whole = train(cfg, runs / "seed4__population-2")
    assert whole.frames == 160 and whole.updates > 0
    half = quick_config(2, "policy3_g", "seed=4", "reading=paper_fit", "experiment.max_frames=64")
    train(half, tmp_path / "resumed")
    again = quick_config(2, "policy3_g", "seed=4", "reading=paper_fit", "resume=true")
    train(again, tmp_path / "resumed")
    a = load_checkpoint(runs / "seed4__population-2" / "last.pt")
    b = load_checkpoint(tmp_path / "resumed" / "last.pt")
    for ma, mb in zip(a["members"], b["members"]):
        assert all(torch.equal(v, mb["actor"][k]) for k, v in ma["actor"].items())
        assert same_rows(ma["evaluations"][-1:], mb["evaluations"][-1:])  # the half run evaluated at its end too
    for seed in (4, 5):
        assert ((runs / "seed4__population-2" / f"seed{seed}" / "episodes.csv").read_text()
                == (tmp_path / "resumed" / f"seed{seed}" / "episodes.csv").read_text())
    assert not torch.equal(a["members"][0]["actor"]["module.0.module.0.0.weight"],
                           a["members"][1]["actor"]["module.0.module.0.0.weight"])
    shipped = ship_checkpoints("paper_fit", "tiny", tmp_path / "runs", tmp_path / "ckpt", "paper",
                               tmp_path / "ckpt" / "paper_fit" / "paper_recipe", log=lambda _: None)
    names = sorted(p.name for p in shipped)
    assert names == ["seed4.pt", "seed5.pt"]
    for k, seed in enumerate((4, 5)):
        policy = load_policy(tmp_path / "ckpt" / "paper_fit" / "policy3_g" / f"seed{seed}.pt")
        assert policy.flock_meta["seed"] == seed
        assert all(torch.equal(v, a["members"][k]["actor"][n]) for n, v in policy.actor.state_dict().items())


@pytest.mark.slow
def test_a_signalled_population_checkpoints_and_resumes_to_the_uninterrupted_run(tmp_path):
    """SIGTERM to a real population process: it checkpoints, exits 143, and its resume.yaml
    continues it to the weights and episode logs of an uninterrupted run."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(root)}
    args = ["policy=policy3_g", "experiment=tiny", "population=2", *QUICK, "experiment.max_frames=800",
            "experiment.checkpoint_every_frames=64", "experiment.eval_every_frames=0"]
    folder = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, str(root / "scripts" / "train.py"), *args, f"hydra.run.dir={folder}"],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 180
    while not (folder / "last.pt").exists():
        assert proc.poll() is None, proc.communicate()
        assert time.time() < deadline, "no checkpoint appeared"
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 143, err
    assert "Traceback" not in err
    stopped = load_checkpoint(folder / "last.pt")["counters"]["frames"]
    assert stopped < 800, "the signal did not land mid-run"
    resumed = subprocess.run([sys.executable, str(root / "scripts" / "train.py"), "-cd", str(folder), "-cn", "resume"],
                             cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    whole = train(make_train_config("policy3_g", "tiny", args[2:]), tmp_path / "whole")
    a, b = load_checkpoint(whole.checkpoint), load_checkpoint(folder / "last.pt")
    assert a["counters"]["frames"] == b["counters"]["frames"] == 800
    for ma, mb in zip(a["members"], b["members"]):
        assert all(torch.equal(v, mb["actor"][k]) for k, v in ma["actor"].items())
    for seed in (0, 1):
        assert (tmp_path / "whole" / f"seed{seed}" / "episodes.csv").read_text() == \
            (folder / f"seed{seed}" / "episodes.csv").read_text()


def test_a_populations_memory_estimate_counts_every_member():
    from flock_torchrl.world.memory import train_bytes

    one, ten = train_bytes(quick_config(1)), train_bytes(quick_config(10))
    assert ten["algo.buffer_size"] == 10 * one["algo.buffer_size"]
    assert ten["experiment.num_envs"] == 10 * one["experiment.num_envs"]


# ---------------------------------------------------------------------------- a population's checkpoint, used
@pytest.fixture(scope="module")
def population_run(tmp_path_factory):
    """A finished population of two Policy1-G members (seeds 4 and 5): not the apps' default policy."""
    folder = tmp_path_factory.mktemp("population") / "seed4__population-2"
    train(quick_config(2, "policy1_g", *POPULATION_RUN, "experiment.max_frames=96"), folder)
    return folder


POPULATION_RUN = ["seed=4", "reading=paper_fit", "scenario.max_steps=12"]


def test_a_populations_checkpoint_loads_one_member_by_name_or_lists_them(population_run, tmp_path):
    from flock_torchrl import CheckpointError
    from flock_torchrl.policies.registry import resolve

    with pytest.raises(CheckpointError, match=r"population of 2 policies: choose one with member=0 \(seed 4\), "
                                              r"member=1 \(seed 5\)$"):
        load_policy(population_run / "last.pt")
    payload = load_checkpoint(population_run / "last.pt")
    policy = load_policy(population_run, member=1)
    assert policy.flock_meta["seed"] == 5 and policy.flock_meta["policy_id"] == "policy1_g"
    assert all(torch.equal(v, payload["members"][1]["actor"][n]) for n, v in policy.actor.state_dict().items())
    with pytest.raises(CheckpointError, match=r"not member=2: choose one of member=0"):
        load_policy(population_run, member=2)
    solo = train(quick_config(1, "policy3_g", "experiment.max_frames=16"), tmp_path / "solo")
    with pytest.raises(CheckpointError, match="one run's policy, not a population's: member=0"):
        load_policy(solo.checkpoint, member=0)
    # The registry (evaluate, scaling, reproduce) takes every member, each named, or the one asked for.
    handles = resolve(population_run / "last.pt", "paper_fit")
    assert [(h.member, h.seed) for h in handles] == [(0, 4), (1, 5)]
    assert handles[1].source.endswith("last.pt member=1 (seed 5)")
    (one,) = resolve(population_run / "last.pt", "paper_fit", member=1)
    assert (one.member, one.seed) == (1, 5)


@pytest.mark.slow  # scripts/evaluate.py in a process of its own (~8 s)
def test_evaluate_takes_the_policy_and_member_of_a_checkpoint(population_run, tmp_path):
    """``checkpoint=`` alone: the checkpoint's policy (Policy1-G, not the app's default Policy3-G)
    and its world; ``member=`` one member, said in the output; a conflicting ``policy=`` is one line."""
    import json

    from helpers import run_script

    proc = run_script("evaluate.py", f"checkpoint={population_run / 'last.pt'}", "member=1", "episodes=2",
                      "scenario=s1", cwd=tmp_path)
    assert "member=1 (seed 5)" in proc.stdout and "[1/1] Policy1-G" in proc.stdout, proc.stdout
    (out,) = (tmp_path / "outputs" / "evaluate" / "paper_fit" / "policy1_g").iterdir()  # named after its policy
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["policy"]["id"] == "policy1_g" and summary["config"]["scenario"]["fov"] == \
        pytest.approx(2 * math.pi)
    from flock_torchrl.config import app_config
    from flock_torchrl.run.evaluation import evaluated_handles

    every = evaluated_handles(app_config("evaluate", policy="policy1_g", checkpoint=str(population_run / "last.pt")))
    assert [h.source.rsplit(" ", 3)[1:] for h in every] == [["member=0", "(seed", "4)"], ["member=1", "(seed", "5)"]]
    proc = run_script("evaluate.py", f"checkpoint={population_run / 'last.pt'}", "policy=policy3_g", "episodes=2",
                      f"hydra.run.dir={tmp_path / 'conflict'}", cwd=tmp_path, check=False)
    assert proc.returncode == 2 and proc.stderr.startswith("error: policy: ") and "leave policy= out" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and not (tmp_path / "conflict").exists()


def test_a_non_finite_member_in_a_populations_checkpoint_is_refused_naming_field_member_and_file(
        population_run, tmp_path):
    """Digest-valid, but member 1's stacked actor weights (or its slim actor) are NaN: refused in
    one line naming the field, the member and its seed, and the file, before anything is built."""
    from flock_torchrl import CheckpointError
    from flock_torchrl.policies.checkpoint import save_checkpoint

    payload = load_checkpoint(population_run / "last.pt")
    params = payload["learner"]["params"]["actor_network_params"]
    name, weight = next((k, v) for k, v in _leaves(params) if v.is_floating_point())
    weight[1].fill_(float("nan"))
    bad = save_checkpoint({k: v for k, v in payload.items() if k != "kind"}, tmp_path / "run" / "last.pt",
                          kind="training")
    with pytest.raises(CheckpointError) as info:
        load_checkpoint(bad)
    message = str(info.value)
    assert message == f"{bad}: learner.params.actor_network_params.{name} holds NaN or infinite values for " \
                      "member 1 (seed 5)"
    with pytest.raises(CheckpointError, match="member 1 \\(seed 5\\)"):  # a resume is refused before it starts
        train(quick_config(2, "policy1_g", *POPULATION_RUN, "resume=true"), tmp_path / "run")
    payload = load_checkpoint(population_run / "last.pt")
    first = next(iter(payload["members"][1]["actor"]))
    payload["members"][1]["actor"][first].fill_(float("inf"))
    bad = save_checkpoint({k: v for k, v in payload.items() if k != "kind"}, tmp_path / "bad.pt", kind="training")
    with pytest.raises(CheckpointError, match=rf"^{bad}: members\[1\]\.actor\.{first} \(member 1, seed 5\) holds NaN"):
        load_checkpoint(bad)


def _leaves(tree, prefix=""):
    for key, value in tree.items():
        if isinstance(value, dict):
            yield from _leaves(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


def test_a_resume_without_a_members_episode_log_is_refused_naming_it(population_run, tmp_path):
    import shutil

    from flock_torchrl import CheckpointError

    run = tmp_path / "run"
    shutil.copytree(population_run, run)
    assert load_checkpoint(run / "last.pt")["members"][1]["episodes_seen"] > 0
    (run / "seed5" / "episodes.csv").unlink()
    before = {p: p.stat().st_mtime_ns for p in run.rglob("*")}
    with pytest.raises(CheckpointError, match=rf"^{run / 'seed5' / 'episodes.csv'} is missing, but the checkpoint"):
        train(quick_config(2, "policy1_g", *POPULATION_RUN, "experiment.max_frames=128", "resume=true"), run)
    assert {p: p.stat().st_mtime_ns for p in run.rglob("*")} == before  # nothing was changed


def test_a_populations_scalars_are_logged_per_member_and_as_the_solo_runs_names(tmp_path):
    """Each member's scalars under seed<s>/, their mean under the solo run's train/* names, the
    loop's speed under perf/frames_per_s as a solo run logs it (every member's frames), and each
    member's under perf/member_*."""
    import csv

    train(quick_config(2, "policy3_g", *POPULATION_RUN, "logger=csv", "experiment.max_frames=96"), tmp_path / "run")
    root = tmp_path / "run" / "logs" / "scalars"
    logged = {p.relative_to(root).with_suffix("").as_posix() for p in root.rglob("*.csv")}
    losses = {name.split("/", 2)[2] for name in logged if name.startswith("seed4/train/loss")}
    assert losses and {"episode_reward", "success_rate"} <= {n.split("/", 2)[2] for n in logged
                                                             if n.startswith("seed5/train/")}
    for name in [*losses, "episode_reward", "success_rate"]:
        assert f"train/{name}" in logged, name
        last = lambda key: float(list(csv.reader((root / f"{key}.csv").open()))[-1][1])  # noqa: E731
        assert last(f"train/{name}") == pytest.approx((last(f"seed4/train/{name}") + last(f"seed5/train/{name}")) / 2)
    assert {"perf/frames_per_s", "perf/updates_per_s", "perf/member_frames_per_s"} <= logged
    # perf/frames_per_s is every member's frames, perf/member_frames_per_s one member's
    assert last("perf/frames_per_s") == pytest.approx(2 * last("perf/member_frames_per_s"))


@pytest.mark.slow
def test_scaling_names_the_member_of_a_population_it_flies(population_run, tmp_path):
    from flock_torchrl.config import app_config
    from flock_torchrl.report.scaling import scaling

    cfg = app_config("scaling", reading="paper_fit", policy_name="policy_ma", others=[str(population_run / "last.pt")],
                     sizes=[3], episodes=1)
    rows = scaling(cfg, tmp_path, log=lambda _: None)
    assert rows[-1]["policy"] == "Policy1-G [tiny, seed 4, member=0 of a population]"


@pytest.mark.slow  # ~7 s: each member evaluated alone, then all together
def test_members_evaluated_together_fly_the_episodes_each_would_fly_alone():
    """evaluate_members (a population's evaluation: K actors, one batched rollout) gives each
    member the episodes evaluate() gives it alone: the same starts, the same outcomes, metrics to
    the batched actor's round-off."""
    from flock_torchrl.run.rollout import evaluate, evaluate_members

    env, cfg, _ = transitions()
    learner = OffPolicyLearner(env, cfg.algo, cfg.policy.critic_input, [0, 1, 2])
    params = learner.params.get("actor_network_params").detach()
    actor = copy.deepcopy(learner.actor)
    together = evaluate_members(actor, params, "s1", n_episodes=6, seed=11)
    assert len(together) == 3
    for k, result in enumerate(together):
        actor.load_state_dict(learner.actor_state(k))
        alone = evaluate(actor, "s1", n_episodes=6, seed=11)
        for key in ("success", "safe_success", "reached", "crashed", "steps"):
            assert torch.equal(result.episodes[key], alone.episodes[key]), (k, key)
        for key in ("return", "d_min_uav", "d_c"):
            torch.testing.assert_close(result.episodes[key], alone.episodes[key], rtol=1e-4, atol=1e-4)
    # Members that differ fly differently: the batch is not one member's episodes three times.
    assert not torch.equal(together[0].episodes["return"], together[1].episodes["return"])
