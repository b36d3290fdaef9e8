"""Memory a run may really use, and the estimates checked against it before anything is
allocated or written.

:func:`usable_memory` is the smallest of what the machine can still give (``MemAvailable``),
what the process's own limits leave (``ulimit -v`` / ``RLIMIT_AS`` and ``ulimit -d`` /
``RLIMIT_DATA``, less what the process already maps) and what its cgroup leaves
(``memory.max`` less ``memory.current``). :func:`check_memory` refuses an estimate above it
with one :class:`~flock_torchrl.config.ConfigError` naming the key that costs most, the
estimate and the limit. The estimates (bytes: :func:`train_bytes`, :func:`world_bytes`,
:func:`reserve_bytes`, :func:`spawn_check_bytes`, :func:`forest_bytes`) are upper bounds of the
big tensors, measured against peak resident memory in ``tests/test_memory.py``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from ..config.scenario import ConfigError

GiB = 2**30


@dataclass(frozen=True)
class Usable:
    bytes: int
    what: str          # where the bound comes from, for the message


def _meminfo(field: str, path: str = "/proc/meminfo") -> int | None:
    try:
        for line in Path(path).read_text().splitlines():
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_room() -> int | None:
    """``memory.max - memory.current`` of this process's cgroup (v2), ``None`` when unlimited."""
    try:
        line = Path("/proc/self/cgroup").read_text().splitlines()[0]
        folder = Path("/sys/fs/cgroup") / line.split("::", 1)[1].lstrip("/")
        limit = (folder / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return max(int(limit) - int((folder / "memory.current").read_text()), 0)
    except (OSError, ValueError, IndexError):
        return None


def usable_memory() -> Usable | None:
    """The bytes this process can still allocate, and what bounds them (``None``: unknown)."""
    import resource

    bounds: list[Usable] = []
    available = _meminfo("MemAvailable")
    if available is None:
        try:
            available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            available = None
    if available is not None:
        bounds.append(Usable(available, "what this machine has free"))
    for limit, name, field in ((getattr(resource, "RLIMIT_AS", None), "ulimit -v", "VmSize"),
                               (getattr(resource, "RLIMIT_DATA", None), "ulimit -d", "VmData")):
        if limit is None:
            continue
        soft = resource.getrlimit(limit)[0]
        if soft == resource.RLIM_INFINITY:
            continue
        used = _meminfo(field, "/proc/self/status") or 0
        bounds.append(Usable(max(soft - used, 0), f"its {name} of {soft / GiB:.1f} GiB, {used / GiB:.1f} GiB "
                                                  "of it in use"))
    room = _cgroup_room()
    if room is not None:
        bounds.append(Usable(room, "what its cgroup's memory.max leaves"))
    return min(bounds, key=lambda u: u.bytes) if bounds else None


def gib(n: float) -> str:
    return f"{n / GiB:.1f} GiB" if n >= GiB / 10 else f"{n / 2**20:.0f} MiB"


def check_memory(parts: Mapping[str, float], what: str, usable: Usable | None = None) -> None:
    """Refuse ``parts`` (bytes by the config key that sets them) when together they exceed
    what this process may use: one line naming the costliest key, the estimate and the bound."""
    usable = usable or usable_memory()
    parts = {k: v for k, v in parts.items() if v > 0}
    if usable is None or not parts:
        return
    total = sum(parts.values())
    if total > usable.bytes:
        key = max(parts, key=parts.get)
        share = "" if len(parts) == 1 else f", {gib(parts[key])} of it for {key}"
        raise ConfigError(key, f"{what} needs about {gib(total)}{share}, but this process can use "
                               f"{gib(usable.bytes)} ({usable.what}); lower it")


# ---------------------------------------------------------------------------- estimates
def world_bytes(scenario: Any) -> int:
    """One batched world of ``scenario`` while it steps: about 8 kB per UAV of state and
    sensing, 10 float32 ``[N, N]`` pairwise terms, the beams, and the random forest's per-world
    fallback grid (measured peaks: 4.7 kB per UAV at N = 5, 44 kB at N = 2000, 12 kB at N = 200
    among obstacles)."""
    n = scenario.n_uavs
    beams = getattr(scenario, "n_laser", scenario.n_beams)  # every ring's beams in 3-D (section 11)
    return n * (8192 + 40 * n + 64 * beams) + 64 * forest_cells(scenario) * _blockers(scenario)


def reserve_bytes(scenario: Any, pool: int) -> int:
    """A training env's reserve of ``pool`` fresh worlds (``reset_pool``, FlockingEnv): the
    worlds it keeps, and at a refill the new draw and its concatenation with the unused ones:
    1.25 stepping worlds (:func:`world_bytes`) each (measured peaks: 0.3 to 0.9 of ``pool``
    stepping worlds, 2-D and 3-D, with and without a forest, 5 to 50 UAVs)."""
    return pool * world_bytes(scenario) * 5 // 4


def _blockers(scenario: Any) -> int:
    return 2 + len(scenario.circles) + len(scenario.rectangles) + scenario.n_moving


def forest_cells(scenario: Any) -> int:
    """The number of cells of the random forest's fallback grid (0 without drawn obstacles)."""
    from .forest import cell_grid, drawn_count

    if not drawn_count(scenario):
        return 0
    columns, rows, _, _ = cell_grid(scenario)
    return columns * rows


def forest_bytes(scenario: Any, centres: int = 360) -> int:
    """The forest check: the grid ``[G, 5]`` and ``box_gap`` over ``[centres, G, P]`` (float64,
    about 12 temporaries of 8 bytes)."""
    cells = forest_cells(scenario)
    return cells * 40 * 3 + centres * cells * _blockers(scenario) * 96


def lattice_points(scenario: Any) -> int:
    """``P`` of the spawn lattices ``[16, P, 2]`` (:func:`~flock_torchrl.world.spawn.lattice_offsets`)."""
    radius, spacing = scenario.swarm_spawn_radius, max(scenario.spawn_separation, 1e-3) * (1 + 1e-4)
    rows = math.ceil((radius + 2 * spacing) / (spacing * math.sqrt(3) / 2))
    cols = math.ceil((radius + 2 * spacing) / spacing)
    return (2 * rows + 1) * (2 * cols + 1)


def spawn_check_bytes(scenario: Any, centres: int = 360, lattices: int = 16) -> int:
    """The spawn check: lattice points around every centre ``[360, 16, P, 2]`` float64, their
    copy, and their distances to every fixed obstacle (a few float64 temporaries each)."""
    if scenario.n_uavs <= 1 or scenario.spawn_separation <= 0:
        return 0
    obstacles = len(scenario.circles) + len(scenario.rectangles)
    return centres * lattices * lattice_points(scenario) * (48 + 40 * obstacles)


def train_bytes(cfg: Any) -> dict[str, int]:
    """What a training run holds, by the key that sets it: the replay buffer (swarm transitions
    of every key the learner stores; with ``experiment.keep_buffer_in_checkpoint``, a checkpoint's
    write besides: a copy of the filled rows and their serialised bytes, at most the rows
    ``experiment.max_frames`` fills, :func:`~flock_torchrl.run.parts.buffer_state`), the training
    worlds, their reserves of fresh worlds (``reset_pool``: one per training env, of each member,
    of each collector worker and of the main process beside them) and the evaluation's worlds."""
    from .sensors import observation_size, state_size

    s, exp, sizes = cfg.scenario, cfg.experiment, cfg.train_scenarios
    n = max(t.n_uavs for t in sizes)
    per_uav = 4 * (2 * (observation_size(s) + state_size(s)) + 2 + 1 + 1 + 2 + 2)  # float32 obs/state twice, ...
    members = int(getattr(cfg, "population", 1) or 1)   # a population holds K buffers and K x B worlds
    parts = {}
    if cfg.algo.name in ("sac", "ddpg"):
        capacity = max(1, math.ceil(cfg.algo.buffer_size / n)) * n          # UAV transitions, per member
        filled = min(capacity, exp.max_frames * n) if exp.max_frames else capacity  # the most the run writes
        written = 2 * filled if getattr(exp, "keep_buffer_in_checkpoint", True) else 0
        parts["algo.buffer_size"] = members * (capacity + written) * per_uav
    worlds = "experiment.swarm_sizes" if exp.swarm_sizes else "experiment.num_envs"
    parts[worlds] = members * sum(exp.num_envs // len(sizes) * world_bytes(t) for t in sizes)
    pool = int(getattr(cfg, "reset_pool", 0) or 0)
    if pool:
        envs = exp.workers + (exp.workers > 1)  # each worker's env, and the main process's
        parts["reset_pool"] = members * envs * sum(reserve_bytes(t, pool) for t in sizes)
    parts["experiment.eval_episodes"] = exp.eval_episodes * world_bytes(s)
    return parts


def check_episodes_memory(scenario: Any, episodes: int, key: str = "episodes") -> None:
    """An evaluation steps all its episodes at once: ``episodes`` worlds of ``scenario``."""
    check_memory({key: episodes * world_bytes(scenario)}, f"evaluating {episodes} episodes at once")


def check_scenario_memory(scenario: Any, key: str = "scenario.n_uavs") -> None:
    """What checking ``scenario``'s spawn and forest needs, before it is allocated."""
    check_memory({key: spawn_check_bytes(scenario), "scenario.random_region": forest_bytes(scenario)},
                 "checking that the swarm and the forest can always be placed")


__all__ = ["check_episodes_memory", "train_bytes", "Usable", "check_memory", "check_scenario_memory", "forest_bytes",
           "forest_cells", "lattice_points", "reserve_bytes", "spawn_check_bytes", "usable_memory", "world_bytes"]
