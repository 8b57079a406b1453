"""Rigid transform identities as seeded property tests (hypothesis), plus edge cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reloc import transforms as tf

finite = st.floats(min_value=-50.0, max_value=50.0, allow_nan=False, allow_infinity=False)
angle = st.floats(min_value=-math.pi, max_value=math.pi, allow_nan=False)


@st.composite
def rigid(draw):
    axis = np.array([draw(finite), draw(finite), draw(finite)])
    if np.linalg.norm(axis) < 1e-3:
        axis = np.array([0.0, 0.0, 1.0])
    rotvec = axis / np.linalg.norm(axis) * draw(angle)
    t = np.array([draw(finite), draw(finite), draw(finite)])
    return tf.transform_from_rotation_translation(tf.rotation_from_axis_angle(rotvec), t)


points = st.lists(st.tuples(finite, finite, finite), min_size=1, max_size=20).map(np.array)


@settings(max_examples=200, deadline=None)
@given(rigid())
def test_compose_with_inverse_is_identity(T):
    np.testing.assert_allclose(tf.compose(T, tf.invert(T)), np.eye(4), atol=1e-9)
    np.testing.assert_allclose(tf.compose(tf.invert(T), T), np.eye(4), atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(rigid(), rigid(), points)
def test_compose_matches_sequential_application(T_a_b, T_b_c, p_c):
    direct = tf.apply(tf.compose(T_a_b, T_b_c), p_c)
    stepwise = tf.apply(T_a_b, tf.apply(T_b_c, p_c))
    np.testing.assert_allclose(direct, stepwise, atol=1e-8)


@settings(max_examples=200, deadline=None)
@given(rigid(), points)
def test_apply_preserves_distances(T, p):
    q = tf.apply(T, p)
    d_p = np.linalg.norm(p[:, None] - p[None], axis=-1)
    d_q = np.linalg.norm(q[:, None] - q[None], axis=-1)
    np.testing.assert_allclose(d_p, d_q, atol=1e-8)


@settings(max_examples=300, deadline=None)
@given(rigid())
def test_tum_round_trip(T):
    v = tf.tum_from_transform(T)
    assert v.shape == (7,)
    assert abs(np.linalg.norm(v[3:]) - 1.0) < 1e-12 and v[6] >= 0
    np.testing.assert_allclose(tf.transform_from_tum(v), T, atol=1e-9)


@settings(max_examples=300, deadline=None)
@given(rigid())
def test_quaternion_sign_does_not_matter(T):
    q = tf.quaternion_from_rotation(T[:3, :3])
    np.testing.assert_allclose(tf.rotation_from_quaternion(-q), T[:3, :3], atol=1e-9)


@settings(max_examples=300, deadline=None)
@given(rigid())
def test_log_exp_round_trip(T):
    np.testing.assert_allclose(tf.exp_se3(tf.log_se3(T)), T, atol=1e-7)


@settings(max_examples=200, deadline=None)
@given(rigid(), rigid())
def test_pose_error_is_symmetric_and_zero_on_self(A, B):
    t_ab, r_ab = tf.pose_error(A, B)
    t_ba, r_ba = tf.pose_error(B, A)
    assert t_ab == pytest.approx(t_ba, abs=1e-9) and r_ab == pytest.approx(r_ba, abs=1e-6)
    assert tf.pose_error(A, A) == pytest.approx((0.0, 0.0), abs=1e-6)


def test_pose_error_known_values():
    A = tf.transform_from_rotation_translation(tf.rotation_from_axis_angle([0, 0, math.radians(30)]), [1, 2, 3])
    B = tf.transform_from_rotation_translation(np.eye(3), [1, 2, 3.5])
    t_err, r_err = tf.pose_error(A, B)
    assert t_err == pytest.approx(0.5)
    assert r_err == pytest.approx(30.0, abs=1e-9)


@pytest.mark.parametrize("deg", [0.0, 1e-7, 1e-3, 90.0, 179.9, 180.0])
def test_rotation_angle_near_zero_and_pi(deg):
    R = tf.rotation_from_axis_angle(np.array([1.0, 2.0, -0.5]) / math.sqrt(5.25) * math.radians(deg))
    assert math.degrees(tf.rotation_angle_rad(R)) == pytest.approx(deg, abs=1e-6)
    np.testing.assert_allclose(tf.rotation_from_axis_angle(tf.axis_angle_from_rotation(R)), R, atol=1e-6)


@pytest.mark.parametrize("gap", [2e-4, 9e-5, 5e-5, 1e-6, 0.0])
def test_axis_angle_round_trips_within_1e4_rad_of_pi(gap):
    """Within 1e-4 rad of pi the axis comes from the symmetric part of R; it was read from a row of (R + I) / 2,
    whose antisymmetric part (sin(theta) of the axis) put it 6.6e-5 rad off at pi - 9e-5."""
    axis = np.array([0.3, -0.5, 0.81])
    axis /= np.linalg.norm(axis)
    phi = axis * (math.pi - gap)
    R = tf.rotation_from_axis_angle(phi)
    back = tf.axis_angle_from_rotation(R)
    if gap == 0.0:  # at pi, the axis and its opposite are the same rotation
        back = back if back @ phi > 0 else -back
    np.testing.assert_allclose(back, phi, atol=1e-10)
    np.testing.assert_allclose(tf.rotation_from_axis_angle(back), R, atol=1e-12)
    T = tf.transform_from_rotation_translation(R, np.array([0.4, -1.0, 2.0]))
    np.testing.assert_allclose(tf.exp_se3(tf.log_se3(T)), T, atol=1e-10)


def test_tum_matches_known_quaternion():
    # 90 degrees about z: qz = qw = sqrt(1/2)
    T = tf.transform_from_tum([1, 2, 3, 0, 0, math.sqrt(0.5), math.sqrt(0.5)])
    np.testing.assert_allclose(T[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [1, 2, 3])


@settings(max_examples=100, deadline=None)
@given(st.tuples(finite, finite, finite), st.tuples(finite, finite, finite))
def test_rotation_between_maps_a_to_b(a, b):
    a, b = np.array(a), np.array(b)
    if np.linalg.norm(a) < 1e-3 or np.linalg.norm(b) < 1e-3:
        return
    R = tf.rotation_between(a, b)
    np.testing.assert_allclose(R @ (a / np.linalg.norm(a)), b / np.linalg.norm(b), atol=1e-8)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-10)


def test_check_transform_names_the_problem():
    with pytest.raises(ValueError, match=r"T_map_cam: expected a 4x4 rigid transform, got shape \(3, 4\)"):
        tf.check_transform(np.zeros((3, 4)), "T_map_cam")
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(ValueError, match="T_x: expected a rotation block"):
        tf.check_transform(bad, "T_x")
    bad = np.eye(4)
    bad[3, 0] = 1.0
    with pytest.raises(ValueError, match="last row"):
        tf.check_transform(bad, "T")
    with pytest.raises(ValueError, match="finite"):
        tf.check_transform(np.full((4, 4), np.nan), "T")
    mirror = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="det"):
        tf.check_transform(mirror, "T")


def test_bad_quaternion_and_tum_values_raise():
    with pytest.raises(ValueError, match="non-zero"):
        tf.rotation_from_quaternion([0, 0, 0, 0])
    with pytest.raises(ValueError, match="7 finite numbers"):
        tf.transform_from_tum([1, 2, 3])


def test_apply_keeps_float32():
    p = np.ones((5, 3), np.float32)
    assert tf.apply(np.eye(4), p).dtype == np.float32
