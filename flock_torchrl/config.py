"""Configuration: the schema of every Hydra group, and the one composer.

Every value lives once, in the YAML files under ``conf/``; the dataclasses below give each
group its fields, types and checks (their fields are ``MISSING``: a YAML that forgets one
fails when it is composed). :func:`register_schemas` puts them in Hydra's ConfigStore, where
each group's YAML names its schema in its defaults list, so Hydra itself type-checks every
file, every composition and every command-line override.

:func:`compose` is the only way configs are built, for the scripts (``hydra.main``) and for
Python callers alike: it runs Hydra's compose API on the same ``conf/``. What
``--cfg job`` prints is therefore what runs, and what a run saves as ``config.yaml``.

Checks that need more than a type (ranges, enumerations, feasibility) live in the
``check_*`` functions; each raises :class:`ConfigError` naming the dotted key, e.g.
``scenario.n_uavs: must be an integer >= 1, got 0``. See ``docs/specification.md`` for what
every scenario field means.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence

from omegaconf import MISSING, DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException


class ConfigError(ValueError):
    """A configuration value is invalid. ``key`` is the dotted name of the field."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}" if key else message)
        self.key = key
        self.message = message


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


# ---------------------------------------------------------------------------- resolvers
def _register_resolvers() -> None:
    # ``${pi:0.5}`` = 0.5 pi: angles written as the paper writes them.
    if not OmegaConf.has_resolver("pi"):
        OmegaConf.register_new_resolver("pi", lambda k=1.0: float(k) * math.pi)
    # ``${flock.run_name:seed0,<override_dirname>}``: a run folder name that shows its overrides.
    if not OmegaConf.has_resolver("flock.run_name"):
        OmegaConf.register_new_resolver("flock.run_name", run_name)


def run_name(base: Any, overrides: Any = "") -> str:
    """``seed0`` or ``seed0__algo.lr_actor=0.001,scenario.tau_v=0.5``: the folder of one run.

    ``overrides`` is Hydra's ``override_dirname`` (the task overrides that are not already in
    the path, sorted); slashes would nest folders, so they become ``-``.
    """
    overrides = str(overrides or "")
    name = str(base) + (f"__{overrides}" if overrides else "")
    return name.replace("/", "-")


_register_resolvers()


# ---------------------------------------------------------------------------- schemas
@dataclass
class ScenarioConfig:
    """The world (docs/specification.md sections 1-6, 9). Values: ``conf/scenario/*.yaml``
    (the world), ``conf/reading/*.yaml`` (the reading's fields), ``conf/policy/*.yaml``
    (the policy's sensing, instinct and reward variant)."""

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
    circles: List[List[float]] = MISSING     # [cx, cy, radius]
    rectangles: List[List[float]] = MISSING  # [cx, cy, width_x, height_y]
    # --- moving circles (S5)
    n_moving: int = MISSING
    moving_radius: float = MISSING
    moving_speed: float = MISSING
    moving_clearance: float = MISSING
    moving_box: List[float] = MISSING
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


SCENARIO_FIELDS = frozenset(f.name for f in dataclasses.fields(ScenarioConfig))
# The scenario fields a policy YAML sets (its sensing, instinct, reward variant, action
# interface): a checkpoint records them, and evaluation applies them in any scenario.
POLICY_SCENARIO_FIELDS = ("fov", "instinct", "tangential", "collision_reward_source", "action_mode")
READINGS = ("literal", "paper_fit")


@dataclass
class PolicyConfig:
    """One of the twelve policies (section 7); its scenario fields sit in the YAML's ``scenario:``."""

    id: str = MISSING                        # the YAML's stem, e.g. policy3_g
    name: str = MISSING                      # the paper's name, e.g. Policy3-G
    kind: str = MISSING                      # learned | rule
    critic_input: Optional[str] = None       # observation | state (learned policies)
    controller: Optional[str] = None         # olfati_saber | vasarhelyi (rule-based policies)
    params: Dict[str, Any] = field(default_factory=dict)  # the controller's parameters


@dataclass
class SACConfig:
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


@dataclass
class DDPGConfig:
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


@dataclass
class PPOConfig:
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


ALGO_SCHEMAS: dict[str, type] = {"sac": SACConfig, "ddpg": DDPGConfig, "ppo": PPOConfig}


@dataclass
class ExperimentConfig:
    """How long and how fast to train; its learner tuning is the ``tuning`` group."""

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


@dataclass
class LoggerConfig:
    backend: str = MISSING                   # csv | wandb | tensorboard | none
    project: str = MISSING
    mode: str = MISSING                      # wandb: offline | online


@dataclass
class TrainConfig:
    """``conf/train.yaml``: one training run."""

    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    algo: Any = None
    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    seed: int = MISSING
    device: str = MISSING
    eval_seed: int = MISSING
    resume: Any = MISSING                    # false | true | auto | <run folder>
    progress: bool = MISSING
    threads: int = MISSING
    compile: bool = MISSING                  # torch.compile the learner's update (eager twin: false)


@dataclass
class EvaluateConfig:
    """``conf/evaluate.yaml``: one policy, one scenario, the section 5 protocol."""

    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    algo: Any = None
    checkpoint: Optional[str] = None         # a checkpoint file instead of the shipped ones
    checkpoints_dir: str = MISSING           # shipped checkpoints: <dir>/<reading>/<policy>/seed<k>.pt
    episodes: int = MISSING
    seed: int = MISSING
    device: str = MISSING
    threads: int = MISSING
    max_steps: Optional[int] = None


@dataclass
class ReproduceConfig:
    """``conf/reproduce.yaml``: one of the paper's tables (the reading: ``scenario.reading``)."""

    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    table: int = MISSING
    episodes: int = MISSING
    seed: int = MISSING
    device: str = MISSING
    threads: int = MISSING
    checkpoints_dir: str = MISSING
    only: List[str] = field(default_factory=list)
    episodes_csv: bool = MISSING
    paper_run: Optional[str] = None          # Table III: a checkpoint of the paper's own recipe, its own row


@dataclass
class FiguresConfig:
    """``conf/figures.yaml``: the paper's figures (the reading: ``scenario.reading``)."""

    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    figs: List[int] = MISSING
    checkpoints_dir: str = MISSING
    seed: int = MISSING
    device: str = MISSING
    threads: int = MISSING
    paper_run: Optional[str] = None


def register_schemas() -> None:
    """Put every schema in Hydra's ConfigStore (the YAMLs name them in their defaults lists)."""
    from hydra.core.config_store import ConfigStore

    cs = ConfigStore.instance()
    cs.store(group="scenario", name="scenario_schema", node=ScenarioConfig)
    cs.store(group="policy", name="policy_schema", node=PolicyConfig, package="policy")
    for name, schema in ALGO_SCHEMAS.items():
        cs.store(group="algo", name=f"{name}_schema", node=schema)
    cs.store(group="experiment", name="experiment_schema", node=ExperimentConfig)
    cs.store(group="logger", name="logger_schema", node=LoggerConfig)
    cs.store(name="train_schema", node=TrainConfig)
    cs.store(name="evaluate_schema", node=EvaluateConfig)
    cs.store(name="reproduce_schema", node=ReproduceConfig)
    cs.store(name="figures_schema", node=FiguresConfig)


register_schemas()


# ---------------------------------------------------------------------------- the composer
def compose(config_name: str, overrides: Sequence[str] = (), return_hydra_config: bool = False) -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with Hydra's compose API and command-line style
    ``overrides`` — the same composition ``hydra.main`` performs for the scripts.

    Safe inside a running Hydra app: the app's global Hydra state is put back afterwards.
    Errors become :class:`ConfigError` with Hydra's message.
    """
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.errors import HydraException
    from hydra.initialize import get_gh_backup, restore_gh_from_backup

    choices = {}
    for item in overrides:
        key, sep, value = str(item).lstrip("+~").partition("=")
        if sep and "/" not in key and "." not in key and (CONF_DIR / key).is_dir():
            choices[key] = value
            if value not in ("null", "None") and "," not in value and value not in available(key):
                raise ConfigError(key, f"unknown choice {value!r}; available: {', '.join(available(key))}")
    backup = get_gh_backup()
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
            return hydra_compose(config_name, overrides=list(overrides), return_hydra_config=return_hydra_config)
    except (HydraException, OmegaConfBaseException) as exc:
        if "${algo}" in str(exc) and "policy" in choices:  # a rule-based policy selects no learner
            raise ConfigError("policy", f"{choices['policy']} is rule-based: there is nothing to train (evaluate "
                                        f"it with scripts/evaluate.py policy={choices['policy']})") from exc
        raise config_error_from(exc) from exc
    finally:
        restore_gh_from_backup(backup)


def config_error_from(exc: BaseException) -> ConfigError:
    """One readable :class:`ConfigError` from a Hydra / OmegaConf exception."""
    if isinstance(exc, ConfigError):
        return exc
    cause: BaseException = exc
    while cause.__cause__ is not None and not isinstance(cause, OmegaConfBaseException):
        cause = cause.__cause__
    key = str(getattr(cause, "full_key", "") or "")
    text = str(cause).strip().splitlines()[0] if str(cause).strip() else type(cause).__name__
    match = re.match(r"Value '(.*?)'(?: of type '\w+')? could not be converted to (\w+)", text)
    if match:
        return ConfigError(key, f"expected {_article(match.group(2))}, got {match.group(1)!r}")
    match = re.search(r"Key '(.+?)' not in '(\w+)'", text)
    if match:
        return ConfigError(key or match.group(1), f"unknown key (not a field of {match.group(2)})")
    match = re.search(r"Could not find '(.+?)'", text)
    if match:
        group, _, choice = match.group(1).rpartition("/")
        options = _group_options(group)
        return ConfigError(group or match.group(1), f"unknown choice {choice!r}"
                           + (f"; available: {', '.join(options)}" if options else ""))
    if "Missing mandatory value" in text:
        return ConfigError(key, "missing value (no YAML sets it)")
    return ConfigError(key, text)


def _article(type_name: str) -> str:
    words = {"Integer": "an integer", "Float": "a number", "Boolean": "a boolean (true/false)", "String": "a string"}
    return words.get(type_name, type_name)


def _group_options(group: str) -> list[str]:
    folder = CONF_DIR / group
    return sorted(p.stem for p in folder.glob("*.yaml")) if group and folder.is_dir() else []


def available(group: str) -> list[str]:
    """The choices of a config group (YAML stems under ``conf/<group>/``)."""
    return _group_options(group)


def to_object(node: Any, schema: type, key: str) -> Any:
    """``node`` (DictConfig or mapping) as an instance of the dataclass ``schema``; a type
    error, an unknown key or a missing value becomes a :class:`ConfigError` under ``key``."""
    try:
        if isinstance(node, DictConfig):  # plain values: a key the schema lacks fails the merge
            node = OmegaConf.to_container(node, resolve=True)
        merged = OmegaConf.merge(OmegaConf.structured(schema), node)
        return OmegaConf.to_object(merged)
    except OmegaConfBaseException as exc:
        err = config_error_from(exc)
        if not key or (err.key and err.key.startswith(key)):
            raise ConfigError(err.key or key, err.message) from exc
        raise ConfigError(f"{key}.{err.key}" if err.key else key, err.message) from exc


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
        if isinstance(scenario, ScenarioConfig):
            scenario = dataclasses.asdict(scenario)
        node = scenario
    try:
        node = OmegaConf.merge(OmegaConf.structured(ScenarioConfig), node)
    except OmegaConfBaseException as exc:
        err = config_error_from(exc)
        raise ConfigError(f"scenario.{err.key}" if err.key else "scenario", err.message) from exc
    for name, value in fields.items():
        try:
            OmegaConf.update(node, name, value, merge=False)
        except OmegaConfBaseException as exc:
            raise ConfigError(f"scenario.{name}", config_error_from(exc).message) from exc
    return check_scenario(to_object(node, ScenarioConfig, "scenario"))


def _fail(key: str, message: str) -> None:
    raise ConfigError(key, message)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_positive(obj: Any, prefix: str, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        if not (_is_number(value) and value > 0):
            _fail(f"{prefix}.{name}", f"must be a positive finite number, got {value!r}")


def check_non_negative(obj: Any, prefix: str, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        if not (_is_number(value) and value >= 0):
            _fail(f"{prefix}.{name}", f"must be a finite number >= 0, got {value!r}")


def check_count(obj: Any, prefix: str, *names: str, minimum: int = 1) -> None:
    for name in names:
        value = getattr(obj, name)
        if not (_is_int(value) and value >= minimum):
            _fail(f"{prefix}.{name}", f"must be an integer >= {minimum}, got {value!r}")


def check_choice(obj: Any, prefix: str, name: str, choices: Sequence[Any]) -> None:
    value = getattr(obj, name)
    if value not in choices:
        _fail(f"{prefix}.{name}", f"must be one of {', '.join(map(str, choices))}; got {value!r}")


def _rect_rect_overlap(a: Sequence[float], b: Sequence[float]) -> bool:
    return abs(a[0] - b[0]) < (a[2] + b[2]) / 2 and abs(a[1] - b[1]) < (a[3] + b[3]) / 2


def _circle_rect_overlap(c: Sequence[float], r: Sequence[float]) -> bool:
    dx = max(abs(c[0] - r[0]) - r[2] / 2, 0.0)
    dy = max(abs(c[1] - r[1]) - r[3] / 2, 0.0)
    return math.hypot(dx, dy) < c[2]


def check_scenario(cfg: ScenarioConfig) -> ScenarioConfig:
    """Check every field's range; raise :class:`ConfigError` naming the first bad one.

    Whether the spawn sampler can always meet the separation is the world's question:
    :func:`flock_torchrl.world.spawn.check_spawn_feasible` (run by every ``FlockingEnv``).
    """
    p = "scenario"
    check_choice(cfg, p, "reading", READINGS)
    check_count(cfg, p, "n_uavs", "max_steps", "n_beams", "n_scan", "n_cam", "spawn_max_tries",
                "spawn_reference_uavs")
    check_count(cfg, p, "n_moving", minimum=0)
    check_positive(cfg, p, "dt", "tau_v", "v_max", "goal_radius", "camera_range", "laser_range", "area_size",
                   "goal_scale", "spawn_radius", "rep_range", "fov")
    check_non_negative(cfg, p, "collision_distance", "safe_distance", "rep_gain", "heading_speed_threshold",
                       "spawn_separation", "spawn_clearance", "d_env", "noise_scan", "noise_distance",
                       "noise_angle", "moving_speed", "moving_clearance", "moving_radius")
    if cfg.n_scan > cfg.n_beams:
        _fail(f"{p}.n_scan", f"cannot exceed n_beams={cfg.n_beams}, got {cfg.n_scan}")
    if cfg.fov > 2 * math.pi + 1e-9:
        _fail(f"{p}.fov", f"must lie in (0, 2 pi], got {cfg.fov!r}")
    check_choice(cfg, p, "fov_convention", ("total", "half_angle"))
    check_choice(cfg, p, "collision_reward_source", ("scan", "min_uav_scan"))
    check_choice(cfg, p, "action_mode", ("policy", "velocity"))
    if len(cfg.area_center) != 2:
        _fail(f"{p}.area_center", f"must be [x, y], got {list(cfg.area_center)}")
    for i, c in enumerate(cfg.circles):
        if len(c) != 3 or not c[2] > 0:
            _fail(f"{p}.circles", f"entry {i} must be [cx, cy, radius > 0], got {list(c)}")
    for i, r in enumerate(cfg.rectangles):
        if len(r) != 4 or not (r[2] > 0 and r[3] > 0):
            _fail(f"{p}.rectangles", f"entry {i} must be [cx, cy, width > 0, height > 0], got {list(r)}")
    for i, a in enumerate(cfg.circles):
        for j, b in enumerate(cfg.circles[i + 1:], i + 1):
            if math.hypot(a[0] - b[0], a[1] - b[1]) < a[2] + b[2]:
                _fail(f"{p}.circles", f"circles {i} and {j} overlap")
        for j, r in enumerate(cfg.rectangles):
            if _circle_rect_overlap(a, r):
                _fail(f"{p}.circles", f"circle {i} overlaps rectangle {j}")
    for i, a in enumerate(cfg.rectangles):
        for j, b in enumerate(cfg.rectangles[i + 1:], i + 1):
            if _rect_rect_overlap(a, b):
                _fail(f"{p}.rectangles", f"rectangles {i} and {j} overlap")
    if cfg.n_moving:
        check_positive(cfg, p, "moving_radius")
        if len(cfg.moving_box) != 2 or not cfg.moving_box[0] < cfg.moving_box[1]:
            _fail(f"{p}.moving_box", f"must be [low, high] with low < high, got {list(cfg.moving_box)}")
    return cfg


# ---------------------------------------------------------------------------- the other groups
def check_policy(cfg: PolicyConfig) -> PolicyConfig:
    p = "policy"
    check_choice(cfg, p, "kind", ("learned", "rule"))
    if cfg.kind == "learned":
        check_choice(cfg, p, "critic_input", ("observation", "state"))
    else:
        check_choice(cfg, p, "controller", ("olfati_saber", "vasarhelyi"))
    return cfg


def check_algo(node: Any) -> Any:
    """The algo node as its dataclass (chosen by ``name``), ranges checked."""
    name = node.get("name") if hasattr(node, "get") else None
    if name not in ALGO_SCHEMAS:
        _fail("algo.name", f"must be one of {', '.join(ALGO_SCHEMAS)}; got {name!r}")
    cfg = to_object(node, ALGO_SCHEMAS[name], "algo")
    p = "algo"
    if not (_is_number(cfg.gamma) and 0 < cfg.gamma <= 1):
        _fail(f"{p}.gamma", f"must lie in (0, 1], got {cfg.gamma!r}")
    for key in ("lr_actor", "lr_critic", "lr_alpha", "lr", "hidden", "depth", "batch_size", "buffer_size",
                "minibatch_size", "epochs", "rollout_steps", "num_qvalue_nets", "alpha_init", "clip_epsilon"):
        if hasattr(cfg, key):
            check_positive(cfg, p, key)
    for key in ("hidden", "depth", "batch_size", "buffer_size", "minibatch_size", "epochs", "rollout_steps",
                "num_qvalue_nets", "noise_anneal_frames"):
        if hasattr(cfg, key):
            check_count(cfg, p, key)
    for key in ("tau",):
        if hasattr(cfg, key) and not (_is_number(cfg.tau) and 0 < cfg.tau <= 1):
            _fail(f"{p}.tau", f"must lie in (0, 1], got {cfg.tau!r}")
    for key in ("max_grad_norm", "noise_sigma", "noise_sigma_end", "entropy_coeff", "critic_coeff"):
        if hasattr(cfg, key):
            check_non_negative(cfg, p, key)
    if hasattr(cfg, "lmbda") and not (_is_number(cfg.lmbda) and 0 <= cfg.lmbda <= 1):
        _fail(f"{p}.lmbda", f"must lie in [0, 1], got {cfg.lmbda!r}")
    if hasattr(cfg, "target_entropy") and not _is_number(cfg.target_entropy):
        _fail(f"{p}.target_entropy", f"must be a finite number, got {cfg.target_entropy!r}")
    if hasattr(cfg, "loss_function"):
        check_choice(cfg, p, "loss_function", ("l1", "l2", "smooth_l1"))
    if hasattr(cfg, "loss_critic_type"):
        check_choice(cfg, p, "loss_critic_type", ("l1", "l2", "smooth_l1"))
    return cfg


def check_experiment(cfg: ExperimentConfig) -> ExperimentConfig:
    p = "experiment"
    check_count(cfg, p, "num_envs", "workers", "steps_per_batch", "eval_episodes")
    check_count(cfg, p, "updates_per_batch", "init_random_frames", "max_episodes", "max_frames",
                "log_every_frames", "eval_every_frames", "checkpoint_every_frames", minimum=0)
    check_non_negative(cfg, p, "max_minutes")
    if not (cfg.max_episodes or cfg.max_frames or cfg.max_minutes):
        _fail(p, "set at least one budget: max_episodes, max_frames or max_minutes")
    unknown = sorted(set(cfg.train_env) - SCENARIO_FIELDS)
    if unknown:
        _fail(f"{p}.train_env", f"unknown scenario field(s) {unknown}")
    if cfg.workers > 1 and cfg.num_envs % cfg.workers:
        _fail(f"{p}.workers", f"{cfg.workers} must divide num_envs={cfg.num_envs}")
    return cfg


def check_logger(cfg: LoggerConfig) -> LoggerConfig:
    check_choice(cfg, "logger", "backend", ("csv", "wandb", "tensorboard", "none"))
    check_choice(cfg, "logger", "mode", ("offline", "online"))
    return cfg


def check_device(device: str, key: str = "device") -> str:
    """``cpu``, ``cuda`` or ``cuda:<k>`` on a machine that has it."""
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
    return text


def check_seed(seed: Any, key: str = "seed") -> int:
    if not (_is_int(seed) and 0 <= seed < 2**63):
        _fail(key, f"must be an integer >= 0, got {seed!r}")
    return seed


def resume_mode(value: Any) -> str | Path:
    """``resume`` as ``"never"``, ``"always"``, ``"auto"`` or a run folder (:class:`Path`)."""
    text = str(value).strip()
    lowered = text.lower()
    if lowered in ("false", "no", "0", "never"):
        return "never"
    if lowered in ("true", "yes", "1", "always"):
        return "always"
    if lowered == "auto":
        return "auto"
    if not text:
        _fail("resume", "must be true, false, auto or a run folder")
    return Path(text)


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
    "ALGO_SCHEMAS", "CONF_DIR", "ConfigError", "DDPGConfig", "EvaluateConfig", "ExperimentConfig", "FiguresConfig",
    "LoggerConfig", "POLICY_SCENARIO_FIELDS", "PPOConfig", "PolicyConfig", "READINGS", "ReproduceConfig",
    "SACConfig", "SCENARIO_FIELDS", "ScenarioConfig", "TrainConfig", "available", "check_algo", "check_device",
    "check_experiment", "check_logger", "check_policy", "check_scenario", "check_seed", "compose", "compose_world",
    "config_dir", "flatten", "plain", "resume_mode", "scenario_config", "to_object",
]
