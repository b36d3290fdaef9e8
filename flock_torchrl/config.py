"""Configuration: the schema of every Hydra group and app, and the one composer.

Every value lives once, in the YAML files under ``conf/``; the dataclasses below give each
group and each app its fields and types (fields are ``MISSING``: a YAML that forgets one fails
when it is composed) and one :meth:`~Schema.check` that validates what a type cannot say
(ranges, choices, consistency), raising :class:`ConfigError` naming the dotted key, e.g.
``scenario.n_uavs: must be an integer >= 1, got 0``. :func:`register_schemas` puts them in
Hydra's ConfigStore as root configs (``scenario_schema``, ``train_schema`` ...) that the YAMLs
name in their defaults lists, so Hydra type-checks every file, every composition and every
command-line override, and the schemas never show up as choices of a group.

A config becomes a checked object exactly once: :meth:`Schema.from_config` converts Hydra's
composed ``DictConfig`` (``OmegaConf.to_object``) and runs ``check()``; the checked object is
what the app runs. A checked object remembers it (``is_checked``), so :class:`FlockingEnv`
does not check a scenario again.

:func:`compose` is Hydra's compose API on the package's ``conf/`` for Python callers
(``make_train_config``, ``FlockingEnv("train", ...)``); the scripts use ``hydra.main`` on the
same folder, with the user's ``--config-dir`` and ``hydra.searchpath`` added by Hydra itself.
See ``docs/specification.md`` for what every scenario field means.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Dict, List, Mapping, Optional, Sequence, TypeVar

from omegaconf import MISSING, DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException


# The largest swarm any config may ask for (scenario.n_uavs, experiment.swarm_sizes, sizes).
MAX_UAVS = 2000


class ConfigError(ValueError):
    """A configuration value is invalid. ``key`` is the dotted name of the field."""

    def __init__(self, key: str, message: str, also: Sequence[str] = ()) -> None:
        super().__init__(f"{key}: {message}" if key else message)
        self.key = key
        self.message = message
        self.also = tuple(also)  # other keys the error is about: the one the user set is named


# ---------------------------------------------------------------------------- where conf/ is
def config_dir() -> Path:
    """The ``conf/`` folder: packaged as ``flock_torchrl.conf`` in an installed wheel (and
    mapped to the repository's ``conf/`` by an editable install), else the source checkout's."""
    spec = importlib.util.find_spec("flock_torchrl.conf")
    if spec is not None and spec.submodule_search_locations:
        for location in spec.submodule_search_locations:
            if (Path(location) / "train.yaml").is_file():
                return Path(location)
    return Path(__file__).resolve().parent.parent / "conf"


CONF_DIR = config_dir()


def shipped_checkpoints_dir() -> Path:
    """The shipped checkpoints: packaged as ``flock_torchrl.checkpoints`` in a wheel (the
    repository's ``checkpoints/`` in an editable install), else the source checkout's. It is the
    default of ``checkpoints_dir`` (conf/world.yaml), so the apps find them from any folder."""
    spec = importlib.util.find_spec("flock_torchrl.checkpoints")
    if spec is not None and spec.submodule_search_locations:
        for location in spec.submodule_search_locations:
            if Path(location).is_dir():
                return Path(location)
    return Path(__file__).resolve().parent.parent / "checkpoints"


# ---------------------------------------------------------------------------- resolvers
# A folder name made from values: letters, digits and ``._+-`` only (no separators, no
# quoting needed on a command line or in a Hydra override).
_UNSAFE = re.compile(r"[^A-Za-z0-9._+-]")


def safe_name(text: Any) -> str:
    """``text`` as one plain folder name: other characters become ``_``; never ``.`` or ``..``."""
    name = _UNSAFE.sub("_", str(text))
    return name if name.strip(".") else name.replace(".", "_")


def run_name(base: Any, overrides: Any = "") -> str:
    """``seed0`` or ``seed0__algo.lr_actor-0.001__scenario.tau_v-0.5``: the folder of one run.

    ``overrides`` is Hydra's ``override_dirname`` (``key-value`` pairs joined by ``__``, the
    task overrides not already in the path, sorted; conf/train.yaml sets the separators so that
    a folder name needs no quoting in a Hydra override). Anything else becomes ``_``.
    """
    overrides = str(overrides or "")
    return safe_name(str(base) + (f"__{overrides}" if overrides else ""))


def selection_dir(overrides: Any = "") -> str:
    """``""`` for a table of the whole selection, else ``/<selection>``: the reproduce app's
    subfolder for a table of some rows, contenders or other checkpoints (Hydra's
    ``override_dirname`` of those keys), so it never replaces another selection's table. A
    name over 120 characters keeps its start and a digest of the whole."""
    import hashlib

    name = safe_name(str(overrides or ""))
    if not name:
        return ""
    if len(name) > 120:
        name = f"{name[:100]}__{hashlib.sha256(name.encode()).hexdigest()[:12]}"
    return "/" + name


def config_folder(sources: Any, config_name: Any) -> str:
    """The folder Hydra read the primary config ``<config_name>.yaml`` from: the first ``file``
    source of ``hydra.runtime.config_sources`` that holds it. A run's ``resume.yaml`` sets its
    output folder to this, so a copied or moved run folder continues where it stands now."""
    for source in sources or ():
        path = Path(str(source["path"]))
        if str(source["schema"]) == "file" and (path / f"{config_name}.yaml").is_file():
            return str(path.resolve())
    raise ConfigError("hydra.run.dir", f"no folder of the config search path holds {config_name}.yaml")


def _register_resolvers() -> None:
    # ``${pi:0.5}`` = 0.5 pi: angles written as the paper writes them.
    if not OmegaConf.has_resolver("pi"):
        OmegaConf.register_new_resolver("pi", lambda k=1.0: float(k) * math.pi)
    if not OmegaConf.has_resolver("flock.run_name"):
        OmegaConf.register_new_resolver("flock.run_name", run_name)
    if not OmegaConf.has_resolver("flock.shipped_checkpoints"):
        OmegaConf.register_new_resolver("flock.shipped_checkpoints", lambda: str(shipped_checkpoints_dir()))
    if not OmegaConf.has_resolver("flock.evaluated"):
        OmegaConf.register_new_resolver("flock.evaluated", lambda policy, contender=None: evaluated_name(policy,
                                                                                                       contender))
    if not OmegaConf.has_resolver("flock.selection"):
        OmegaConf.register_new_resolver("flock.selection", selection_dir)
    if not OmegaConf.has_resolver("flock.safe_name"):
        OmegaConf.register_new_resolver("flock.safe_name", safe_name)
    # ``${flock.concat:[a,b],${some_list}}``: lists joined (one list written once, used twice).
    if not OmegaConf.has_resolver("flock.concat"):
        OmegaConf.register_new_resolver("flock.concat", lambda *lists: [x for items in lists for x in items])
    # ``${flock.config_folder:${hydra.runtime.config_sources},${hydra.job.config_name}}``: where
    # the primary config was read (a run folder's resume.yaml is its own output folder).
    if not OmegaConf.has_resolver("flock.config_folder"):
        OmegaConf.register_new_resolver("flock.config_folder", config_folder)


_register_resolvers()


# ---------------------------------------------------------------------------- checks
def _fail(key: str, message: str) -> None:
    raise ConfigError(key, message)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def positive(key: str, value: Any, maximum: float = math.inf) -> None:
    if not (_is_number(value) and 0 < value <= maximum):
        bound = "" if math.isinf(maximum) else f" and <= {maximum:g}"
        _fail(key, f"must be a positive finite number{bound}, got {value!r}")


def non_negative(key: str, value: Any, maximum: float = math.inf) -> None:
    if not (_is_number(value) and 0 <= value <= maximum):
        bound = "" if math.isinf(maximum) else f" and <= {maximum:g}"
        _fail(key, f"must be a finite number >= 0{bound}, got {value!r}")


def count(key: str, value: Any, minimum: int = 1, maximum: int | None = None) -> None:
    if not (_is_int(value) and value >= minimum and (maximum is None or value <= maximum)):
        bound = "" if maximum is None else f" and <= {maximum}"
        _fail(key, f"must be an integer >= {minimum}{bound}, got {value!r}")


def fraction(key: str, value: Any, low_open: bool = True) -> None:
    ok = _is_number(value) and (0 < value if low_open else 0 <= value) and value <= 1
    if not ok:
        _fail(key, f"must lie in {'(0' if low_open else '[0'}, 1], got {value!r}")


def choice(key: str, value: Any, choices: Sequence[Any]) -> None:
    if value not in choices:
        _fail(key, f"must be one of {', '.join(map(str, choices))}; got {value!r}")


def folder_name(key: str, value: Any) -> None:
    """A value that becomes one folder of a path: no separators, no ``..``."""
    if not (isinstance(value, str) and value and safe_name(value) == value):
        _fail(key, f"becomes a folder name, so it may hold only letters, digits and ._+- (and not be '.' or "
                   f"'..'); got {value!r}")


# Seeds: the trainer derives env seeds as seed * 1000 + worker, within torch's 64-bit range.
MAX_SEED = 2**32 - 1


def check_seed(key: str, value: Any) -> None:
    count(key, value, 0, MAX_SEED)


def check_device(key: str, device: Any) -> None:
    """``cpu``, ``cuda``, ``cuda:<k>`` or ``mps`` on a machine that has it."""
    import torch

    text = str(device)
    if not re.fullmatch(r"cpu|cuda(:\d+)?|mps", text):
        _fail(key, f"must be cpu, cuda or cuda:<index>, got {text!r}")
    if text.startswith("cuda"):
        if not torch.cuda.is_available():
            _fail(key, f"{text!r} asked for, but this torch build ({torch.__version__}) sees no CUDA device")
        index = int(text.split(":")[1]) if ":" in text else 0
        if index >= torch.cuda.device_count():
            _fail(key, f"{text!r} asked for, but only {torch.cuda.device_count()} CUDA device(s) exist")
    if text == "mps" and not (getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()):
        _fail(key, "'mps' asked for, but it is not available")


def check_threads(key: str, value: Any) -> None:
    count(key, value, 0, 1024)


def _key(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


S = TypeVar("S", bound="Schema")


class Schema:
    """What every schema dataclass can do: be built from a composed config and checked once."""

    prefix: ClassVar[str] = ""

    def check(self, prefix: str | None = None) -> "Schema":  # pragma: no cover - every schema overrides it
        raise NotImplementedError

    @property
    def is_checked(self) -> bool:
        return bool(self.__dict__.get("_checked"))

    def _mark_checked(self: S) -> S:
        object.__setattr__(self, "_checked", True)
        return self

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
                obj = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(cls), node))
            except OmegaConfBaseException as exc:
                raise config_error(exc, prefix) from exc
        if not obj.is_checked:
            obj.check(prefix)
        return obj


def config_error(exc: BaseException, prefix: str = "") -> ConfigError:
    """One readable :class:`ConfigError` from an OmegaConf exception (its key and message)."""
    if isinstance(exc, ConfigError):
        return exc
    key = str(getattr(exc, "full_key", "") or "")
    text = str(getattr(exc, "msg", "") or exc).strip().splitlines()
    message = text[0] if text else type(exc).__name__
    full = key if not prefix or key.startswith(prefix) else _key(prefix, key) if key else prefix
    return ConfigError(full, message)


# ---------------------------------------------------------------------------- group schemas
@dataclass
class ScenarioConfig(Schema):
    """The world (docs/specification.md sections 1-6, 9). Values: ``conf/scenario/*.yaml``
    (the world), ``conf/reading/*.yaml`` (the reading's fields), ``conf/policy/*.yaml``
    (the policy's sensing, instinct and reward variant)."""

    prefix: ClassVar[str] = "scenario"

    name: str = MISSING
    reading: str = MISSING                   # literal | paper_fit (section 9)
    # --- world (section 1)
    n_uavs: int = MISSING
    dt: float = MISSING
    max_steps: int = MISSING
    tau_v: float = MISSING
    v_max: float = MISSING
    goal_radius: float = MISSING
    collision_distance: float = MISSING
    uav_collision_terminates: bool = MISSING
    heading_speed_threshold: float = MISSING
    # --- sensors (section 2)
    camera_range: float = MISSING
    fov: float = MISSING                     # phi_v, as the paper states it
    fov_convention: str = MISSING            # total (visible iff |bearing| <= fov/2) | half_angle (<= fov)
    n_beams: int = MISSING
    laser_range: float = MISSING
    n_scan: int = MISSING
    n_cam: int = MISSING
    goal_scale: float = MISSING
    # --- instinct (section 3)
    instinct: bool = MISSING
    tangential: bool = MISSING
    rep_gain: float = MISSING
    rep_range: float = MISSING
    safe_distance: float = MISSING
    # --- action interface: policy (Eq. 19-20) | velocity (the rule-based controllers)
    action_mode: str = MISSING
    # --- reward (section 4): scan | min_uav_scan (Policy4-G)
    collision_reward_source: str = MISSING
    # --- starts, goals, obstacles (sections 1, 6, 9)
    area_center: List[float] = MISSING
    area_size: float = MISSING
    d_env: float = MISSING
    spawn_radius: float = MISSING            # radius at the reference swarm size
    spawn_reference_uavs: int = MISSING      # the radius grows as sqrt(N / this) ...
    spawn_radius_shrinks: bool = MISSING     # ... and below it shrinks too (else stays)
    spawn_separation: float = MISSING
    spawn_clearance: float = MISSING
    spawn_max_tries: int = MISSING
    # Lists of numbers ([[40, 40, 6]] as well as [[40.0, 40.0, 6.0]]: OmegaConf's nested typed
    # lists refuse an int, so check() verifies and converts them).
    circles: List[Any] = MISSING             # [cx, cy, radius]
    rectangles: List[Any] = MISSING          # [cx, cy, width_x, height_y]
    # --- moving circles (S5)
    n_moving: int = MISSING
    moving_radius: float = MISSING
    moving_speed: float = MISSING
    moving_clearance: float = MISSING
    moving_box: List[float] = MISSING
    # --- obstacles drawn per episode (the forest; docs/specification.md section 6, decision). A
    # scenario saved before these fields existed takes conf/scenario/train.yaml's ("none"):
    # :func:`saved_scenario`.
    random_circles: int = MISSING            # how many circles each episode draws
    random_circle_radius: List[float] = MISSING   # [min, max] radius
    random_rectangles: int = MISSING         # how many axis-aligned rectangles each episode draws
    random_rectangle_size: List[float] = MISSING  # [min, max] of each side
    random_region: List[float] = MISSING     # [x0, y0, x1, y1]
    random_clearance: float = MISSING        # m between drawn obstacles, and from starts, goal, other obstacles
    # --- observation noise (S4)
    noise: bool = MISSING
    noise_scan: float = MISSING
    noise_distance: float = MISSING
    noise_angle: float = MISSING

    @property
    def half_fov(self) -> float:
        """The largest |bearing| the camera sees (docs/specification.md sections 2 and 9)."""
        return self.fov if self.fov_convention == "half_angle" else self.fov / 2

    @property
    def swarm_spawn_radius(self) -> float:
        """Spawn disc radius for this swarm size: ``spawn_radius * sqrt(N / N_ref)``, kept at
        ``spawn_radius`` below ``N_ref`` unless ``spawn_radius_shrinks`` (section 9)."""
        scale = self.n_uavs / self.spawn_reference_uavs
        if not self.spawn_radius_shrinks:
            scale = max(scale, 1.0)
        return self.spawn_radius * math.sqrt(scale)

    @property
    def n_obstacles(self) -> int:
        """Obstacles in every world, the laser's indices: fixed, moving and drawn circles, then
        fixed and drawn rectangles."""
        return (len(self.circles) + self.n_moving + self.random_circles + len(self.rectangles)
                + self.random_rectangles)

    def check(self, prefix: str | None = None) -> "ScenarioConfig":
        """Every field's range; whether the starts can always be placed is the world's question
        (:func:`flock_torchrl.world.spawn.check_spawn_feasible`, asked once per scenario)."""
        p = self.prefix if prefix is None else prefix
        k = lambda name: _key(p, name)  # noqa: E731
        choice(k("reading"), self.reading, READINGS)
        # Bounds keep a config from asking for more than any machine holds (the world's
        # [B, N, N] pairwise terms, the episode loop): far above every use, well below overflow.
        count(k("n_uavs"), self.n_uavs, 1, MAX_UAVS)
        count(k("max_steps"), self.max_steps, 1, 10**7)
        count(k("n_beams"), self.n_beams, 1, 3600)
        for name in ("n_scan", "n_cam"):
            count(k(name), getattr(self, name), 1, 100)
        count(k("spawn_max_tries"), self.spawn_max_tries, 1, 10**5)
        count(k("spawn_reference_uavs"), self.spawn_reference_uavs, 1)
        count(k("n_moving"), self.n_moving, 0, 1000)
        # Lengths and speeds against the world: at most 1e6 m and 1e4 s, so float32 positions
        # stay exact to about a metre's millionth over an episode.
        for name in ("dt", "tau_v"):
            positive(k(name), getattr(self, name), 1e4)
        for name in ("v_max", "goal_radius", "camera_range", "laser_range", "area_size", "goal_scale",
                     "spawn_radius", "rep_range"):
            positive(k(name), getattr(self, name), 1e6)
        positive(k("fov"), self.fov, 2 * math.pi + 1e-9)
        for name in ("collision_distance", "safe_distance", "rep_gain", "heading_speed_threshold",
                     "spawn_separation", "spawn_clearance", "d_env", "noise_scan", "noise_distance", "noise_angle",
                     "moving_speed", "moving_clearance", "moving_radius"):
            non_negative(k(name), getattr(self, name), 1e6)
        if self.n_scan > self.n_beams:
            _fail(k("n_scan"), f"cannot exceed n_beams={self.n_beams}, got {self.n_scan}")
        choice(k("fov_convention"), self.fov_convention, ("total", "half_angle"))
        choice(k("collision_reward_source"), self.collision_reward_source, ("scan", "min_uav_scan"))
        choice(k("action_mode"), self.action_mode, ("policy", "velocity"))
        if len(self.area_center) != 2 or not all(_is_number(v) for v in self.area_center):
            _fail(k("area_center"), f"must be [x, y], got {list(self.area_center)}")
        for name, size, shape in (("circles", 3, "[cx, cy, radius > 0]"),
                                  ("rectangles", 4, "[cx, cy, width > 0, height > 0]")):
            entries = getattr(self, name)
            for i, entry in enumerate(entries):
                ok = isinstance(entry, (list, tuple)) and len(entry) == size and all(_is_number(v) for v in entry)
                if not ok or not all(v > 0 for v in entry[2:]):
                    _fail(k(name), f"entry {i} must be {shape}, got {entry!r}")
            setattr(self, name, [[float(v) for v in entry] for entry in entries])
        for i, a in enumerate(self.circles):
            for j, b in enumerate(self.circles[i + 1:], i + 1):
                if math.hypot(a[0] - b[0], a[1] - b[1]) < a[2] + b[2]:
                    _fail(k("circles"), f"circles {i} and {j} overlap")
            for j, r in enumerate(self.rectangles):
                if _circle_rect_overlap(a, r):
                    _fail(k("circles"), f"circle {i} overlaps rectangle {j}")
        for i, a in enumerate(self.rectangles):
            for j, b in enumerate(self.rectangles[i + 1:], i + 1):
                if _rect_rect_overlap(a, b):
                    _fail(k("rectangles"), f"rectangles {i} and {j} overlap")
        if self.n_moving:
            positive(k("moving_radius"), self.moving_radius, 1e6)
            if len(self.moving_box) != 2 or not self.moving_box[0] < self.moving_box[1]:
                _fail(k("moving_box"), f"must be [low, high] with low < high, got {list(self.moving_box)}")
        self._check_random_obstacles(k)
        return self._mark_checked()

    def _check_random_obstacles(self, k: Any) -> None:
        """The drawn obstacles' fields (always, so a typo shows before a count makes it matter);
        whether they can always be placed is :func:`flock_torchrl.world.forest.check_forest_feasible`."""
        for name in ("random_circles", "random_rectangles"):
            count(k(name), getattr(self, name), 0, 1000)
        for name in ("random_circle_radius", "random_rectangle_size"):
            low_high = list(getattr(self, name))
            if not (len(low_high) == 2 and all(_is_number(v) and 0 < v <= 1e6 for v in low_high)
                    and low_high[0] <= low_high[1]):
                _fail(k(name), f"must be [min, max] with 0 < min <= max <= 1e6 (m), got {low_high}")
        region = list(self.random_region)
        if not (len(region) == 4 and all(_is_number(v) and abs(v) <= 1e6 for v in region)
                and region[0] < region[2] and region[1] < region[3]):
            _fail(k("random_region"), f"must be [x0, y0, x1, y1] with x0 < x1, y0 < y1, inside [-1e6, 1e6]^2 (m), "
                                      f"got {region}")
        non_negative(k("random_clearance"), self.random_clearance, 1e6)
        width, height = region[2] - region[0], region[3] - region[1]
        if self.random_circles and 2 * self.random_circle_radius[1] > min(width, height):
            _fail(k("random_region"), f"{width:g} m x {height:g} m cannot hold a circle of radius "
                                      f"{self.random_circle_radius[1]:g} m (random_circle_radius)")
        if self.random_rectangles and self.random_rectangle_size[1] > min(width, height):
            _fail(k("random_region"), f"{width:g} m x {height:g} m cannot hold a rectangle side of "
                                      f"{self.random_rectangle_size[1]:g} m (random_rectangle_size)")


def _rect_rect_overlap(a: Sequence[float], b: Sequence[float]) -> bool:
    return abs(a[0] - b[0]) < (a[2] + b[2]) / 2 and abs(a[1] - b[1]) < (a[3] + b[3]) / 2


def _circle_rect_overlap(c: Sequence[float], r: Sequence[float]) -> bool:
    dx = max(abs(c[0] - r[0]) - r[2] / 2, 0.0)
    dy = max(abs(c[1] - r[1]) - r[3] / 2, 0.0)
    return math.hypot(dx, dy) < c[2]


SCENARIO_FIELDS = frozenset(f.name for f in dataclasses.fields(ScenarioConfig))
# The scenario fields a policy YAML sets (its sensing, instinct, reward variant, action
# interface): a checkpoint records them, and evaluation applies them in any scenario.
POLICY_SCENARIO_FIELDS = ("fov", "instinct", "tangential", "collision_reward_source", "action_mode")
READINGS = ("literal", "paper_fit")


@dataclass
class PolicyConfig(Schema):
    """One of the twelve policies (section 7); its scenario fields sit in the YAML's ``scenario:``."""

    prefix: ClassVar[str] = "policy"

    id: str = MISSING                        # the YAML's stem, e.g. policy3_g
    name: str = MISSING                      # the paper's name, e.g. Policy3-G
    kind: str = MISSING                      # learned | rule
    critic_input: Optional[str] = None       # observation | state (learned policies)
    controller: Optional[str] = None         # olfati_saber | vasarhelyi (rule-based policies)
    params: Dict[str, Any] = field(default_factory=dict)  # the controller's parameters

    def check(self, prefix: str | None = None) -> "PolicyConfig":
        p = self.prefix if prefix is None else prefix
        folder_name(_key(p, "id"), self.id)
        choice(_key(p, "kind"), self.kind, ("learned", "rule"))
        if self.kind == "learned":
            choice(_key(p, "critic_input"), self.critic_input, ("observation", "state"))
        else:
            choice(_key(p, "controller"), self.controller, ("olfati_saber", "vasarhelyi"))
        return self._mark_checked()


class _Learner(Schema):
    """What every learner's schema checks: the shared network and optimisation fields."""

    prefix: ClassVar[str] = "algo"
    # Network sizes and batches a machine can hold: far above every recipe.
    _counts: ClassVar[tuple[tuple[str, int], ...]] = (("hidden", 65536), ("depth", 64))

    def check(self, prefix: str | None = None) -> "_Learner":
        p = self.prefix if prefix is None else prefix
        for name, maximum in self._counts:
            count(_key(p, name), getattr(self, name), 1, maximum)
        fraction(_key(p, "gamma"), self.gamma)
        non_negative(_key(p, "max_grad_norm"), self.max_grad_norm)
        self._check_own(p)
        return self._mark_checked()

    def _check_own(self, p: str) -> None:
        pass


# Replay buffers are counted in UAV transitions; 1e9 is about 0.5 TB of swarm transitions.
MAX_BUFFER = 10**9


@dataclass
class SACConfig(_Learner):
    name: str = MISSING
    gamma: float = MISSING
    lr_actor: float = MISSING
    lr_critic: float = MISSING
    lr_alpha: float = MISSING
    alpha_init: float = MISSING
    target_entropy: float = MISSING
    tau: float = MISSING
    batch_size: int = MISSING                # UAV transitions
    buffer_size: int = MISSING               # UAV transitions
    num_qvalue_nets: int = MISSING
    loss_function: str = MISSING
    hidden: int = MISSING
    depth: int = MISSING
    max_grad_norm: float = MISSING

    _counts: ClassVar = (("hidden", 65536), ("depth", 64), ("batch_size", 10**7), ("buffer_size", MAX_BUFFER),
                         ("num_qvalue_nets", 16))

    def _check_own(self, p: str) -> None:
        for name in ("lr_actor", "lr_critic", "lr_alpha", "alpha_init"):
            positive(_key(p, name), getattr(self, name))
        fraction(_key(p, "tau"), self.tau)
        if not _is_number(self.target_entropy):
            _fail(_key(p, "target_entropy"), f"must be a finite number, got {self.target_entropy!r}")
        choice(_key(p, "loss_function"), self.loss_function, ("l1", "l2", "smooth_l1"))


@dataclass
class DDPGConfig(_Learner):
    name: str = MISSING
    gamma: float = MISSING
    lr_actor: float = MISSING
    lr_critic: float = MISSING
    tau: float = MISSING
    batch_size: int = MISSING
    buffer_size: int = MISSING
    loss_function: str = MISSING
    hidden: int = MISSING
    depth: int = MISSING
    noise_sigma: float = MISSING
    noise_sigma_end: float = MISSING
    noise_anneal_frames: int = MISSING
    max_grad_norm: float = MISSING

    _counts: ClassVar = (("hidden", 65536), ("depth", 64), ("batch_size", 10**7), ("buffer_size", MAX_BUFFER),
                         ("noise_anneal_frames", 10**12))

    def _check_own(self, p: str) -> None:
        for name in ("lr_actor", "lr_critic"):
            positive(_key(p, name), getattr(self, name))
        fraction(_key(p, "tau"), self.tau)
        for name in ("noise_sigma", "noise_sigma_end"):
            non_negative(_key(p, name), getattr(self, name))
        choice(_key(p, "loss_function"), self.loss_function, ("l1", "l2", "smooth_l1"))


@dataclass
class PPOConfig(_Learner):
    name: str = MISSING
    rollout_steps: int = MISSING             # env steps per env per on-policy batch
    gamma: float = MISSING
    lmbda: float = MISSING
    clip_epsilon: float = MISSING
    lr: float = MISSING
    epochs: int = MISSING
    minibatch_size: int = MISSING            # swarm transitions per gradient step
    entropy_coeff: float = MISSING
    critic_coeff: float = MISSING
    loss_critic_type: str = MISSING
    normalize_advantage: bool = MISSING
    hidden: int = MISSING
    depth: int = MISSING
    max_grad_norm: float = MISSING

    _counts: ClassVar = (("hidden", 65536), ("depth", 64), ("rollout_steps", 10**6), ("epochs", 10**4),
                         ("minibatch_size", 10**7))

    def _check_own(self, p: str) -> None:
        for name in ("lr", "clip_epsilon"):
            positive(_key(p, name), getattr(self, name))
        fraction(_key(p, "lmbda"), self.lmbda, low_open=False)
        for name in ("entropy_coeff", "critic_coeff"):
            non_negative(_key(p, name), getattr(self, name))
        choice(_key(p, "loss_critic_type"), self.loss_critic_type, ("l1", "l2", "smooth_l1"))


ALGO_SCHEMAS: dict[str, type[_Learner]] = {"sac": SACConfig, "ddpg": DDPGConfig, "ppo": PPOConfig}


def algo_config(node: Any, prefix: str = "algo") -> _Learner:
    """A learner's node as its schema, chosen by ``name`` (``sac``, ``ddpg``, ``ppo``), checked."""
    if isinstance(node, _Learner):
        return node if node.is_checked else node.check(prefix)
    name = node.get("name") if hasattr(node, "get") else None
    if name not in ALGO_SCHEMAS:
        _fail(_key(prefix, "name"), f"must be one of {', '.join(ALGO_SCHEMAS)}; got {name!r}")
    return ALGO_SCHEMAS[name].from_config(node, prefix)


@dataclass
class ExperimentConfig(Schema):
    """How long and how fast to train; its learner tuning is the ``tuning`` group."""

    prefix: ClassVar[str] = "experiment"

    name: str = MISSING
    num_envs: int = MISSING                  # envs stepped together in one batched FlockingEnv
    workers: int = MISSING                   # >1: MultiSyncCollector over that many processes
    steps_per_batch: int = MISSING           # env steps per env between updates (off-policy)
    updates_per_batch: int = MISSING         # gradient steps per collected batch (off-policy)
    init_random_frames: int = MISSING        # env frames of uniform random actions first
    max_episodes: int = MISSING              # budgets: 0 = no limit; at least one is set
    max_frames: int = MISSING
    max_minutes: float = MISSING
    log_every_frames: int = MISSING          # scalar logs at most this often (0: every collector batch)
    eval_every_frames: int = MISSING
    eval_episodes: int = MISSING
    checkpoint_every_frames: int = MISSING
    keep_buffer_in_checkpoint: bool = MISSING
    # Scenario fields changed for the *training* env only (a training recipe such as ending
    # an episode at UAV contact); evaluation runs the scenario as composed.
    train_env: Dict[str, Any] = field(default_factory=dict)
    # Several swarm sizes trained at once, one shared policy (docs/specification.md section 7,
    # a decision beyond the paper): the training worlds are split evenly between the sizes and
    # the replay buffer holds single UAV transitions. Empty: the scenario's n_uavs only.
    swarm_sizes: List[int] = field(default_factory=list)

    def check(self, prefix: str | None = None) -> "ExperimentConfig":
        p = self.prefix if prefix is None else prefix
        folder_name(_key(p, "name"), self.name)
        count(_key(p, "num_envs"), self.num_envs, 1, 10**7)
        count(_key(p, "workers"), self.workers, 1, 1024)
        count(_key(p, "steps_per_batch"), self.steps_per_batch, 1, 10**6)
        count(_key(p, "eval_episodes"), self.eval_episodes, 1, 10**6)
        for name in ("updates_per_batch", "init_random_frames", "max_episodes", "max_frames", "log_every_frames",
                     "eval_every_frames", "checkpoint_every_frames"):
            count(_key(p, name), getattr(self, name), 0, 10**13)
        non_negative(_key(p, "max_minutes"), self.max_minutes)
        if not (self.max_episodes or self.max_frames or self.max_minutes):
            _fail(p, "set at least one budget: max_episodes, max_frames or max_minutes")
        unknown = sorted(set(self.train_env) - SCENARIO_FIELDS)
        if unknown:
            _fail(_key(p, "train_env"), f"unknown scenario field(s) {unknown}")
        if self.workers > 1 and self.num_envs % self.workers:
            _fail(_key(p, "workers"), f"{self.workers} must divide num_envs={self.num_envs}")
        if self.swarm_sizes:
            key = _key(p, "swarm_sizes")
            for i, n in enumerate(self.swarm_sizes):
                count(f"{key}[{i}]", n, 1, MAX_UAVS)  # the bound of scenario.n_uavs
            if len(set(self.swarm_sizes)) != len(self.swarm_sizes):
                _fail(key, f"sizes repeat: {list(self.swarm_sizes)}")
            if self.num_envs % len(self.swarm_sizes):
                _fail(key, f"{len(self.swarm_sizes)} sizes must divide num_envs={self.num_envs} (worlds per size)")
            if self.workers > 1:
                _fail(key, "trains in one process: set workers=1")
            if "n_uavs" in self.train_env:
                _fail(key, "and train_env.n_uavs both set the training swarm size; keep one")
        return self._mark_checked()


@dataclass
class LoggerConfig(Schema):
    prefix: ClassVar[str] = "logger"

    backend: str = MISSING                   # csv | wandb | tensorboard | none
    project: str = MISSING
    mode: str = MISSING                      # wandb: offline | online

    def check(self, prefix: str | None = None) -> "LoggerConfig":
        p = self.prefix if prefix is None else prefix
        choice(_key(p, "backend"), self.backend, ("csv", "wandb", "tensorboard", "none"))
        choice(_key(p, "mode"), self.mode, ("offline", "online"))
        extra = {"tensorboard": "tensorboard", "wandb": "wandb"}.get(self.backend)
        if extra and importlib.util.find_spec(extra) is None:
            _fail(_key(p, "backend"), f"{self.backend} is not installed: pip install 'flock_torchrl[{extra}]'")
        return self._mark_checked()


# ---------------------------------------------------------------------------- app schemas
@dataclass
class WorldApp(Schema):
    """What every app composed from ``conf/world.yaml`` holds: the scenario (with its reading)
    and the values the apps share, each set once there."""

    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    eval_seed: int = MISSING                 # the evaluation seed of every policy (section 5)
    checkpoints_dir: str = MISSING           # shipped checkpoints: <dir>/<reading>/<policy>/seed<k>.pt
    paper_recipe_dir: str = MISSING          # the paper recipe's shipped checkpoints (<policy>/seed<k>.pt)

    def _check_world(self) -> None:
        self.scenario.check()
        check_seed("eval_seed", self.eval_seed)


@dataclass
class TrainConfig(WorldApp):
    """``conf/train.yaml``: one training run (``scripts/train.py``)."""

    policy: PolicyConfig = field(default_factory=PolicyConfig)
    algo: Any = None
    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    seed: int = MISSING
    device: str = MISSING
    resume: str = MISSING                    # false | true | auto
    progress: bool = MISSING
    threads: int = MISSING
    compile: Any = MISSING                   # false | true (the loss and the step) | step | loss: torch.compile
    objective: str = MISSING                 # what the app returns to a sweeper: a final-evaluation metric
    resumable: List[str] = field(default_factory=list)   # keys a resume may change (a trailing . = a group)
    population: int = 1                      # members trained together, seeds seed .. seed + population - 1

    def check(self, prefix: str | None = None) -> "TrainConfig":
        self._check_world()
        self.policy.check()
        if self.policy.kind != "learned":
            _fail("policy", f"{self.policy.name} is rule-based: there is nothing to train (evaluate it with "
                            f"scripts/evaluate.py policy={self.policy.id})")
        if self.algo is None:
            _fail("algo", f"policy {self.policy.id} selects no learner")
        self.algo = algo_config(self.algo)
        self.experiment.check()
        if self.experiment.swarm_sizes and self.algo.name not in ("sac", "ddpg"):
            _fail("experiment.swarm_sizes", f"needs an off-policy learner (sac, ddpg): {self.policy.id} trains "
                                            f"with {self.algo.name}")
        self.logger.check()
        self.train_scenario  # noqa: B018 - the training env's scenario is checked too
        check_seed("seed", self.seed)
        check_device("device", self.device)
        check_threads("threads", self.threads)
        choice("resume", str(self.resume).lower(), RESUME_MODES)
        choice("compile", str(self.compile).lower(), COMPILE_MODES)
        choice("objective", self.objective, OBJECTIVES)
        self._check_population()
        return self._mark_checked()

    def _check_population(self) -> None:
        """A population (``population > 1``) trains SAC or DDPG, one swarm size, in this process."""
        count("population", self.population, 1, MAX_POPULATION)
        check_seed("seed", self.seed + self.population - 1)
        if self.population == 1:
            return
        if self.algo.name not in ("sac", "ddpg"):
            _fail("population", f"a population trains an off-policy learner (sac, ddpg); {self.policy.id} trains "
                                f"with {self.algo.name}: use population=1")
        if self.experiment.swarm_sizes:
            _fail("population", "a population trains one swarm size; experiment.swarm_sizes (mixed sizes) needs "
                                "population=1")
        if self.experiment.workers != 1:
            _fail("population", f"a population steps its worlds in this process; experiment.workers must be 1, "
                                f"got {self.experiment.workers}")
        if self.compile_loss:
            _fail("population", "a population's update runs eagerly (torch.vmap over its members): use compile=false "
                                "or compile=step")

    @property
    def seeds(self) -> list[int]:
        """The members' seeds: ``seed .. seed + population - 1``."""
        return list(range(self.seed, self.seed + self.population))

    @property
    def compile_step(self) -> bool:
        """``compile`` is ``true`` or ``step``: the env's step is compiled (``world/lanes.py``)."""
        return str(self.compile).lower() in ("true", "step")

    @property
    def compile_loss(self) -> bool:
        """``compile`` is ``true`` or ``loss``: the learner's loss is compiled."""
        return str(self.compile).lower() in ("true", "loss")

    @property
    def train_scenario(self) -> ScenarioConfig:
        """The scenario plus the experiment's ``train_env`` recipe (the training env's world)."""
        if not self.experiment.train_env:
            return self.scenario
        try:
            return dataclasses.replace(self.scenario, **dict(self.experiment.train_env)).check()
        except ConfigError as exc:
            raise ConfigError(f"experiment.train_env ({exc.key})", exc.message) from exc

    @property
    def train_scenarios(self) -> list[ScenarioConfig]:
        """The training envs' scenarios: one per ``experiment.swarm_sizes`` entry (or one)."""
        base = self.train_scenario
        return [dataclasses.replace(base, n_uavs=n) for n in self.experiment.swarm_sizes] or [base]

    @property
    def resume_mode(self) -> str:
        """``never``, ``always`` or ``auto``."""
        return {"false": "never", "true": "always", "auto": "auto"}[str(self.resume).lower()]


RESUME_MODES = ("false", "true", "auto")
# Members of one population (each holds its own networks, optimiser state and replay buffer).
MAX_POPULATION = 64
# What `compile` may be: nothing, both, or one of the env's step and the learner's loss.
COMPILE_MODES = ("false", "true", "step", "loss")
# What the train app returns to a sweeper (Optuna, Ax): a metric of the run's final evaluation.
OBJECTIVES = ("success_rate", "safe_success_rate", "return")


@dataclass
class EvaluateConfig(WorldApp):
    """``conf/evaluate.yaml``: one policy (or a checkpoint), one scenario, the section 5 protocol."""

    policy: PolicyConfig = field(default_factory=PolicyConfig)
    algo: Any = None
    checkpoint: Optional[str] = None         # a checkpoint file instead of the shipped ones
    contender: Any = None                    # a controller of the user's instead (registry.contender_handle)
    episodes: int = MISSING
    seed: int = MISSING
    device: str = MISSING
    threads: int = MISSING
    max_steps: Optional[int] = None

    def check(self, prefix: str | None = None) -> "EvaluateConfig":
        self.policy.check()
        if self.checkpoint is not None and self.contender is not None:
            _fail("contender", "evaluates one controller: give checkpoint= or contender=, not both")
        _check_contender("contender", self.contender)
        if self.max_steps is not None:
            count("max_steps", self.max_steps, 1, 10**7)
            self.scenario = dataclasses.replace(self.scenario, max_steps=self.max_steps)
        self._check_world()
        _check_run(self)
        return self._mark_checked()


def is_file_target(text: str) -> bool:
    """``path/to/file.py:function``: a contender's factory given as a file and a function."""
    return bool(re.fullmatch(r".+\.py:[A-Za-z_][A-Za-z0-9_]*", text))


def contender_name(spec: Any) -> str:
    """A contender's row name: a mapping's ``name``, else the function's, or its module's (file's)
    for ``make`` / ``build`` / ``create`` / ``factory``; a checkpoint's file stem."""
    if isinstance(spec, Mapping):
        if spec.get("name"):
            return str(spec["name"])
        spec = spec.get("_target_", "")
    target = str(spec)
    if target.endswith(".pt"):
        return Path(target).stem
    where, _, function = target.rpartition(":" if is_file_target(target) else ".")
    if function not in ("make", "build", "create", "factory"):
        return function
    return Path(where).stem if is_file_target(target) else where.rpartition(".")[2] or function


def evaluated_name(policy_id: Any, contender: Any = None) -> str:
    """The evaluate app's folder for what it evaluates: the policy's id, or
    ``contender-<name>`` when a contender flies (``${flock.evaluated:...}`` in conf/evaluate.yaml)."""
    if contender is None or contender == "":
        return str(policy_id)
    if isinstance(contender, DictConfig):
        contender = OmegaConf.to_container(contender, resolve=True)
    return "contender-" + safe_name(contender_name(contender))


def _check_contender(key: str, spec: Any) -> None:
    """A contender's shape (a string, or a mapping with a string ``_target_``); whether it
    imports or loads is the registry's check, made before the first episode."""
    if spec is None or isinstance(spec, str) and spec:
        return
    if isinstance(spec, Mapping) and isinstance(spec.get("_target_"), str) and spec["_target_"]:
        return
    _fail(key, "a checkpoint path, a factory's import path (pkg.module.make or file.py:make) or a mapping with "
               f"_target_; got {spec!r}")


def _check_run(cfg: Any) -> None:
    """The fields every evaluating app shares: episodes, seed, device, threads."""
    count("episodes", cfg.episodes, 1, 10**7)
    check_seed("seed", cfg.seed)
    check_device("device", cfg.device)
    check_threads("threads", cfg.threads)


@dataclass
class ReproduceConfig(WorldApp):
    """``conf/reproduce.yaml``: one of the paper's tables (the reading: ``scenario.reading``)."""

    table: int = MISSING
    episodes: int = MISSING
    seed: int = MISSING
    device: str = MISSING
    threads: int = MISSING
    only: List[str] = field(default_factory=list)
    contenders: List[Any] = field(default_factory=list)  # the user's controllers, as extra rows
    recipe: str = MISSING                    # fast: checkpoints_dir; paper: paper_recipe_dir (Table III)
    episodes_csv: bool = MISSING
    compare_to: Optional[str] = None         # a table CSV written before: also written side by side
    compare_tolerance: Dict[str, float] = field(default_factory=dict)

    def check(self, prefix: str | None = None) -> "ReproduceConfig":
        self._check_world()
        choice("table", self.table, (3, 4, 5))
        choice("recipe", self.recipe, ("fast", "paper"))
        check_tolerance(self.compare_tolerance)
        if self.recipe == "paper" and self.table != 3:
            _fail("recipe", "the paper recipe trained the policies of Table III only (table=3)")
        for i, spec in enumerate(self.contenders):
            _check_contender(f"contenders[{i}]", spec)
        _check_run(self)
        return self._mark_checked()


# What reproduce's compare_to= puts side by side (report/compare.py): success rates are
# fractions, distances m, speeds m/s, times s.
COMPARED = ("success_rate", "safe_success_rate", "d_min_uav", "d_min_obs", "d_c", "speed", "t_goal")


def check_tolerance(tolerance: Mapping[str, float]) -> dict[str, float]:
    """``compare_tolerance``: compared columns -> a largest difference >= 0."""
    out = {}
    for key, value in dict(tolerance).items():
        if key not in COMPARED:
            _fail(f"compare_tolerance.{key}", f"not a compared column; one of {', '.join(COMPARED)}")
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not value >= 0:
            _fail(f"compare_tolerance.{key}", f"must be a number >= 0; got {value!r}")
        out[key] = float(value)
    return out


@dataclass
class FiguresConfig(WorldApp):
    """``conf/figures.yaml``: the paper's figures (the reading: ``scenario.reading``)."""

    figs: List[int] = MISSING
    seed: int = MISSING
    device: str = MISSING
    threads: int = MISSING

    def check(self, prefix: str | None = None) -> "FiguresConfig":
        self._check_world()
        if not self.figs or any(f not in (4, 5, 6) for f in self.figs):
            _fail("figs", f"a list of 4, 5 and 6, got {list(self.figs)}")
        check_seed("seed", self.seed)
        check_device("device", self.device)
        check_threads("threads", self.threads)
        return self._mark_checked()


@dataclass
class ScalingConfig(WorldApp):
    """``conf/scaling.yaml``: one shipped policy flown by larger swarms."""

    policy_name: str = MISSING
    others: List[str] = field(default_factory=list)   # more policies (ids, checkpoint files) as extra rows
    sizes: List[int] = MISSING
    episodes: int = MISSING
    seed: int = MISSING
    device: str = MISSING
    threads: int = MISSING

    def check(self, prefix: str | None = None) -> "ScalingConfig":
        self._check_world()
        if not self.sizes:
            _fail("sizes", "a list of swarm sizes, got []")
        for n in self.sizes:
            count("sizes", n, 1, MAX_UAVS)
        _check_run(self)
        return self._mark_checked()


@dataclass
class TuneConfig(WorldApp):
    """``conf/tune_baselines.yaml``: the rule-based baselines' grid search."""

    controllers: List[str] = MISSING
    episodes: int = MISSING
    max_steps: int = MISSING
    seed: int = MISSING
    threads: int = MISSING
    evaluate: bool = MISSING
    scenarios: List[str] = MISSING

    def check(self, prefix: str | None = None) -> "TuneConfig":
        self._check_world()
        count("episodes", self.episodes, 1, 10**7)
        count("max_steps", self.max_steps, 1, 10**7)
        check_seed("seed", self.seed)
        check_threads("threads", self.threads)
        for name in self.scenarios:
            choice("scenarios", name, available("scenario"))
        return self._mark_checked()


@dataclass
class ShipConfig(WorldApp):
    """``conf/ship.yaml``: the named step that exports finished runs into ``checkpoints/``."""

    experiment: str = MISSING
    runs_dir: str = MISSING
    paper_experiment: str = MISSING
    collections: Dict[str, str] = field(default_factory=dict)  # experiment -> folder under <checkpoints>/<reading>/

    def check(self, prefix: str | None = None) -> "ShipConfig":
        self._check_world()
        folder_name("experiment", self.experiment)
        folder_name("paper_experiment", self.paper_experiment)
        for experiment, folder in self.collections.items():
            folder_name(f"collections.{experiment}", experiment)
            folder_name(f"collections.{experiment}", folder)
        return self._mark_checked()


APP_SCHEMAS: dict[str, type[Schema]] = {
    "train": TrainConfig, "evaluate": EvaluateConfig, "reproduce": ReproduceConfig, "figures": FiguresConfig,
    "scaling": ScalingConfig, "tune_baselines": TuneConfig, "ship": ShipConfig,
}


def register_schemas() -> None:
    """Put every schema in Hydra's ConfigStore as a root config (``<name>_schema``): the YAMLs
    name them in their defaults lists (a group's file as ``/scenario_schema@_here_``), so they
    type the composition without appearing among a group's choices."""
    from hydra.core.config_store import ConfigStore

    cs = ConfigStore.instance()
    cs.store(name="scenario_schema", node=ScenarioConfig)
    cs.store(name="policy_schema", node=PolicyConfig)
    for name, schema in ALGO_SCHEMAS.items():
        cs.store(name=f"{name}_schema", node=schema)
    cs.store(name="experiment_schema", node=ExperimentConfig)
    cs.store(name="logger_schema", node=LoggerConfig)
    for app, schema in APP_SCHEMAS.items():
        cs.store(name=f"{app}_schema", node=schema)


register_schemas()


# ---------------------------------------------------------------------------- the composer
def compose(config_name: str, overrides: Sequence[str] = (), return_hydra_config: bool = False) -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with Hydra's compose API and command-line style
    ``overrides``, as ``hydra.main`` does for the scripts.

    Safe inside a running Hydra app: the app's global Hydra state is put back afterwards.
    Errors become :class:`ConfigError` (Hydra's message, the key where there is one).
    """
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.errors import HydraException
    from hydra.initialize import get_gh_backup, restore_gh_from_backup

    backup = get_gh_backup()
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
            return hydra_compose(config_name, overrides=list(overrides), return_hydra_config=return_hydra_config)
    except OmegaConfBaseException as exc:
        raise config_error(exc) from exc
    except HydraException as exc:
        cause = exc.__cause__
        if isinstance(cause, OmegaConfBaseException):
            raise config_error(cause) from exc
        # Hydra's message up to its (long) listing of the config search path.
        raise ConfigError(_hydra_key(exc), " ".join(str(exc).split("Config search path")[0].split())) from exc
    finally:
        restore_gh_from_backup(backup)


def _hydra_key(exc: BaseException) -> str:
    """The config group or key a Hydra error is about, from its attributes."""
    missing = getattr(exc, "missing_cfg_file", None)
    if missing:
        return str(missing).rpartition("/")[0] or str(missing)
    return ""


def available(group: str) -> list[str]:
    """The choices of a config group in the package's ``conf/`` (YAML stems)."""
    folder = CONF_DIR / group
    return sorted(p.stem for p in folder.glob("*.yaml")) if group and folder.is_dir() else []


@functools.lru_cache(maxsize=1)
def _world_values() -> DictConfig:
    return OmegaConf.load(CONF_DIR / "world.yaml")


# The evaluation seed every policy shares (docs/specification.md section 5): conf/world.yaml.
EVAL_SEED: int = int(_world_values().eval_seed)


def default_checkpoints_dir() -> Path:
    """Where the shipped checkpoints are (``checkpoints_dir`` of conf/world.yaml)."""
    return Path(str(_world_values().checkpoints_dir))


# ---------------------------------------------------------------------------- scenarios
def scenario_overrides(scenario: str = "train", reading: str | None = None, policy: str | None = None) -> list[str]:
    """The override strings that select a scenario, a reading and (optionally) a policy."""
    overrides = [f"scenario={scenario}"]
    if reading is not None:
        overrides.append(f"reading={reading}")
    if policy is not None:
        overrides.append(f"policy={policy}")
    return overrides


def compose_world(scenario: str = "train", reading: str | None = None, policy: str | None = None,
                  overrides: Sequence[str] = ()) -> DictConfig:
    """``conf/world.yaml``: a scenario, a reading and optionally a policy, composed by Hydra."""
    return compose("world", [*scenario_overrides(scenario, reading, policy), *overrides])


def scenario_config(scenario: str | Mapping[str, Any] | DictConfig | ScenarioConfig = "train",
                    reading: str | None = None, policy: str | None = None, **fields: Any) -> ScenarioConfig:
    """A checked :class:`ScenarioConfig`.

    Args:
        scenario: a name under ``conf/scenario/`` (composed with the reading and policy by
            Hydra), or a complete scenario (mapping, DictConfig or ScenarioConfig).
        reading: ``literal`` or ``paper_fit`` (default: the one ``conf/world.yaml`` selects).
        policy: a policy id whose scenario fields (``fov``, ``instinct`` ...) apply.
        **fields: any scenario field, applied last.
    """
    unknown = sorted(set(fields) - SCENARIO_FIELDS)
    if unknown:
        raise ConfigError(f"scenario.{unknown[0]}", f"unknown field; known: {', '.join(sorted(SCENARIO_FIELDS))}")
    if isinstance(scenario, str):
        node: Any = compose_world(scenario.lower(), reading, policy).scenario
    else:
        if reading is not None or policy is not None:
            raise ConfigError("scenario", "reading= and policy= select YAMLs; pass them with a scenario name")
        if isinstance(scenario, ScenarioConfig) and not fields:
            return ScenarioConfig.from_config(scenario)
        node = dataclasses.asdict(scenario) if isinstance(scenario, ScenarioConfig) else scenario
    try:
        node = OmegaConf.merge(OmegaConf.structured(ScenarioConfig), node)
        for name, value in fields.items():
            OmegaConf.update(node, name, value, merge=False)
    except OmegaConfBaseException as exc:
        raise config_error(exc, "scenario") from exc
    return ScenarioConfig.from_config(node)


def saved_scenario(saved: Mapping[str, Any]) -> dict[str, Any]:
    """A scenario a checkpoint or a run folder saved, as this version's fields: fields added
    since (e.g. the drawn obstacles) take the training scenario's values of its reading
    (conf/scenario/train.yaml), which mean "as it was"."""
    missing = SCENARIO_FIELDS - set(saved)
    if not missing:
        return dict(saved)
    base = compose_world("train", str(saved.get("reading", "paper_fit"))).scenario
    return {**{k: OmegaConf.to_container(base, resolve=True)[k] for k in missing}, **dict(saved)}


def plain(cfg: Any) -> Any:
    """A config as plain, resolved Python containers (for saving and logging)."""
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)
    if dataclasses.is_dataclass(cfg) and not isinstance(cfg, type):
        return dataclasses.asdict(cfg)
    return cfg


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}`` (lists stay values): hyperparameters for loggers."""
    out: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten(value, f"{name}."))
        else:
            out[name] = value
    return out


__all__ = [
    "ALGO_SCHEMAS", "APP_SCHEMAS", "BenchmarkConfig", "COMPARED", "COMPILE_MODES", "CONF_DIR", "ConfigError",
    "DDPGConfig", "EVAL_SEED",
    "EvaluateConfig", "ExperimentConfig", "FiguresConfig", "LoggerConfig", "MAX_SEED", "OBJECTIVES",
    "POLICY_SCENARIO_FIELDS", "PPOConfig", "PolicyConfig", "READINGS", "ReproduceConfig", "SACConfig",
    "SCENARIO_FIELDS", "ScalingConfig", "ScenarioConfig", "Schema", "ShipConfig", "TrainConfig", "TuneConfig",
    "WorldApp",
    "algo_config", "available", "check_device", "check_seed", "check_tolerance", "compose", "compose_world",
    "config_dir",
    "default_checkpoints_dir", "saved_scenario", "shipped_checkpoints_dir",
    "config_error", "contender_name", "evaluated_name", "flatten", "is_file_target", "plain", "run_name",
    "safe_name", "scenario_config", "selection_dir",
]
