"""Evaluation protocol of SPEC section 5: many seeded episodes in one batched rollout.

``evaluate`` builds one :class:`~flock_torchrl.env.FlockingEnv` with ``num_envs = n_episodes``,
resets it once and steps the policy (deterministic actions, no gradients, no auto-reset) until
every env has finished one episode. Each env's SPEC-5 metrics are read at its *first* ``done``;
nothing after that counts. Every policy sees the same starts because the env is seeded with
:data:`EVAL_SEED` and draws all ``n_episodes`` layouts in the single reset.

Example:
    >>> from flock_torchrl.evaluation import evaluate, goal_seeking_policy
    >>> result = evaluate(goal_seeking_policy(), scenario="s1", n_episodes=8)
    >>> result.rate("success").rate
    1.0
    >>> sorted(result.summary())[:3]
    ['d_c', 'd_c_std', 'd_min_obs']
"""

from __future__ import annotations

import copy
import csv
import math
import os
import re
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import torch
from omegaconf import OmegaConf
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from torchrl.envs.utils import ExplorationType, set_exploration_type

from .config import CONF_DIR, ConfigError
from .env import FlockingEnv
from .metrics import METRIC_KEYS

# The evaluation seed shared by every policy (SPEC 5 "the same evaluation seed for every
# policy"); the same number as ``eval_seed`` in conf/train.yaml.
EVAL_SEED = 2024
# Where ``checkpoints/<policy>/seed<k>.pt`` live (next to conf/, like the configs).
CHECKPOINT_DIR = CONF_DIR.parent / "checkpoints"
# Table cells (mean +- std), in the paper's column order; t_goal over the episodes that reached.
CELL_METRICS = ("d_min_obs", "d_min_uav", "d_c", "v_error", "phi_error", "speed", "t_goal")
RATE_METRICS = ("success", "safe_success")
WILSON_Z = 1.959963984540054  # two-sided 95 %
# Compact the batch once fewer than this fraction of its envs is still running: the tail of
# slow or stuck episodes then costs what a small batch costs, not what n_episodes cost. Below
# MIN_COMPACT_BATCH envs a step costs about the same at any batch size (fixed per-step
# overhead), so rebuilding the env (about 0.1 s) would not pay for itself.
COMPACT_BELOW = 0.5
MIN_COMPACT_BATCH = 32


# ---------------------------------------------------------------------------- statistics
@dataclass(frozen=True)
class Cell:
    """``mean +- std`` of one metric over ``n`` episodes (population std, like ``numpy.std``)."""

    mean: float
    std: float
    n: int


@dataclass(frozen=True)
class Rate:
    """A proportion ``k / n`` with its 95 % Wilson score interval ``[low, high]``."""

    rate: float
    low: float
    high: float
    k: int
    n: int


def wilson_interval(k: int, n: int, z: float = WILSON_Z) -> tuple[float, float]:
    """Wilson score interval of ``k`` successes in ``n`` trials (``(nan, nan)`` for ``n = 0``).

    ``centre = (p + z^2/2n) / (1 + z^2/n)``, ``half = z / (1 + z^2/n) sqrt(p(1-p)/n + z^2/4n^2)``.
    """
    if n <= 0:
        return math.nan, math.nan
    p = k / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def mean_std(values: torch.Tensor) -> Cell:
    """Mean and population std of the finite entries of a 1-D tensor (NaN cell if none)."""
    v = values.double()
    v = v[torch.isfinite(v)]
    if v.numel() == 0:
        return Cell(math.nan, math.nan, 0)
    return Cell(float(v.mean()), float(v.std(correction=0)), int(v.numel()))


# ---------------------------------------------------------------------------- results
@dataclass
class EvaluationResult:
    """Per-episode SPEC-5 metrics of one policy in one scenario, and their summary.

    Attributes:
        policy: the policy's name (``"Policy3-G"``, ``"Policy-MA"``, ...).
        scenario: the scenario name (``"train"``, ``"s1"``, ...).
        seed: the env seed the episodes were drawn with.
        env_overrides: scenario fields changed for this evaluation (policy's and caller's).
        episodes: metric name -> ``[n]`` CPU tensor, one entry per episode (METRIC_KEYS).
        rollout_steps: env steps the batched rollout took (the slowest episode's length).
        wall_time_s: seconds from env construction to the last step.
        source: where the policy came from (a checkpoint path, ``baseline:<name>``, ``module``).
    """

    policy: str
    scenario: str
    seed: int
    env_overrides: dict[str, Any]
    episodes: dict[str, torch.Tensor]
    rollout_steps: int = 0
    wall_time_s: float = 0.0
    source: str = "module"
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def n_episodes(self) -> int:
        return int(self.episodes["success"].numel())

    def cell(self, metric: str) -> Cell:
        """``mean +- std`` of a metric; ``t_goal`` only over the episodes that reached the goal."""
        values = self.episodes[metric]
        if metric == "t_goal":
            values = values[self.episodes["reached"]]
        return mean_std(values)

    def rate(self, metric: str = "success") -> Rate:
        """Rate of a boolean metric (``success``, ``safe_success``, ``reached``, ``crashed``)."""
        flags = self.episodes[metric].bool()
        k, n = int(flags.sum()), int(flags.numel())
        low, high = wilson_interval(k, n)
        return Rate(k / n if n else math.nan, low, high, k, n)

    def summary(self) -> dict[str, float | int]:
        """One flat row: ``<metric>``, ``<metric>_std`` for the table cells (the paper's column
        names), ``success_rate`` / ``safe_success_rate`` with ``_low`` / ``_high`` Wilson
        bounds, ``n_episodes`` and ``n_reached``."""
        row: dict[str, float | int] = {}
        for m in CELL_METRICS:
            c = self.cell(m)
            row[m], row[f"{m}_std"] = c.mean, c.std
        for m in RATE_METRICS:
            r = self.rate(m)
            row[f"{m}_rate"], row[f"{m}_rate_low"], row[f"{m}_rate_high"] = r.rate, r.low, r.high
        row["n_episodes"] = self.n_episodes
        row["n_reached"] = int(self.episodes["reached"].sum())
        return row

    def records(self) -> list[dict[str, Any]]:
        """One dict per episode: ``episode`` index, ``policy``, ``scenario`` and every metric."""
        cols = {k: v.tolist() for k, v in self.episodes.items()}
        return [
            {"episode": i, "policy": self.policy, "scenario": self.scenario,
             **{k: cols[k][i] for k in self.episodes}}
            for i in range(self.n_episodes)
        ]

    def write_csv(self, path: str | os.PathLike) -> Path:
        """Per-episode records as CSV, written atomically; returns the path."""
        records = self.records()
        fields = list(records[0]) if records else ["episode", "policy", "scenario", *METRIC_KEYS]
        return write_csv_atomic(path, fields, records)

    def __str__(self) -> str:
        s = self.summary()
        cells = ", ".join(f"{m} {s[m]:.3f}±{s[f'{m}_std']:.3f}" for m in CELL_METRICS)
        return (f"{self.policy} on {self.scenario} ({self.n_episodes} episodes, seed {self.seed}): "
                f"success {s['success_rate']:.3f} [{s['success_rate_low']:.3f}, {s['success_rate_high']:.3f}], "
                f"safe_success {s['safe_success_rate']:.3f}; {cells}; "
                f"{self.rollout_steps} steps in {self.wall_time_s:.1f} s")

    @classmethod
    def pooled(cls, results: Sequence["EvaluationResult"]) -> "EvaluationResult":
        """All episodes of several results (e.g. one per training seed) as one result."""
        if not results:
            raise ValueError("pooled() needs at least one result")
        first = results[0]
        episodes = {k: torch.cat([r.episodes[k] for r in results]) for k in first.episodes}
        return cls(
            policy=first.policy, scenario=first.scenario, seed=first.seed, env_overrides=dict(first.env_overrides),
            episodes=episodes, rollout_steps=max(r.rollout_steps for r in results),
            wall_time_s=sum(r.wall_time_s for r in results),
            source="; ".join(r.source for r in results), extra={"pooled": len(results)},
        )


# ---------------------------------------------------------------------------- atomic files
def replace_atomic(path: str | os.PathLike, write: Callable[[str], None], suffix: str = ".tmp") -> Path:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then ``os.replace`` it into
    place, so a reader never sees a half-written file (and a crash leaves the old one)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual mode
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`replace_atomic`)."""
    def write(tmp: str) -> None:
        with open(tmp, "w", newline="") as fh:
            fh.write(text)

    return replace_atomic(path, write)


def write_csv_atomic(path: str | os.PathLike, fieldnames: Sequence[str], rows: Iterable[Mapping[str, Any]]) -> Path:
    """Rows of dicts as CSV (``csv`` module, missing keys empty), written atomically."""
    import io

    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(fieldnames), extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: _csv_value(v) for k, v in row.items()})
    return write_text_atomic(path, buf.getvalue())


def _csv_value(v: Any) -> Any:
    if isinstance(v, bool):
        return int(v)
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v) if math.isinf(v) else f"{v:.6g}"
    return "" if v is None else v


# ---------------------------------------------------------------------------- policies
def policy_config_stem(name: str) -> str:
    """``"Policy3-G"`` / ``"policy3_g"`` / ``"Policy-MA"`` -> the YAML stem ``policy3_g`` / ``policy_ma``."""
    return re.sub(r"[-\s]+", "_", name.strip()).lower()


def available_policies() -> list[str]:
    """Stems of ``conf/policy/*.yaml``."""
    return sorted(p.stem for p in (CONF_DIR / "policy").glob("*.yaml"))


def load_policy_config(name: str) -> dict[str, Any]:
    """``conf/policy/<stem>.yaml`` as a plain dict with ``name``, ``kind`` and resolved ``env``.

    The YAML's Hydra ``defaults`` (its algo group) are not needed for evaluation and dropped.
    """
    stem = policy_config_stem(name)
    path = CONF_DIR / "policy" / f"{stem}.yaml"
    if not path.is_file():
        raise ConfigError(f"unknown policy {name!r}: no {path}; available: {available_policies()}")
    node = OmegaConf.load(path)
    if "defaults" in node:
        node.pop("defaults")
    cfg = OmegaConf.to_container(node, resolve=True)
    cfg.setdefault("name", stem)
    cfg.setdefault("kind", "learned")
    cfg["env"] = dict(cfg.get("env") or {})
    cfg["stem"] = stem
    return cfg  # type: ignore[return-value]


def policy_checkpoints(name: str, checkpoint_dir: str | os.PathLike | None = None) -> list[Path]:
    """``<checkpoint_dir>/<stem>/seed<k>.pt`` of a policy, sorted by ``k`` (empty if none).

    Also looks under the paper's spelling (``checkpoints/Policy3-G/``).
    """
    root = Path(checkpoint_dir) if checkpoint_dir is not None else CHECKPOINT_DIR
    found: dict[Path, None] = {}
    for folder in (policy_config_stem(name), name):
        for p in (root / folder).glob("seed*.pt"):
            found[p.resolve()] = None

    def seed_of(p: Path) -> tuple[int, str]:
        m = re.match(r"seed(\d+)", p.stem)
        return (int(m.group(1)) if m else 1 << 30, p.name)

    return sorted(found, key=seed_of)


def policy_runs(name: str, checkpoint_dir: str | os.PathLike | None = None,
                overrides: Mapping[str, Any] | None = None) -> tuple[list[tuple[str, Any]], str]:
    """What there is to evaluate for a policy name: ``([(label, policy)], note)``.

    ``overrides[name]`` (a module / path, or a list of them) wins; a rule-based policy gives its
    baseline (if ``flock_torchrl.baselines`` imports); a learned one every
    ``<checkpoint_dir>/<stem>/seed<k>.pt``. When the list is empty, ``note`` says why.
    """
    if overrides and name in overrides:
        given = overrides[name]
        items = given if isinstance(given, (list, tuple)) else [given]
        return [(f"given[{i}]", p) for i, p in enumerate(items)], ""
    try:
        cfg = load_policy_config(name)
    except ConfigError as exc:  # no conf/policy YAML (yet)
        return [], f"skipped: {exc}"
    if cfg["kind"] == "rule":
        try:
            from . import baselines  # noqa: F401  (lazy: lands separately)
        except ImportError as exc:
            return [], f"skipped: rule-based baseline unavailable ({exc})"
        return [(f"baseline:{cfg['stem']}", cfg["stem"])], ""
    checkpoints = policy_checkpoints(name, checkpoint_dir)
    if not checkpoints:
        root = Path(checkpoint_dir) if checkpoint_dir is not None else CHECKPOINT_DIR
        return [], (f"skipped: no checkpoint {root / cfg['stem'] / 'seed*.pt'} "
                    f"(train it: python scripts/train.py policy={cfg['stem']} seed=0)")
    return [(str(p), p) for p in checkpoints], ""


@dataclass
class PolicySource:
    """A policy before it meets an env: its name, the scenario fields it implies, and how to
    build the TensorDict module for a given env (rule-based controllers need the env config,
    learned actors the number of UAVs)."""

    name: str
    env: dict[str, Any]
    build: Callable[[FlockingEnv], Callable[[TensorDictBase], TensorDictBase]]
    origin: str


def adapt_n_agents(module: Any, n_agents: int) -> Any:
    """A copy of ``module`` whose shared, decentralised ``MultiAgentMLP`` s take ``n_agents`` UAVs.

    Shared parameters do not depend on N (SPEC 7), so a policy trained with five UAVs runs S2's
    nine; torchrl's MultiAgentMLP only checks its stored ``n_agents``. Returns ``module`` itself
    when nothing needs changing; raises for per-agent or centralised networks.
    """
    try:
        from torchrl.modules import MultiAgentMLP
    except ImportError:  # pragma: no cover
        return module
    if not isinstance(module, torch.nn.Module) or callable(getattr(module, "actor_for", None)):
        return module  # not a network, or one that rebuilds itself per N (checkpoint.SharedPolicy)
    mismatched = [m for m in module.modules() if isinstance(m, MultiAgentMLP) and m.n_agents != n_agents]
    if not mismatched:
        return module
    bad = [m for m in mismatched if not m.share_params or m.centralized]
    if bad:
        raise ValueError(f"the policy's MultiAgentMLP was built for {bad[0].n_agents} agents with "
                         f"share_params={bad[0].share_params}, centralized={bad[0].centralized}; "
                         f"it cannot run {n_agents} UAVs")
    module = copy.deepcopy(module)
    for m in module.modules():
        if isinstance(m, MultiAgentMLP):
            m.n_agents = n_agents
    return module


def _load_checkpoint(path: Path, device: str | torch.device) -> PolicySource:
    from . import load_policy  # lazy: the training package lands separately

    module = load_policy(str(path), device=device)
    meta = dict(getattr(module, "flock_meta", None) or {})
    name = str(meta.get("policy") or path.parent.name)
    env = dict(meta.get("env") or {})
    if not env:  # fall back on the policy's YAML when the checkpoint carries no env overrides
        try:
            env = load_policy_config(name)["env"]
        except ConfigError:
            env = {}
    return PolicySource(name=name, env=env, build=lambda e: adapt_n_agents(module, e.n_agents), origin=str(path))


def policy_source(policy: Any, device: str | torch.device = "cpu",
                  checkpoint_dir: str | os.PathLike | None = None) -> PolicySource:
    """Resolve what :func:`evaluate` accepts as a policy.

    Args:
        policy: a TensorDict module (``td -> td`` writing ``("agents", "action")``; its
            ``flock_meta`` gives name and env overrides, if present), a checkpoint path
            (``*.pt``, loaded with ``flock_torchrl.load_policy``), or a policy name: a
            rule-based one (``policy_ma``, ``Policy-OP``: ``flock_torchrl.baselines.make_baseline``)
            or a learned one (its lowest-seed checkpoint under ``checkpoint_dir``).
    """
    if isinstance(policy, PolicySource):
        return policy
    if callable(policy) and not isinstance(policy, (str, os.PathLike)):
        meta = dict(getattr(policy, "flock_meta", None) or {})
        name = str(meta.get("policy") or getattr(policy, "name", None) or type(policy).__name__)
        return PolicySource(name=name, env=dict(meta.get("env") or {}),
                            build=lambda e: adapt_n_agents(policy, e.n_agents), origin="module")
    path = Path(policy)
    if path.suffix == ".pt" or path.is_file():
        if not path.is_file():
            raise FileNotFoundError(f"no checkpoint at {path}")
        return _load_checkpoint(path, device)
    cfg = load_policy_config(str(policy))
    if cfg["kind"] == "rule":
        def build(env: FlockingEnv):
            from .baselines import make_baseline  # lazy: the baselines land separately

            return make_baseline(cfg["stem"], env.cfg)

        return PolicySource(name=cfg["name"], env=cfg["env"], build=build, origin=f"baseline:{cfg['stem']}")
    checkpoints = policy_checkpoints(cfg["name"], checkpoint_dir)
    if not checkpoints:
        root = Path(checkpoint_dir) if checkpoint_dir is not None else CHECKPOINT_DIR
        raise FileNotFoundError(f"{cfg['name']} is a learned policy and {root / cfg['stem']} holds no seed*.pt; "
                                f"train it (scripts/train.py policy={cfg['stem']}) or pass a checkpoint path")
    source = _load_checkpoint(checkpoints[0], device)
    source.env = {**cfg["env"], **source.env}
    return source


# ---------------------------------------------------------------------------- scripted policy
class _GoalSeeking(torch.nn.Module):
    def __init__(self, speed_action: float) -> None:
        super().__init__()
        self.speed_action = speed_action

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        # o_g = [d_g / d_s, alpha_g / pi]: turn by alpha_g (dphi = a0 pi/2, so a0 = 2 alpha_g / pi).
        turn = (2.0 * observation[..., 1:2]).clamp(-1.0, 1.0)
        return torch.cat((turn, torch.full_like(turn, self.speed_action)), -1)


def goal_seeking_policy(speed_action: float = 0.0) -> TensorDictModule:
    """A scripted policy that steers every UAV straight at the goal at ``V = 2 + speed_action``.

    It reads only ``o_g`` of ``("agents", "observation")`` and ignores obstacles and
    neighbours, so its episodes have a known answer in S1 (tests, timing, sanity checks).
    """
    module = TensorDictModule(_GoalSeeking(speed_action), in_keys=[("agents", "observation")],
                              out_keys=[("agents", "action")])
    module.flock_meta = {"policy": "GoalSeeking", "env": {}}
    return module


# ---------------------------------------------------------------------------- rollout
def _index_state(value: Any, idx: torch.Tensor, batch: int) -> Any:
    if isinstance(value, torch.Tensor) and value.dim() > 0 and value.shape[0] == batch:
        return value[idx]
    if isinstance(value, TensorDictBase) and value.batch_size[:1] == torch.Size([batch]):
        return value[idx]
    if isinstance(value, dict) and value and all(isinstance(v, torch.Tensor) for v in value.values()):
        return {k: _index_state(v, idx, batch) for k, v in value.items()}
    return value


def compact_env(env: FlockingEnv, keep: torch.Tensor) -> FlockingEnv:
    """A new env holding only the envs ``keep`` (``[k]`` indices) of ``env``, mid-episode.

    Every env of a FlockingEnv evolves independently of the others, so continuing a subset
    gives each kept env the same trajectory (the S4 noise generator's draws aside, whose
    shape follows the batch). The new env takes over every per-env state tensor (first
    dimension ``num_envs``), the accumulators, the sensing cache and the generator state.
    """
    batch, k = env.num_envs, int(keep.numel())
    small = FlockingEnv(env.cfg, num_envs=k, device=env.device, seed=None)
    for name, value in vars(env).items():
        if name.startswith("_") or name in ("cfg", "num_envs", "n_agents", "obs_dim", "state_dim"):
            continue
        new = _index_state(value, keep, batch)
        if new is not value:
            setattr(small, name, new)
    small._generator.set_state(env._generator.get_state())
    for name, value in vars(small).items():  # guard against per-env state this copy missed
        if not name.startswith("_") and isinstance(value, torch.Tensor) and value.dim() and value.shape[0] != k:
            raise RuntimeError(f"compact_env: FlockingEnv.{name} has shape {tuple(value.shape)}, "
                               f"expected a first dimension of {k}")
    return small


def run_episodes(env: FlockingEnv, policy: Callable[[TensorDictBase], TensorDictBase],
                 compact: bool = True) -> tuple[TensorDict, int]:
    """Step ``policy`` in ``env`` from one reset until every env has been done once.

    Args:
        env: a fresh FlockingEnv; it is reset here (once) and never auto-reset.
        policy: ``td -> td`` writing ``("agents", "action")``; run under
            ``ExplorationType.DETERMINISTIC`` and ``torch.no_grad()``.
        compact: continue the still-running envs in a smaller batch once fewer than
            :data:`COMPACT_BELOW` of them are left (same trajectories, less work).

    Returns:
        ``(episodes, steps)``: the ``"episode"`` TensorDict ``[B]`` of each env at its first
        ``done`` (on the CPU), and the number of steps the rollout took.
    """
    limit = env.cfg.max_steps
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.reset()
        records = td["episode"].clone()
        rows = torch.arange(env.num_envs, device=env.device)  # original env index of each batch row
        finished = torch.zeros(env.num_envs, dtype=torch.bool, device=env.device)
        steps = 0
        while not bool(finished.all()):
            if steps > limit:
                raise RuntimeError(f"{int((~finished).sum())} episodes still running after {steps} steps; "
                                   f"the env should truncate at max_steps={limit}")
            td = policy(td)
            td = env.step(td)["next"]
            steps += 1
            # Rows of envs that finished earlier keep stepping (no auto-reset) and are ignored.
            first = td["done"].reshape(-1) & ~finished[rows]
            if first.any():
                records[rows[first]] = td["episode"][first]
                finished[rows[first]] = True
            running = ~finished[rows]
            n_running = int(running.sum())
            if compact and env.num_envs >= MIN_COMPACT_BATCH and 0 < n_running < COMPACT_BELOW * env.num_envs:
                keep = running.nonzero().squeeze(-1)
                env, td, rows = compact_env(env, keep), td[keep], rows[keep]
    return records.cpu(), steps


def evaluate(policy: Any, scenario: str = "train", n_episodes: int = 500, seed: int = EVAL_SEED,
             device: str | torch.device = "cpu", env_overrides: Mapping[str, Any] | None = None,
             max_steps: int | None = None, *, compact: bool = True,
             checkpoint_dir: str | os.PathLike | None = None) -> EvaluationResult:
    """Evaluate one policy on ``n_episodes`` seeded episodes of a scenario (SPEC 5 protocol).

    Args:
        policy: a TensorDict module, a checkpoint path, or a policy name (see :func:`policy_source`).
        scenario: ``train``, ``s1`` ... ``s5``, ``tau_v`` (or a scenario mapping).
        n_episodes: episodes, all stepped together as one batch of envs.
        seed: env seed; :data:`EVAL_SEED` gives every policy the same starts and goals.
        device: torch device of the env and the policy.
        env_overrides: scenario fields on top of the policy's own (e.g. ``{"tau_v": 0.5}``).
        max_steps: episode limit T_max override (default: the scenario's, 500 steps).
        compact: see :func:`run_episodes`; the metrics do not depend on it.
        checkpoint_dir: where a learned policy given by name finds ``<stem>/seed<k>.pt``.

    Returns:
        an :class:`EvaluationResult` with one record per episode, in env order.
    """
    if not isinstance(n_episodes, int) or n_episodes < 1:
        raise ValueError(f"n_episodes must be an integer >= 1, got {n_episodes!r}")
    start = time.perf_counter()
    source = policy_source(policy, device=device, checkpoint_dir=checkpoint_dir)
    overrides = {**source.env, **dict(env_overrides or {})}
    if max_steps is not None:
        overrides["max_steps"] = int(max_steps)
    env = FlockingEnv(scenario, num_envs=n_episodes, device=device, seed=seed, **overrides)
    module = source.build(env)
    records, steps = run_episodes(env, module, compact=compact)
    return EvaluationResult(
        policy=source.name,
        scenario=env.cfg.name if not isinstance(scenario, str) else scenario,
        seed=seed,
        env_overrides=overrides,
        episodes={k: records[k].clone() for k in METRIC_KEYS},
        rollout_steps=steps,
        wall_time_s=time.perf_counter() - start,
        source=source.origin,
    )


def rollout_episode(policy: Any, scenario: str = "train", seed: int = EVAL_SEED, device: str | torch.device = "cpu",
                    env_overrides: Mapping[str, Any] | None = None, max_steps: int | None = None,
                    checkpoint_dir: str | os.PathLike | None = None) -> tuple[TensorDict, FlockingEnv]:
    """One seeded episode of one env, kept step by step (for plots and animations).

    The env is built with ``num_envs=1`` and seeded with ``seed``, so every policy given the
    same seed starts from the same layout (a batch of one draws other layouts than the first
    env of a larger batch). Deterministic actions.

    Returns:
        ``(rollout, env)``: the rollout TensorDict ``[1, T]`` (``T`` steps up to the first
        ``done``; the state before each step at the root, after it under ``"next"``) and the env
        (for its config: obstacles, goal radius, field of view).
    """
    source = policy_source(policy, device=device, checkpoint_dir=checkpoint_dir)
    overrides = {**source.env, **dict(env_overrides or {})}
    if max_steps is not None:
        overrides["max_steps"] = int(max_steps)
    env = FlockingEnv(scenario, num_envs=1, device=device, seed=seed, **overrides)
    module = source.build(env)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(env.cfg.max_steps, module, break_when_any_done=True)
    return rollout.cpu(), env


# ---------------------------------------------------------------------------- scripts/evaluate.py
def policy_path_override(argv: Sequence[str]) -> list[str]:
    """Command-line shim: ``policy=<path>`` (with a ``/`` or ending in ``.pt``) becomes
    ``checkpoint=<path>``, since ``policy`` is the Hydra group of policy configs."""
    out = []
    for arg in argv:
        key, sep, value = arg.partition("=")
        if sep and key == "policy" and ("/" in value or value.endswith(".pt")):
            arg = f"checkpoint={value}"
        out.append(arg)
    return out


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


def evaluate_from_config(cfg: Any) -> tuple[EvaluationResult, list[Path]]:
    """Run ``scripts/evaluate.py``'s composed config (``conf/evaluate.yaml``) and write
    ``<out>/<policy>_<scenario>.csv`` (per episode) and ``.json`` (summary, config).

    The policy is ``cfg.checkpoint`` if set, else the composed ``cfg.policy`` node: a rule-based
    one is built from that node (so ``policy.params.<p>=...`` on the command line applies), a
    learned one from its lowest-seed checkpoint under ``cfg.checkpoints_dir``.
    """
    import json

    if int(cfg.get("threads") or 0) > 0:
        torch.set_num_threads(int(cfg.threads))
    policy_node = OmegaConf.to_container(cfg.policy, resolve=True)
    policy_env = dict(policy_node.get("env") or {})  # type: ignore[union-attr]
    if cfg.get("checkpoint"):
        policy: Any = cfg.checkpoint
    elif policy_node.get("kind") == "rule":  # type: ignore[union-attr]
        node = {k: v for k, v in policy_node.items() if k in ("name", "kind", "controller", "env", "params")}  # type: ignore[union-attr]

        def build(env: FlockingEnv):
            from .baselines import make_baseline  # lazy: the baselines land separately

            return make_baseline(node, env.cfg)

        policy = PolicySource(name=str(node["name"]), env=policy_env, build=build,
                              origin=f"baseline:{policy_config_stem(str(node['name']))}")
    else:
        policy = policy_config_stem(str(policy_node["name"]))  # type: ignore[index]
    scenario = OmegaConf.to_container(cfg.scenario, resolve=True)
    result = evaluate(policy, scenario=scenario, n_episodes=int(cfg.episodes), seed=int(cfg.seed),  # type: ignore[arg-type]
                      device=str(cfg.device), max_steps=cfg.get("max_steps"), checkpoint_dir=cfg.checkpoints_dir)
    stem = f"{policy_config_stem(result.policy)}_{result.scenario}"
    if result.scenario == "tau_v":
        stem += f"{float(scenario['tau_v']):g}"  # type: ignore[index]
    if cfg.get("checkpoint"):
        stem += f"_{Path(str(cfg.checkpoint)).stem}"
    out = Path(str(cfg.out))
    csv_path = result.write_csv(out / f"{stem}.csv")
    summary = {
        "policy": result.policy, "scenario": result.scenario, "source": result.source, "seed": result.seed,
        "n_episodes": result.n_episodes, "env_overrides": result.env_overrides, "summary": result.summary(),
        "rollout_steps": result.rollout_steps, "wall_time_s": round(result.wall_time_s, 3),
        "config": OmegaConf.to_container(cfg, resolve=True),
    }
    json_path = write_text_atomic(out / f"{stem}.json", json.dumps(_jsonable(summary), indent=2) + "\n")
    return result, [csv_path, json_path]
