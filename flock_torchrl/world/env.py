"""``FlockingEnv``: B independent copies of the world of docs/specification.md as one batched
TorchRL environment."""

from __future__ import annotations

import functools
import time
from typing import Any, Iterable, Mapping, Sequence

import torch
from omegaconf import DictConfig
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from ..capture import captured
from ..config.scenario import ScenarioConfig
from .geometry import Obstacles
from .metrics import FLAG_METRICS, METRIC_KEYS, new_accumulator, summary_values
from .sensors import observation_size, state_size
from .spawn import check_spawn_feasible, sample_layout, static_obstacles
from .state import (ACTION, STATE_KEYS, check_like, check_seed, check_state, checked_action, empty_state, fill_absent,
                    torch_device)
from .step import noise_draws, sense, transition, world_obstacles

# Inductor's CPU code for the compiled step: the step's innermost dimensions are tiny (5 UAVs, 3
# obstacles, 2 coordinates, 36 beams against 16-lane AVX-512 vectors), and inductor's defaults
# vectorise them anyway, with masked loads and stores for each loop's remainder and 16 x 16 tiles
# of which 5 rows hold data. Scalar remainders and no 2-D tiling measured 4.2x the eager step at
# B = 1024 where the defaults gave 2.1x (one process, alternated; docs/throughput.md). CUDA
# kernels (Triton) ignore both settings.
STEP_COMPILE_OPTIONS = {"cpp.enable_loop_tail_vec": False, "cpp.enable_tiling_heuristics": False}
# Calls of a whole compiled step and reset (compile_step with reset_pool) that run eagerly first
# (TorchRL's compile warm-up): the tensordict's layout after a step is settled before tracing.
WHOLE_WARMUP = 2


def _without_memo_guards(entries: Sequence[Any]) -> list[bool]:
    """Dynamo's guards for the whole compiled step, less those on tensordict's memo of which
    classes are tensorclasses: the traced step reads that memo, so dynamo guarded its length, and
    any class checked anywhere later in the process (a learner's first update) recompiled the
    step. The memo caches a class attribute: its other entries cannot change what the step does."""
    return ["_TENSORCLASS_MEMO" not in entry.name for entry in entries]


# Keys emitted on request (``extras=``): nobody pays for what nobody reads.
EXTRAS = {
    "physics": (("agents", "position"), ("agents", "velocity"), ("agents", "heading"), "goal",
                ("obstacles", "position"), ("obstacles", "drawn_circles"), ("obstacles", "drawn_rectangles")),
    "command": (("agents", "command"), ("agents", "instinct")),
    "laser": (("agents", "scan"), ("agents", "scan_obstacle")),
}


def take_from_reserve(world: dict, reserve: dict, pointer: torch.Tensor, done: torch.Tensor,
                      pool: int) -> tuple[dict, torch.Tensor]:
    """``(world, pointer)`` after the done worlds took the next unused reserve worlds.

    ``world``: the worlds' entries (nested dicts of ``[K * B, ...]`` tensors), ``reserve`` the
    reserve's (``[K * pool, ...]``, member-major), ``pointer [K]`` each member's next unused
    reserve world, ``done [K, B]`` the done flags: world ``b`` of member ``k`` takes reserve world
    ``pointer[k] + (done worlds of k up to b) - 1`` (clamped into the member's reserve) when done.
    Tensor operations only: no host read, no branch on a value (what :meth:`FlockingEnv.maybe_reset`
    runs; with ``compile_step``, traced with the step as one function)."""
    members = done.shape[0]
    taken = done.long().cumsum(-1)                                                       # [K, B]
    first = torch.arange(members, device=done.device)[:, None] * pool
    slot = ((pointer[:, None] + taken - 1).clamp(0, pool - 1) + first).reshape(-1)      # never past the reserve
    mask = done.reshape(-1)

    def put(old: Any, new: Any) -> Any:
        if isinstance(old, dict):
            return {key: put(value, new[key]) for key, value in old.items()}
        return torch.where(mask.reshape(-1, *(1,) * (old.ndim - 1)), new[slot], old)

    return put(world, reserve), pointer + taken[:, -1]


class FlockingEnv(EnvBase):
    """Multi-UAV flocking (Bai et al. 2024) as a batched, torch-native TorchRL environment.

    Per-UAV entries live under the ``"agents"`` group (batch ``[B, N]``): the policy's
    ``observation`` [17], the critic's ``state`` [20], the ``reward``; ``done``,
    ``terminated`` and ``truncated`` are shared by the swarm, ``[B, 1]`` at the root, and
    ``"episode"`` holds the running section 5 metrics of each world (final when ``done``).
    More keys on request (``extras``): ``"physics"`` (``position``, ``velocity``,
    ``heading``, ``goal``, moving obstacles' ``("obstacles", "position")``, the episode's drawn
    obstacles ``("obstacles", "drawn_circles")`` and ``("obstacles", "drawn_rectangles")``), ``"command"``
    (the executed velocity ``command`` and the ``instinct`` flags), ``"laser"`` (the sensed
    ``scan`` [36] and the obstacle each beam hit, ``scan_obstacle``).

    The worlds' state is one ``TensorDict[B]`` (:attr:`world`): saving is a clone, a subset
    (:meth:`subset`) an index, a partial reset (``"_reset"``) a masked write of freshly drawn
    worlds. Stepping a world that is done raises: reset it first (TorchRL's collectors and
    ``rollout`` do, through ``step_and_maybe_reset``).

    Args:
        scenario: a :class:`~flock_torchrl.config.ScenarioConfig` (checked here unless it is
            already: ``scenario_config(...)`` and the apps hand over checked ones), or a name under
            ``conf/scenario/`` (``train``, ``s1`` ... ``s5``, ``tau_v``, ``forest``; in 3-D ``train3d``,
            ``forest3d``, ``wall3d``), composed with ``reading``, ``policy_id`` and ``overrides`` by
            :func:`flock_torchrl.config.scenario_config`.
        num_envs: batch size ``B``.
        device: torch device of every tensor.
        seed: seed of the env's own generator (spawns, S4 noise, moving and drawn obstacles).
        reading: ``literal`` or ``paper_fit`` (docs/specification.md section 9).
        policy_id: a policy (``policy3_g`` ...) whose sensing, instinct and reward apply (TorchRL
            reserves the keyword ``policy``).
        extras: names from :data:`EXTRAS`, or ``"all"``.
        compile_step: ``torch.compile`` the world's step (:func:`~flock_torchrl.world.step.advance`);
            its eager twin (``False``) gives the same transitions up to float round-off. Worth it
            for a fixed batch (training); each new batch size compiles again.
        check_actions: check every step's action for NaN / inf and refuse to step a world that
            is done (``ValueError``). Both checks read a tensor on the host, which waits for the
            device; with ``False`` the step skips exactly these two (a NaN action then flows
            into the world, a done world keeps moving) and only checks the action's key, shape
            and floating dtype (Python-side, no synchronisation), casts it to float32 on the
            env's device and clips it to the action box, so a GPU step never waits for the host.
        reset_pool: ``0`` (the default): a done world is reset by drawing its new episode there and
            then, as TorchRL's ``maybe_reset`` asks (reading the done flags on the host, and
            rejection sampling with a data-dependent number of rounds). ``P > 0``: the env keeps a
            reserve of ``P`` freshly drawn worlds (per member in a population; ``P >= num_envs``,
            the worlds per member there), and :meth:`maybe_reset` (what ``step_and_maybe_reset``
            and TorchRL's collectors call) hands the done worlds the next unused ones, in world
            order, with tensor operations only: no host read, no branch on a value. The reserve
            is refilled on the host, after every ``P // num_envs`` calls (the most it can take
            before it could run dry): one read of how many were used, then one batched draw of that
            many. Reproducible from the seed, and :meth:`get_state` carries the reserve, but the
            episodes differ from ``reset_pool=0`` once a world was reset (the draws happen in
            another order). See :meth:`maybe_reset` for what else keeps or refills the reserve.
        capture_step: on a GPU, record the world's step as one CUDA graph and replay it
            (``flock_torchrl.capture``, tensordict's ``CudaGraphModule``), and with a reserve
            (``reset_pool``) its hand-out as another: launching the step's hundreds of small
            kernels one by one costs far more than running them. The step is the static-shape
            one (every UAV pair, every beam and obstacle), which never reads the host, eager or
            compiled (``compile_step``; the step alone then, not the whole ``step_and_maybe_reset``
            traced with a reserve). On a CPU it runs as it is: the static-shape step, equal to the
            default one to float round-off. ``check_actions`` stays outside the graph.
        **overrides: any scenario field, e.g. ``tau_v=0.5``, ``n_uavs=9``.

    Example:
        >>> env = FlockingEnv("train", num_envs=4, seed=0, policy_id="policy3_g")
        >>> td = env.rollout(3)
        >>> td["agents", "observation"].shape, td["next", "agents", "reward"].shape
        (torch.Size([4, 3, 5, 17]), torch.Size([4, 3, 5, 1]))
        >>> td["next", "done"].shape
        torch.Size([4, 3, 1])
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}
    batch_locked = True

    def __init__(self, scenario: ScenarioConfig | str = "train", num_envs: int = 1,
                 device: str | torch.device = "cpu", seed: int | None = 0, *, reading: str | None = None,
                 policy_id: str | None = None, extras: str | Iterable[str] = (), compile_step: bool = False,
                 check_actions: bool = True, reset_pool: int = 0, capture_step: bool = False,
                 **overrides: Any) -> None:
        if isinstance(scenario, ScenarioConfig) and not overrides and reading is None and policy_id is None:
            cfg = scenario if scenario.is_checked else scenario.check()  # checked once
        elif isinstance(scenario, (str, ScenarioConfig)):  # a name: the one helper composes it (Hydra)
            from ..config.compose import scenario_config

            cfg = scenario_config(scenario, reading=reading, policy=policy_id, **overrides)
        else:
            raise TypeError(f"scenario: a ScenarioConfig or a scenario's name, got {type(scenario).__name__} "
                            "(flock_torchrl.scenario_config(mapping) checks a mapping)")
        check_spawn_feasible(cfg)
        if not isinstance(num_envs, int) or isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        check_seed(seed)
        if not isinstance(reset_pool, int) or isinstance(reset_pool, bool) or reset_pool < 0:
            raise ValueError(f"reset_pool must be an integer >= 0 (0: no reserve of fresh worlds), got {reset_pool!r}")
        super().__init__(device=torch_device(device), batch_size=torch.Size([num_envs]))
        self.reset_pool = reset_pool
        members, per_member = self._reserve_groups()
        if reset_pool and reset_pool < per_member:
            worlds = "num_envs" if members == 1 else "worlds per member"
            raise ValueError(f"reset_pool must be 0 or at least the {worlds} ({per_member}): one step can reset "
                             f"every world, got {reset_pool}")
        self.cfg = cfg
        self.num_envs = num_envs
        self.n_agents = cfg.n_uavs
        self.extras = _extras(extras)
        self.obs_dim = observation_size(cfg)
        self.state_dim = state_size(cfg)
        self.group_map = {"agents": [f"agent_{i}" for i in range(cfg.n_uavs)]}
        self._static = static_obstacles(cfg, self.device)
        self._generator = torch.Generator(device=self.device)
        self.compile_step = bool(compile_step)
        self.check_actions = bool(check_actions)
        self.capture_step = bool(capture_step)
        # Compiled or captured, the step measures every UAV pair and every (beam, obstacle) pair: static
        # shapes. Called (state, sensed, episode, action, normals): what changes, all tensors (what a
        # captured function is given each call is copied into its graph's inputs); the obstacles and
        # the scenario are bound (a graph holds them as they are).
        step = functools.partial(transition, static_shapes=self.compile_step or self.capture_step)
        if self.compile_step:
            step = torch.compile(step, dynamic=False, fullgraph=True, options=STEP_COMPILE_OPTIONS)
        self._transition = captured(functools.partial(step, static=self._static, cfg=cfg), self.device,
                                    self.capture_step)
        self._hand_out = captured(functools.partial(take_from_reserve, pool=reset_pool), self.device,
                                  self.capture_step and reset_pool > 0)
        self._counted = False                     # whether step_and_maybe_reset counted the reserve's hand-out
        self._normals: dict | None = None         # sensor noise drawn before a whole compiled step
        self._whole_calls = 0                     # calls of the whole compiled step and reset
        self._compiled_whole = bool(self.compile_step and reset_pool and not self.capture_step)  # read in the trace
        if self._compiled_whole:
            # Nothing left reads the host: the step and the hand-out are traced whole, with TorchRL's plumbing.
            self._transition = functools.partial(transition, static_shapes=True, static=self._static, cfg=cfg)
            self.compile(warmup=WHOLE_WARMUP, fullgraph=not self.check_actions, dynamic=False,
                         options={**STEP_COMPILE_OPTIONS, "guard_filter_fn": _without_memo_guards})
        self._agent_batch = torch.Size((num_envs, cfg.n_uavs))
        self._make_spec()
        self.world = self._empty_world()
        if reset_pool:  # empty (all used) until the first maybe_reset fills it
            self._reserve = self._empty_world(sensed=True)[torch.zeros(members * reset_pool, dtype=torch.long,
                                                                       device=self.device)]
            self._reserve_next = torch.zeros(members, dtype=torch.long, device=self.device)
            self._empty_reserve()
            self._fresh_summary = summary_values(new_accumulator(num_envs, self.device), cfg.collision_distance)
        self._sensed_once = False
        self._restored = False
        self.busy_seconds = 0.0  # wall time spent in reset and step (a trainer's time split reads it)
        self.compile_seconds = 0.0  # the compiled step's first call, where torch.compile works (not in busy)
        if seed is not None:
            self.set_seed(seed)

    @classmethod
    def from_config(cls, cfg: ScenarioConfig | DictConfig | Mapping[str, Any], num_envs: int = 1,
                    device: str | torch.device = "cpu", seed: int | None = 0, **kwargs: Any) -> "FlockingEnv":
        """Build from a composed scenario (e.g. Hydra's ``cfg.scenario``), exactly as composed."""
        return cls(ScenarioConfig.from_config(cfg), num_envs=num_envs, device=device, seed=seed, **kwargs)

    # ------------------------------------------------------------------ specs
    def _make_spec(self) -> None:
        b, n, dev = self.num_envs, self.n_agents, self.device
        cfg = self.cfg

        def box(*shape, low=-1.0, high=1.0):
            return Bounded(low=low, high=high, shape=(b, n, *shape), dtype=torch.float32, device=dev)

        def free(*shape, dtype=torch.float32, batch=(b, n)):
            return Unbounded(shape=(*batch, *shape), dtype=dtype, device=dev)

        def flag(*shape, batch=(b, n)):
            return Categorical(2, shape=(*batch, *shape), dtype=torch.bool, device=dev)

        agents = {"observation": box(self.obs_dim), "state": box(self.state_dim)}
        d = cfg.dims
        if "physics" in self.extras:
            agents.update(position=free(d), velocity=free(d), heading=free())
            if d == 3:
                agents.update(climb=free())
        if "command" in self.extras:
            agents.update(command=box(d, low=-cfg.v_max, high=cfg.v_max), instinct=flag())
        if "laser" in self.extras:
            agents.update(scan=box(cfg.n_laser, low=0.0, high=cfg.laser_range),
                          scan_obstacle=Bounded(low=-1, high=max(cfg.n_obstacles - 1, 0),
                                                shape=(b, n, cfg.n_laser), dtype=torch.int64, device=dev))
        episode = Composite(
            {k: (flag(batch=(b,)) if k in FLAG_METRICS else free(batch=(b,), dtype=torch.int64) if k == "steps"
                 else free(batch=(b,))) for k in METRIC_KEYS},
            shape=(b,), device=dev)
        observation = Composite(agents=Composite(agents, shape=(b, n), device=dev), episode=episode, shape=(b,),
                                device=dev)
        if "physics" in self.extras:
            observation["goal"] = free(d, batch=(b,))
            obstacles = {}
            if cfg.n_moving:
                obstacles["position"] = free(cfg.n_moving, 2, batch=(b,))
            if cfg.drawn_cylinders:
                obstacles["drawn_circles"] = free(cfg.drawn_cylinders, cfg.circle_size, batch=(b,))
            if cfg.random_rectangles:
                obstacles["drawn_rectangles"] = free(cfg.random_rectangles, cfg.rectangle_size, batch=(b,))
            if cfg.drawn_spheres:
                obstacles["drawn_spheres"] = free(cfg.drawn_spheres, 4, batch=(b,))
            if obstacles:
                observation["obstacles"] = Composite(obstacles, shape=(b,), device=dev)
        self.observation_spec = observation
        action = box(d) if cfg.action_mode == "policy" else box(d, low=-cfg.v_max, high=cfg.v_max)
        self.action_spec = Composite(agents=Composite(action=action, shape=(b, n), device=dev), shape=(b,), device=dev)
        self.reward_spec = Composite(agents=Composite(reward=free(1), shape=(b, n), device=dev), shape=(b,),
                                     device=dev)
        self.done_spec = Composite(done=flag(1, batch=(b,)), terminated=flag(1, batch=(b,)),
                                   truncated=flag(1, batch=(b,)), shape=(b,), device=dev)
        # What a whole compiled step is traced on: the env's outputs and the action.
        self._whole_keys = [*self.full_observation_spec.keys(True, True), *self.full_done_spec.keys(True, True),
                            *self.full_state_spec.keys(True, True), *self.full_action_spec.keys(True, True)]

    # ------------------------------------------------------------------ state
    def _empty_world(self, sensed: bool = False) -> TensorDict:
        """All-zero worlds (before the first reset); ``sensed``: with the sensing of that state
        (noise-free), the layout every stored world has."""
        b, dev = self.num_envs, self.device
        state = empty_state(self.cfg, b, dev)
        world = {**state, "episode": new_accumulator(b, dev)}
        if sensed:
            n, k = self.cfg.n_uavs, self.cfg.n_laser
            normals = None if not self.cfg.noise else {
                "scan": torch.zeros(b, n, k, device=dev),
                **{key: torch.zeros(b, n, n, device=dev) for key in ("distance", "bearing", "heading_difference")}}
            world["sensed"] = sense(state, self._static, self.cfg, normals)
        return TensorDict(world, batch_size=[b], device=dev)

    # The env's only random draws go through these two (a population draws per member).
    def _draw_layout(self, index: torch.Tensor | None):
        """Spawns for the worlds ``index`` (ascending; ``None``: every world), from the env's generator."""
        count = self.num_envs if index is None else int(index.numel())
        return sample_layout(self.cfg, count, self._static, self._generator, self.device)

    def _draw_noise(self, index: torch.Tensor | None):
        """Sensor noise for the worlds ``index`` (``None``: every world); ``None`` without noise."""
        count = self.num_envs if index is None else int(index.numel())
        return noise_draws(self.cfg, count, self._generator, self.device)

    def _fresh_worlds(self, index: torch.Tensor | None = None) -> TensorDict:
        """New episodes for the worlds ``index`` (``None``: all): spawned (Eq. 30), at rest, sensed.
        A world's episode depends on its index only through the generator it draws from (a
        population's member), so the reserve (``reset_pool``) draws with an index repeating a
        member's first world as often as it needs worlds."""
        layout = self._draw_layout(index)
        count = self.num_envs if index is None else int(index.numel())
        dev = self.device
        state = empty_state(self.cfg, count, dev)
        state.update(position=layout.position, heading=layout.heading, goal=layout.goal,
                     moving_position=layout.moving_position, moving_velocity=layout.moving_velocity,
                     drawn_circles=layout.drawn_circles, drawn_rectangles=layout.drawn_rectangles,
                     drawn_spheres=layout.drawn_spheres)
        sensed = sense(state, self._static, self.cfg, self._draw_noise(index))
        return TensorDict({**state, "episode": new_accumulator(count, dev), "sensed": sensed},
                          batch_size=[count], device=dev)

    def _output(self, summary: Mapping[str, torch.Tensor] | None = None, reward: torch.Tensor | None = None
                ) -> TensorDict:
        """What ``reset`` / ``step`` return for the current world; ``summary``: the episode
        summary if the step computed it already, ``reward [B, N]`` after a step.

        Built with ``TensorDict._new_unsafe``: every entry comes from the world, whose shapes
        and device are the env's by construction, so the per-entry checks would only cost time."""
        world, extras = self.world, self.extras
        sensed = world["sensed"]
        agents = {"observation": sensed["observation"], "state": sensed["state"]}
        if reward is not None:
            agents["reward"] = reward[..., None]
        if "physics" in extras:
            agents.update(position=world["position"], velocity=world["velocity"], heading=world["heading"])
            if self.cfg.dims == 3:
                agents["climb"] = world["climb"]
        if "command" in extras:
            agents.update(command=world["command"], instinct=world["instinct"])
        if "laser" in extras:
            agents.update(scan=sensed["scan"], scan_obstacle=sensed["scan_obstacle"])
        terminated, truncated = world["terminated"], world["truncated"]
        if summary is None:
            summary = summary_values(world["episode"], self.cfg.collision_distance)
        out = {
            "agents": TensorDict._new_unsafe(agents, batch_size=self._agent_batch, device=self.device),
            "episode": summary,
            "terminated": terminated, "truncated": truncated, "done": terminated | truncated,
        }
        if "physics" in extras:
            out["goal"] = world["goal"]
            obstacles = self._obstacle_extras()
            if obstacles:
                out["obstacles"] = obstacles
        return TensorDict._new_unsafe(out, batch_size=self.batch_size, device=self.device)

    def _obstacle_extras(self) -> dict[str, torch.Tensor]:
        """The ``"obstacles"`` entries of the ``"physics"`` extras: the moving circles' centres
        and the drawn obstacles, each only where the scenario has them."""
        cfg, world = self.cfg, self.world
        entries = {"position": ("moving_position", cfg.n_moving),
                   "drawn_circles": ("drawn_circles", cfg.drawn_cylinders),
                   "drawn_rectangles": ("drawn_rectangles", cfg.random_rectangles),
                   "drawn_spheres": ("drawn_spheres", cfg.drawn_spheres)}
        return {name: world[key] for name, (key, count) in entries.items() if count}

    # ------------------------------------------------------------------ TorchRL API
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDict:
        start = time.perf_counter()
        try:
            return self._reset_worlds(tensordict)
        finally:
            self.busy_seconds += time.perf_counter() - start

    def _reset_worlds(self, tensordict: TensorDictBase | None) -> TensorDict:
        mask = None
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset")
            if not isinstance(mask, torch.Tensor) or mask.dtype != torch.bool:
                raise ValueError(f"FlockingEnv.reset: \"_reset\" must be a torch.bool mask of {self.num_envs} "
                                 f"world(s) (shape [{self.num_envs}, 1]), got "
                                 f"{mask.dtype if isinstance(mask, torch.Tensor) else type(mask).__name__}")
            if mask.numel() != self.num_envs:
                raise ValueError(f"FlockingEnv.reset: \"_reset\" has shape {list(mask.shape)}, expected "
                                 f"[{self.num_envs}, 1] (one flag per world)")
            mask = mask.reshape(self.num_envs).to(self.device)
        if self._restored and mask is None:  # a restored state continues its episodes
            self._restored = False
            return self._output()
        self._restored = False
        if mask is None or bool(mask.all()) or not self._sensed_once:
            self.world = self._fresh_worlds()
            self._sensed_once = True
        elif bool(mask.any()):
            index = mask.nonzero().squeeze(-1)
            fresh = self._fresh_worlds(index)
            # Out of place: tensors already handed out in earlier outputs stay as they were.
            self.world = self.world.apply(lambda old, new: old.index_put((index,), new), fresh)
        return self._output()

    # ------------------------------------------------------------------ the reserve (reset_pool > 0)
    def _reserve_groups(self) -> tuple[int, int]:
        """``(groups, worlds per group)`` of the reserve: one group here, a member's worlds in a
        population (each member's done worlds take from that member's own reserve)."""
        return 1, int(self.batch_size[0])

    def maybe_reset(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Reset the done worlds of ``tensordict`` (what ``step_and_maybe_reset`` returns next).

        With ``reset_pool = 0``: TorchRL's ``maybe_reset`` (the done flags read on the host, and
        a masked ``reset`` drawing the new episodes there and then). With ``reset_pool = P``: the
        done worlds take the next unused worlds of the reserve, in world order (world ``i`` the
        ``pointer + (done worlds up to i) - 1``-th), and the returned tensordict holds their
        outputs where TorchRL's masked reset would put them (the same keys, shapes and dtypes;
        the other worlds' entries unchanged), all in tensor operations: no host read. Before a
        call that could take more worlds than the reserve has left (after ``P // B`` calls for
        ``B`` worlds), the reserve is refilled on the host: the used worlds' count read once, the
        unused kept in order and that many new ones drawn after them from the env's generator.

        The reserve serves this method only: a full ``reset()``, a ``reset`` with a ``"_reset"``
        mask, :meth:`place` and :meth:`subset` (whose new env has no reserve) draw or set worlds
        as without one and leave the reserve as it is; :meth:`set_seed` empties it (the next call
        here draws it anew, so the same seed gives the same episodes); :meth:`get_state` and
        :meth:`set_state` carry it, its pointer and the calls since its refill. A TorchRL
        ``TransformedEnv`` around this env resets through its own ``maybe_reset`` (a masked
        ``reset``), so there the reserve goes unused."""
        if not self.reset_pool:
            return super().maybe_reset(tensordict)
        if torch.compiler.is_compiling():  # traced whole: counted, refilled and timed by the caller
            return self._reset_from_reserve(tensordict)
        if self._compiled_whole and self._counted:  # its eager warm-up: step_and_maybe_reset times it
            return self._reset_from_reserve(tensordict)
        start = time.perf_counter()
        try:
            if not self._counted:
                self._reserve_due()
            return self._reset_from_reserve(tensordict)
        finally:
            self.busy_seconds += time.perf_counter() - start

    def _reserve_due(self) -> None:
        """Count one hand-out of the reserve, refilling it first if that hand-out could run it dry."""
        members, per_member = self._reserve_groups()
        if (self._reserve_calls + 1) * per_member > self.reset_pool:
            self._refill_reserve()
        self._reserve_calls += 1

    def step_and_maybe_reset(self, tensordict: TensorDictBase) -> tuple[TensorDictBase, TensorDictBase]:
        """TorchRL's ``step_and_maybe_reset``. With a reserve (``reset_pool``) the reserve's
        hand-out is counted (and the reserve refilled when due) here, before the step; with
        ``compile_step`` too, the sensor noise is drawn here as well and the rest, the step and
        the reserve's hand-out with TorchRL's bookkeeping around them, runs as one compiled
        function (TorchRL's ``EnvBase.compile``): the same random draws in the same order as
        its eager twin."""
        if not self.reset_pool:
            return super().step_and_maybe_reset(tensordict)
        start, whole = time.perf_counter(), self._compiled_whole
        self._reserve_due()
        if whole:
            self._normals = self._draw_noise(None)
        self._counted = True
        try:
            if not whole:
                return super().step_and_maybe_reset(tensordict)
            # Traced on the env's own keys and the action: what else a policy wrote (a SAC actor's
            # loc and scale, absent while random actions fill the buffer) would change the traced
            # tensordict's layout and recompile it. The caller's tensordict gets the step's "next".
            out, following = super().step_and_maybe_reset(tensordict.select(*self._whole_keys, strict=False))
            tensordict.set("next", out.get("next"))
            return tensordict, following
        finally:
            self._counted, self._normals = False, None
            if whole:  # timed here: the traced step and hand-out do not time themselves
                self._whole_calls += 1
                seconds = time.perf_counter() - start
                if self._whole_calls == WHOLE_WARMUP + 1:  # the call that compiles
                    self.compile_seconds += seconds
                else:
                    self.busy_seconds += seconds

    def _reset_from_reserve(self, tensordict: TensorDictBase) -> TensorDictBase:
        done = tensordict.get("done", None)
        if done is None:  # as TorchRL's any_done: no done flags, nothing to reset
            return tensordict
        members, per_member = self._reserve_groups()
        done = done.reshape(members, per_member).to(self.device)
        old = self.world.to_dict()
        world, self._reserve_next = self._hand_out(old, self._reserve.to_dict(), self._reserve_next, done)

        def restrided(old: dict, new: dict) -> dict:
            # The world's own layout (the compiled step reads back what it wrote, as it wrote it).
            return {key: restrided(value, new[key]) if isinstance(value, dict)
                    else new[key] if new[key].stride() == value.stride() else torch.empty_like(value).copy_(new[key])
                    for key, value in old.items()}

        self.world = TensorDict._new_unsafe(restrided(old, world), batch_size=self.batch_size, device=self.device)
        mask = done.reshape(-1)
        self._restored = False
        # Every reset world is fresh: its episode summary is a fresh accumulator's, made once.
        fresh = self._output(self._fresh_summary)
        # What a reset does not write (the action) is zeroed in the reset worlds, as TorchRL's padding
        # does, with zeros made on the device: its pad is a tensor made from a Python number per key
        # and call, a copy from the host on a GPU.
        for key in set(tensordict.keys(True, True)) - set(fresh.keys(True, True)):
            fresh.set(key, torch.zeros_like(tensordict.get(key)))
        # As TorchRL's reset with a "_reset" mask merges its output (torchrl.envs.utils._update_during_reset).
        return tensordict.where(~mask, other=fresh, out=tensordict, pad=0, update_batch_size=True)

    def _refill_reserve(self) -> None:
        """Keep the reserve's unused worlds, in order, and draw as many new ones after them."""
        members, per_member = self._reserve_groups()
        pool, dev = self.reset_pool, self.device
        used = [int(n) for n in self._reserve_next.cpu()]  # the reserve's one read of the device
        if sum(used):
            # One draw for every member's used worlds (a population reads the member off the world index).
            index = torch.cat([torch.full((n,), k * per_member, dtype=torch.long) for k, n in enumerate(used) if n])
            fresh = self._fresh_worlds(index.to(dev))
            order, drawn = [], members * pool
            for k, n in enumerate(used):  # members, not worlds
                order += [torch.arange(k * pool + n, (k + 1) * pool), torch.arange(drawn, drawn + n)]
                drawn += n
            self._reserve = torch.cat([self._reserve, fresh])[torch.cat(order).to(dev)]
        self._reserve_next.zero_()
        self._reserve_calls = 0

    def _empty_reserve(self) -> None:
        """Mark every reserve world used: the next :meth:`maybe_reset` draws the reserve anew."""
        members, per_member = self._reserve_groups()
        self._reserve_next.fill_(self.reset_pool)
        self._reserve_calls = self.reset_pool // per_member

    def _step(self, tensordict: TensorDictBase) -> TensorDict:
        if self._compiled_whole:  # with the reserve's hand-out, in one function: step_and_maybe_reset times it
            return self._advance(tensordict)
        start = time.perf_counter()
        out = self._advance(tensordict)
        if self.compile_step and not self.compile_seconds:
            self.compile_seconds = time.perf_counter() - start
        else:
            self.busy_seconds += time.perf_counter() - start
        return out

    def _advance(self, tensordict: TensorDictBase) -> TensorDict:
        if not self._sensed_once:
            raise ValueError("FlockingEnv.step: no episode has started; call reset() first (or place(), set_state())")
        action = self._checked_action(tensordict)
        world = self.world
        state = {k: world[k] for k in STATE_KEYS}
        # Drawn before the step when the whole step and reset is compiled (a generator cannot be traced).
        normals = self._draw_noise(None) if self._normals is None else self._normals
        state, sensed, episode, reward, summary = self._transition(
            state, world["sensed"].to_dict(), world["episode"].to_dict(), action, normals=normals)
        # The step's outputs have the world's shapes by construction: no per-entry checks.
        self.world = TensorDict._new_unsafe({**state, "sensed": sensed, "episode": episode},
                                            batch_size=self.batch_size, device=self.device)
        return self._output(summary, reward)

    def _checked_action(self, tensordict: TensorDictBase) -> torch.Tensor:
        """:func:`~.state.checked_action` of this env's worlds (with ``check_actions``: values too)."""
        done = (self.world["terminated"] | self.world["truncated"]).reshape(-1) if self.check_actions else None
        return checked_action(tensordict.get(ACTION, None), self.cfg, self.num_envs, self.device, done)

    def set_seed(self, seed: int | None = None, static_seed: bool = False) -> int | None:
        """TorchRL's ``set_seed``; a seed that is not an integer in [0, 2**64 - 1] is a
        ``ValueError`` naming ``seed``."""
        check_seed(seed)
        return super().set_seed(seed, static_seed)

    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            seed = int(torch.empty((), dtype=torch.int64).random_().item())
        self._generator.manual_seed(int(seed))
        if self.reset_pool:
            self._empty_reserve()

    # ------------------------------------------------------------------ state API
    def get_state(self) -> dict:
        """Everything needed to continue these episodes bit for bit, as plain tensors and dicts."""
        state = {"world": self.world.to_dict(), "generator": self._generator.get_state()}
        if self.reset_pool:
            state["reset_pool"] = {"worlds": self._reserve.to_dict(), "next": self._reserve_next.clone(),
                                   "calls": self._reserve_calls}
        return state

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state`; the next full ``reset()`` returns the restored episodes
        instead of drawing new ones (so a collector built afterwards continues them).

        Every tensor must have the shape and dtype this env keeps (no silent casts: a float64
        state would not continue bit for bit); anything else is a ``ValueError`` naming the key."""
        reference = self._empty_world(sensed=True)
        world = state["world"] if isinstance(state, Mapping) and "world" in state else None
        if not isinstance(world, (Mapping, TensorDictBase)):
            raise ValueError("env state: expected a mapping with a 'world' entry (what get_state() returns)")
        world = TensorDict(fill_absent(self.cfg, world, self.num_envs, self.device), batch_size=[], device=self.device)
        check_state(self.cfg, world, self.num_envs, "env state")
        for key in STATE_KEYS:  # a NaN position would give NaN observations and never end the episode
            value = world.get(key)
            if value.is_floating_point() and not bool(torch.isfinite(value).all()):
                raise ValueError(f"env state: {key!r} contains NaN or inf; a world's state must be finite")
        check_like(world, reference, ("episode", "sensed"), "env state")  # the metrics and the sensing cache
        reserve = self._checked_reserve(state)
        world.batch_size = self.batch_size
        self.world = world
        self._generator.set_state(state["generator"])
        if reserve is not None:
            self._reserve, self._reserve_next, self._reserve_calls = reserve
        self._sensed_once = True
        self._restored = True

    def _checked_reserve(self, state: Mapping[str, Any]) -> tuple[TensorDict, torch.Tensor, int] | None:
        """The reserve of a :meth:`get_state` (``None`` without ``reset_pool``), checked as the
        worlds are; a state saved with another ``reset_pool`` is a ``ValueError``."""
        saved = state.get("reset_pool")
        if not self.reset_pool:
            if saved is not None:
                raise ValueError("env state: it carries a reserve of fresh worlds (saved with reset_pool > 0); this "
                                 "env has reset_pool=0")
            return None
        members, per_member = self._reserve_groups()
        if not isinstance(saved, Mapping) or not {"worlds", "next", "calls"} <= saved.keys():
            raise ValueError(f"env state: no 'reset_pool' entry with 'worlds', 'next' and 'calls' (saved with "
                             f"reset_pool=0?); this env keeps a reserve of {self.reset_pool} worlds")
        count = members * self.reset_pool
        worlds = saved["worlds"]
        if not isinstance(worlds, (Mapping, TensorDictBase)):
            raise ValueError("env state: 'reset_pool' has no mapping of worlds")
        worlds = TensorDict(fill_absent(self.cfg, worlds, count, self.device), batch_size=[], device=self.device)
        check_state(self.cfg, worlds, count, f"env state's reset_pool (reset_pool={self.reset_pool})")
        check_like(worlds, self._reserve, ("episode", "sensed"), "env state's reset_pool")
        pointer, calls = saved["next"], saved["calls"]
        if not (isinstance(pointer, torch.Tensor) and pointer.dtype == torch.long and pointer.shape == (members,)
                and bool(((pointer >= 0) & (pointer <= self.reset_pool)).all())):
            raise ValueError(f"env state: reset_pool 'next' must be an int64 tensor of shape [{members}] in "
                             f"[0, {self.reset_pool}], got {pointer!r}")
        if not isinstance(calls, int) or isinstance(calls, bool) or not 0 <= calls <= self.reset_pool // per_member:
            raise ValueError(f"env state: reset_pool 'calls' must be an integer in [0, "
                             f"{self.reset_pool // per_member}], got {calls!r}")
        if int(pointer.max()) + (self.reset_pool // per_member - calls) * per_member > self.reset_pool:
            raise ValueError(f"env state: reset_pool 'next' ({pointer.tolist()}) is more than {calls} call(s) since "
                             "the refill can have taken: the reserve would run dry")
        worlds.batch_size = torch.Size([count])
        return worlds, pointer.to(self.device).clone(), calls

    def place(self, position: Any, heading: Any, goal: Any, velocity: Any = None,
              moving_position: Any = None, drawn_circles: Any = None, drawn_rectangles: Any = None) -> TensorDict:
        """Start an episode in every world from an exact physical state and return what
        ``reset`` would: ``position [B, N, 2]``, ``heading [B, N]``, ``goal [B, 2]``,
        ``velocity [B, N, 2]`` (default 0), ``moving_position [B, K, 2]`` (S5; default: kept),
        ``drawn_circles [B, C, 3]`` and ``drawn_rectangles [B, R, 4]`` (the forest; default:
        kept). For tests, demos and scripted scenes; a wrong shape, a NaN / inf value or a drawn
        obstacle of size <= 0 is a ``ValueError`` naming the argument."""
        def tensor(x: Any) -> torch.Tensor:
            return torch.as_tensor(x, dtype=torch.float32, device=self.device)

        if not self._sensed_once:
            self.world = self._fresh_worlds()
            self._sensed_once = True
        given = {"position": position, "heading": heading, "goal": goal, "velocity": velocity,
                 "moving_position": moving_position, "drawn_circles": drawn_circles,
                 "drawn_rectangles": drawn_rectangles}
        state = empty_state(self.cfg, self.num_envs, self.device)
        kept = ("moving_position", "moving_velocity", "drawn_circles", "drawn_rectangles", "drawn_spheres")
        state.update({key: self.world[key] for key in kept})
        state.update({key: tensor(value) for key, value in given.items() if value is not None})
        check_state(self.cfg, state, self.num_envs, "place", keys=tuple(given))
        for key, value in given.items():
            if value is not None and not bool(torch.isfinite(state[key]).all()):
                raise ValueError(f"place: {key} contains NaN or inf; positions, headings, goals and velocities "
                                 "must be finite")
        for key in ("drawn_circles", "drawn_rectangles"):
            if given[key] is not None and not bool((state[key][..., 2:] > 0).all()):
                raise ValueError(f"place: {key} has a size <= 0; radii, widths and heights must be positive")
        sensed = sense(state, self._static, self.cfg, self._draw_noise(None))
        self.world = TensorDict({**state, "episode": new_accumulator(self.num_envs, self.device), "sensed": sensed},
                                batch_size=self.batch_size, device=self.device)
        self._restored = False
        return self._output()

    def current(self) -> TensorDict:
        """What the last ``reset`` / ``step`` returned for the current state (no reward): the
        tensordict to put the next action into."""
        return self._output()

    def subset(self, index: torch.Tensor | Sequence[int] | Sequence[bool]) -> "FlockingEnv":
        """A new env holding worlds ``index`` of this one, mid-episode (each continues exactly
        as it would have here, S4 noise draws aside: their shape follows the batch).

        ``index``: world indices (integers, in the order wanted), or a boolean mask with one
        flag per world (the worlds where it is ``True``, in order). The new env has no reserve of
        fresh worlds (``reset_pool = 0``)."""
        index = torch.as_tensor(index, device=self.device)
        if index.dtype == torch.bool:
            if index.numel() != self.num_envs:
                raise ValueError(f"subset: a boolean mask needs one flag per world ({self.num_envs}), got shape "
                                 f"{list(index.shape)}")
            index = index.reshape(-1).nonzero().reshape(-1)
        elif index.is_floating_point() or index.is_complex():
            raise ValueError(f"subset: index has dtype {index.dtype}; expected world indices (integers) or a "
                             "boolean mask")
        index = index.reshape(-1).long()
        if not index.numel():
            raise ValueError("subset: no world selected (an env holds at least one world)")
        outside = index[(index < -self.num_envs) | (index >= self.num_envs)].tolist()
        if outside:
            raise ValueError(f"subset: world index {outside[:8]} out of range for {self.num_envs} world(s)")
        small = FlockingEnv(self.cfg, num_envs=int(index.numel()), device=self.device, seed=None,
                            extras=self.extras, compile_step=self.compile_step, check_actions=self.check_actions)
        small.world = self.world[index]
        small._generator.set_state(self._generator.get_state())
        small._sensed_once = self._sensed_once
        return small

    def obstacles(self) -> Obstacles:
        """Current obstacles of every world, in the laser's index order (fixed, moving and drawn
        circles; fixed and drawn rectangles)."""
        return world_obstacles(self.world, self._static, self.cfg)

    # ------------------------------------------------------------------ rendering
    def render(self, mode: str = "rgb_array", env_index: int = 0, agent_index_focus: int | None = None,
               **kwargs: Any):
        """An RGB frame ``[H, W, 3]`` (uint8) of world ``env_index``: obstacles, goal, UAVs,
        headings, fields of view (``size``, ``extent``, ``show_fov``, ``title``:
        :func:`flock_torchrl.world.frame.render_frame`).

        Takes the call TorchRL's multi-agent scripts make for VMAS,
        ``render(mode="rgb_array", agent_index_focus=None, visualize_when_possible=True)``:
        ``agent_index_focus`` centres a 20 m view on that UAV (``None``: the whole world);
        VMAS's other display options (:data:`VMAS_RENDER_OPTIONS`) have no meaning here and are ignored."""
        if mode != "rgb_array":
            raise ValueError(f"render mode {mode!r} is not supported; use 'rgb_array'")
        from .frame import render_frame

        unknown = sorted(set(kwargs) - FRAME_OPTIONS - VMAS_RENDER_OPTIONS)
        if unknown:
            raise TypeError(f"render: unknown option(s) {unknown}; known: {sorted(FRAME_OPTIONS)} (and VMAS's "
                            f"{sorted(VMAS_RENDER_OPTIONS)}, ignored)")
        options = {k: v for k, v in kwargs.items() if k in FRAME_OPTIONS}
        if agent_index_focus is not None and "extent" not in options:
            x, y = self.world["position"][env_index, int(agent_index_focus), :2].tolist()
            options["extent"] = (x - 10.0, x + 10.0, y - 10.0, y + 10.0)
        return render_frame(self, env_index=env_index, **options)


# render(): the frame's options, and VMAS's display options TorchRL's scripts pass (ignored).
FRAME_OPTIONS = frozenset({"size", "extent", "show_fov", "title"})
VMAS_RENDER_OPTIONS = frozenset({"visualize_when_possible", "plot_position_function", "plot_position_function_range",
                                 "plot_position_function_cmap_range", "plot_position_function_cmap_alpha",
                                 "plot_position_function_precision", "plot_position_function_cmap_name"})


def _extras(extras: str | Iterable[str]) -> frozenset[str]:
    names = set(EXTRAS) if extras == "all" else {extras} if isinstance(extras, str) else set(extras)
    unknown = sorted(names - set(EXTRAS))
    if unknown:
        raise ValueError(f"extras: unknown name(s) {unknown}; known: {sorted(EXTRAS)} or 'all'")
    return frozenset(names)


__all__ = ["ACTION", "EXTRAS", "FlockingEnv"]
