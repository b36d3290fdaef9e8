"""Evaluation protocol (specification section 5): batched episodes, records at the first done,
summaries, intervals. Expected values are worked out by hand in the comments beside them."""

from __future__ import annotations

import csv
import math

import pytest
import torch
from tensordict import TensorDict

from flock_torchrl import CheckpointError, ConfigError, FlockingEnv
from flock_torchrl.config import EvaluateConfig
from torchrl.envs.utils import ExplorationType, set_exploration_type
from flock_torchrl.policies.registry import policy_config_of, policy_id
from flock_torchrl.config import EVAL_SEED
from flock_torchrl.policies.scripted import goal_seeking_policy
from flock_torchrl.run.results import EvaluationResult, mean_std, wilson_interval
from flock_torchrl.run.rollout import evaluate
from flock_torchrl.world.metrics import METRIC_KEYS

Z2 = 1.959963984540054 ** 2


def test_goal_seeking_swarm_in_s1_has_the_known_metrics():
    result = evaluate(goal_seeking_policy(), scenario="s1", n_episodes=6)
    e = result.episodes
    assert result.n_episodes == 6 and result.policy == "GoalSeeking" and result.seed == EVAL_SEED
    # No obstacles: nothing to crash into, every swarm flies straight to the goal.
    assert e["reached"].all() and not e["crashed"].any() and e["success"].all()
    assert (e["safe_success"] <= e["success"]).all()
    # Nearest-obstacle distance is capped at 10 m and S1 has none (section 5: "exactly 10.000").
    assert torch.equal(e["d_min_obs"], torch.full((6,), 10.0))
    # t_goal bounds. Swarm centre 2 d_env = 80 m from the goal, UAVs within 3 m of it: the nearest
    # UAV starts >= 77 m away and must come within 1 m, i.e. fly >= 76 m. Its command has speed
    # V = a1 + 2 = 2, and v <- v + 0.2 (v_cmd - v) from rest gives |v_j| <= 2 (1 - 0.8^j), so after k
    # steps it has flown <= sum_j 0.2 * 2 (1 - 0.8^j) = 0.4 k - 1.6 (1 - 0.8^k) < 0.4 k - 1.6 + 0.1;
    # 76 m needs k >= 193.75 -> t >= 194 * 0.2 = 38.8 s. Upward: <= 83 - 1 = 82 m at 2 m/s (41 s) plus
    # the 1.6 m lag (0.8 s) and two turning steps; 45 s leaves room for the curved first metres.
    assert (e["t_goal"] >= 38.8 - 1e-4).all() and (e["t_goal"] <= 45.0).all()
    # The episode ends on the step the goal is reached: steps = t_goal / dt.
    assert torch.equal(e["steps"], torch.round(e["t_goal"] / 0.2).long())
    # Mean swarm speed never exceeds the commanded 2 m/s.
    assert (e["speed"] <= 2.0 + 1e-5).all() and (e["speed"] > 1.5).all()
    assert result.rollout_steps == int(e["steps"].max())
    s = result.summary()
    assert s["success_rate"] == 1.0 and s["n_reached"] == 6 and s["d_min_obs"] == 10.0 and s["d_min_obs_std"] == 0.0
    # Wilson lower bound for k = n: n / (n + z^2) = 6 / 9.8415 = 0.6097.
    assert s["success_rate_low"] == pytest.approx(6 / (6 + Z2)) and s["success_rate_high"] == 1.0


def _reference_first_done(env: FlockingEnv, policy) -> dict[str, torch.Tensor]:
    """The protocol written out plainly: step all envs to the end, keep every step's metrics,
    pick each env's row at its first done."""
    td = env.reset()
    steps, dones = [], []
    with torch.no_grad():
        for _ in range(env.cfg.max_steps):
            td = env.step(policy(td))["next"]
            steps.append(td["episode"].clone())
            dones.append(td["done"].reshape(-1).clone())
            if torch.stack(dones).any(0).all():
                break
    first = torch.stack(dones).float().argmax(0)  # index of the first True per env
    return {k: torch.stack([s[k] for s in steps])[first, torch.arange(env.num_envs)] for k in METRIC_KEYS}


class _Held(FlockingEnv):
    """The plain protocol's env: a world that is done stays as it is when stepped (the
    reference keeps stepping every world, where ``FlockingEnv`` refuses)."""

    def _checked_action(self, tensordict):
        for key in ("terminated", "truncated"):
            self.world.set(key, torch.zeros_like(self.world[key]))
        return super()._checked_action(tensordict)


def test_records_come_from_each_envs_first_done_and_subsets_change_nothing(monkeypatch):
    # S5 (static + moving circles) without the instinct: straight flights crash at different times,
    # so the running worlds continue in ever smaller envs.
    calls = []
    real = FlockingEnv.subset
    monkeypatch.setattr(FlockingEnv, "subset", lambda env, keep: calls.append(int(keep.numel())) or real(env, keep))
    result = evaluate(goal_seeking_policy(), scenario="s5", reading="literal", n_episodes=40, seed=3, max_steps=90)
    assert len(calls) > 3, "the rollout never took a subset; the test would not check it"
    reference = _reference_first_done(_Held("s5", num_envs=40, seed=3, reading="literal", max_steps=90),
                                      goal_seeking_policy())
    assert result.episodes["crashed"].any() and result.episodes["steps"].unique().numel() > 5
    for k in METRIC_KEYS:
        assert torch.allclose(result.episodes[k].double(), reference[k].double(), atol=1e-5, equal_nan=True), k


def test_max_steps_truncates_every_episode():
    result = evaluate(goal_seeking_policy(), scenario="s1", n_episodes=3, max_steps=10)
    e = result.episodes
    assert (e["steps"] == 10).all() and not e["reached"].any() and not e["success"].any()
    assert torch.isnan(e["t_goal"]).all()
    s = result.summary()
    assert math.isnan(s["t_goal"]) and s["success_rate"] == 0.0
    # Wilson upper bound for k = 0: z^2 / (n + z^2).
    assert s["success_rate_high"] == pytest.approx(Z2 / (3 + Z2))


def test_summary_cells_rates_records_csv_and_pooling(tmp_path):
    episodes = {k: torch.zeros(4) for k in METRIC_KEYS}
    episodes.update(
        success=torch.tensor([True, True, False, True]), safe_success=torch.tensor([True, False, False, False]),
        reached=torch.tensor([True, True, False, True]), crashed=torch.tensor([False, False, True, False]),
        d_c=torch.tensor([1.0, 2.0, 3.0, 4.0]), t_goal=torch.tensor([30.0, 40.0, math.nan, 50.0]),
        steps=torch.tensor([150, 200, 37, 250]),
    )
    r = EvaluationResult("P", "train", "literal", 0, episodes)
    s = r.summary()
    # d_c: mean 2.5, population std sqrt(((1.5)^2 + 0.5^2) * 2 / 4) = sqrt(1.25).
    assert s["d_c"] == pytest.approx(2.5) and s["d_c_std"] == pytest.approx(math.sqrt(1.25))
    # t_goal over the three that reached: mean 40, std sqrt(200 / 3).
    assert s["t_goal"] == pytest.approx(40.0) and s["t_goal_std"] == pytest.approx(math.sqrt(200 / 3))
    assert s["success_rate"] == 0.75 and s["safe_success_rate"] == 0.25 and s["n_reached"] == 3
    low, high = wilson_interval(3, 4)
    # Wilson, p = 0.75, n = 4: centre (0.75 + z^2/8) / (1 + z^2/4), half z/(1 + z^2/4) sqrt(3/64 + z^2/64).
    centre, half = (0.75 + Z2 / 8) / (1 + Z2 / 4), math.sqrt(Z2) / (1 + Z2 / 4) * math.sqrt(3 / 64 + Z2 / 64)
    assert (low, high) == pytest.approx((centre - half, centre + half))
    path = r.write_csv(tmp_path / "out" / "episodes.csv")
    rows = list(csv.DictReader(open(path)))
    assert len(rows) == 4 and rows[2]["t_goal"] == "" and rows[0]["success"] == "1" and rows[3]["steps"] == "250"
    assert not [p for p in path.parent.iterdir() if p.name.startswith(".")]  # no temp file left behind
    pooled = EvaluationResult.pooled([r, r])
    assert pooled.n_episodes == 8 and pooled.summary()["d_c"] == pytest.approx(2.5)
    assert math.isnan(mean_std(torch.tensor([math.nan])).mean)


def test_policy_resolution_errors_name_the_problem(tmp_path):
    with pytest.raises(ConfigError, match="unknown policy"):
        evaluate("no_such_policy", n_episodes=1)
    with pytest.raises(CheckpointError, match="scripts/train.py policy=policy3_g"):
        evaluate("Policy3-G", reading="literal", n_episodes=1, checkpoints_dir=tmp_path)
    with pytest.raises(CheckpointError, match="no checkpoint"):
        evaluate(str(tmp_path / "missing.pt"), n_episodes=1)
    with pytest.raises(ValueError, match="n_episodes"):
        evaluate(goal_seeking_policy(), n_episodes=0)
    assert policy_config_of("Policy3-G")[1]["instinct"] is True
    assert policy_id("Policy-MA") == "policy_ma"


def test_shared_actor_built_for_five_uavs_runs_nine():
    from flock_torchrl.policies.models import make_actor

    actor = make_actor(FlockingEnv("train", num_envs=1, seed=0), hidden=8, depth=1)
    nine = FlockingEnv("s2", num_envs=3, seed=0)
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        td = actor(nine.reset())
        assert td["agents", "action"].shape == (3, 9, 2)
        # One network for every UAV: UAV 7 acts on its own observation exactly as UAV 0 would.
        alone = actor(TensorDict({"agents": {"observation": td["agents", "observation"][:, 7:8]}}, batch_size=[3]))
    assert torch.allclose(alone["agents", "action"][:, 0], td["agents", "action"][:, 7])


def test_every_policy_sees_the_same_starts():
    # The policies' scenario overrides (field of view, instinct, velocity actions) do not touch
    # the spawn draws, so with EVAL_SEED every policy starts from the same layouts.
    layouts = []
    for policy in (None, "policy3_g", "policy1", "policy_ma"):
        td = FlockingEnv("s5", num_envs=8, seed=EVAL_SEED, reading="literal", policy_id=policy,
                         extras="physics").reset()
        layouts.append((td["agents", "position"], td["agents", "heading"], td["goal"], td["obstacles", "position"]))
    for other in layouts[1:]:
        assert all(torch.equal(a, b) for a, b in zip(layouts[0], other))


def test_the_wilson_interval_is_scipys_and_the_textbook_formula():
    """run/results.py takes the interval from scipy (binomtest(k, n).proportion_ci, method
    "wilson"), bit for bit; it is the textbook formula (centre (p + z^2/2n) / (1 + z^2/n), half
    z / (1 + z^2/n) sqrt(p(1-p)/n + z^2/4n^2), clipped to [0, 1]) to round-off, and n = 0 has no
    interval (NaN, as the empty cells of a table)."""
    from scipy.stats import binomtest

    z = 1.959963984540054
    for n in (*range(1, 41), 100, 499, 500, 5000):
        for k in sorted({0, 1, n // 3, n // 2, n - 1, n}):
            low, high = wilson_interval(k, n)
            ci = binomtest(k, n).proportion_ci(method="wilson")
            assert (low, high) == (ci.low, ci.high), (k, n)
            assert type(low) is float and type(high) is float
            p, denom = k / n, 1 + z * z / n
            centre, half = (p + z * z / (2 * n)) / denom, z / denom * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
            assert (low, high) == pytest.approx((max(0.0, centre - half), min(1.0, centre + half)), abs=1e-15)
    assert wilson_interval(0, 4)[0] == 0.0 and wilson_interval(4, 4)[1] == 1.0
    assert all(math.isnan(x) for x in wilson_interval(0, 0))
    empty = EvaluationResult("P", "train", "literal", 0, {k: torch.zeros(0) for k in METRIC_KEYS}).rate("success")
    assert math.isnan(empty.rate) and math.isnan(empty.low) and math.isnan(empty.high) and empty.n == 0


# ---------------------------------------------------------------------------- loaded policies
def test_a_shipped_checkpoint_is_named_the_same_from_any_folder(tmp_path, monkeypatch):
    """A path relative to the shipped collection (or as from a clone's root, checkpoints/...)
    names a shipped checkpoint from any folder, as it does from the wheel; a file of that name in
    the working folder comes first; a missing one says where the shipped ones are."""
    import shutil

    from flock_torchrl import load_policy, resolve
    from flock_torchrl.config import shipped_checkpoints_dir

    monkeypatch.chdir(tmp_path)
    threed = load_policy("paper_fit/threed/policy3_g/seed0.pt")
    assert threed.dims == 3 and threed.flock_meta["policy_id"] == "policy3_g"
    (handle,) = resolve("checkpoints/paper_fit/threed/policy3_g/seed1.pt")
    assert handle.origin == str(shipped_checkpoints_dir() / "paper_fit" / "threed" / "policy3_g" / "seed1.pt")
    assert load_policy("checkpoints/paper_fit/policy3_g/seed0.pt").dims == 2
    mine = tmp_path / "paper_fit" / "policy3_g"
    mine.mkdir(parents=True)
    shutil.copy(shipped_checkpoints_dir() / "paper_fit" / "policy1" / "seed0.pt", mine / "seed0.pt")
    assert load_policy("paper_fit/policy3_g/seed0.pt").flock_meta["policy_id"] == "policy1"   # the working folder's
    with pytest.raises(CheckpointError) as info:
        load_policy("paper_fit/threed/policy3_g/seed99.pt")
    message = str(info.value)
    assert message.startswith("no checkpoint at paper_fit/threed/policy3_g/seed99.pt;") and "\n" not in message
    assert str(shipped_checkpoints_dir()) in message and "paper_fit/threed/policy3_g/seed0.pt" in message
    with pytest.raises(CheckpointError, match=f"the shipped checkpoints are in {shipped_checkpoints_dir()}"):
        evaluate(str(tmp_path / "missing.pt"), n_episodes=1)


@pytest.mark.parametrize("scenario, dims, seeds", [("wall3d", 3, 5), ("s2", 2, 10)])
def test_a_learned_policy_of_the_evaluate_app_flies_its_shipped_seeds_of_the_scenarios_dimension(scenario, dims, seeds):
    """policy=policy3_g scenario=wall3d evaluates the 3-D seeds (checkpoints/<reading>/threed/),
    not the 2-D ones; on either the world is the one those seeds were trained in (their fields,
    the taper saved before it existed among them), so the env builds as the app's would."""
    from flock_torchrl.config import compose
    from flock_torchrl.run.evaluation import checkpoint_world, evaluated_handles
    from flock_torchrl.run.rollout import policy_env

    overrides = ["policy=policy3_g", f"scenario={scenario}"]
    cfg = checkpoint_world(compose("evaluate", overrides), overrides)
    checked = EvaluateConfig.from_config(cfg)
    handles = evaluated_handles(checked)
    assert len(handles) == seeds and {h.id for h in handles} == {"policy3_g"}
    assert all(("/threed/" in h.origin) == (dims == 3) for h in handles)
    assert cfg.scenario.tangential_taper == handles[0].scenario["tangential_taper"]
    env = policy_env(handles[0], checked.scenario, num_envs=1, seed=0)
    assert env.cfg.dims == dims and handles[0].build(env) is not None


def test_a_learned_name_without_seeds_of_the_worlds_dimension_names_those_there(tmp_path):
    from flock_torchrl import resolve

    with pytest.raises(CheckpointError) as info:
        resolve("policy1", "paper_fit", dims=3)
    assert "threed/policy1 holds no seed*.pt (the 3-D policies there: policy2_g, policy3_g)" in str(info.value)
    # A 2-D seed built for a 3-D world (evaluate("policy3_g", scenario="wall3d") loads the 2-D
    # seeds) says where the 3-D ones are.
    (handle,) = resolve("paper_fit/policy3_g/seed0.pt")
    with pytest.raises(ConfigError, match="its shipped 3-D seeds are .*threed/policy3_g/seed<k>.pt"):
        handle.build(FlockingEnv("wall3d", num_envs=1, policy_id="policy3_g"))


def test_a_policy_of_the_other_dimension_in_an_envs_rollout_is_one_line():
    """env.rollout(n, policy) with a 2-D checkpoint in a 3-D env (or the reverse) says so, where
    torch said "mat1 and mat2 shapes cannot be multiplied (20x27 and 17x128)"."""
    from flock_torchrl import load_policy

    flat, space = load_policy("paper_fit/policy3_g/seed0.pt"), load_policy("paper_fit/threed/policy3_g/seed0.pt")
    for policy, scenario, words in ((flat, "wall3d", "trained in a 2-D world (observations of 17) and is given a "
                                                      "3-D world's (observations of 27): fly it in a 2-D scenario"),
                                    (space, "s1", "trained in a 3-D world (observations of 27) and is given a "
                                                  "2-D world's (observations of 17): fly it in a 3-D scenario")):
        env = FlockingEnv(scenario, num_envs=2, seed=0, policy_id="policy3_g")
        with pytest.raises(ValueError) as info:
            env.rollout(3, policy)
        assert words in str(info.value) and "\n" not in str(info.value), str(info.value)
        assert "mat1" not in str(info.value)


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA machine has what is asked for")
def test_cuda_asked_of_a_cpu_only_torch_is_one_line():
    """load_policy(..., device="cuda") and evaluate(..., device="cuda") say what FlockingEnv(device="cuda")
    says, where torch raised "AssertionError: Torch not compiled with CUDA enabled"."""
    from flock_torchrl import load_policy

    with pytest.raises(ValueError) as env_error:
        FlockingEnv("s1", num_envs=1, device="cuda")
    for call in (lambda: load_policy("paper_fit/policy3_g/seed0.pt", device="cuda"),
                 lambda: evaluate("paper_fit/policy3_g/seed0.pt", "s1", n_episodes=1, device="cuda"),
                 lambda: evaluate("policy3_g", "s1", n_episodes=1, device="cuda")):
        with pytest.raises(ValueError) as info:
            call()
        assert str(info.value) == str(env_error.value) and "no CUDA device" in str(info.value)


def test_a_loaded_policy_acts_without_gradients_and_trains_when_asked():
    """load_policy's parameters do not require gradients, so env.rollout(n, policy) builds no
    autograd graph through the differentiable step; requires_grad_(True) makes it trainable again
    (and moving it keeps that)."""
    from flock_torchrl import load_policy

    policy = load_policy("paper_fit/policy3_g/seed0.pt")
    assert not any(p.requires_grad for p in policy.parameters())
    env = FlockingEnv("train", num_envs=4, seed=0, policy_id="policy3_g")
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.rollout(5, policy, break_when_any_done=False)
    assert td["agents", "action"].grad_fn is None and td["next", "agents", "observation"].grad_fn is None
    # Further training: ask for gradients, then the actions carry them back to the weights.
    policy.requires_grad_(True)
    policy.follow("cpu")
    assert all(p.requires_grad for p in policy.parameters())
    optimiser = torch.optim.Adam(policy.parameters(), lr=1e-3)
    before = [p.detach().clone() for p in policy.parameters()]
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        acted = policy(td.select(("agents", "observation")).clone())   # the observations it met
    assert acted["agents", "action"].requires_grad
    acted["agents", "action"].pow(2).mean().backward()
    assert all(p.grad is not None for p in policy.parameters())
    optimiser.step()
    assert any(not torch.equal(a, b) for a, b in zip(before, policy.parameters()))
