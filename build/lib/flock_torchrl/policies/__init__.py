"""Policies: the networks (paper Fig. 3), the three learners wired from TorchRL's losses, the
two rule-based baselines, checkpoints, and the registry that says what a policy name, a
checkpoint or a module means."""

from .checkpoint import CheckpointError, SharedPolicy, load_policy
from .registry import PolicyHandle, make_policy, resolve

__all__ = ["CheckpointError", "PolicyHandle", "SharedPolicy", "load_policy", "make_policy", "resolve"]
