"""``reset_pool``: done worlds take fresh worlds drawn ahead into a reserve, with no host read
between the reserve's refills; reproducible, resumable, and the default path untouched."""

from __future__ import annotations

import functools
import io

import pytest
import tensordict
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector

from flock_torchrl import FlockingEnv
from flock_torchrl.config import ConfigError, TrainConfig
from flock_torchrl.run.batches import AgentwiseDone
from benchmarks.counting import HostReads
from flock_torchrl.run.launch import train
from flock_torchrl.run.setup import make_train_config
from flock_torchrl.world.step import WHOLE_WARMUP
from flock_torchrl.world.population import PopulationEnv
from flock_torchrl.world.step import transition
from test_spawn import surface_distance


def pool_env(scenario="train", num_envs=6, reset_pool=18, seed=0, max_steps=4, **kwargs) -> FlockingEnv:
    """A training-like env (no host checks of the actions) whose step runs as ``compile_step``
    compiles it, eagerly: the static-shape step the counter can see into."""
    env = FlockingEnv(scenario, num_envs=num_envs, seed=seed, policy_id="policy3_g", max_steps=max_steps,
                      reset_pool=reset_pool, check_actions=False, **kwargs)
    env._transition = functools.partial(transition, static_shapes=True, static=env._static, cfg=env.cfg)
    return env


def staggered(env: FlockingEnv, gen: torch.Generator) -> TensorDict:
    """Reset, then restart worlds ``i % 4 == t`` after step ``t`` (explicit masked resets), so
    that with ``max_steps = 4`` one or two worlds end at each later step."""
    td = env.reset()
    b = env.num_envs
    for t in range(3):
        td = act(env, td, gen)
        td = env.step_and_maybe_reset(td)[1]
        td = env.reset(td.set("_reset", (torch.arange(b) % 4 == t)[:, None]))
    return td


def act(env: FlockingEnv, td: TensorDict, gen: torch.Generator) -> TensorDict:
    return td.set(("agents", "action"), torch.rand(env.num_envs, env.n_agents, env.cfg.dims, generator=gen) * 2 - 1)


def step_pieces(env: FlockingEnv, td: TensorDict) -> tuple[TensorDict, TensorDict]:
    """``step_and_maybe_reset`` in its pieces: the step and what it hands to ``maybe_reset``."""
    stepped = env.step(td)
    return stepped, env._step_mdp(stepped)


def same(x: torch.Tensor, y: torch.Tensor) -> bool:
    """Bit for bit, NaN where NaN (an episode's ``t_goal`` before the goal is reached)."""
    if x.shape != y.shape or x.dtype != y.dtype:
        return False
    return bool(((x == y) | (x.isnan() & y.isnan()) if x.is_floating_point() else x == y).all())


def rows_equal(a: TensorDict, b: TensorDict) -> bool:
    return set(a.keys(True, True)) == set(b.keys(True, True)) and all(
        same(a[key], b[key]) for key in a.keys(True, True))


def test_between_refills_a_step_with_done_worlds_reads_nothing_on_the_host():
    env = pool_env(num_envs=6, reset_pool=18)  # 18 // 6: a refill every third call
    refills = []
    refill = env.reserve.refill
    env.reserve.refill = lambda draw: (refills.append(True), refill(draw))
    gen = torch.Generator().manual_seed(0)
    td = staggered(env, gen)
    quiet = done_seen = 0
    for _ in range(9):
        td = act(env, td, gen)
        refills.clear()
        with HostReads() as reads:
            out, td = env.step_and_maybe_reset(td)
        done = out["next", "done"].reshape(-1)
        if refills:
            # the pointer, read once (reserve.py), plus whatever the batched draw of the used worlds reads
            assert sum(n for (_, place), n in reads.counts.items()
                       if place.startswith("flock_torchrl/world/reserve.py")) == 1, reads.table()
        else:
            assert reads.total == 0, reads.table()
            quiet += 1
            done_seen += int(done.any())
    assert quiet == 6 and done_seen >= 4  # refills at the 3rd, 6th and 9th calls; dones in between
    # The standard path reads the done flags at least (and draws on the host when one is done).
    plain = pool_env(num_envs=6, reset_pool=0)
    td = staggered(plain, torch.Generator().manual_seed(0))
    with HostReads() as reads:
        plain.step_and_maybe_reset(act(plain, td, gen))
    assert reads.total >= 2


@pytest.mark.parametrize("scenario", ["train", pytest.param("s5", marks=pytest.mark.slow), "forest",
                                      pytest.param("train3d", marks=pytest.mark.slow)])
def test_done_worlds_take_the_next_reserve_worlds_and_the_rest_stay(scenario):
    env = pool_env(scenario, num_envs=6, reset_pool=12, extras="all")
    plain = pool_env(scenario, num_envs=6, reset_pool=0, extras="all")
    gen = torch.Generator().manual_seed(1)
    td = staggered(env, gen)
    resets = 0
    for _ in range(6):
        td = act(env, td, gen)
        stepped, handed = step_pieces(env, td)
        before, next_free = env.world.clone(), int(env.reserve.pointer[0])
        if env.reserve.due():
            next_free = 0  # this call refills first
        # The same worlds through TorchRL's masked reset (a pool-less twin in the same state).
        plain.set_state({k: v for k, v in env.get_state().items() if k != "reset_pool"})
        standard = plain.maybe_reset(handed.clone())
        out = env.maybe_reset(handed.clone())
        reserve = env.reserve.worlds
        done = handed["done"].reshape(-1)
        rank = done.long().cumsum(0) - 1
        for i in range(env.num_envs):
            if done[i]:
                resets += 1
                # the reserve's next unused world, in world order; a fresh start
                assert rows_equal(env.world[i], reserve[next_free + int(rank[i])]), i
                assert int(env.world["episode", "steps"][i]) == 0
                assert torch.equal(env.world["velocity"][i], torch.zeros_like(env.world["velocity"][i]))
                assert torch.equal(out["agents", "action"][i], torch.zeros_like(out["agents", "action"][i]))
            else:
                assert rows_equal(env.world[i], before[i]), i      # bitwise untouched
                assert rows_equal(out[i], handed[i]), i
                assert rows_equal(out[i], standard[i]), i
        # what the reset worlds return is what the env returns for its new state
        current = env.current()
        for key in current.keys(True, True):
            assert same(out[key], current[key]), key
        # the standard path's keys, shapes and dtypes
        assert set(out.keys(True, True)) == set(standard.keys(True, True))
        for key in standard.keys(True, True):
            assert (out[key].shape, out[key].dtype) == (standard[key].shape, standard[key].dtype), key
        # the world keeps its layout (a compiled step reads it back as it wrote it)
        for key in before.keys(True, True):
            assert env.world[key].stride() == before[key].stride(), key
        # spawn constraints of the new starts (spawn.py): separation, and clearance from the obstacles
        new = env.world["position"][done][..., :2]
        n = env.cfg.n_uavs
        gap = torch.linalg.vector_norm(new[:, :, None] - new[:, None], dim=-1) + torch.eye(n) * 1e9
        assert gap.amin().item() >= env.cfg.spawn_separation - 1e-4
        if env.cfg.dims == 2:
            clear = surface_distance(new, env.cfg.circles, env.cfg.rectangles)
            assert clear.amin().item() >= env.cfg.spawn_clearance - 1e-4
        td = out
    assert resets >= 6


def test_the_reserve_never_runs_dry_nor_hands_out_a_world_twice():
    # Every world ends every step (max_steps = 1): each call takes all 4, from a reserve of 10.
    env = pool_env(num_envs=4, reset_pool=10, max_steps=1)
    gen = torch.Generator().manual_seed(2)
    td = env.reset()
    goals = []
    for _ in range(15):
        td = act(env, td, gen)
        out, td = env.step_and_maybe_reset(td)
        assert out["next", "done"].all()
        assert 0 <= int(env.reserve.pointer[0]) <= env.reset_pool
        goals.append(env.world["goal"].clone())
    goals = torch.cat(goals)
    assert len(goals) == 60 and len(torch.unique(goals, dim=0)) == 60  # 60 fresh worlds, none twice
    # A refill keeps the unused worlds, in order, before the new ones.
    env.reserve.pointer.fill_(7)
    unused = env.reserve.worlds[7:].clone()
    env.reserve.refill(env._fresh_worlds)
    assert rows_equal(env.reserve.worlds[:3], unused)
    assert int(env.reserve.pointer[0]) == 0 and env.reserve.calls == 0
    assert len(torch.unique(torch.cat((goals, env.reserve.worlds["goal"])), dim=0)) == 70


def rollout(env: FlockingEnv, steps: int, seed: int = 3, td: TensorDict | None = None) -> list[TensorDict]:
    gen = torch.Generator().manual_seed(seed)
    td = env.reset() if td is None else td
    outs = []
    for _ in range(steps):
        out, td = env.step_and_maybe_reset(act(env, td, gen))
        outs.append(out)
    return outs


def assert_same(a: list[TensorDict], b: list[TensorDict]) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert set(x.keys(True, True)) == set(y.keys(True, True))
        for key in x.keys(True, True):
            assert same(x[key], y[key]), key


# s4: sensor noise drawn from the same generator
@pytest.mark.parametrize("scenario", ["train", pytest.param("s4", marks=pytest.mark.slow)])
def test_same_seed_same_episodes_and_a_restored_state_continues_bit_for_bit(scenario):
    a = rollout(pool_env(scenario, num_envs=4, reset_pool=8, max_steps=3, extras="all"), 12)
    b = rollout(pool_env(scenario, num_envs=4, reset_pool=8, max_steps=3, extras="all"), 12)
    assert_same(a, b)
    reseeded = pool_env(scenario, num_envs=4, reset_pool=8, max_steps=3, extras="all", seed=9)
    rollout(reseeded, 5)
    reseeded.set_seed(0)  # empties the reserve: the seed's episodes, not the old seed's reserve
    assert_same(a, rollout(reseeded, 12))
    # Saved mid-run (between refills, through torch.save), restored into an env of another seed.
    env = pool_env(scenario, num_envs=4, reset_pool=8, max_steps=3, extras="all")
    gen = torch.Generator().manual_seed(3)
    td = env.reset()
    for _ in range(6):
        td = env.step_and_maybe_reset(act(env, td, gen))[1]
    assert env.reserve.calls == 2 and int(env.reserve.pointer[0]) == 4  # 4 worlds taken; the next call refills
    buffer = io.BytesIO()
    torch.save({"env": env.get_state(), "gen": gen.get_state()}, buffer)
    later = []
    for _ in range(7):
        out, td = env.step_and_maybe_reset(act(env, td, gen))
        later.append(out)
    buffer.seek(0)
    saved = torch.load(buffer, weights_only=False)
    other = pool_env(scenario, num_envs=4, reset_pool=8, max_steps=3, extras="all", seed=5)
    other.set_state(saved["env"])
    gen.set_state(saved["gen"])
    td = other.reset()  # the restored worlds
    again = []
    for _ in range(7):
        out, td = other.step_and_maybe_reset(act(other, td, gen))
        again.append(out)
    assert_same([o.exclude(("agents", "action")) for o in later], [o.exclude(("agents", "action")) for o in again])


def test_without_the_pool_the_standard_reset_runs():
    env = pool_env(num_envs=4, reset_pool=0, max_steps=3)
    assert env.reserve is None and "reset_pool" not in env.get_state()
    gen = torch.Generator().manual_seed(0)
    td = env.reset()
    with HostReads() as reads:
        env.step_and_maybe_reset(act(env, td, gen))
    assert any(place.startswith("torchrl/envs/common.py") and "any_done" in place for _, place in reads.counts)
    # Until the first world ends, the pool changes nothing (the train world draws no sensor noise);
    # afterwards the episodes differ (the reserve was drawn in another order).
    plain = rollout(pool_env(num_envs=4, reset_pool=0, max_steps=3), 6)
    pooled = rollout(pool_env(num_envs=4, reset_pool=8, max_steps=3), 6)
    assert_same(plain[:3], pooled[:3])
    assert not torch.equal(plain[3]["agents", "observation"], pooled[3]["agents", "observation"])


def test_a_collector_with_the_pool_gives_the_standard_batches():
    def batch(reset_pool: int) -> TensorDict:
        env = FlockingEnv("train", num_envs=4, seed=0, policy_id="policy3_g", max_steps=3, check_actions=False,
                          reset_pool=reset_pool)
        collector = Collector(env, None, frames_per_batch=4 * 8, total_frames=-1, track_traj_ids=False,
                              postproc=AgentwiseDone(env.n_agents))
        try:
            return next(iter(collector))
        finally:
            collector.shutdown()

    standard, pooled = batch(0), batch(8)
    assert pooled["next", "done"].any()
    assert set(pooled.keys(True, True)) == set(standard.keys(True, True))
    for key in standard.keys(True, True):
        assert (pooled[key].shape, pooled[key].dtype) == (standard[key].shape, standard[key].dtype), key
    steps = pooled["episode", "steps"]
    assert steps.max() < 3 and (steps == 0).sum() > 4  # restarted worlds begin at step 0


def test_population_members_draw_their_reserves_from_their_own_generators():
    env = PopulationEnv("train", 2, 3, [1, 2], policy_id="policy3_g", max_steps=2, check_actions=False,
                        reset_pool=6)
    gen = torch.Generator().manual_seed(0)
    td = env.reset()
    for _ in range(4):
        out, td = env.step_and_maybe_reset(act(env, td, gen))
    assert out["next", "done"].all() and env.reserve.pointer.tolist() == [3, 3]
    for k, seed in enumerate((1, 2)):
        solo = FlockingEnv("train", num_envs=3, seed=seed, policy_id="policy3_g", max_steps=2, reset_pool=6)
        solo.reset()
        solo.step_and_maybe_reset(act(solo, solo.current(), gen))  # the first call draws the reserve
        for key in ("position", "heading", "goal"):
            assert torch.equal(env.reserve.worlds[key][6 * k:6 * k + 3], solo.reserve.worlds[key][3:]), key
    with pytest.raises(ValueError, match="reset_pool must be 0 or at least the worlds per member \\(3\\)"):
        PopulationEnv("train", 2, 3, [1, 2], reset_pool=2)


def test_bad_values_are_refused():
    for bad, match in ((-1, "integer >= 0"), (1.5, "integer >= 0"), (True, "integer >= 0"),
                       (3, "at least the num_envs \\(4\\)")):
        with pytest.raises(ValueError, match=f"reset_pool.*{match}"):
            FlockingEnv("train", num_envs=4, reset_pool=bad)
    for value, match in (("-1", "integer >= 0"), ("3", "at least num_envs \\(4\\)")):
        with pytest.raises(ConfigError, match="reset_pool"):
            TrainConfig.from_config(make_train_config("policy3_g", "tiny", [f"reset_pool={value}"]))
    TrainConfig.from_config(make_train_config("policy3_g", "tiny", ["reset_pool=4"]))
    # A state must come from an env with the same reserve.
    pooled, plain = FlockingEnv("train", num_envs=4, reset_pool=4), FlockingEnv("train", num_envs=4)
    pooled.reset(), plain.reset()
    with pytest.raises(ValueError, match="reset_pool=0"):
        plain.set_state(pooled.get_state())
    with pytest.raises(ValueError, match="no 'reset_pool' entry"):
        pooled.set_state(plain.get_state())
    with pytest.raises(ValueError, match="reset_pool"):
        FlockingEnv("train", num_envs=4, reset_pool=8).set_state(pooled.get_state())
    state = pooled.get_state()
    state["reset_pool"]["next"] = torch.tensor([9])
    with pytest.raises(ValueError, match="'next'"):
        pooled.set_state(state)
    state["reset_pool"].update(next=torch.tensor([4]), calls=0)  # 4 taken in no call: inconsistent
    with pytest.raises(ValueError, match="run dry"):
        pooled.set_state(state)


@pytest.mark.slow
def test_a_tiny_training_run_with_the_pool_resumes_bit_for_bit(tmp_path):
    from flock_torchrl.policies.checkpoint import load_checkpoint

    def tiny(*overrides: str):
        return make_train_config("policy3_g", "tiny", ["scenario.max_steps=10", "progress=false", "logger=csv",
                                                      "experiment.eval_every_frames=0", "reset_pool=8", *overrides])

    whole = load_checkpoint(train(tiny(), tmp_path / "whole").checkpoint)
    assert whole["counters"]["frames"] == 160 and whole["counters"]["episodes"] >= 8
    assert whole["env_state"]["reset_pool"]["worlds"]["position"].shape == (8, 5, 2)
    assert train(tiny("experiment.max_frames=96"), tmp_path / "split").frames == 96
    resumed = load_checkpoint(train(tiny("resume=true"), tmp_path / "split").checkpoint)
    for key in ("frames", "episodes", "updates"):
        assert resumed["counters"][key] == whole["counters"][key], key
    for key, value in whole["actor"].items():
        assert torch.equal(value, resumed["actor"][key]), key
    assert (tmp_path / "whole" / "episodes.csv").read_text() == (tmp_path / "split" / "episodes.csv").read_text()


@pytest.mark.slow  # a compilation (~15 s); the fast tests check the layout kept on the eager step
def test_a_compiled_step_compiles_once_across_worlds_taken_from_the_reserve():
    # The reserve's worlds are written in the world's own layout: the compiled step, which reads
    # its outputs back, sees the same strides after a reset from the reserve as after a step.
    # Compiled with a reserve, the whole step and hand-out is one function (TorchRL's env.compile):
    # its eager warm-up calls, then its compilation (and one more for the layout the compiled
    # step writes), then none across steps and hand-outs.
    env = FlockingEnv("train", num_envs=4, seed=2, policy_id="policy3_g", compile_step=True, check_actions=False,
                      max_steps=2, reset_pool=16)
    gen = torch.Generator().manual_seed(0)
    td = env.reset()
    for _ in range(WHOLE_WARMUP + 2):  # compiles
        td = env.step_and_maybe_reset(act(env, td, gen))[1]
    # Neither a policy that writes more than the action (a SAC actor's loc and scale, after the
    # random actions that fill a buffer first) nor a class tensordict has not seen before (a
    # learner's first update) recompiles it.
    tensordict.is_tensorclass(type("NotSeenBefore", (), {}))
    with torch.compiler.set_stance("fail_on_recompile"):
        for _ in range(6):  # worlds taken at every second call; the reserve refilled every fourth
            given = act(env, td, gen).set(("agents", "loc"), torch.zeros(4, 5, 2))
            out, td = env.step_and_maybe_reset(given)
    assert out is given and ("agents", "loc") in out.keys(True) and ("next", "agents", "observation") in out.keys(True)
    assert out["next", "done"].all() and env._compiled_whole


@pytest.mark.parametrize("extra", [pytest.param("population=2", marks=pytest.mark.slow),
                                   "experiment.swarm_sizes=[3,5]"])
def test_population_and_mixed_size_runs_take_the_pool(tmp_path, extra):
    from flock_torchrl.policies.checkpoint import load_checkpoint

    cfg = make_train_config("policy3_g", "tiny", ["scenario.max_steps=10", "progress=false", "logger=none",
                                                 "experiment.eval_every_frames=0", "reset_pool=8", extra])
    result = train(cfg, tmp_path / "run")
    assert result.frames == 160 and result.episodes >= 8
    ckpt = load_checkpoint(result.checkpoint)
    states = ckpt["env_state"] if isinstance(ckpt["env_state"], list) else [ckpt["env_state"]]
    # a population: a reserve of 8 per member (2 x 4 worlds); mixed sizes: one per size (2 worlds each)
    assert [s["reset_pool"]["worlds"]["goal"].shape[0] for s in states] == ([16] if extra.startswith("pop") else
                                                                            [8, 8])


def test_the_hand_out_by_hand_and_its_compiled_twin():
    """take_from_reserve on a hand-made case (two members, reserves of 3), and compiled equal to
    eager bit for bit."""
    from flock_torchrl.world.reserve import take_from_reserve

    world = {"a": torch.tensor([[0.0, 0.5], [1.0, 1.5], [2.0, 2.5], [3.0, 3.5]]), "b": {"c": torch.arange(4)}}
    reserve = {"a": 10.0 + torch.arange(12.0).reshape(6, 2), "b": {"c": 100 + torch.arange(6)}}
    pointer = torch.tensor([1, 0])
    done = torch.tensor([[True, True], [False, True]])
    # Member 0 takes its reserve worlds 1 and 2; member 1's world 1 takes its reserve world 0 (row 3).
    new, after = take_from_reserve(world, reserve, pointer, done, 3)
    assert new["b"]["c"].tolist() == [101, 102, 2, 103]
    assert new["a"].tolist() == [[12.0, 13.0], [14.0, 15.0], [2.0, 2.5], [16.0, 17.0]]
    assert after.tolist() == [3, 1]
    compiled = torch.compile(take_from_reserve, dynamic=False, fullgraph=True)
    twin, twin_after = compiled(world, reserve, pointer, done, 3)
    assert torch.equal(twin["a"], new["a"]) and torch.equal(twin["b"]["c"], new["b"]["c"])
    assert torch.equal(twin_after, after)


@pytest.mark.slow  # a compilation of the whole step (~20 s)
def test_the_whole_compiled_step_and_reset_matches_its_eager_twin():
    """compile_step with a reserve traces the step and the hand-out whole (noise drawn before
    it): the same episodes as the eager twin, to the compiled step's round-off, the same draws."""
    def rollout(compile_step: bool):
        env = FlockingEnv("s4", num_envs=3, seed=5, policy_id="policy3_g", compile_step=compile_step,
                          check_actions=False, max_steps=5, reset_pool=12)
        gen, td, seen = torch.Generator().manual_seed(1), env.reset(), []
        for _ in range(24):
            out, td = env.step_and_maybe_reset(act(env, td, gen))
            seen.append((out["next", "agents", "observation"].clone(), td["agents", "observation"].clone(),
                         out["next", "done"].clone()))
        return env, seen

    eager, expected = rollout(False)
    compiled, got = rollout(True)
    assert compiled._compiled_whole and not eager._compiled_whole
    for (obs, root, done), (obs_c, root_c, done_c) in zip(expected, got):
        assert torch.equal(done, done_c)
        torch.testing.assert_close(obs_c, obs, rtol=1e-4, atol=1e-4)
        torch.testing.assert_close(root_c, root, rtol=1e-4, atol=1e-4)
    assert torch.equal(eager._generator.get_state(), compiled._generator.get_state())
    assert sum(int(d.sum()) for _, _, d in expected) >= 9  # worlds were reset, from the reserve


def test_a_masked_reset_with_a_reserve_warns_once_that_the_reserve_is_not_used_there():
    """A TransformedEnv resets its done worlds through "_reset" masks, which draw their worlds there
    and then: an env with a reserve says so once (a warning), and the reserve's pointer stays."""
    import warnings

    from torchrl.envs import StepCounter, TransformedEnv

    env = pool_env(num_envs=4, reset_pool=8, max_steps=3)
    wrapped = TransformedEnv(env, StepCounter())
    td = wrapped.reset()
    pointer = env.reserve.pointer.clone()
    mask = torch.tensor([[True], [False], [True], [False]])
    with pytest.warns(UserWarning, match=r"reset_pool>0.*draws its new worlds there and then.*TransformedEnv"):
        wrapped.reset(td.clone().set("_reset", mask))
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # once: the next masked reset is silent
        wrapped.reset(td.clone().set("_reset", mask))
    assert torch.equal(env.reserve.pointer, pointer)
