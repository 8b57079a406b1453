"""Plane geometry identities: transforms, orientation, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reloc import planes as pl
from reloc import transforms as tf


def random_rigid(rng):
    R = tf.rotation_from_axis_angle(rng.normal(size=3))
    return tf.transform_from_rotation_translation(R, rng.uniform(-5, 5, 3))


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_transformed_plane_contains_transformed_points(seed):
    rng = np.random.default_rng(seed)
    n = rng.normal(size=3)
    n /= np.linalg.norm(n)
    d = rng.uniform(-3, 3)
    # Points on the plane: p = -d n + a u + b v.
    u = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    ab = rng.uniform(-2, 2, (10, 2))
    p_b = -d * n + ab[:, :1] * u + ab[:, 1:] * v
    T_a_b = random_rigid(rng)
    plane_a = pl.transform_plane(T_a_b, np.concatenate([n, [d]]))
    np.testing.assert_allclose(pl.point_plane_distance(tf.apply(T_a_b, p_b), plane_a), 0.0, atol=1e-9)
    # Moving there and back is the identity.
    back = pl.transform_plane(tf.invert(T_a_b), plane_a)
    np.testing.assert_allclose(back, np.concatenate([n, [d]]), atol=1e-9)


def test_orient_toward_sensor_and_viewpoint():
    n = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    d = np.array([-2.0, 2.0])  # both: the plane z = 2
    n2, d2 = pl.orient_toward(n, d)
    np.testing.assert_allclose(n2, [[0, 0, -1], [0, 0, -1]])
    np.testing.assert_allclose(d2, [2, 2])
    n3, d3 = pl.orient_toward(n, d, viewpoint=[0, 0, 5])
    np.testing.assert_allclose(n3, [[0, 0, 1], [0, 0, 1]])
    np.testing.assert_allclose(d3, [-2, -2])


def test_plane_errors_known_values_and_sign_agnostic():
    ref = np.array([0.0, 0.0, 1.0, -2.0])
    tilt = math.radians(1.0)
    est = np.array([math.sin(tilt), 0.0, math.cos(tilt), -2.01])
    ang, off = pl.plane_errors(est, ref)
    assert ang == pytest.approx(1.0, abs=1e-9)
    assert off == pytest.approx(0.01, abs=1e-12)
    ang2, off2 = pl.plane_errors(-est, ref)
    assert (ang2, off2) == pytest.approx((ang, off))


def test_plane_angle_unsigned():
    assert pl.plane_angle_deg([0, 0, 1], [0, 0, -1]) == pytest.approx(180.0)
    assert pl.plane_angle_deg([0, 0, 1], [0, 0, -1], unsigned=True) == pytest.approx(0.0)
    np.testing.assert_allclose(pl.plane_angle_deg(np.eye(3), np.roll(np.eye(3), 1, axis=0)), [90, 90, 90])


def test_plane_from_three_points_and_collinear_error():
    p = pl.plane_from_points_exact([0, 0, 1], [1, 0, 1], [0, 1, 1])
    np.testing.assert_allclose(p, [0, 0, 1, -1])
    with pytest.raises(ValueError, match="non-collinear"):
        pl.plane_from_points_exact([0, 0, 0], [1, 1, 1], [2, 2, 2])


def test_check_normals_messages():
    with pytest.raises(ValueError, match=r"normals: expected shape \(N, 3\), got \(3,\)"):
        pl.check_normals(np.zeros(3))
    with pytest.raises(ValueError, match="row 1 has norm 2"):
        pl.check_normals(np.array([[1.0, 0, 0], [0, 2.0, 0]]))


def _rotated(normals, seed):
    R = tf.rotation_from_axis_angle(np.random.default_rng(seed).normal(size=3))
    return np.asarray(normals, dtype=np.float64) @ R.T


@pytest.mark.parametrize("seed", range(8))
def test_weakest_direction_of_a_corner_is_held_by_one_wall(seed):
    # Floor 6 m^2, two perpendicular walls of 2 m^2 and a 0.1 m^2 face at 45 degrees between them, turned at
    # random. Along either wall's normal only that wall pins the translation (the face is within 60 degrees of
    # both normals, but not of directions 15-30 degrees past them). The eigenvector of the smallest eigenvalue
    # lies half-way between the walls, where both of them count (4 m^2).
    s = 2**-0.5
    normals = _rotated([[1, 0, 0], [0, 1, 0], [0, 0, 1], [s, s, 0]], seed)
    areas = np.array([2.0, 2.0, 6.0, 0.1])
    e, support = pl.weakest_direction_support(normals, areas)
    assert support == pytest.approx(2.0, abs=1e-9)
    assert abs(np.linalg.norm(e) - 1.0) < 1e-9
    held = np.abs(normals @ e) >= 0.5
    assert held.tolist() in ([True, False, False, False], [False, True, False, False])


@pytest.mark.parametrize("seed", range(8))
def test_weakest_direction_of_two_equal_walls_whatever_their_turn(seed):
    # Exactly equal walls: every direction between them is as stiff, so the eigenvector is whatever rounding
    # gives; the support must not depend on it.
    normals = _rotated([[1, 0, 0], [0, 1, 0], [0, 0, 1]], seed)
    assert pl.weakest_direction_support(normals, np.array([1.5, 1.5, 8.0]))[1] == pytest.approx(1.5, abs=1e-9)


def test_weakest_direction_of_a_corridor_is_its_door_jamb():
    # Floor, ceiling, two walls of 5 m^2 and a door jamb of 0.3 m^2 across the corridor (x): pinned by the jamb.
    normals = np.array([[1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)
    e, support = pl.weakest_direction_support(normals, np.array([0.3, 5, 5, 5, 5]))
    assert support == pytest.approx(0.3)
    assert abs(e[0]) == pytest.approx(1.0)


def test_weakest_direction_of_unequal_walls_is_the_smaller_walls_normal():
    # Walls of 1 and 3 m^2 (more than twice as stiff): the eigenvector, the smaller wall's normal, alone is weak.
    e, support = pl.weakest_direction_support(np.eye(3), np.array([1.0, 3.0, 9.0]))
    assert support == pytest.approx(1.0)
    assert abs(e[0]) == pytest.approx(1.0)
