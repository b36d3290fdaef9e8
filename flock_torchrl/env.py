"""``FlockingEnv``: B independent copies of the SPEC world as one batched TorchRL env."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import torch
from omegaconf import DictConfig
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from .config import ScenarioConfig, load_scenario
from .dynamics import action_to_command, clip_command, first_order_step, reflect_in_box, update_heading
from .geometry import Obstacles, circular_mean, nearest_obstacle_distance, relative_angle, wrap
from .instinct import instinct_command
from .metrics import METRIC_KEYS, episode_summary, new_accumulator, step_statistics, update_episode
from .reward import total_reward
from .sensors import (add_sensor_noise, camera_observation, goal_observation, laser_scan, observe_neighbours,
                      scan_observation, swarm_centre_state, visibility)
from .spawn import sample_layout


class FlockingEnv(EnvBase):
    """Multi-UAV flocking (Bai et al. 2024) as a batched, torch-native TorchRL environment.

    Per-UAV entries live under ``"agents"`` (batch ``[B, N]``); ``done`` / ``terminated`` /
    ``truncated`` are shared by the swarm, ``[B, 1]`` at the root. Besides the policy's
    ``observation`` [17] and the critic's ``state`` [20], every step carries the raw physical
    state (``position``, ``velocity``, ``heading``), the executed ``command``, whether the
    instinct produced it, the sensed laser ``scan`` [36] with the obstacle each beam hit
    (``scan_obstacle``, -1 for none), the ``goal`` [B, 2], moving obstacles'
    ``("obstacles", "position")`` when the scenario has some, and the running SPEC section 5
    metrics of each episode under ``"episode"`` (final when ``done``).

    Args:
        scenario: a name under ``conf/scenario/`` (``train``, ``s1`` ... ``s5``, ``tau_v``), a
            mapping / DictConfig of scenario fields, or a :class:`ScenarioConfig`.
        num_envs: batch size ``B``.
        device: torch device of every tensor.
        seed: seed of the env's own generator (spawns, S4 noise, moving obstacles).
        **overrides: any scenario field, e.g. ``fov=math.pi``, ``instinct=True``, ``tau_v=0.5``.

    Example:
        >>> env = FlockingEnv("train", num_envs=4, seed=0, instinct=True)
        >>> td = env.rollout(3)
        >>> td["agents", "observation"].shape, td["next", "agents", "reward"].shape
        (torch.Size([4, 3, 5, 17]), torch.Size([4, 3, 5, 1]))
        >>> td["next", "done"].shape
        torch.Size([4, 3, 1])
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}
    batch_locked = True

    def __init__(self, scenario: str | ScenarioConfig | DictConfig | dict = "train", num_envs: int = 1,
                 device: str | torch.device = "cpu", seed: int | None = 0, **overrides: Any) -> None:
        cfg = load_scenario(scenario, **overrides)
        if not isinstance(num_envs, int) or isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        super().__init__(device=torch.device(device), batch_size=torch.Size([num_envs]))
        self.cfg = cfg
        self.num_envs = num_envs
        self.n_agents = cfg.n_uavs
        self.obs_dim = 2 + 2 * cfg.n_scan + 3 * cfg.n_cam
        self.state_dim = self.obs_dim + 3
        dev = self.device
        self._static = Obstacles(
            torch.tensor(cfg.circles, dtype=torch.float32, device=dev).reshape(1, -1, 3),
            torch.tensor(cfg.rectangles, dtype=torch.float32, device=dev).reshape(1, -1, 4),
        )
        self._generator = torch.Generator(device=dev)
        self._make_spec()
        self._allocate()
        if seed is not None:
            self.set_seed(seed)

    @classmethod
    def from_config(cls, cfg: DictConfig | dict, num_envs: int = 1, device: str = "cpu", seed: int | None = 0,
                    **overrides: Any) -> "FlockingEnv":
        """Build from a scenario config node (e.g. Hydra's ``cfg.scenario``)."""
        return cls(cfg, num_envs=num_envs, device=device, seed=seed, **overrides)

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

        agents = Composite(
            observation=box(self.obs_dim),
            state=box(self.state_dim),
            position=free(2),
            velocity=free(2),
            heading=free(),
            command=box(2, low=-cfg.v_max, high=cfg.v_max),
            instinct=flag(),
            scan=box(cfg.n_beams, low=0.0, high=cfg.laser_range),
            scan_obstacle=Bounded(low=-1, high=max(self._static.count + cfg.n_moving - 1, 0),
                                  shape=(b, n, cfg.n_beams), dtype=torch.int64, device=dev),
            shape=(b, n),
            device=dev,
        )
        episode = Composite(
            {k: (flag(batch=(b,)) if k in ("success", "safe_success", "reached", "crashed")
                 else free(batch=(b,), dtype=torch.int64) if k == "steps" else free(batch=(b,)))
             for k in METRIC_KEYS},
            shape=(b,),
            device=dev,
        )
        observation = Composite(agents=agents, goal=free(2, batch=(b,)), episode=episode, shape=(b,), device=dev)
        if cfg.n_moving:
            observation["obstacles"] = Composite(position=free(cfg.n_moving, 2, batch=(b,)), shape=(b,), device=dev)
        self.observation_spec = observation
        action = box(2) if cfg.action_mode == "policy" else box(2, low=-cfg.v_max, high=cfg.v_max)
        self.action_spec = Composite(
            agents=Composite(action=action, shape=(b, n), device=dev), shape=(b,), device=dev
        )
        self.reward_spec = Composite(
            agents=Composite(reward=free(1), shape=(b, n), device=dev), shape=(b,), device=dev
        )
        self.done_spec = Composite(
            done=flag(1, batch=(b,)), terminated=flag(1, batch=(b,)), truncated=flag(1, batch=(b,)),
            shape=(b,), device=dev,
        )

    # ------------------------------------------------------------------ state
    def _allocate(self) -> None:
        b, n, k, dev = self.num_envs, self.n_agents, self.cfg.n_moving, self.device

        def zeros(*shape, dtype=torch.float32):
            return torch.zeros(*shape, dtype=dtype, device=dev)

        self.position, self.velocity, self.heading = zeros(b, n, 2), zeros(b, n, 2), zeros(b, n)
        self.goal = zeros(b, 2)
        self.moving_position, self.moving_velocity = zeros(b, k, 2), zeros(b, k, 2)
        self.command = zeros(b, n, 2)
        self.used_instinct = zeros(b, n, dtype=torch.bool)
        self.prev_action = zeros(b, n, 2)
        self.has_prev_action = zeros(b, dtype=torch.bool)
        self.terminated = zeros(b, 1, dtype=torch.bool)
        self.truncated = zeros(b, 1, dtype=torch.bool)
        self.accumulator = new_accumulator(b, dev)
        self.sensed: dict[str, torch.Tensor] = {}

    def obstacles(self) -> Obstacles:
        """Current obstacles of every env (static circles, moving circles, rectangles)."""
        b = self.num_envs
        circles = self._static.circles.expand(b, -1, -1)
        if self.cfg.n_moving:
            moving = torch.cat(
                (self.moving_position,
                 torch.full_like(self.moving_position[..., :1], self.cfg.moving_radius)), -1)
            circles = torch.cat((circles, moving), 1)
        return Obstacles(circles, self._static.rectangles.expand(b, -1, -1))

    def _sense(self) -> dict[str, torch.Tensor]:
        """Everything the step needs from the current physical state, all envs at once."""
        cfg = self.cfg
        obstacles = self.obstacles()
        beams, beam_obstacle = laser_scan(self.position, self.heading, obstacles, cfg.n_beams, cfg.laser_range)
        true_neighbours = observe_neighbours(self.position, self.heading, cfg.camera_range, cfg.fov)
        # The critic's camera sees all round (phi_v = 2 pi): same measurements, wider visibility.
        all_round = dataclasses.replace(
            true_neighbours, visible=visibility(true_neighbours.distance, true_neighbours.bearing,
                                                cfg.camera_range, 2 * math.pi))
        sensed_beams, neighbours = beams, true_neighbours
        if cfg.noise:
            sensed_beams, neighbours = add_sensor_noise(
                beams, true_neighbours, scan_std=cfg.noise_scan, distance_std=cfg.noise_distance,
                angle_std=cfg.noise_angle, max_range=cfg.laser_range, generator=self._generator)
        o_g = goal_observation(self.position, self.heading, self.goal, cfg.goal_scale)
        observation = torch.cat(
            (o_g, scan_observation(sensed_beams, cfg.n_scan, cfg.laser_range),
             camera_observation(neighbours, cfg.n_cam, cfg.camera_range)), -1)
        state = torch.cat(
            (o_g, scan_observation(beams, cfg.n_scan, cfg.laser_range),
             camera_observation(all_round, cfg.n_cam, cfg.camera_range),
             swarm_centre_state(self.position, self.heading, cfg.camera_range)), -1)
        triggered, repulsion_command = instinct_command(
            self.position, self.heading, self.goal, sensed_beams, neighbours, gain=cfg.rep_gain,
            r0=cfg.rep_range, safe_distance=cfg.safe_distance, tangential=cfg.tangential)
        to_goal = self.goal[:, None] - self.position
        return {
            "observation": observation,
            "state": state,
            "scan": sensed_beams,
            "scan_obstacle": beam_obstacle,
            "instinct_triggered": triggered,
            "instinct_command": repulsion_command,
            "d_scan1": beams.amin(-1),
            "d_uav1": true_neighbours.nearest_distance(),
            "d_goal": torch.linalg.vector_norm(to_goal, dim=-1),
            "alpha_goal": relative_angle(to_goal, self.heading),
            "obstacle_distance": nearest_obstacle_distance(self.position, obstacles),
        }

    def _output(self) -> TensorDict:
        b, n = self.batch_size, (self.num_envs, self.n_agents)
        agents = TensorDict(
            {
                "observation": self.sensed["observation"],
                "state": self.sensed["state"],
                "position": self.position.clone(),
                "velocity": self.velocity.clone(),
                "heading": self.heading.clone(),
                "command": self.command.clone(),
                "instinct": self.used_instinct.clone(),
                "scan": self.sensed["scan"],
                "scan_obstacle": self.sensed["scan_obstacle"],
            },
            batch_size=n,
            device=self.device,
        )
        out = TensorDict(
            {
                "agents": agents,
                "goal": self.goal.clone(),
                "episode": episode_summary(self.accumulator, self.cfg.collision_distance),
                "terminated": self.terminated.clone(),
                "truncated": self.truncated.clone(),
                "done": self.terminated | self.truncated,
            },
            batch_size=b,
            device=self.device,
        )
        if self.cfg.n_moving:
            out["obstacles"] = TensorDict({"position": self.moving_position.clone()}, batch_size=b, device=self.device)
        return out

    # ------------------------------------------------------------------ TorchRL API
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDict:
        mask = None
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(self.num_envs).to(self.device)
        if mask is not None and not mask.any() and self.sensed:
            return self._output()
        if getattr(self, "_restored", False) and mask is None:
            self._restored = False
            return self._output()
        full = mask is None or bool(mask.all()) or not self.sensed
        layout = sample_layout(self.cfg, self.num_envs, self._static, self._generator, self.device)
        fresh_acc = new_accumulator(self.num_envs, self.device)
        if full:
            self.position, self.heading, self.goal = layout.position, layout.heading, layout.goal
            self.velocity = torch.zeros_like(self.position)
            self.moving_position, self.moving_velocity = layout.moving_position, layout.moving_velocity
            self.command = torch.zeros_like(self.command)
            self.used_instinct = torch.zeros_like(self.used_instinct)
            self.has_prev_action = torch.zeros_like(self.has_prev_action)
            self.terminated = torch.zeros_like(self.terminated)
            self.truncated = torch.zeros_like(self.truncated)
            self.accumulator = fresh_acc
            self.sensed = self._sense()
            return self._output()

        m1, m2, m3 = mask[:, None], mask[:, None, None], mask
        self.position = torch.where(m2, layout.position, self.position)
        self.velocity = torch.where(m2, torch.zeros_like(self.velocity), self.velocity)
        self.heading = torch.where(m1, layout.heading, self.heading)
        self.goal = torch.where(m1, layout.goal, self.goal)
        self.moving_position = torch.where(m2, layout.moving_position, self.moving_position)
        self.moving_velocity = torch.where(m2, layout.moving_velocity, self.moving_velocity)
        self.command = torch.where(m2, torch.zeros_like(self.command), self.command)
        self.used_instinct = self.used_instinct & ~m1
        self.has_prev_action = self.has_prev_action & ~m3
        self.terminated = self.terminated & ~m1
        self.truncated = self.truncated & ~m1
        self.accumulator = fresh_acc.where(m3, self.accumulator)
        # Non-reset envs keep the sensing (and S4 noise draw) their last step returned.
        new = self._sense()
        self.sensed = {k: torch.where(mask.reshape(-1, *([1] * (v.dim() - 1))), v, self.sensed[k])
                       for k, v in new.items()}
        return self._output()

    def _step(self, tensordict: TensorDictBase) -> TensorDict:
        cfg = self.cfg
        action = tensordict.get(("agents", "action")).to(self.device)
        if not torch.isfinite(action).all():
            raise ValueError("('agents', 'action') contains NaN or inf; actions must be finite")
        if cfg.action_mode == "policy":
            action = action.clamp(-1.0, 1.0)
            command = action_to_command(action, self.heading)
        else:  # the action is the velocity command (rule-based controllers)
            command = action
        if cfg.instinct:
            use = self.sensed["instinct_triggered"]
            command = torch.where(use[..., None], self.sensed["instinct_command"], command)
        else:
            use = torch.zeros_like(self.used_instinct)
        self.command = clip_command(command, cfg.v_max)
        self.used_instinct = use
        self.position, self.velocity = first_order_step(self.position, self.velocity, self.command, cfg.dt, cfg.tau_v)
        self.heading = update_heading(self.heading, self.velocity, cfg.heading_speed_threshold)
        if cfg.n_moving:
            self.moving_position, self.moving_velocity = reflect_in_box(
                self.moving_position + cfg.dt * self.moving_velocity, self.moving_velocity, 0.0, cfg.area_size)

        d_goal_prev = self.sensed["d_goal"]
        self.sensed = sensed = self._sense()
        prev_action = torch.where(self.has_prev_action[:, None, None], self.prev_action, action)
        d_collision = sensed["d_scan1"]
        if cfg.collision_reward_source == "min_uav_scan":
            d_collision = torch.minimum(sensed["d_uav1"], d_collision)
        centre = self.position.mean(-2, keepdim=True)
        reward = total_reward(
            d_goal=sensed["d_goal"], d_goal_prev=d_goal_prev, alpha_goal=sensed["alpha_goal"],
            goal_radius=cfg.goal_radius, d_collision=d_collision,
            heading_deviation=wrap(self.heading - circular_mean(self.heading, -1, keepdim=True)),
            d_centre=torch.linalg.vector_norm(self.position - centre, dim=-1),
            action=action, prev_action=prev_action)
        self.prev_action, self.has_prev_action = action, torch.ones_like(self.has_prev_action)

        reached = (sensed["d_goal"] < cfg.goal_radius).any(-1)
        crashed = (sensed["obstacle_distance"] < cfg.collision_distance).any(-1)
        stats = step_statistics(self.position, self.velocity, self.heading, sensed["obstacle_distance"])
        terminated = reached | crashed
        if cfg.uav_collision_terminates:
            terminated = terminated | (stats["uav"] < cfg.collision_distance)
        update_episode(self.accumulator, stats, reached, crashed, cfg.dt, reward.mean(-1))
        self.terminated = terminated[:, None]
        self.truncated = (self.accumulator["steps"] >= cfg.max_steps)[:, None] & ~self.terminated
        out = self._output()
        out.set(("agents", "reward"), reward[..., None])
        return out

    # ------------------------------------------------------------------ exact resume
    _STATE_KEYS = ("position", "velocity", "heading", "goal", "moving_position", "moving_velocity", "command",
                   "used_instinct", "prev_action", "has_prev_action", "terminated", "truncated")

    def get_state(self) -> dict:
        """Everything needed to continue these episodes bit for bit (plain tensors and dicts)."""
        return {
            **{k: getattr(self, k).clone() for k in self._STATE_KEYS},
            "accumulator": self.accumulator.to_dict(),
            "sensed": {k: v.clone() for k, v in self.sensed.items()},
            "generator": self._generator.get_state(),
        }

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state`; the next full ``reset()`` returns the restored episodes
        instead of drawing new ones (so a collector built afterwards continues them)."""
        for k in self._STATE_KEYS:
            current = getattr(self, k)
            if tuple(state[k].shape) != tuple(current.shape):
                raise ValueError(f"env state {k!r} has shape {tuple(state[k].shape)}, this env {tuple(current.shape)}")
            setattr(self, k, state[k].to(current.device, current.dtype))
        self.accumulator = TensorDict(state["accumulator"], batch_size=[self.num_envs], device=self.device)
        self.sensed = {k: v.to(self.device) for k, v in state["sensed"].items()}
        self._generator.set_state(state["generator"])
        self._restored = True

    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            seed = int(torch.empty((), dtype=torch.int64).random_().item())
        self._generator.manual_seed(int(seed))

    # ------------------------------------------------------------------ rendering
    def render(self, env_index: int = 0, **kwargs: Any):
        """RGB frame ``[H, W, 3]`` (uint8) of one env: obstacles, goal, UAVs, headings, fields of view."""
        from .render import render_frame

        return render_frame(self, env_index=env_index, **kwargs)
