"""geometry.py: wrap, circular mean, exact ray casting, distances (specification, "Conventions", section 2 "Laser")."""

import math

import pytest
import torch

from flock_torchrl.world.geometry import (
    Obstacles, cast_rays, circular_mean, distance_to_obstacles, nearest_obstacle_distance, pairwise,
    relative_angle, wrap,
)

PI = math.pi
# The training scenario's rectangle centred at (10, 40), 6 m (x) by 16 m (y): x in [7, 13], y in [32, 48].
TRAIN_RECT = [10.0, 40.0, 6.0, 16.0]


def world(circles=(), rectangles=(), dtype=torch.float64):
    """One world (B = 1) with the given obstacles."""
    return Obstacles(torch.tensor(list(circles), dtype=dtype).reshape(1, -1, 3),
                     torch.tensor(list(rectangles), dtype=dtype).reshape(1, -1, 4))


def ray(origin, angle, obstacles, max_range=10.0, dtype=torch.float64):
    """Cast one ray; returns ``(distance, obstacle index)`` as Python numbers."""
    o = torch.tensor([[origin]], dtype=dtype)  # [1, 1, 2]
    a = torch.tensor([[[angle]]], dtype=dtype)  # [1, 1, 1]
    d, idx = cast_rays(o, a, obstacles, max_range)
    return d.item(), idx.item()


# ---------------------------------------------------------------- angles
@pytest.mark.parametrize("angle, expected", [
    (PI, -PI),               # the range is [-pi, pi): +pi maps to -pi
    (-PI, -PI),              # -pi is already in range
    (1.5 * PI, -0.5 * PI),   # 270 deg = -90 deg
    (-1.5 * PI, 0.5 * PI),   # -270 deg = +90 deg
    (0.1 + 2 * PI, 0.1),     # a full turn is removed
    (0.3, 0.3),              # in range: unchanged
    (-7.0, -7.0 + 2 * PI),   # -7 + 6.2832 = -0.7168
])
def test_wrap(angle, expected):
    out = wrap(torch.tensor([angle], dtype=torch.float64)).item()
    assert out == pytest.approx(expected, abs=1e-12)


def test_wrap_is_identity_on_wrapped_float32_angles():
    # An angle already in [-pi, pi) must come back bit-identical (else a UAV exactly on the
    # camera's edge drops out of view by one ulp).
    x = torch.tensor([0.25 * PI, -0.25 * PI, 0.1, 3.0, -3.0, -PI], dtype=torch.float32)
    assert torch.equal(wrap(x), x)


def test_relative_angle():
    # vec (0, 1) points at 90 deg; seen from heading 120 deg it is at 90 - 120 = -30 deg.
    out = relative_angle(torch.tensor([0.0, 1.0], dtype=torch.float64), torch.tensor(2 * PI / 3, dtype=torch.float64))
    assert out.item() == pytest.approx(-PI / 6)
    # vec (-1, 0) at 180 deg seen from heading -90 deg: 180 + 90 = 270 deg -> wrap -> -90 deg.
    out = relative_angle(torch.tensor([-1.0, 0.0], dtype=torch.float64), torch.tensor(-PI / 2, dtype=torch.float64))
    assert out.item() == pytest.approx(-PI / 2)


def test_circular_mean_near_plus_minus_pi_is_pi_not_zero():
    # Headings pi - 0.1 and -pi + 0.1 point almost the same way (backwards): sum sin = 0.0998 - 0.0998 = 0,
    # sum cos = -0.995 - 0.995 = -1.990 -> atan2(0, -1.99) = +-pi. The arithmetic mean would say 0.
    m = circular_mean(torch.tensor([PI - 0.1, -PI + 0.1], dtype=torch.float64)).item()
    assert abs(m) == pytest.approx(PI, abs=1e-9)
    # 0 and pi/2: sum sin = 1, sum cos = 1 -> atan2(1, 1) = pi/4.
    assert circular_mean(torch.tensor([0.0, PI / 2], dtype=torch.float64)).item() == pytest.approx(PI / 4)
    # Batched over [B, N] with keepdim: each row on its own.
    rows = circular_mean(torch.tensor([[0.2, 0.2, 0.2], [-1.0, -1.0, -1.0]]), -1, keepdim=True)
    assert rows.shape == (2, 1)
    assert torch.allclose(rows[:, 0], torch.tensor([0.2, -1.0]), atol=1e-6)


# ---------------------------------------------------------------- laser vs circles
def test_ray_hits_circle_head_on():
    # Circle (40, 40) r 6, ray from (30, 40) along +x: hits the near side at x = 34 -> 34 - 30 = 4.
    d, idx = ray([30.0, 40.0], 0.0, world(circles=[[40.0, 40.0, 6.0]]))
    assert d == pytest.approx(4.0, abs=1e-12) and idx == 0


def test_ray_hits_circle_obliquely():
    # Circle (0, 0) r 5, ray from (3, -10) straight up (+y): the line x = 3 meets the circle at
    # y = -sqrt(25 - 9) = -4, so the distance is -4 - (-10) = 6.
    d, _ = ray([3.0, -10.0], PI / 2, world(circles=[[0.0, 0.0, 5.0]]))
    assert d == pytest.approx(6.0, abs=1e-9)


def test_ray_misses_circle_beside_and_behind():
    obstacles = world(circles=[[0.0, 0.0, 5.0]])
    # Line x = 6 passes 6 > 5 from the centre: a miss, capped at the range 10.
    assert ray([6.0, -8.0], PI / 2, obstacles) == (10.0, -1)
    # Circle behind the ray (origin (8, 0) heading +x): a miss.
    assert ray([8.0, 0.0], 0.0, obstacles) == (10.0, -1)
    # Tangent ray (line y = 5 touches the circle at (0, 5)): from (-3, 5), hit at distance 3.
    d, _ = ray([-3.0, 5.0], 0.0, obstacles)
    assert d == pytest.approx(3.0, abs=1e-6)


def test_ray_inside_or_on_circle_is_zero():
    obstacles = world(circles=[[40.0, 40.0, 6.0]])
    for angle in (0.0, 1.0, PI / 2, -2.0):
        assert ray([40.0, 41.0], angle, obstacles)[0] == 0.0  # 1 m from the centre, inside r = 6
        assert ray([46.0, 40.0], angle, obstacles)[0] == 0.0  # on the surface


def test_ray_capped_at_range():
    # Circle at x in [34, 46], ray from (20, 40): the hit at 14 m is beyond the 10 m range.
    assert ray([20.0, 40.0], 0.0, world(circles=[[40.0, 40.0, 6.0]])) == (10.0, -1)
    # ... and with a 20 m range the hit is reported: 34 - 20 = 14.
    assert ray([20.0, 40.0], 0.0, world(circles=[[40.0, 40.0, 6.0]]), max_range=20.0)[0] == pytest.approx(14.0)
    # No obstacles at all: every beam is the range.
    d, idx = cast_rays(torch.zeros(2, 3, 2), torch.zeros(2, 3, 4), world(dtype=torch.float32), 10.0)
    assert torch.equal(d, torch.full((2, 3, 4), 10.0)) and (idx == -1).all()


# ---------------------------------------------------------------- laser vs rectangles
def test_ray_hits_rectangle_faces():
    obstacles = world(rectangles=[TRAIN_RECT])
    # From (0, 40) along +x to the face x = 7: 7 - 0 = 7.
    assert ray([0.0, 40.0], 0.0, obstacles) == (pytest.approx(7.0), 0)
    # From (20, 40) along -x to the face x = 13: 20 - 13 = 7.
    assert ray([20.0, 40.0], PI, obstacles)[0] == pytest.approx(7.0, abs=1e-9)
    # From (10, 25) along +y to the face y = 32: 32 - 25 = 7.
    assert ray([10.0, 25.0], PI / 2, obstacles)[0] == pytest.approx(7.0, abs=1e-9)
    # From (10, 55) along -y to the face y = 48: 55 - 48 = 7.
    assert ray([10.0, 55.0], -PI / 2, obstacles)[0] == pytest.approx(7.0, abs=1e-9)
    # From (0, 33) at 45 deg: reaches x = 7 at y = 33 + 7 = 40 (inside [32, 48]) after 7 sqrt(2) = 9.8995.
    assert ray([0.0, 33.0], PI / 4, obstacles)[0] == pytest.approx(7 * math.sqrt(2), abs=1e-9)
    # From (0, 30) at 45 deg: at x = 7, y = 37; enters through x = 7 after 7 sqrt 2 = 9.8995
    # (the y slab is entered earlier, at y = 32 -> t = 2 sqrt 2).
    assert ray([0.0, 30.0], PI / 4, obstacles)[0] == pytest.approx(7 * math.sqrt(2), abs=1e-9)


def test_ray_misses_rectangle():
    obstacles = world(rectangles=[TRAIN_RECT])
    # From (0, 20) at 45 deg: reaches x = 7 at y = 27 < 32 and y = 32 at x = 12 after
    # 12 sqrt 2 = 16.97 > 10 -> capped (with range 20 it is a hit at 16.97: the top of the slab).
    assert ray([0.0, 20.0], PI / 4, obstacles) == (10.0, -1)
    assert ray([0.0, 20.0], PI / 4, obstacles, max_range=20.0)[0] == pytest.approx(12 * math.sqrt(2), abs=1e-9)
    # Pointing away.
    assert ray([0.0, 40.0], PI, obstacles) == (10.0, -1)


def test_ray_parallel_to_rectangle_edge():
    obstacles = world(rectangles=[TRAIN_RECT])
    # Heading exactly 0: direction (1, 0), the y component is exactly 0 (the slab-parallel branch).
    # Inside the y slab (y = 40 in [32, 48]): hits x = 7 at distance 7.
    assert ray([0.0, 40.0], 0.0, obstacles)[0] == pytest.approx(7.0)
    # Running along the top edge line y = 48 (slab bounds inclusive): touches the corner face at 7.
    assert ray([0.0, 48.0], 0.0, obstacles)[0] == pytest.approx(7.0)
    # Just above (y = 48.5) or below (y = 31.5) the slab: parallel and outside -> a miss.
    assert ray([0.0, 48.5], 0.0, obstacles) == (10.0, -1)
    assert ray([0.0, 31.5], 0.0, obstacles) == (10.0, -1)
    # Heading pi/2 (cos = 6e-17, not exactly 0): beside the x slab at x = 6.5 -> miss,
    # inside it at x = 10 -> the face y = 32 from y = 25 at 7.
    assert ray([6.5, 25.0], PI / 2, obstacles) == (10.0, -1)
    assert ray([10.0, 25.0], PI / 2, obstacles)[0] == pytest.approx(7.0, abs=1e-9)


def test_ray_inside_rectangle_is_zero():
    obstacles = world(rectangles=[TRAIN_RECT])
    for angle in (0.0, PI / 3, PI, -PI / 2):
        assert ray([10.0, 40.0], angle, obstacles)[0] == 0.0  # centre
        assert ray([7.0, 40.0], angle, obstacles)[0] == 0.0   # on the face x = 7


def test_nearest_obstacle_wins_and_index_counts_circles_first():
    # Circle (20, 0) r 2 (index 0) and rectangle centred (12, 0) 2 x 2 (index 1, x in [11, 13]).
    obstacles = world(circles=[[20.0, 0.0, 2.0]], rectangles=[[12.0, 0.0, 2.0, 2.0]])
    # From (5, 0) along +x: rectangle face x = 11 at 6, the circle at 18 - 5 = 13 -> 6, index 1.
    assert ray([5.0, 0.0], 0.0, obstacles, max_range=20.0) == (pytest.approx(6.0), 1)
    # From (25, 0) along -x: circle's far side x = 22 at 3 (index 0) before the rectangle (12 m).
    d, idx = ray([25.0, 0.0], PI, obstacles, max_range=20.0)
    assert d == pytest.approx(3.0, abs=1e-9) and idx == 0


def test_cast_rays_batched_shapes():
    # B = 2 worlds with different circles; N = 1 UAV at the origin; K = 2 beams (+x, -x).
    obstacles = Obstacles(torch.tensor([[[5.0, 0.0, 1.0]], [[-3.0, 0.0, 1.0]]]), torch.zeros(2, 0, 4))
    angles = torch.tensor([[[0.0, PI]], [[0.0, PI]]])
    d, idx = cast_rays(torch.zeros(2, 1, 2), angles, obstacles, 10.0)
    assert d.shape == idx.shape == (2, 1, 2)
    # World 0: +x hits at 5 - 1 = 4, -x misses (10). World 1: +x misses, -x hits at 3 - 1 = 2.
    assert torch.allclose(d, torch.tensor([[[4.0, 10.0]], [[10.0, 2.0]]]), atol=1e-5)
    assert idx.tolist() == [[[0, -1]], [[-1, 0]]]


# ---------------------------------------------------------------- true distances
def test_distance_to_obstacles():
    obstacles = world(circles=[[40.0, 40.0, 6.0]], rectangles=[TRAIN_RECT])
    points = torch.tensor([[[30.0, 40.0], [4.0, 29.0], [10.0, 40.0], [40.0, 41.0]]], dtype=torch.float64)
    d = distance_to_obstacles(points, obstacles)[0]
    # columns: circle, rectangle (circles first)
    # (30, 40): circle 10 - 6 = 4; rectangle face x = 13: 30 - 13 = 17.
    assert d[0].tolist() == pytest.approx([4.0, 17.0])
    # (4, 29): circle sqrt(36^2 + 11^2) - 6 = 37.643 - 6 = 31.643; rectangle corner (7, 32): sqrt(9 + 9) = 4.2426.
    assert d[1].tolist() == pytest.approx([math.hypot(36, 11) - 6, math.sqrt(18)])
    # (10, 40): rectangle centre, 3 m inside (faces x = 7, 13) -> -3.
    assert d[2, 1].item() == pytest.approx(-3.0)
    # (40, 41): 1 m from the circle centre -> 1 - 6 = -5.
    assert d[3, 0].item() == pytest.approx(-5.0)
    nearest = nearest_obstacle_distance(points, obstacles)[0]
    assert nearest.tolist() == pytest.approx([4.0, math.sqrt(18), -3.0, -5.0])


def test_nearest_obstacle_distance_without_obstacles_is_inf():
    out = nearest_obstacle_distance(torch.zeros(2, 3, 2), world(dtype=torch.float32))
    assert out.shape == (2, 3) and torch.isinf(out).all()


def test_pairwise():
    offset, dist = pairwise(torch.tensor([[[0.0, 0.0], [3.0, 4.0], [0.0, -1.0]]]))
    # offset[b, i, j] = p_j - p_i: from UAV 0 to 1 is (3, 4), |.| = 5; from 1 to 2 is (-3, -5), sqrt 34.
    assert offset[0, 0, 1].tolist() == [3.0, 4.0]
    assert offset[0, 1, 0].tolist() == [-3.0, -4.0]
    expected = torch.tensor([[0, 5, 1], [5, 0, math.sqrt(34)], [1, math.sqrt(34), 0]])
    assert torch.allclose(dist[0], expected)


def test_a_constant_is_made_once_per_values_dtype_and_device():
    from flock_torchrl.world.geometry import constant

    like = torch.zeros(3, dtype=torch.float64)
    first = constant([0.1, -2.0], like)
    assert first.dtype == torch.float64 and first.tolist() == [0.1, -2.0]
    assert constant((0.1, -2.0), like) is first  # reused: no tensor made from Python numbers again
    assert constant([0.1, -2.0], like.float()).dtype == torch.float32
