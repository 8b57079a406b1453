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
