"""The world's configuration: :class:`ScenarioConfig`, a plain dataclass and its checks
(docs/specification.md sections 1-6 and 9 say what every field means).

No Hydra here: ``flock_torchrl.world`` imports this module (and :mod:`.checks`) only. A scenario
is composed from ``conf/scenario/*.yaml``, ``conf/reading/*.yaml`` and a policy's fields by
:func:`flock_torchrl.config.compose.scenario_config`, or built directly and checked:
``ScenarioConfig(**fields).check()`` returns the checked scenario.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar, List, Sequence

from omegaconf import MISSING

from .checks import (MAX_UAVS, ConfigError, Schema, choice, count, dotted, is_number, non_negative, positive,
                     reject)


@dataclass
class ScenarioConfig(Schema):
    """The world (docs/specification.md sections 1-6, 9). Values: ``conf/scenario/*.yaml``
    (the world), ``conf/reading/*.yaml`` (the reading's fields), ``conf/policy/*.yaml``
    (the policy's sensing, instinct and reward variant)."""

    prefix: ClassVar[str] = "scenario"

    name: str = MISSING
    reading: str = MISSING                   # literal | paper_fit (section 9)
    dims: int = MISSING                      # 2 | 3: the plane (sections 1-10) or space (section 11)
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
    instinct_mode: str = MISSING             # paper (Eq. 29) | no_push_in | saturated (beyond the paper)
    tangential_taper: float = MISSING        # rad, 3-D only: the tangential term fades to 0 within this angle of
                                             # v_r's line (section 11; 0: the goal's orthogonal part at full length)
    # --- action interface: policy (Eq. 19-20) | velocity (the rule-based controllers)
    action_mode: str = MISSING
    # --- reward (section 4): scan | min_uav_scan (Policy4-G)
    collision_reward_source: str = MISSING
    # --- r_f's range: paper (d_c / 3 m) | sqrt_n (d_c / (3 sqrt(N / 5)) m, beyond the paper)
    cohesion_range: str = MISSING
    # --- r_c's shape: paper (Eq. 23's bands) | ramp (-1 at 0.5 m up to 0 at 3 m, beyond the paper)
    collision_shape: str = MISSING
    # --- the actor's camera slots: paper (the camera's field of view, shared with the instinct) |
    # all_round (every UAV within camera range, the instinct keeping the field of view; beyond the paper)
    actor_camera: str = MISSING
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
    # --- three dimensions (section 11; read only with dims: 3)
    climb_max: float = MISSING               # rad, gamma_max: |flight-path angle| commanded (0: climb disabled)
    altitude: List[float] = MISSING          # m, [ground, ceiling]: the altitude is clamped into it
    laser_rings: List[float] = MISSING       # rad, elevations of the laser's rings of n_beams beams
    laser_vertical: bool = MISSING           # a beam straight down and one straight up after the rings
    spawn_altitude: List[float] = MISSING    # m, [min, max] of the swarm centre's altitude at spawn
    spawn_height: float = MISSING            # m, vertical spread of the starts about that altitude
    goal_altitude: List[float] = MISSING     # m, [min, max] of the goal's altitude
    chi_range: List[float] = MISSING         # rad, Eq. 30's chi ~ U[min, max) (both dims)
    spheres: List[Any] = MISSING             # [cx, cy, cz, radius]
    random_heights: List[float] = MISSING    # m, [min, max] top of each drawn cylinder and box
    random_spheres: int = MISSING            # the last this many drawn circles are spheres
    random_sphere_altitude: List[float] = MISSING  # m, [min, max] of a drawn sphere's centre altitude
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
        fixed and drawn rectangles (then, in 3-D, fixed and drawn spheres)."""
        return (len(self.circles) + self.n_moving + self.random_circles + len(self.rectangles)
                + self.random_rectangles + (len(self.spheres) if self.dims == 3 else 0))

    # Shapes that follow the dimension (section 11); in 2-D each is what it always was.
    @property
    def circle_size(self) -> int:
        """Numbers per circle: ``[cx, cy, r]``, in 3-D ``[cx, cy, r, z_low, z_high]``."""
        return 5 if self.dims == 3 else 3

    @property
    def rectangle_size(self) -> int:
        """Numbers per rectangle: ``[cx, cy, w, h]``, in 3-D ``[cx, cy, w, h, z_low, z_high]``."""
        return 6 if self.dims == 3 else 4

    @property
    def n_climb(self) -> int:
        """Flight-path angles per world: one per UAV in 3-D, none in 2-D."""
        return self.n_uavs if self.dims == 3 else 0

    @property
    def drawn_spheres(self) -> int:
        """Drawn spheres per episode (3-D only): the last ``random_spheres`` drawn circles."""
        return self.random_spheres if self.dims == 3 else 0

    @property
    def drawn_cylinders(self) -> int:
        """Drawn circles that stay circles (cylinders in 3-D)."""
        return self.random_circles - self.drawn_spheres

    @property
    def n_laser(self) -> int:
        """Laser beams in all: ``n_beams`` per ring (and the vertical pair, in 3-D)."""
        return self.laser.count if self.dims == 3 else self.n_beams

    @property
    def laser(self) -> "Laser | None":
        """The 3-D laser's beams (what :func:`~flock_torchrl.world.space.space_of` hands the
        sensors), ``None`` in 2-D."""
        if self.dims != 3:
            return None
        return Laser(self.n_beams, tuple(float(e) for e in self.laser_rings), bool(self.laser_vertical))

    def checked_fields(self, prefix: str) -> dict[str, Any]:
        """Every field's range; whether the starts can always be placed is the world's question
        (:func:`flock_torchrl.world.spawn.check_spawn_feasible`, asked once per scenario). The
        obstacle lists come back as lists of floats."""
        k = lambda name: dotted(prefix, name)  # noqa: E731
        choice(k("reading"), self.reading, READINGS)
        check_booleans(vars(self), prefix)
        if self.dims not in (2, 3) or isinstance(self.dims, bool):
            reject(k("dims"), f"must be 2 or 3, got {self.dims!r}")
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
            reject(k("n_scan"), f"cannot exceed n_beams={self.n_beams}, got {self.n_scan}")
        choice(k("fov_convention"), self.fov_convention, ("total", "half_angle"))
        choice(k("collision_reward_source"), self.collision_reward_source, ("scan", "min_uav_scan"))
        choice(k("action_mode"), self.action_mode, ("policy", "velocity"))
        choice(k("instinct_mode"), self.instinct_mode, INSTINCT_MODES)
        if not self.instinct and self.instinct_mode != "paper":  # a mode of an instinct that never switches on
            raise ConfigError(k("instinct_mode"), f"{self.instinct_mode!r} shapes the repulsion instinct, which "
                                                  f"{k('instinct')}=false turns off, so it would do nothing; set "
                                                  f"{k('instinct_mode')}=paper or {k('instinct')}=true",
                              also=(k("instinct"),))
        choice(k("cohesion_range"), self.cohesion_range, COHESION_RANGES)
        choice(k("collision_shape"), self.collision_shape, COLLISION_SHAPES)
        choice(k("actor_camera"), self.actor_camera, ACTOR_CAMERAS)
        if len(self.area_center) != 2 or not all(is_number(v) for v in self.area_center):
            reject(k("area_center"), f"must be [x, y], got {list(self.area_center)}")
        lists: dict[str, list[list[float]]] = {}
        three = self.dims == 3
        for name, size, shape in (("circles", 3, "[cx, cy, radius > 0]"),
                                  ("rectangles", 4, "[cx, cy, width > 0, height > 0]")):
            entries = getattr(self, name)
            for i, entry in enumerate(entries):
                sizes = (size, size + 2) if three else (size,)
                ok = isinstance(entry, (list, tuple)) and len(entry) in sizes and all(is_number(v) for v in entry)
                if not ok or not all(v > 0 for v in entry[2:size]) or (len(entry) > size and entry[-2] >= entry[-1]):
                    more = f" or {shape[:-1]}, z_low < z_high] (3-D)" if three else ""
                    reject(k(name), f"entry {i} must be {shape}{more}, got {entry!r}")
            # In 3-D a 2-D entry is unbounded in height (section 11): [-FULL_HEIGHT, FULL_HEIGHT].
            lists[name] = [[float(v) for v in entry] + ([-FULL_HEIGHT, FULL_HEIGHT] if three and len(entry) == size
                                                         else []) for entry in entries]
        circles, rectangles = [c[:3] for c in lists["circles"]], [r[:4] for r in lists["rectangles"]]
        self._check_three_d(k, lists)
        for i, a in enumerate(circles):
            for j, b in enumerate(circles[i + 1:], i + 1):
                if math.hypot(a[0] - b[0], a[1] - b[1]) < a[2] + b[2]:
                    reject(k("circles"), f"circles {i} and {j} overlap")
            for j, r in enumerate(rectangles):
                if _circle_rect_overlap(a, r):
                    reject(k("circles"), f"circle {i} overlaps rectangle {j}")
        for i, a in enumerate(rectangles):
            for j, b in enumerate(rectangles[i + 1:], i + 1):
                if _rect_rect_overlap(a, b):
                    reject(k("rectangles"), f"rectangles {i} and {j} overlap")
        if self.n_moving:
            positive(k("moving_radius"), self.moving_radius, 1e6)
            if len(self.moving_box) != 2 or not self.moving_box[0] < self.moving_box[1]:
                reject(k("moving_box"), f"must be [low, high] with low < high, got {list(self.moving_box)}")
        self._check_random_obstacles(k)
        return lists

    def _check_three_d(self, k: Any, lists: dict[str, list[list[float]]]) -> None:
        """Section 11's fields (always, so a typo shows before ``dims: 3`` makes it matter);
        ``lists`` gains the checked ``spheres``."""
        def pair(name: str, low: float = -1e6, high: float = 1e6) -> list[float]:
            value = list(getattr(self, name))
            if not (len(value) == 2 and all(is_number(v) and low <= v <= high for v in value) and value[0] <= value[1]):
                reject(k(name), f"must be [min, max] with {low:g} <= min <= max <= {high:g}, got {value}")
            return [float(v) for v in value]

        non_negative(k("climb_max"), self.climb_max, math.pi / 2 - 1e-3)
        non_negative(k("spawn_height"), self.spawn_height, 1e6)
        ground, ceiling = pair("altitude")
        if not ground < ceiling:
            reject(k("altitude"), f"must be [ground, ceiling] with ground < ceiling, got {list(self.altitude)}")
        for name in ("spawn_altitude", "goal_altitude"):
            low, high = pair(name)
            if self.dims == 3 and not (ground <= low and high <= ceiling):
                reject(k(name), f"{[low, high]} must lie within altitude {[ground, ceiling]}")
        low, high = pair("spawn_altitude")
        if self.dims == 3 and not (ground <= low - self.spawn_height / 2 and high + self.spawn_height / 2 <= ceiling):
            reject(k("spawn_height"), f"starts spread {self.spawn_height:g} m about {[low, high]} leave altitude "
                                      f"{[ground, ceiling]}")
        pair("chi_range", -math.pi - 1e-9, math.pi + 1e-9)
        heights = pair("random_heights", 0.0)
        if self.dims == 3 and heights[0] <= ground and (self.random_circles > self.random_spheres
                                                        or self.random_rectangles):
            reject(k("random_heights"), f"drawn obstacles rise from the ground ({ground:g} m): their tops "
                                        f"{heights} must lie above it")
        pair("random_sphere_altitude")
        if not is_number(self.tangential_taper) or not 0 <= self.tangential_taper < math.pi / 2:
            reject(k("tangential_taper"), f"must be an angle in [0, pi/2) rad, got {self.tangential_taper!r}")
        rings = list(self.laser_rings)
        if not (1 <= len(rings) <= 36 and all(is_number(e) and abs(e) < math.pi / 2 - 1e-3 for e in rings)):
            reject(k("laser_rings"), f"must be 1 to 36 elevations strictly inside (-pi/2, pi/2) rad, got {rings}")
        count(k("random_spheres"), self.random_spheres, 0, 1000)
        if isinstance(self.random_circles, int) and 0 <= self.random_circles < self.random_spheres:
            reject(k("random_spheres"), f"counts the last drawn circles that are spheres: at most random_circles="
                                        f"{self.random_circles}, got {self.random_spheres}")
        spheres = list(self.spheres)
        for i, entry in enumerate(spheres):
            if not (isinstance(entry, (list, tuple)) and len(entry) == 4 and all(is_number(v) for v in entry)
                    and entry[3] > 0):
                reject(k("spheres"), f"entry {i} must be [cx, cy, cz, radius > 0], got {entry!r}")
        if spheres and self.dims != 3:
            reject(k("spheres"), "spheres need dims: 3")
        lists["spheres"] = [[float(v) for v in entry] for entry in spheres]

    def _check_random_obstacles(self, k: Any) -> None:
        """The drawn obstacles' fields (always, so a typo shows before a count makes it matter);
        whether they can always be placed is :func:`flock_torchrl.world.forest.check_forest_feasible`."""
        for name in ("random_circles", "random_rectangles"):
            count(k(name), getattr(self, name), 0, 1000)
        for name in ("random_circle_radius", "random_rectangle_size"):
            low_high = list(getattr(self, name))
            if not (len(low_high) == 2 and all(is_number(v) and 0 < v <= 1e6 for v in low_high)
                    and low_high[0] <= low_high[1]):
                reject(k(name), f"must be [min, max] with 0 < min <= max <= 1e6 (m), got {low_high}")
        region = list(self.random_region)
        if not (len(region) == 4 and all(is_number(v) and abs(v) <= 1e6 for v in region)
                and region[0] < region[2] and region[1] < region[3]):
            reject(k("random_region"), f"must be [x0, y0, x1, y1] with x0 < x1, y0 < y1, inside [-1e6, 1e6]^2 (m), "
                                      f"got {region}")
        non_negative(k("random_clearance"), self.random_clearance, 1e6)
        width, height = region[2] - region[0], region[3] - region[1]
        if self.random_circles and 2 * self.random_circle_radius[1] > min(width, height):
            reject(k("random_region"), f"{width:g} m x {height:g} m cannot hold a circle of radius "
                                      f"{self.random_circle_radius[1]:g} m (random_circle_radius)")
        if self.random_rectangles and self.random_rectangle_size[1] > min(width, height):
            reject(k("random_region"), f"{width:g} m x {height:g} m cannot hold a rectangle side of "
                                      f"{self.random_rectangle_size[1]:g} m (random_rectangle_size)")


def _rect_rect_overlap(a: Sequence[float], b: Sequence[float]) -> bool:
    return abs(a[0] - b[0]) < (a[2] + b[2]) / 2 and abs(a[1] - b[1]) < (a[3] + b[3]) / 2


def _circle_rect_overlap(c: Sequence[float], r: Sequence[float]) -> bool:
    dx = max(abs(c[0] - r[0]) - r[2] / 2, 0.0)
    dy = max(abs(c[1] - r[1]) - r[3] / 2, 0.0)
    return math.hypot(dx, dy) < c[2]


@dataclass(frozen=True)
class Laser:
    """The 3-D laser (docs/specification.md section 11): ``n_beams`` beams on each ring of constant
    elevation ``rings[r]``, beam ``(r, k)`` at index ``r n_beams + k`` and azimuth ``phi_i + k 360 /
    n_beams`` deg; with ``vertical``, then a beam straight down (index ``len(rings) n_beams``) and
    one straight up (the next). Per-beam tables as Python floats, for the sensors' constants."""

    n_beams: int
    rings: tuple[float, ...]
    vertical: bool = False

    @property
    def ring_beams(self) -> int:
        """Beams on the rings (the vertical pair's indices follow them)."""
        return self.n_beams * len(self.rings)

    @property
    def count(self) -> int:
        """Beams in all."""
        return self.ring_beams + (2 if self.vertical else 0)

    def elevations(self) -> list[float]:
        """Every beam's elevation (rad): ring by ring, then ``-pi/2`` and ``pi/2``."""
        return [e for e in self.rings for _ in range(self.n_beams)] + ([-math.pi / 2, math.pi / 2]
                                                                         if self.vertical else [])

    def cos_sin(self) -> tuple[list[float], list[float]]:
        """``cos`` and ``sin`` of every beam's elevation; exactly ``(0, -1)`` and ``(0, 1)`` for the
        vertical pair, whose rays then have no horizontal part at all."""
        cos_e = [math.cos(e) for e in self.rings for _ in range(self.n_beams)]
        sin_e = [math.sin(e) for e in self.rings for _ in range(self.n_beams)]
        if self.vertical:
            cos_e += [0.0, 0.0]
            sin_e += [-1.0, 1.0]
        return cos_e, sin_e


SCENARIO_FIELDS = frozenset(f.name for f in dataclasses.fields(ScenarioConfig))
BOOLEAN_FIELDS = tuple(f.name for f in dataclasses.fields(ScenarioConfig) if f.type in ("bool", bool))


def check_booleans(values: Any, prefix: str = "scenario") -> None:
    """Boolean fields among ``values`` (a mapping) are booleans (not 2, "yes" or 1, which OmegaConf
    would take as true), in the fields' order."""
    for name in BOOLEAN_FIELDS:
        if name in values and not isinstance(values[name], bool):
            reject(dotted(prefix, name), f"must be true or false, got {values[name]!r}")

# The scenario fields a policy YAML sets (its sensing, instinct, reward variant, action
# interface): a checkpoint records them, and evaluation applies them in any scenario. A
# checkpoint written before a field was added here flies with the scenario's value of it,
# which is what it trained with (``n_cam``: 3 for every checkpoint written before the field existed).
POLICY_SCENARIO_FIELDS = ("fov", "n_cam", "instinct", "tangential", "instinct_mode", "collision_reward_source",
                          "cohesion_range", "collision_shape", "actor_camera", "action_mode", "tangential_taper",
                          "laser_vertical")
# Fields whose value before they existed is not today's default (docs/specification.md section 11):
# a scenario saved before them (a run folder, a checkpoint) gets these, what it was trained with.
FIELDS_BEFORE = {"tangential_taper": 0.0, "laser_vertical": False}
READINGS = ("literal", "paper_fit")
# Half the height (m) of an obstacle "unbounded in height" in 3-D (section 11): a 2-D circle or
# rectangle is a prism from -FULL_HEIGHT to FULL_HEIGHT, beyond every altitude a config allows.
FULL_HEIGHT = 1e6
# How the UAVs' part of the instinct applies (field ``instinct_mode``; world/instinct.py
# ``hold_in_crowd``): ``paper`` sums it as Eq. 29 does; the others are variants beyond the paper
# that hold in a crowd (docs/specification.md section 3; docs/scaling.md measured them).
INSTINCT_MODES = ("paper", "no_push_in", "saturated")
# The range of r_f's cohesion term (field ``cohesion_range``; world/reward.py ``cohesion_range``):
# ``paper`` is Eq. 24's 3 m at every swarm size; ``sqrt_n`` grows it as the radius a swarm of
# N UAVs needs at the density of five, 3 sqrt(N / 5) m (beyond the paper).
COHESION_RANGES = ("paper", "sqrt_n")
# The shape of r_c (field ``collision_shape``; world/reward.py ``collision_reward``): ``paper`` is
# Eq. 23's three bands, flat at -0.5 from 0.5 m to 2 m; ``ramp`` falls linearly from 0 at 3 m to -1
# at 0.5 m, so that every centimetre of spacing pays (beyond the paper).
COLLISION_SHAPES = ("paper", "ramp")
# What the actor's camera slots see (field ``actor_camera``; world/step.py ``sense``): ``paper`` is
# the camera of section 2, whose field of view the instinct shares; ``all_round`` fills the slots
# from every UAV within camera range (as the critic's camera), while the instinct keeps acting on
# the UAVs inside the field of view only (beyond the paper).
ACTOR_CAMERAS = ("paper", "all_round")


__all__ = ["ACTOR_CAMERAS", "COHESION_RANGES", "COLLISION_SHAPES", "ConfigError", "FIELDS_BEFORE", "FULL_HEIGHT",
           "INSTINCT_MODES", "Laser", "POLICY_SCENARIO_FIELDS", "READINGS", "SCENARIO_FIELDS", "ScenarioConfig"]
