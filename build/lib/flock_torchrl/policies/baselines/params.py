"""Controller parameter dataclasses from YAML: unknown or bad fields fail naming the field."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping, TypeVar

from ...config import ConfigError

P = TypeVar("P")


def raise_param(params: Any, name: str, message: str) -> None:
    """Raise :class:`~flock_torchrl.config.ConfigError` for field ``name`` of a params dataclass."""
    raise ConfigError(f"policy.params.{name}", message)


def check_params(params: Any, positive: tuple[str, ...] = (), non_negative: tuple[str, ...] = (),
                 unit_interval: tuple[str, ...] = ()) -> None:
    """Check every field is a finite number; ``positive`` > 0, ``non_negative`` >= 0, ``unit_interval`` in [0, 1)."""
    for field in dataclasses.fields(params):
        value = getattr(params, field.name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise_param(params, field.name, f"must be a finite number, got {value!r}")
    for name in positive:
        if getattr(params, name) <= 0:
            raise_param(params, name, f"must be > 0, got {getattr(params, name)}")
    for name in non_negative:
        if getattr(params, name) < 0:
            raise_param(params, name, f"must be >= 0, got {getattr(params, name)}")
    for name in unit_interval:
        if not 0 <= getattr(params, name) < 1:
            raise_param(params, name, f"must lie in [0, 1), got {getattr(params, name)}")


def params_from_mapping(cls: type[P], values: Mapping[str, Any] | None) -> P:
    """Build the params dataclass ``cls`` from a mapping, rejecting unknown keys by name.

    Integers are accepted for float fields; every other check is the dataclass's own.
    """
    values = dict(values or {})
    known = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(values) - known)
    if unknown:
        raise ConfigError(f"policy.params.{unknown[0]}", f"unknown parameter of {cls.__name__}; known: {sorted(known)}")
    missing = sorted(known - set(values))
    if missing:
        raise ConfigError(f"policy.params.{missing[0]}", f"missing parameter of {cls.__name__} (no YAML sets it)")
    for name, value in values.items():
        if isinstance(value, int) and not isinstance(value, bool):
            values[name] = float(value)
    return cls(**values)  # type: ignore[call-arg]
