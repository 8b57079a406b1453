"""Rigid transforms ``T_a_b`` (4x4 float64) with ``p_a = T_a_b @ p_b``.

Every pose in the project is one of these. Names carry both frames so that in ``T_a_b @ T_b_c`` the inner frames
cancel. Quaternions follow the TUM RGB-D order ``qx qy qz qw`` (scalar last) and are unit, with ``qw >= 0`` on output.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "check_transform",
    "identity",
    "compose",
    "invert",
    "apply",
    "transform_from_rotation_translation",
    "rotation_from_quaternion",
    "quaternion_from_rotation",
    "transform_from_tum",
    "tum_from_transform",
    "rotation_angle_rad",
    "pose_error",
    "rotation_from_axis_angle",
    "axis_angle_from_rotation",
    "log_se3",
    "exp_se3",
    "rotation_between",
]

_ORTHO_TOL = 1e-5
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_EYE3 = np.eye(3)


def check_transform(T: np.ndarray, name: str = "T") -> np.ndarray:
    """Validate a rigid transform and return it as a float64 (4, 4) array.

    Raises ``ValueError`` naming ``name`` when the shape is wrong, a value is not finite, the last row is not
    ``[0, 0, 0, 1]`` or the rotation block is not orthonormal with determinant +1.
    """
    arr = np.asarray(T, dtype=np.float64)
    if arr.shape != (4, 4):
        raise ValueError(f"{name}: expected a 4x4 rigid transform, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: expected finite values, got {arr.tolist()}")
    # np.allclose(arr[3], [0, 0, 0, 1], atol=1e-9) written out: called for every frame of a window, and allclose
    # alone took ~20 us.
    if not bool(np.all(np.abs(arr[3] - _LAST_ROW) <= 1e-9 + 1e-5 * _LAST_ROW)):
        raise ValueError(f"{name}: expected last row [0, 0, 0, 1], got {arr[3].tolist()}")
    R = arr[:3, :3]
    err = np.abs(R @ R.T - _EYE3).max()
    det = (R[0, 0] * (R[1, 1] * R[2, 2] - R[1, 2] * R[2, 1]) - R[0, 1] * (R[1, 0] * R[2, 2] - R[1, 2] * R[2, 0])
           + R[0, 2] * (R[1, 0] * R[2, 1] - R[1, 1] * R[2, 0]))
    if err > _ORTHO_TOL or det < 0:
        raise ValueError(
            f"{name}: expected a rotation block with R R^T = I and det(R) = +1, "
            f"got max |R R^T - I| = {err:.3g}, det = {det:.6f}"
        )
    return arr


def identity() -> np.ndarray:
    """The identity transform (4, 4) float64."""
    return np.eye(4)


def transform_from_rotation_translation(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Build ``T`` from a (3, 3) rotation and a (3,) translation."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=np.float64)
    T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def compose(*transforms: np.ndarray) -> np.ndarray:
    """``compose(T_a_b, T_b_c, ...)`` is ``T_a_b @ T_b_c @ ...``."""
    out = np.eye(4)
    for T in transforms:
        out = out @ np.asarray(T, dtype=np.float64)
    return out


def invert(T_a_b: np.ndarray) -> np.ndarray:
    """Return ``T_b_a`` using the rigid structure (no general matrix inverse)."""
    T = np.asarray(T_a_b, dtype=np.float64)
    R = T[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def apply(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Map points (N, 3) or (3,) from frame b into frame a. Keeps the input dtype for float32 clouds."""
    pts = np.asarray(points_b)
    if pts.shape[-1] != 3:
        raise ValueError(f"points_b: expected shape (N, 3) or (3,), got {pts.shape}")
    T = np.asarray(T_a_b, dtype=np.float64)
    out = pts @ T[:3, :3].T.astype(pts.dtype if pts.dtype == np.float32 else np.float64)
    out += T[:3, 3].astype(out.dtype)
    return out


def rotation_from_quaternion(q_xyzw: np.ndarray) -> np.ndarray:
    """(3, 3) rotation from a quaternion ``[qx, qy, qz, qw]`` (normalized here; must not be zero)."""
    q = np.asarray(q_xyzw, dtype=np.float64).reshape(4)
    norm = np.linalg.norm(q)
    if not np.isfinite(norm) or norm < 1e-12:
        raise ValueError(f"q_xyzw: expected a non-zero finite quaternion [qx, qy, qz, qw], got {q.tolist()}")
    x, y, z, w = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """Unit quaternion ``[qx, qy, qz, qw]`` with ``qw >= 0`` from a (3, 3) rotation (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = np.array([(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s])
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = np.array([0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s])
    elif R[1, 1] > R[2, 2]:
        s = math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = np.array([(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s])
    else:
        s = math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = np.array([(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s])
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def transform_from_tum(values: np.ndarray) -> np.ndarray:
    """``T`` from the 7 TUM values ``tx ty tz qx qy qz qw``."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if v.shape != (7,) or not np.all(np.isfinite(v)):
        raise ValueError(f"values: expected 7 finite numbers 'tx ty tz qx qy qz qw', got {v.tolist()}")
    return transform_from_rotation_translation(rotation_from_quaternion(v[3:]), v[:3])


def tum_from_transform(T: np.ndarray) -> np.ndarray:
    """The 7 TUM values ``tx ty tz qx qy qz qw`` of ``T``."""
    T = np.asarray(T, dtype=np.float64)
    return np.concatenate([T[:3, 3], quaternion_from_rotation(T[:3, :3])])


def rotation_angle_rad(R: np.ndarray) -> float:
    """Angle (radians, in [0, pi]) of a rotation matrix, computed stably for small and large angles."""
    R = np.asarray(R, dtype=np.float64)
    # atan2 of |axis * sin| and cos is accurate near 0 and pi, unlike arccos of the trace.
    s = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    c = 0.5 * (np.trace(R) - 1.0)
    return float(math.atan2(s, c))


def pose_error(T_est: np.ndarray, T_ref: np.ndarray) -> tuple[float, float]:
    """Distance between two poses of the same frames: (translation error in m, rotation angle in degrees)."""
    A = np.asarray(T_est, dtype=np.float64)
    B = np.asarray(T_ref, dtype=np.float64)
    t_err = float(np.linalg.norm(A[:3, 3] - B[:3, 3]))
    r_err = math.degrees(rotation_angle_rad(A[:3, :3].T @ B[:3, :3]))
    return t_err, r_err


def _hat(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def rotation_from_axis_angle(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: (3, 3) rotation from a rotation vector (axis times angle in radians)."""
    w = np.asarray(rotvec, dtype=np.float64).reshape(3)
    theta = float(np.linalg.norm(w))
    K = _hat(w)
    if theta < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + math.sin(theta) / theta * K + (1 - math.cos(theta)) / theta**2 * K @ K


def axis_angle_from_rotation(R: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) of a rotation matrix; the inverse of :func:`rotation_from_axis_angle`."""
    R = np.asarray(R, dtype=np.float64)
    theta = rotation_angle_rad(R)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-6:
        return 0.5 * v
    if math.pi - theta < 1e-4:
        # Near pi the antisymmetric part vanishes: take the axis from the symmetric part, which is
        # cos(theta) I + (1 - cos(theta)) a a^T exactly (R's own rows alone are off by its antisymmetric part).
        c = math.cos(theta)
        B = (0.5 * (R + R.T) - c * np.eye(3)) / (1.0 - c)
        axis = B[np.argmax(np.diag(B))]
        axis = axis / np.linalg.norm(axis)
        if np.dot(axis, v) < 0:
            axis = -axis
        return axis * theta
    return v * (theta / (2 * math.sin(theta)))


# Below this rotation angle (rad) the SE(3) Jacobians use their Taylor series (truncation error ~theta^4 / 720).
_SMALL_ANGLE = 1e-4


def log_se3(T: np.ndarray) -> np.ndarray:
    """Logarithm of a rigid transform as the 6-vector ``[rho (translation part), phi (rotation vector)]``."""
    T = np.asarray(T, dtype=np.float64)
    phi = axis_angle_from_rotation(T[:3, :3])
    theta = float(np.linalg.norm(phi))
    K = _hat(phi)
    if theta < _SMALL_ANGLE:  # series: the closed form cancels catastrophically for tiny angles
        V_inv = np.eye(3) - 0.5 * K + (1.0 / 12.0 + theta**2 / 720.0) * K @ K
    else:
        half = 0.5 * theta
        coef = (1.0 - half * math.cos(half) / math.sin(half)) / theta**2
        V_inv = np.eye(3) - 0.5 * K + coef * K @ K
    return np.concatenate([V_inv @ T[:3, 3], phi])


def exp_se3(xi: np.ndarray) -> np.ndarray:
    """Inverse of :func:`log_se3`: 4x4 transform from ``[rho, phi]``."""
    xi = np.asarray(xi, dtype=np.float64).reshape(6)
    rho, phi = xi[:3], xi[3:]
    theta = float(np.linalg.norm(phi))
    K = _hat(phi)
    R = rotation_from_axis_angle(phi)
    if theta < _SMALL_ANGLE:  # series: 1 - cos and theta - sin lose every digit for tiny angles
        V = np.eye(3) + (0.5 - theta**2 / 24.0) * K + (1.0 / 6.0 - theta**2 / 120.0) * K @ K
    else:
        V = np.eye(3) + (1 - math.cos(theta)) / theta**2 * K + (theta - math.sin(theta)) / theta**3 * K @ K
    return transform_from_rotation_translation(R, V @ rho)


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation ``R`` with ``R @ a_hat == b_hat`` for two non-zero 3-vectors."""
    a = np.asarray(a, dtype=np.float64).reshape(3)
    b = np.asarray(b, dtype=np.float64).reshape(3)
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        # Opposite vectors: rotate by pi about any axis perpendicular to a.
        helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        axis = np.cross(a, helper)
        axis /= np.linalg.norm(axis)
        return rotation_from_axis_angle(axis * math.pi)
    return rotation_from_axis_angle(v / s * math.atan2(s, c))
