"""The apps' schemas (``conf/<app>.yaml``): what each command-line app, and its Python function,
takes as one checked object.

Every app composed from ``conf/world.yaml`` is a :class:`WorldApp` (the scenario and the values
the apps share); the run options they share are checked once, in :class:`RunOptions` (seed,
device, threads) and :class:`EpisodeOptions` (the evaluating apps' episode count).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Dict, List, Mapping, Optional

from omegaconf import MISSING, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from .checks import (MAX_UAVS, ConfigError, Schema, check_device, check_seed, check_threads, choice, config_error,
                     count, folder_name, reject)
from .groups import ExperimentConfig, LoggerConfig, PolicyConfig
from .learners import ALGO_SCHEMAS, LearnerConfig, algo_config
from .paths import available
from .scenario import ScenarioConfig

RESUME_MODES = ("false", "true", "auto")
# Members of one population (each holds its own networks, optimiser state and replay buffer): a
# GPU's populations of 80 fit, with room.
MAX_POPULATION = 128
# Fresh worlds a training env may hold in reserve (reset_pool): as many as experiment.num_envs may
# be (the reserve needs at least num_envs); what a machine can hold is the memory check's.
MAX_RESET_POOL = 10**7
# What `compile` may be: nothing, both, or one of the env's step and the learner's loss.
COMPILE_MODES = ("false", "true", "step", "loss")
# What the train app returns to a sweeper (Optuna, Ax): a metric of the run's final evaluation.
OBJECTIVES = ("success_rate", "safe_success_rate", "return")
# What reproduce's compare_to= puts side by side (report/compare.py): success rates are
# fractions, distances m, speeds m/s, times s.
COMPARED = ("success_rate", "safe_success_rate", "d_min_uav", "d_min_obs", "d_c", "speed", "t_goal")


@dataclass
class WorldApp(Schema):
    """What every app composed from ``conf/world.yaml`` holds: the scenario (with its reading)
    and the values the apps share, each set once there."""

    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    eval_seed: int = MISSING                 # the evaluation seed of every policy (section 5)
    checkpoints_dir: str = MISSING           # shipped checkpoints: <dir>/<reading>/<policy>/seed<k>.pt
    paper_recipe_dir: str = MISSING          # the paper recipe's shipped checkpoints (<policy>/seed<k>.pt)

    def checked_fields(self, p: str) -> dict[str, Any]:
        fields = dict(super().checked_fields(p))
        check_seed("eval_seed", self.eval_seed)
        scenario = self.scenario
        return {**fields, "scenario": scenario if scenario.is_checked else scenario.check()}

    @classmethod
    def structured(cls, node: Any) -> Any:
        """An ``algo`` node becomes its learner's schema (chosen by ``name``), so OmegaConf types it."""
        algo = node.get("algo") if isinstance(node, Mapping) else None
        if not isinstance(algo, Mapping):
            return node
        name = algo.get("name")
        if name not in ALGO_SCHEMAS:
            reject("algo.name", f"must be one of {', '.join(ALGO_SCHEMAS)}; got {name!r}")
        try:
            return {**node, "algo": OmegaConf.merge(OmegaConf.structured(ALGO_SCHEMAS[name]), algo)}
        except OmegaConfBaseException as exc:
            raise config_error(exc, "algo") from exc


@dataclass
class RunOptions(Schema):
    """The run options every app that runs policies shares, checked here once."""

    seed: int = MISSING
    device: str = MISSING                    # cpu, cuda, cuda:<k>, mps
    threads: int = MISSING                   # torch threads (0: torch's default)

    def checked_fields(self, p: str) -> dict[str, Any]:
        check_seed("seed", self.seed)
        check_device("device", self.device)
        check_threads("threads", self.threads)
        return dict(super().checked_fields(p))


@dataclass
class EpisodeOptions(RunOptions):
    """The run options of the apps that evaluate: how many episodes, too."""

    episodes: int = MISSING

    def checked_fields(self, p: str) -> dict[str, Any]:
        count("episodes", self.episodes, 1, 10**7)
        return dict(super().checked_fields(p))


@dataclass
class TrainConfig(RunOptions, WorldApp):
    """``conf/train.yaml``: one training run (``scripts/train.py``)."""

    policy: PolicyConfig = field(default_factory=PolicyConfig)
    algo: Optional[LearnerConfig] = None     # the policy's learner (conf/algo), with the experiment's settings
    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    resume: str = MISSING                    # false | true | auto
    progress: bool = MISSING
    compile: Any = MISSING                   # false | true (the loss and the step) | step | loss: torch.compile
    objective: str = MISSING                 # what the app returns to a sweeper: a final-evaluation metric
    resumable: List[str] = field(default_factory=list)   # keys a resume may change (a trailing . = a group)
    population: int = 1                      # members trained together, seeds seed .. seed + population - 1
    cudagraphs: bool = False                 # update, policy and env step as CUDA graphs (sac, ddpg; CPU: eager)
    reset_pool: int = 0                      # P > 0: a reserve of P fresh worlds per env (FlockingEnv)

    def checked_fields(self, p: str) -> dict[str, Any]:
        fields = dict(super().checked_fields(p))  # the run options, then the world
        policy = self.policy if self.policy.is_checked else self.policy.check()
        if policy.kind != "learned":
            reject("policy", f"{policy.name} is rule-based: there is nothing to train (evaluate it with "
                             f"scripts/evaluate.py policy={policy.id})")
        if self.algo is None:
            reject("algo", f"policy {policy.id} selects no learner")
        algo = algo_config(self.algo)
        experiment = self.experiment.check()
        for mixed in ("swarm_sizes", "train_mix"):
            if getattr(experiment, mixed) and algo.name not in ("sac", "ddpg"):
                reject(f"experiment.{mixed}", f"needs an off-policy learner (sac, ddpg): {policy.id} trains "
                                              f"with {algo.name}")
        fields.update(policy=policy, algo=algo, experiment=experiment, logger=self.logger.check())
        training_scenario(fields["scenario"], experiment)  # the training env's scenario is checked too
        for i, kind in enumerate(experiment.train_mix):  # and each kind of training world
            kind_of(training_scenario(fields["scenario"], experiment), kind, f"experiment.train_mix[{i}]")
        choice("resume", str(self.resume).lower(), RESUME_MODES)
        choice("compile", str(self.compile).lower(), COMPILE_MODES)
        choice("objective", self.objective, OBJECTIVES)
        self._check_population(algo, experiment)
        count("reset_pool", self.reset_pool, 0, MAX_RESET_POOL)
        if 0 < self.reset_pool < experiment.num_envs:
            reject("reset_pool", f"a reserve of fresh worlds needs at least num_envs ({experiment.num_envs}) of "
                                 f"them (one step can reset every world), got {self.reset_pool}; 0 turns it off")
        if self.cudagraphs and algo.name not in ("sac", "ddpg"):
            reject("cudagraphs", f"the captured update is SAC's and DDPG's; {policy.id} trains with {algo.name}: "
                                 "use cudagraphs=false")
        return fields

    def _check_population(self, algo: LearnerConfig, experiment: ExperimentConfig) -> None:
        """A population (``population > 1``) trains SAC or DDPG in this process."""
        count("population", self.population, 1, MAX_POPULATION)
        check_seed("seed", self.seed + self.population - 1)
        if self.population == 1:
            return
        if algo.name not in ("sac", "ddpg"):
            reject("population", f"a population trains an off-policy learner (sac, ddpg); {self.policy.id} trains "
                                 f"with {algo.name}: use population=1")
        if experiment.workers != 1:
            reject("population", f"a population steps its worlds in this process; experiment.workers must be 1, "
                                 f"got {experiment.workers}")
        if self.compile_loss:
            reject("population", "a population's update runs eagerly (torch.vmap over its members): use "
                                 "compile=false or compile=step")

    @property
    def seeds(self) -> list[int]:
        """The members' seeds: ``seed .. seed + population - 1``."""
        return list(range(self.seed, self.seed + self.population))

    @property
    def compile_step(self) -> bool:
        """``compile`` is ``true`` or ``step``: the env's step is compiled."""
        return str(self.compile).lower() in ("true", "step")

    @property
    def compile_loss(self) -> bool:
        """``compile`` is ``true`` or ``loss``: the learner's loss is compiled."""
        return str(self.compile).lower() in ("true", "loss")

    @property
    def train_scenario(self) -> ScenarioConfig:
        """The scenario plus the experiment's ``train_env`` recipe (the training env's world)."""
        return training_scenario(self.scenario, self.experiment)

    @property
    def train_scenarios(self) -> list[ScenarioConfig]:
        """The training envs' scenarios: one per ``experiment.swarm_sizes`` entry (or one) and kind
        of world (``experiment.train_mix``, or the training scenario alone), sizes outermost."""
        base, exp = self.train_scenario, self.experiment
        sizes = [dataclasses.replace(base, n_uavs=n) for n in exp.swarm_sizes] or [base]
        if not exp.train_mix:
            return sizes
        return [kind_of(size, kind, f"experiment.train_mix[{i}]") for size in sizes
                for i, kind in enumerate(exp.train_mix)]

    @property
    def resume_mode(self) -> str:
        """``never``, ``always`` or ``auto``."""
        return {"false": "never", "true": "always", "auto": "auto"}[str(self.resume).lower()]


def training_scenario(scenario: ScenarioConfig, experiment: ExperimentConfig) -> ScenarioConfig:
    """``scenario`` with ``experiment.train_env`` applied, checked (the training env's world)."""
    return kind_of(scenario, experiment.train_env, "experiment.train_env") if experiment.train_env else scenario


def kind_of(scenario: ScenarioConfig, fields: Any, key: str) -> ScenarioConfig:
    """``scenario`` with scenario ``fields`` applied (``train_env``'s, or one kind of training world's),
    checked; an error names ``key``."""
    try:
        return dataclasses.replace(scenario, **dict(fields)).check()
    except ConfigError as exc:
        raise ConfigError(f"{key} ({exc.key})", exc.message) from exc


def check_contender(key: str, spec: Any) -> None:
    """A contender's shape (a string, or a mapping with a string ``_target_``); whether it
    imports or loads is the registry's check, made before the first episode."""
    if spec is None or isinstance(spec, str) and spec:
        return
    if isinstance(spec, Mapping) and isinstance(spec.get("_target_"), str) and spec["_target_"]:
        return
    reject(key, "a checkpoint path, a factory's import path (pkg.module.make or file.py:make) or a mapping with "
                f"_target_; got {spec!r}")


@dataclass
class EvaluateConfig(EpisodeOptions, WorldApp):
    """``conf/evaluate.yaml``: one policy (or a checkpoint), one scenario, the section 5 protocol."""

    policy: PolicyConfig = field(default_factory=PolicyConfig)
    algo: Optional[LearnerConfig] = None     # the policy's learner (not used to evaluate)
    checkpoint: Optional[str] = None         # a checkpoint file instead of the shipped ones
    member: Optional[int] = None             # of a population's checkpoint, one member (default: every member)
    contender: Any = None                    # a controller of the user's instead (registry.contender_handle)
    max_steps: Optional[int] = None

    def checked_fields(self, p: str) -> dict[str, Any]:
        policy = self.policy.check()
        if self.checkpoint is not None and self.contender is not None:
            reject("contender", "evaluates one controller: give checkpoint= or contender=, not both")
        check_contender("contender", self.contender)
        if self.member is not None:
            if self.checkpoint is None:
                reject("member", "chooses a member of a population's checkpoint: give checkpoint= too")
            count("member", self.member, 0, MAX_POPULATION - 1)
        if self.max_steps is not None:
            count("max_steps", self.max_steps, 1, 10**7)
        fields = dict(super().checked_fields(p))  # the run options, then the world
        if self.max_steps is not None:
            fields["scenario"] = dataclasses.replace(fields["scenario"], max_steps=self.max_steps).check()
        return {**fields, "policy": policy}


def check_tolerance(tolerance: Mapping[str, float]) -> dict[str, float]:
    """``compare_tolerance``: compared columns -> a largest difference >= 0."""
    out = {}
    for key, value in dict(tolerance).items():
        if key not in COMPARED:
            reject(f"compare_tolerance.{key}", f"not a compared column; one of {', '.join(COMPARED)}")
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not value >= 0:
            reject(f"compare_tolerance.{key}", f"must be a number >= 0; got {value!r}")
        out[key] = float(value)
    return out


@dataclass
class ReproduceConfig(EpisodeOptions, WorldApp):
    """``conf/reproduce.yaml``: one of the paper's tables (the reading: ``scenario.reading``)."""

    table: int = MISSING
    only: List[str] = field(default_factory=list)
    contenders: List[Any] = field(default_factory=list)  # the user's controllers, as extra rows
    recipe: str = MISSING                    # fast: checkpoints_dir; paper: paper_recipe_dir (Table III)
    episodes_csv: bool = MISSING
    compare_to: Optional[str] = None         # a table CSV written before: also written side by side
    compare_tolerance: Dict[str, float] = field(default_factory=dict)

    def checked_fields(self, p: str) -> dict[str, Any]:
        fields = dict(super().checked_fields(p))  # the run options, then the world
        choice("table", self.table, (3, 4, 5))
        choice("recipe", self.recipe, ("fast", "paper"))
        check_tolerance(self.compare_tolerance)
        if self.recipe == "paper" and self.table != 3:
            reject("recipe", "the paper recipe trained the policies of Table III only (table=3)")
        for i, spec in enumerate(self.contenders):
            check_contender(f"contenders[{i}]", spec)
        return fields


@dataclass
class FiguresConfig(RunOptions, WorldApp):
    """``conf/figures.yaml``: the paper's figures (the reading: ``scenario.reading``)."""

    figs: List[int] = MISSING

    def checked_fields(self, p: str) -> dict[str, Any]:
        fields = dict(super().checked_fields(p))  # the run options, then the world
        if not self.figs or any(f not in (4, 5, 6) for f in self.figs):
            reject("figs", f"a list of 4, 5 and 6, got {list(self.figs)}")
        return fields


@dataclass
class ScalingConfig(EpisodeOptions, WorldApp):
    """``conf/scaling.yaml``: one shipped policy flown by larger swarms."""

    policy_name: str = MISSING
    others: List[str] = field(default_factory=list)   # more policies (ids, checkpoint files) as extra rows
    sizes: List[int] = MISSING

    def checked_fields(self, p: str) -> dict[str, Any]:
        fields = dict(super().checked_fields(p))  # the run options, then the world
        if not self.sizes:
            reject("sizes", "a list of swarm sizes, got []")
        for n in self.sizes:
            count("sizes", n, 1, MAX_UAVS)
        return fields


@dataclass
class TuneConfig(EpisodeOptions, WorldApp):
    """``conf/tune_baselines.yaml``: the rule-based baselines' grid search."""

    controllers: List[str] = MISSING
    max_steps: int = MISSING
    evaluate: bool = MISSING
    scenarios: List[str] = MISSING

    def checked_fields(self, p: str) -> dict[str, Any]:
        fields = dict(super().checked_fields(p))  # the run options, then the world
        count("max_steps", self.max_steps, 1, 10**7)
        for name in self.scenarios:
            choice("scenarios", name, available("scenario"))
        return fields


@dataclass
class ShipConfig(WorldApp):
    """``conf/ship.yaml``: the named step that exports finished runs into ``checkpoints/``."""

    experiment: str = MISSING
    runs_dir: str = MISSING
    paper_experiment: str = MISSING
    collections: Dict[str, str] = field(default_factory=dict)  # experiment -> folder under <checkpoints>/<reading>/
    # folder under <checkpoints>/<reading>/ -> {runs_dir, experiment, names[, target]}: runs of another
    # scenario, whose folders are seed<k>__<one of names>; shipped alone, with ``only`` (by ``make <target>``)
    scenario_collections: Dict[str, Any] = field(default_factory=dict)
    only: Optional[str] = None               # a key of scenario_collections: ship that one alone

    def checked_fields(self, p: str) -> dict[str, Any]:
        fields = dict(super().checked_fields(p))  # the run options, then the world
        folder_name("experiment", self.experiment)
        folder_name("paper_experiment", self.paper_experiment)
        for experiment, folder in self.collections.items():
            folder_name(f"collections.{experiment}", experiment)
            folder_name(f"collections.{experiment}", folder)
        for folder, spec in self.scenario_collections.items():
            key = f"scenario_collections.{folder}"
            folder_name(key, folder)
            if not isinstance(spec, Mapping) or set(spec) - {"target"} != {"runs_dir", "experiment", "names"}:
                reject(key, f"must hold runs_dir, experiment and names (and a make target or none), got {spec!r}")
            if spec.get("target") is not None and not isinstance(spec["target"], str):
                reject(f"{key}.target", f"the make target that ships it, or null; got {spec['target']!r}")
            folder_name(f"{key}.experiment", spec["experiment"])
            if not spec["names"] or any(not isinstance(n, str) or not n for n in spec["names"]):
                reject(f"{key}.names", f"a list of run folders' names after seed<k>__, got {spec['names']!r}")
        if self.only is not None and self.only not in self.scenario_collections:
            reject("only", f"must be one of {sorted(self.scenario_collections)} or null, got {self.only!r}")
        return fields


@dataclass
class DiagnoseConfig(EpisodeOptions, WorldApp):
    """``conf/diagnose.yaml``: crash forensics and evaluation-time ablations of shipped policies
    (``scripts/diagnose.py``; logic: ``flock_torchrl.report.diagnosis``)."""

    catalogue: Dict[str, Any] = field(default_factory=dict)  # key -> {label, folder, seeds}
    policies: List[str] = MISSING            # keys of the catalogue, each a row label pooling its seeds
    scenarios: List[str] = MISSING
    sizes: List[int] = MISSING
    variants: List[str] = MISSING

    def checked_fields(self, p: str) -> dict[str, Any]:
        fields = dict(super().checked_fields(p))  # the run options, then the world
        for key, entry in self.catalogue.items():
            ok = (isinstance(entry, Mapping) and isinstance(entry.get("label"), str) and entry.get("label")
                  and isinstance(entry.get("folder"), str) and entry.get("folder"))
            if not ok:
                reject(f"catalogue.{key}", f"must be {{label: <text>, folder: <folder>, seeds: <n>}}, got {entry!r}")
            count(f"catalogue.{key}.seeds", entry.get("seeds"), 1, 1000)
        if not self.policies:
            reject("policies", f"a list of the catalogue's keys ({', '.join(self.catalogue)}), got []")
        for name in self.policies:
            choice("policies", name, list(self.catalogue))
        if not self.scenarios:
            reject("scenarios", "a list of scenarios, got []")
        for name in self.scenarios:
            choice("scenarios", name, available("scenario"))
        if not self.sizes:
            reject("sizes", "a list of swarm sizes, got []")
        for n in self.sizes:
            count("sizes", n, 1, MAX_UAVS)
        if not self.variants:
            reject("variants", "a list of variants, got []")
        return fields


APP_SCHEMAS: dict[str, type[Schema]] = {
    "train": TrainConfig, "evaluate": EvaluateConfig, "reproduce": ReproduceConfig, "figures": FiguresConfig,
    "scaling": ScalingConfig, "tune_baselines": TuneConfig, "ship": ShipConfig, "diagnose": DiagnoseConfig,
}

__all__ = ["APP_SCHEMAS", "COMPARED", "COMPILE_MODES", "DiagnoseConfig", "EpisodeOptions", "EvaluateConfig", "FiguresConfig",
           "MAX_POPULATION", "OBJECTIVES", "RESUME_MODES", "ReproduceConfig", "RunOptions", "ScalingConfig",
           "ShipConfig", "TrainConfig", "TuneConfig", "WorldApp", "check_contender", "check_tolerance",
           "training_scenario"]
