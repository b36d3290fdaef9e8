"""``FlockingEnv``: B independent copies of the world of docs/specification.md as one batched
TorchRL environment."""

from __future__ import annotations

import functools
import warnings
from typing import Any, Iterable, Mapping, Sequence

import torch
from omegaconf import DictConfig
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import EnvBase

from ..config.scenario import ScenarioConfig
from .geometry import Obstacles
from .keys import EXTRAS, env_output, env_specs, extras_of
from .metrics import new_accumulator, summary_values
from .reserve import Reserve, in_layout
from .sensors import observation_size, state_size
from .spawn import check_spawn_feasible, sample_layout, static_obstacles
from .state import (ACTION, STATE_KEYS, check_counts, check_seed, checked_action, checked_reset_mask,
                    empty_state, placed_state, restored_worlds, spawned_state, torch_device, world_index)
from .step import (STEP_COMPILE_OPTIONS, WHOLE_WARMUP, noise_draws, sense, step_function, transition,
                   whole_step_guards, world_obstacles)


class FlockingEnv(EnvBase):
    """Multi-UAV flocking (Bai et al. 2024) as a batched, torch-native TorchRL environment.

    Per-UAV entries live under the ``"agents"`` group (batch ``[B, N]``): the policy's
    ``observation`` [17], the critic's ``state`` [20], the ``reward``; ``done``,
    ``terminated`` and ``truncated`` are shared by the swarm, ``[B, 1]`` at the root, and
    ``"episode"`` holds the running section 5 metrics of each world (final when ``done``).
    More keys on request (``extras``, :data:`~.keys.EXTRAS`): ``"physics"`` (positions, velocities,
    headings, goal, moving and drawn obstacles), ``"command"`` (the executed velocity ``command``
    and the ``instinct`` flags), ``"laser"`` (the sensed ``scan`` and the obstacle each beam hit).

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
        seed: seed of the env's own generator (spawns, S4 noise, moving and drawn obstacles); 0 by
            default, so copies built alike (TorchRL's ``SerialEnv`` / ``ParallelEnv`` of one
            constructor) hold the same worlds until their ``set_seed(s)`` seeds each its own stream.
        reading: ``literal`` or ``paper_fit`` (docs/specification.md section 9).
        policy_id: a policy (``policy3_g`` ...) whose sensing, instinct and reward apply (TorchRL
            reserves the keyword ``policy``).
        extras: names from :data:`EXTRAS`, or ``"all"``.
        compile_step: ``torch.compile`` the world's step (:func:`~flock_torchrl.world.step.advance`);
            its eager twin (``False``) gives the same transitions up to float round-off. Worth it
            for a fixed batch (training); each new batch size compiles again.
        check_actions: check each action for NaN / inf and refuse to step a done world
            (``ValueError``); both checks read the host. ``False``: only the action's key, shape and
            floating dtype (no synchronisation), cast to float32 and clipped to the action box.
        reset_pool: ``P > 0``: a reserve of ``P`` fresh worlds (:class:`~.reserve.Reserve`; per member
            in a population; ``P >= num_envs``, the worlds per member there) that :meth:`maybe_reset`
            hands to the done worlds without a host read. Reproducible from the seed and carried by
            :meth:`get_state`; the episodes differ from ``0`` (TorchRL's masked reset, drawn there and
            then) once a world was reset. See :meth:`maybe_reset`.
        capture_step: on a GPU, the static-shape step (every UAV pair, every beam and obstacle) and
            the reserve's hand-out recorded as CUDA graphs and replayed (``flock_torchrl.capture``);
            on a CPU the static-shape step as it is, equal to the default one to float round-off.
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
        check_counts(num_envs, reset_pool)
        check_seed(seed)
        super().__init__(device=torch_device(device), batch_size=torch.Size([num_envs]))
        self.reset_pool = reset_pool
        groups, per_group = self._reserve_groups()
        check_counts(num_envs, reset_pool, per_group, groups)
        self.cfg = cfg
        self.num_envs = num_envs
        self.n_agents = cfg.n_uavs
        self.extras = extras_of(extras)
        self.obs_dim, self.state_dim = observation_size(cfg), state_size(cfg)
        self.group_map = {"agents": [f"agent_{i}" for i in range(cfg.n_uavs)]}
        self._static = static_obstacles(cfg, self.device)
        self._generator = torch.Generator(device=self.device)
        self.compile_step = bool(compile_step)
        self.check_actions = bool(check_actions)
        self.capture_step = bool(capture_step)
        self._transition = step_function(self._static, cfg, self.device, self.compile_step, self.capture_step)
        self._in_step = False              # step_and_maybe_reset counted this step's hand-out of the reserve
        self._normals: dict | None = None  # sensor noise drawn before a whole compiled step
        self._compiled_whole = bool(self.compile_step and reset_pool and not self.capture_step)  # read in the trace
        if self._compiled_whole:
            # Nothing left reads the host: the step and the hand-out are traced whole, with TorchRL's plumbing.
            self._transition = functools.partial(transition, static_shapes=True, static=self._static, cfg=cfg)
            self.compile(warmup=WHOLE_WARMUP, fullgraph=not self.check_actions, dynamic=False,
                         options={**STEP_COMPILE_OPTIONS, "guard_filter_fn": whole_step_guards})
        specs = env_specs(cfg, num_envs, self.extras, self.device)
        self.observation_spec, self.action_spec = specs["observation"], specs["action"]
        self.reward_spec, self.done_spec = specs["reward"], specs["done"]
        # What a whole compiled step is traced on: the env's outputs and the action.
        self._whole_keys = [*self.full_observation_spec.keys(True, True), *self.full_done_spec.keys(True, True),
                            *self.full_state_spec.keys(True, True), *self.full_action_spec.keys(True, True)]
        self.world = self._empty_world()
        self.reserve: Reserve | None = None  # empty (every world used) until the first hand-out refills it
        if reset_pool:
            stored = self._empty_world(sensed=True)[torch.zeros(groups * reset_pool, dtype=torch.long,
                                                                device=self.device)]
            self.reserve = Reserve(reset_pool, groups, per_group, stored, self.capture_step)
            self._fresh_summary = summary_values(new_accumulator(num_envs, self.device), cfg.collision_distance)
        self._sensed_once = False
        self._restored = False
        self._warned_masked = False
        if seed is not None:
            self.set_seed(seed)

    @classmethod
    def from_config(cls, cfg: ScenarioConfig | DictConfig | Mapping[str, Any], num_envs: int = 1,
                    device: str | torch.device = "cpu", seed: int | None = 0, **kwargs: Any) -> "FlockingEnv":
        """Build from a composed scenario (e.g. Hydra's ``cfg.scenario``), exactly as composed."""
        return cls(ScenarioConfig.from_config(cfg), num_envs=num_envs, device=device, seed=seed, **kwargs)

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
        state = spawned_state(self.cfg, self._draw_layout(index), self.device)
        count, sensed = state["position"].shape[0], sense(state, self._static, self.cfg, self._draw_noise(index))
        return TensorDict({**state, "episode": new_accumulator(count, self.device), "sensed": sensed},
                          batch_size=[count], device=self.device)

    def _output(self, summary: Mapping[str, torch.Tensor] | None = None, reward: torch.Tensor | None = None
                ) -> TensorDict:
        """What ``reset`` / ``step`` return for the current worlds (:func:`~.keys.env_output`)."""
        return env_output(self.world, self.cfg, self.extras, summary, reward)

    # ------------------------------------------------------------------ TorchRL API
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDict:
        mask = None
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = checked_reset_mask(tensordict.get("_reset"), self.num_envs, self.device)
        if self._restored and mask is None:  # a restored state continues its episodes
            self._restored = False
            return self._output()
        self._restored = False
        if mask is None or bool(mask.all()) or not self._sensed_once:
            self.world = self._fresh_worlds()
            self._sensed_once = True
        elif bool(mask.any()):
            if self.reserve is not None and not self._warned_masked:
                self._warned_masked = True
                warnings.warn("FlockingEnv(reset_pool>0): a reset with a \"_reset\" mask draws its new worlds there "
                              "and then; the reserve serves this env's own maybe_reset and step_and_maybe_reset (a "
                              "TransformedEnv resets through masks, so there the reserve goes unused)", stacklevel=2)
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

        Without a reserve: TorchRL's (the done flags read on the host, a masked ``reset`` drawing
        the new episodes there and then). With one (``reset_pool``): the done worlds take the next
        unused reserve worlds in world order (:class:`~.reserve.Reserve`, refilled on the host when
        a hand-out could run it dry), and the returned tensordict holds their outputs where
        TorchRL's masked reset would put them, in tensor operations only. The reserve serves this
        method alone: ``reset()`` (with or without a ``"_reset"`` mask, so a ``TransformedEnv``'s
        resets too), :meth:`place` and :meth:`subset` draw or set worlds as without one;
        :meth:`set_seed` empties it; :meth:`get_state` and :meth:`set_state` carry it."""
        if self.reserve is None:
            return super().maybe_reset(tensordict)
        if not (self._in_step or torch.compiler.is_compiling()):  # traced whole: counted by the caller
            self.reserve.count(self._fresh_worlds)
        return self._reset_from_reserve(tensordict)

    def step_and_maybe_reset(self, tensordict: TensorDictBase) -> tuple[TensorDictBase, TensorDictBase]:
        """TorchRL's ``step_and_maybe_reset``. With a reserve (``reset_pool``) the reserve's
        hand-out is counted (and the reserve refilled when due) here, before the step; with
        ``compile_step`` too, the sensor noise is drawn here as well and the rest, the step and
        the reserve's hand-out with TorchRL's bookkeeping around them, runs as one compiled
        function (TorchRL's ``EnvBase.compile``): the same random draws in the same order as
        its eager twin."""
        if self.reserve is None:
            return super().step_and_maybe_reset(tensordict)
        self.reserve.count(self._fresh_worlds)
        whole = self._compiled_whole
        if whole:
            self._normals = self._draw_noise(None)
        self._in_step = True
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
            self._in_step, self._normals = False, None

    def _reset_from_reserve(self, tensordict: TensorDictBase) -> TensorDictBase:
        done = tensordict.get("done", None)
        if done is None:  # as TorchRL's any_done: no done flags, nothing to reset
            return tensordict
        done = done.reshape(self.reserve.groups, self.reserve.per_group).to(self.device)
        old = self.world.to_dict()
        world = self.reserve.hand_out(old, done)
        self.world = TensorDict._new_unsafe(in_layout(old, world), batch_size=self.batch_size, device=self.device)
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

    def _step(self, tensordict: TensorDictBase) -> TensorDict:
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
        if self.reserve is not None:
            self.reserve.empty()

    # ------------------------------------------------------------------ state API
    def get_state(self) -> dict:
        """Everything needed to continue these episodes bit for bit, as plain tensors and dicts."""
        state = {"world": self.world.to_dict(), "generator": self._generator.get_state()}
        if self.reserve is not None:
            state["reset_pool"] = self.reserve.state_dict()
        return state

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state`; the next full ``reset()`` returns the restored episodes
        instead of drawing new ones (so a collector built afterwards continues them).

        Every tensor must have the shape and dtype this env keeps (no silent casts: a float64
        state would not continue bit for bit); anything else is a ``ValueError`` naming the key."""
        self.world = restored_worlds(self.cfg, state, self.num_envs, self._empty_world(sensed=True), self.reserve,
                                     self.reset_pool, self.device)
        self._generator.set_state(state["generator"])
        self._sensed_once = True
        self._restored = True

    def place(self, position: Any, heading: Any, goal: Any, velocity: Any = None,
              moving_position: Any = None, drawn_circles: Any = None, drawn_rectangles: Any = None) -> TensorDict:
        """Start an episode in every world from an exact physical state and return what
        ``reset`` would: ``position [B, N, 2]``, ``heading [B, N]``, ``goal [B, 2]``,
        ``velocity [B, N, 2]`` (default 0), ``moving_position [B, K, 2]`` (S5; default: kept),
        ``drawn_circles [B, C, 3]`` and ``drawn_rectangles [B, R, 4]`` (the forest; default:
        kept). For tests, demos and scripted scenes; a wrong shape, a NaN / inf value or a drawn
        obstacle of size <= 0 is a ``ValueError`` naming the argument."""
        if not self._sensed_once:
            self.world = self._fresh_worlds()
            self._sensed_once = True
        given = {"position": position, "heading": heading, "goal": goal, "velocity": velocity,
                 "moving_position": moving_position, "drawn_circles": drawn_circles,
                 "drawn_rectangles": drawn_rectangles}
        kept = ("moving_position", "moving_velocity", "drawn_circles", "drawn_rectangles", "drawn_spheres")
        state = placed_state(self.cfg, {key: self.world[key] for key in kept}, given, self.num_envs, self.device)
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
        index = world_index(index, self.num_envs, self.device)
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
        """An RGB frame ``[H, W, 3]`` (uint8) of world ``env_index`` (:func:`~.frame.render_env`: the
        options, and the call TorchRL's multi-agent scripts make for VMAS)."""
        from .frame import render_env

        return render_env(self, mode, env_index, agent_index_focus, **kwargs)


__all__ = ["ACTION", "EXTRAS", "FlockingEnv"]
