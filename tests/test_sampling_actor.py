"""The collector's SAC actor (:class:`~flock_torchrl.policies.models.SamplingActor`) is its
eager twin, the ``ProbabilisticActor``: the same entries, bit for bit, and the same draws from
the same generator, under every exploration type and for any action box."""

import contextlib

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from flock_torchrl import FlockingEnv
from flock_torchrl.policies.models import ACTION, SamplingActor, actor_of_sizes, make_actor

BOXES = {"unit": ([-1.0, -1.0], [1.0, 1.0]), "shifted": ([-2.0, 0.0], [1.0, 3.0]), "space": ([-1.0] * 3, [1.0] * 3)}


def observations(worlds: int, n: int, features: int) -> TensorDict:
    # Large values too: the tanh saturates, where the safe tanh's clamp decides the last bit.
    obs = torch.randn(worlds, n, features) * torch.logspace(-2, 2, features)
    return TensorDict({"agents": TensorDict({"observation": obs}, [worlds, n])}, [worlds])


@pytest.mark.parametrize("box", sorted(BOXES))
@pytest.mark.parametrize("kind", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC, None])
def test_the_sampling_actor_writes_what_the_actor_writes_bit_for_bit(box, kind):
    low, high = (torch.tensor(v) for v in BOXES[box])
    torch.manual_seed(0)
    actor = actor_of_sizes(17, low, high)
    fast = SamplingActor(actor)
    td = observations(6, 5, 17)
    outs = []
    for module in (actor, fast):
        torch.manual_seed(1)
        with torch.no_grad(), set_exploration_type(kind) if kind else contextlib.nullcontext():
            out = module(td.clone())
        outs.append((out, torch.get_rng_state()))
    (slow, slow_rng), (quick, quick_rng) = outs
    assert set(slow.keys(True, True)) == set(quick.keys(True, True)) >= {ACTION, ("agents", "loc"), ("agents", "scale")}
    for key in slow.keys(True, True):
        assert torch.equal(slow[key], quick[key]), key
    assert torch.equal(slow_rng, quick_rng)  # as many draws, from the same generator
    action = quick[ACTION]
    assert ((action >= low) & (action <= high)).all()
    if kind is ExplorationType.RANDOM:  # a draw, not the mode
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            assert not torch.equal(action, actor(td.clone())[ACTION])


def test_the_sampling_actor_shares_the_actors_parameters_once():
    env = FlockingEnv("train", num_envs=1, seed=0)
    actor = make_actor(env)
    fast = SamplingActor(actor)
    assert [p.data_ptr() for p in fast.parameters()] == [p.data_ptr() for p in actor.parameters()]
    with torch.no_grad():
        next(actor.parameters()).add_(1.0)  # an update of the actor is the sampling actor's
    td = env.reset()
    actions = []
    for module in (actor, fast):
        torch.manual_seed(2)
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
            actions.append(module(td.clone())[ACTION])
    assert torch.equal(*actions)


def test_the_sampling_actor_refuses_an_actor_that_returns_its_log_prob():
    actor = actor_of_sizes(17, -torch.ones(2), torch.ones(2), return_log_prob=True)
    with pytest.raises(ValueError, match="return_log_prob"):
        SamplingActor(actor)
