"""Shared fixtures of the test suite.

Every expected value in these tests is computed by hand from docs/specification.md (the
arithmetic sits in a comment next to it), never by calling the function under test a second time.
"""

from __future__ import annotations

import pytest
import torch

from flock_torchrl import FlockingEnv

# Two shared cores: one thread per test process keeps the suite fast under xdist too.
torch.set_num_threads(1)


def _place(env: FlockingEnv, position, heading, goal, velocity=None) -> FlockingEnv:
    env.place(position, heading, goal, velocity)
    return env


def _step_with(env: FlockingEnv, action):
    """One ``env.step`` from the current state with the given ``("agents", "action")`` ``[B, N, 2]``;
    returns ``td["next"]``."""
    td = env.current()
    td.set(("agents", "action"), torch.tensor(action, dtype=torch.float32))
    return env.step(td)["next"]


@pytest.fixture
def make_env():
    """Factory: ``make_env(scenario, num_envs=1, seed=0, **kwargs)``, reset once: reading
    ``literal`` and every extra key unless given."""
    def _make(scenario="train", num_envs=1, seed=0, reading="literal", extras="all", **kwargs):
        env = FlockingEnv(scenario, num_envs=num_envs, seed=seed, reading=reading, extras=extras, **kwargs)
        env.reset()
        return env

    return _make


@pytest.fixture
def place():
    """``place(env, position, heading, goal, velocity=None)``: an exact state, sensed; returns ``env``."""
    return _place


@pytest.fixture
def step_with():
    """``step_with(env, action)``: one step from the current state, returns ``td["next"]``."""
    return _step_with
