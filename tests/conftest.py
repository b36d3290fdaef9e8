"""Shared fixtures of the env test suite.

Every expected value in these tests is computed by hand from SPEC.md (the arithmetic sits in a
comment next to it), never by calling the function under test a second time.
"""

from __future__ import annotations

import pytest
import torch

from flock_torchrl import FlockingEnv

# Two shared cores: one thread per test process keeps the suite fast under xdist too.
torch.set_num_threads(1)


def _place(env: FlockingEnv, position, heading, goal, velocity=None):
    """Put ``env`` in an exact state (the env's state API) and re-sense it.

    Args:
        position: ``[B, N, 2]`` (nested lists); heading ``[B, N]``; goal ``[B, 2]``;
        velocity: ``[B, N, 2]`` (zeros when omitted).
    """
    env.position = torch.tensor(position, dtype=torch.float32)
    env.heading = torch.tensor(heading, dtype=torch.float32)
    env.goal = torch.tensor(goal, dtype=torch.float32)
    env.velocity = (torch.zeros_like(env.position) if velocity is None
                    else torch.tensor(velocity, dtype=torch.float32))
    env.sensed = env._sense()
    return env


def _step_with(env: FlockingEnv, action):
    """One ``env.step`` with the given ``("agents", "action")`` ``[B, N, 2]``; returns ``td["next"]``."""
    td = env._output()
    td.set(("agents", "action"), torch.tensor(action, dtype=torch.float32))
    return env.step(td)["next"]


@pytest.fixture
def make_env():
    """Factory: ``make_env(scenario, num_envs=1, seed=0, **overrides)``, reset once."""
    def _make(scenario="train", num_envs=1, seed=0, **overrides):
        env = FlockingEnv(scenario, num_envs=num_envs, seed=seed, **overrides)
        env.reset()
        return env

    return _make


@pytest.fixture
def place():
    """``place(env, position, heading, goal, velocity=None)``: exact state, re-sensed."""
    return _place


@pytest.fixture
def step_with():
    """``step_with(env, action)``: one step with a given action, returns ``td["next"]``."""
    return _step_with
