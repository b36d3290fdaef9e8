"""What a :class:`~flock_torchrl.world.env.FlockingEnv` emits: its specs, and its outputs read
off the worlds' state (the ``"agents"`` group, the shared done flags, the running episode
metrics, and the extra keys asked for)."""

from __future__ import annotations

from typing import Iterable, Mapping

import torch
from tensordict import TensorDict
from torchrl.data import Bounded, Categorical, Composite, Unbounded

from ..config.scenario import ScenarioConfig
from .metrics import FLAG_METRICS, METRIC_KEYS, summary_values
from .sensors import observation_size, state_size

# Keys emitted on request (``extras=``): nobody pays for what nobody reads.
EXTRAS = {
    "physics": (("agents", "position"), ("agents", "velocity"), ("agents", "heading"), "goal",
                ("obstacles", "position"), ("obstacles", "drawn_circles"), ("obstacles", "drawn_rectangles")),
    "command": (("agents", "command"), ("agents", "instinct")),
    "laser": (("agents", "scan"), ("agents", "scan_obstacle")),
}


def extras_of(extras: str | Iterable[str]) -> frozenset[str]:
    """The names of ``extras`` (``"all"``: every one); an unknown name is a ``ValueError``."""
    names = set(EXTRAS) if extras == "all" else {extras} if isinstance(extras, str) else set(extras)
    unknown = sorted(names - set(EXTRAS))
    if unknown:
        raise ValueError(f"extras: unknown name(s) {unknown}; known: {sorted(EXTRAS)} or 'all'")
    return frozenset(names)


def _drawn(cfg: ScenarioConfig) -> dict[str, tuple[str, int, int]]:
    """The ``"obstacles"`` entries of the ``"physics"`` extras: ``name: (world key, count, size)``,
    the moving circles' centres and the episode's drawn obstacles, each where the scenario has them."""
    entries = {"position": ("moving_position", cfg.n_moving, 2),
               "drawn_circles": ("drawn_circles", cfg.drawn_cylinders, cfg.circle_size),
               "drawn_rectangles": ("drawn_rectangles", cfg.random_rectangles, cfg.rectangle_size),
               "drawn_spheres": ("drawn_spheres", cfg.drawn_spheres, 4)}
    return {name: entry for name, entry in entries.items() if entry[1]}


def env_specs(cfg: ScenarioConfig, b: int, extras: frozenset[str], device: torch.device) -> dict[str, Composite]:
    """The observation, action, reward and done specs of ``b`` worlds of ``cfg``."""
    n, d = cfg.n_uavs, cfg.dims

    def box(*shape, low=-1.0, high=1.0):
        return Bounded(low=low, high=high, shape=(b, n, *shape), dtype=torch.float32, device=device)

    def free(*shape, dtype=torch.float32, batch=(b, n)):
        return Unbounded(shape=(*batch, *shape), dtype=dtype, device=device)

    def flag(*shape, batch=(b, n)):
        return Categorical(2, shape=(*batch, *shape), dtype=torch.bool, device=device)

    agents = {"observation": box(observation_size(cfg)), "state": box(state_size(cfg))}
    if "physics" in extras:
        agents.update(position=free(d), velocity=free(d), heading=free())
        if d == 3:
            agents.update(climb=free())
    if "command" in extras:
        agents.update(command=box(d, low=-cfg.v_max, high=cfg.v_max), instinct=flag())
    if "laser" in extras:
        agents.update(scan=box(cfg.n_laser, low=0.0, high=cfg.laser_range),
                      scan_obstacle=Bounded(low=-1, high=max(cfg.n_obstacles - 1, 0),
                                            shape=(b, n, cfg.n_laser), dtype=torch.int64, device=device))
    episode = Composite(
        {k: (flag(batch=(b,)) if k in FLAG_METRICS else free(batch=(b,), dtype=torch.int64) if k == "steps"
             else free(batch=(b,))) for k in METRIC_KEYS},
        shape=(b,), device=device)
    observation = Composite(agents=Composite(agents, shape=(b, n), device=device), episode=episode, shape=(b,),
                            device=device)
    if "physics" in extras:
        observation["goal"] = free(d, batch=(b,))
        obstacles = {name: free(count, size, batch=(b,)) for name, (_, count, size) in _drawn(cfg).items()}
        if obstacles:
            observation["obstacles"] = Composite(obstacles, shape=(b,), device=device)
    action = box(d) if cfg.action_mode == "policy" else box(d, low=-cfg.v_max, high=cfg.v_max)
    return {
        "observation": observation,
        "action": Composite(agents=Composite(action=action, shape=(b, n), device=device), shape=(b,), device=device),
        "reward": Composite(agents=Composite(reward=free(1), shape=(b, n), device=device), shape=(b,), device=device),
        "done": Composite(done=flag(1, batch=(b,)), terminated=flag(1, batch=(b,)), truncated=flag(1, batch=(b,)),
                          shape=(b,), device=device),
    }


def env_output(world: TensorDict, cfg: ScenarioConfig, extras: frozenset[str],
               summary: Mapping[str, torch.Tensor] | None = None, reward: torch.Tensor | None = None) -> TensorDict:
    """What ``reset`` / ``step`` return for the worlds' state ``world`` (batch ``[B]``); ``summary``:
    the episode summary if the step computed it already, ``reward [B, N]`` after a step.

    Built with ``TensorDict._new_unsafe``: every entry comes from the world, whose shapes and
    device are the env's by construction, so the per-entry checks would only cost time."""
    sensed, device = world["sensed"], world.device
    agents = {"observation": sensed["observation"], "state": sensed["state"]}
    if reward is not None:
        agents["reward"] = reward[..., None]
    if "physics" in extras:
        agents.update(position=world["position"], velocity=world["velocity"], heading=world["heading"])
        if cfg.dims == 3:
            agents["climb"] = world["climb"]
    if "command" in extras:
        agents.update(command=world["command"], instinct=world["instinct"])
    if "laser" in extras:
        agents.update(scan=sensed["scan"], scan_obstacle=sensed["scan_obstacle"])
    terminated, truncated = world["terminated"], world["truncated"]
    if summary is None:
        summary = summary_values(world["episode"], cfg.collision_distance)
    out = {
        "agents": TensorDict._new_unsafe(agents, batch_size=(*world.batch_size, cfg.n_uavs), device=device),
        "episode": summary,
        "terminated": terminated, "truncated": truncated, "done": terminated | truncated,
    }
    if "physics" in extras:
        out["goal"] = world["goal"]
        obstacles = {name: world[key] for name, (key, _, _) in _drawn(cfg).items()}
        if obstacles:
            out["obstacles"] = obstacles
    return TensorDict._new_unsafe(out, batch_size=world.batch_size, device=device)


__all__ = ["EXTRAS", "env_output", "env_specs", "extras_of"]
