"""Scenario configuration: one dataclass whose fields are the YAML keys of ``conf/scenario/``.

Every number of SPEC sections 1-6 is a default here *and* in the YAML files; a test composes
each YAML against this dataclass so the two cannot drift. :func:`validate_scenario` rejects
bad values with an error that names the field, before any tensor is built.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, List, Mapping

from omegaconf import DictConfig, OmegaConf

CONF_DIR = Path(__file__).resolve().parent.parent / "conf"


def _register_resolvers() -> None:
    # ``${pi:0.5}`` = 0.5 pi, so YAML files can state angles as the paper does.
    if not OmegaConf.has_resolver("pi"):
        OmegaConf.register_new_resolver("pi", lambda k=1.0: float(k) * math.pi)


_register_resolvers()


class ConfigError(ValueError):
    """A configuration value is invalid; the message names the field."""


@dataclass
class ScenarioConfig:
    """The world of SPEC sections 1-6 (defaults: the training scenario)."""

    name: str = "train"
    # --- world (SPEC section 1)
    n_uavs: int = 5
    dt: float = 0.2
    max_steps: int = 500
    tau_v: float = 1.0
    v_max: float = 3.0
    goal_radius: float = 1.0
    collision_distance: float = 0.5
    uav_collision_terminates: bool = False
    heading_speed_threshold: float = 0.05
    # --- sensors (SPEC section 2)
    camera_range: float = 5.0
    fov: float = 0.5 * math.pi
    n_beams: int = 36
    laser_range: float = 10.0
    n_scan: int = 3
    n_cam: int = 3
    goal_scale: float = 80.0
    # --- instinct (SPEC section 3)
    instinct: bool = False
    tangential: bool = True
    rep_gain: float = 1.0
    rep_range: float = 5.0
    safe_distance: float = 2.0
    # --- action interface: "policy" (Eq. 19-20, actions in [-1, 1]^2) or "velocity" (the
    # action is the velocity command itself, in [-v_max, v_max]^2: the rule-based baselines)
    action_mode: str = "policy"
    # --- reward (SPEC section 4); "scan" or "min_uav_scan" (Policy4-G)
    collision_reward_source: str = "scan"
    # --- starts, goals and obstacles (SPEC sections 1, 6)
    area_center: List[float] = field(default_factory=lambda: [40.0, 40.0])
    area_size: float = 80.0
    d_env: float = 40.0
    spawn_radius: float = 3.0
    spawn_separation: float = 1.0
    spawn_clearance: float = 1.0
    spawn_max_tries: int = 200
    circles: List[List[float]] = field(default_factory=lambda: [[40.0, 40.0, 6.0]])
    rectangles: List[List[float]] = field(
        default_factory=lambda: [[10.0, 40.0, 6.0, 16.0], [70.0, 40.0, 6.0, 16.0]]
    )
    # --- moving circles (S5)
    n_moving: int = 0
    moving_radius: float = 3.0
    moving_speed: float = 0.5
    moving_clearance: float = 8.0
    moving_box: List[float] = field(default_factory=lambda: [10.0, 70.0])
    # --- observation noise (S4)
    noise: bool = False
    noise_scan: float = 0.1
    noise_distance: float = 0.2
    noise_angle: float = 0.05


SCENARIO_FIELDS = frozenset(f.name for f in dataclasses.fields(ScenarioConfig))
COLLISION_REWARD_SOURCES = ("scan", "min_uav_scan")
ACTION_MODES = ("policy", "velocity")

# Random sequential placement jams near 0.55 area fraction; well below it, rejection
# sampling converges in a handful of rounds. Above it we refuse at config time.
MAX_SPAWN_DENSITY = 0.4


def available_scenarios() -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / "scenario").glob("*.yaml"))


def _fail(field_name: str, message: str) -> None:
    raise ConfigError(f"scenario field '{field_name}': {message}")


def _positive(cfg: ScenarioConfig, *names: str) -> None:
    for name in names:
        value = getattr(cfg, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            _fail(name, f"must be a positive finite number, got {value!r}")


def spawn_density(cfg: ScenarioConfig) -> float:
    """Area fraction of the spawn disc taken by the UAVs' exclusion discs."""
    half = cfg.spawn_separation / 2
    return cfg.n_uavs * half**2 / (cfg.spawn_radius + half) ** 2


def _rect_rect_overlap(a: List[float], b: List[float]) -> bool:
    return abs(a[0] - b[0]) < (a[2] + b[2]) / 2 and abs(a[1] - b[1]) < (a[3] + b[3]) / 2


def _circle_rect_overlap(c: List[float], r: List[float]) -> bool:
    dx = max(abs(c[0] - r[0]) - r[2] / 2, 0.0)
    dy = max(abs(c[1] - r[1]) - r[3] / 2, 0.0)
    return math.hypot(dx, dy) < c[2]


def validate_scenario(cfg: ScenarioConfig) -> ScenarioConfig:
    """Check every field; raise :class:`ConfigError` naming the first bad one."""
    if not isinstance(cfg.n_uavs, int) or isinstance(cfg.n_uavs, bool) or cfg.n_uavs < 1:
        _fail("n_uavs", f"must be an integer >= 1, got {cfg.n_uavs!r}")
    _positive(cfg, "dt", "tau_v", "v_max", "goal_radius", "camera_range", "laser_range")
    _positive(cfg, "area_size", "goal_scale", "spawn_radius", "rep_range")
    for name in ("max_steps", "n_beams", "n_scan", "n_cam", "spawn_max_tries"):
        v = getattr(cfg, name)
        if not isinstance(v, int) or isinstance(v, bool) or v < 1:
            _fail(name, f"must be an integer >= 1, got {v!r}")
    if cfg.n_scan > cfg.n_beams:
        _fail("n_scan", f"cannot exceed n_beams={cfg.n_beams}")
    if not (isinstance(cfg.fov, (int, float)) and 0 < cfg.fov <= 2 * math.pi + 1e-9):
        _fail("fov", f"must lie in (0, 2 pi], got {cfg.fov!r}")
    for name in ("collision_distance", "safe_distance", "rep_gain", "heading_speed_threshold",
                 "spawn_separation", "spawn_clearance", "d_env", "noise_scan", "noise_distance",
                 "noise_angle", "moving_speed", "moving_clearance"):
        v = getattr(cfg, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            _fail(name, f"must be a finite number >= 0, got {v!r}")
    if cfg.collision_reward_source not in COLLISION_REWARD_SOURCES:
        _fail("collision_reward_source", f"must be one of {COLLISION_REWARD_SOURCES}, got {cfg.collision_reward_source!r}")
    if cfg.action_mode not in ACTION_MODES:
        _fail("action_mode", f"must be one of {ACTION_MODES}, got {cfg.action_mode!r}")
    if len(cfg.area_center) != 2:
        _fail("area_center", "must be [x, y]")
    for i, c in enumerate(cfg.circles):
        if len(c) != 3 or c[2] <= 0:
            _fail("circles", f"entry {i} must be [cx, cy, radius > 0], got {list(c)}")
    for i, r in enumerate(cfg.rectangles):
        if len(r) != 4 or r[2] <= 0 or r[3] <= 0:
            _fail("rectangles", f"entry {i} must be [cx, cy, width > 0, height > 0], got {list(r)}")
    for i, a in enumerate(cfg.circles):
        for j, b in enumerate(cfg.circles[i + 1:], i + 1):
            if math.hypot(a[0] - b[0], a[1] - b[1]) < a[2] + b[2]:
                _fail("circles", f"circles {i} and {j} overlap")
        for j, r in enumerate(cfg.rectangles):
            if _circle_rect_overlap(a, r):
                _fail("circles", f"circle {i} overlaps rectangle {j}")
    for i, a in enumerate(cfg.rectangles):
        for j, b in enumerate(cfg.rectangles[i + 1:], i + 1):
            if _rect_rect_overlap(a, b):
                _fail("rectangles", f"rectangles {i} and {j} overlap")
    if not isinstance(cfg.n_moving, int) or cfg.n_moving < 0:
        _fail("n_moving", f"must be an integer >= 0, got {cfg.n_moving!r}")
    if cfg.n_moving:
        _positive(cfg, "moving_radius")
        if len(cfg.moving_box) != 2 or not cfg.moving_box[0] < cfg.moving_box[1]:
            _fail("moving_box", f"must be [low, high] with low < high, got {list(cfg.moving_box)}")
    density = spawn_density(cfg)
    if density > MAX_SPAWN_DENSITY:
        _fail(
            "n_uavs",
            f"{cfg.n_uavs} UAVs at least {cfg.spawn_separation} m apart in a disc of radius "
            f"{cfg.spawn_radius} m fill {density:.2f} of it (limit {MAX_SPAWN_DENSITY}); "
            "raise spawn_radius or lower n_uavs / spawn_separation",
        )
    return cfg


def _load_scenario_yaml(name: str) -> DictConfig:
    """Load ``conf/scenario/<name>.yaml``, applying its Hydra ``defaults`` list as Hydra would."""
    path = CONF_DIR / "scenario" / f"{name}.yaml"
    if not path.is_file():
        raise ConfigError(f"unknown scenario {name!r}; available: {available_scenarios()}")
    own = OmegaConf.load(path)
    defaults = own.pop("defaults", [])
    parts = [_load_scenario_yaml(str(d)) if d != "_self_" else own for d in defaults]
    if "_self_" not in defaults:
        parts.append(own)
    return OmegaConf.merge(*parts)


def load_scenario(scenario: str | Mapping[str, Any] | DictConfig | ScenarioConfig = "train",
                  **overrides: Any) -> ScenarioConfig:
    """Build a validated :class:`ScenarioConfig`.

    Args:
        scenario: a name under ``conf/scenario/`` (``"train"``, ``"s1"`` ... ``"s5"``,
            ``"tau_v"``), a mapping / DictConfig of fields, or a ScenarioConfig.
        **overrides: any scenario field, e.g. ``fov=math.pi, n_uavs=9``.
    """
    if isinstance(scenario, ScenarioConfig):
        base: dict[str, Any] = dataclasses.asdict(scenario)
    elif isinstance(scenario, str):
        base = OmegaConf.to_container(_load_scenario_yaml(scenario.lower()), resolve=True)  # type: ignore[assignment]
    else:
        if isinstance(scenario, DictConfig):
            scenario = OmegaConf.to_container(scenario, resolve=True)  # type: ignore[assignment]
        base = dict(scenario)  # type: ignore[arg-type]
    unknown = sorted((set(base) | set(overrides)) - SCENARIO_FIELDS)
    if unknown:
        raise ConfigError(f"unknown scenario field(s) {unknown}; known fields: {sorted(SCENARIO_FIELDS)}")
    merged = {**base, **overrides}
    # Typed merge: OmegaConf checks types against the dataclass and names the bad key.
    try:
        structured = OmegaConf.merge(OmegaConf.structured(ScenarioConfig), merged)
    except Exception as exc:  # omegaconf.ValidationError and friends
        raise ConfigError(f"invalid scenario config: {exc}") from exc
    cfg: ScenarioConfig = OmegaConf.to_object(structured)  # type: ignore[assignment]
    return validate_scenario(cfg)
