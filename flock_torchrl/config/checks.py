"""What every schema checks with: :class:`ConfigError` naming the dotted key, the range helpers,
and :class:`Schema`, the base that turns a composed node into a checked object once.

No Hydra here: the world (``flock_torchrl.world``) builds on these and on :mod:`.scenario` alone.
"""

from __future__ import annotations

import dataclasses
import math
import re
from typing import Any, ClassVar, Mapping, Sequence, TypeVar

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

# The largest swarm any config may ask for (scenario.n_uavs, experiment.swarm_sizes, sizes).
MAX_UAVS = 2000
# Seeds: the trainer derives env seeds as seed * 1000 + worker, within torch's 64-bit range.
MAX_SEED = 2**32 - 1


class ConfigError(ValueError):
    """A configuration value is invalid. ``key`` is the dotted name of the field."""

    def __init__(self, key: str, message: str, also: Sequence[str] = ()) -> None:
        super().__init__(f"{key}: {message}" if key else message)
        self.key = key
        self.message = message
        self.also = tuple(also)  # other keys the error is about: the one the user set is named


def reject(key: str, message: str) -> None:
    raise ConfigError(key, message)


def dotted(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def positive(key: str, value: Any, maximum: float = math.inf) -> None:
    if not (is_number(value) and 0 < value <= maximum):
        bound = "" if math.isinf(maximum) else f" and <= {maximum:g}"
        reject(key, f"must be a positive finite number{bound}, got {value!r}")


def non_negative(key: str, value: Any, maximum: float = math.inf) -> None:
    if not (is_number(value) and 0 <= value <= maximum):
        bound = "" if math.isinf(maximum) else f" and <= {maximum:g}"
        reject(key, f"must be a finite number >= 0{bound}, got {value!r}")


def count(key: str, value: Any, minimum: int = 1, maximum: int | None = None) -> None:
    if not (is_int(value) and value >= minimum and (maximum is None or value <= maximum)):
        bound = "" if maximum is None else f" and <= {maximum}"
        reject(key, f"must be an integer >= {minimum}{bound}, got {value!r}")


def fraction(key: str, value: Any, low_open: bool = True) -> None:
    if not (is_number(value) and (0 < value if low_open else 0 <= value) and value <= 1):
        reject(key, f"must lie in {'(0' if low_open else '[0'}, 1], got {value!r}")


def choice(key: str, value: Any, choices: Sequence[Any]) -> None:
    if value not in choices:
        reject(key, f"must be one of {', '.join(map(str, choices))}; got {value!r}")


# A folder name made from values: letters, digits and ``._+-`` only (no separators, no
# quoting needed on a command line or in a Hydra override).
UNSAFE = re.compile(r"[^A-Za-z0-9._+-]")


def safe_name(text: Any) -> str:
    """``text`` as one plain folder name: other characters become ``_``; never ``.`` or ``..``."""
    name = UNSAFE.sub("_", str(text))
    return name if name.strip(".") else name.replace(".", "_")


def folder_name(key: str, value: Any) -> None:
    """A value that becomes one folder of a path: no separators, no ``..``."""
    if not (isinstance(value, str) and value and safe_name(value) == value):
        reject(key, f"becomes a folder name, so it may hold only letters, digits and ._+- (and not be '.' or "
                    f"'..'); got {value!r}")


def check_seed(key: str, value: Any) -> None:
    count(key, value, 0, MAX_SEED)


def check_device(key: str, device: Any) -> None:
    """``cpu``, ``cuda``, ``cuda:<k>`` or ``mps`` on a machine that has it."""
    import torch

    text = str(device)
    if not re.fullmatch(r"cpu|cuda(:\d+)?|mps", text):
        reject(key, f"must be cpu, cuda or cuda:<index>, got {text!r}")
    if text.startswith("cuda"):
        if not torch.cuda.is_available():
            reject(key, f"{text!r} asked for, but this torch build ({torch.__version__}) sees no CUDA device")
        index = int(text.split(":")[1]) if ":" in text else 0
        if index >= torch.cuda.device_count():
            reject(key, f"{text!r} asked for, but only {torch.cuda.device_count()} CUDA device(s) exist")
    if text == "mps" and not (getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()):
        reject(key, "'mps' asked for, but it is not available")


def check_threads(key: str, value: Any) -> None:
    count(key, value, 0, 1024)


def config_error(exc: BaseException, prefix: str = "") -> ConfigError:
    """One readable :class:`ConfigError` from an OmegaConf exception (its key and message)."""
    if isinstance(exc, ConfigError):
        return exc
    key = str(getattr(exc, "full_key", "") or "")
    text = str(getattr(exc, "msg", "") or exc).strip().splitlines()
    message = text[0] if text else type(exc).__name__
    full = key if not prefix or key.startswith(prefix) else dotted(prefix, key) if key else prefix
    return ConfigError(full, message)


S = TypeVar("S", bound="Schema")


class Schema:
    """What every schema dataclass can do: be built from a composed config and checked once.

    :meth:`check` never changes the object it is called on: it returns a checked copy (fields a
    check normalises, such as a scenario's obstacle lists, or a group's checked node, are set
    on the copy), which remembers that it is checked (:attr:`is_checked`), so a checked object
    handed on (to :class:`~flock_torchrl.world.env.FlockingEnv`, to an app) is not checked again.
    """

    prefix: ClassVar[str] = ""

    def check(self: S, prefix: str | None = None) -> S:
        """A checked copy of this object (``ConfigError`` naming the dotted key if a value is wrong);
        ``prefix``: the key the object sits under (default: the schema's own, e.g. ``scenario``)."""
        if self.is_checked:
            return self
        checked = dataclasses.replace(self, **self.checked_fields(self.prefix if prefix is None else prefix))
        object.__setattr__(checked, "_checked", True)
        return checked

    def checked_fields(self, prefix: str) -> Mapping[str, Any]:
        """Check every field under ``prefix``; return the fields whose checked value differs in
        form (a nested schema checked, a list normalised). Schemas extend it cooperatively
        (``super().checked_fields(prefix)``), so a mixin's fields are checked once, there."""
        return {}

    @property
    def is_checked(self) -> bool:
        return bool(self.__dict__.get("_checked"))

    @classmethod
    def structured(cls, node: Any) -> Any:
        """``node`` as a plain container OmegaConf can merge into this schema (a hook for schemas
        with a field whose type a value chooses: the apps' ``algo``)."""
        return node

    @classmethod
    def from_config(cls: type[S], node: Any, prefix: str | None = None) -> S:
        """``node`` (DictConfig, mapping or instance) as a checked instance of this schema.

        A wrong type, an unknown key or a missing value becomes a :class:`ConfigError` under
        ``prefix`` (default: the schema's own, e.g. ``scenario``)."""
        prefix = cls.prefix if prefix is None else prefix
        if isinstance(node, cls):
            obj = node
        else:
            try:
                if isinstance(node, DictConfig):
                    if "hydra" in node:
                        node = OmegaConf.masked_copy(node, [k for k in node if k != "hydra"])
                    node = OmegaConf.to_container(node, resolve=True)
                elif dataclasses.is_dataclass(node):
                    node = dataclasses.asdict(node)
                obj = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(cls), cls.structured(node)))
            except OmegaConfBaseException as exc:
                raise config_error(exc, prefix) from exc
        return obj if obj.is_checked else obj.check(prefix)
