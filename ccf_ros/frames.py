"""Sensor mounting: rotations between the IMU's, the magnetometer's and the output frame. No ROS import.

A rotation is given as ``[roll, pitch, yaw]`` (rad, fixed axes X then Y then Z, as ``static_transform_publisher``:
``R = Rz(yaw) Ry(pitch) Rx(roll)``) or as a quaternion ``[x, y, z, w]``. ``mount_rotation`` is the IMU frame's
rotation in the output frame: a vector ``v`` measured in the IMU frame is ``R v`` in the output frame (the rotation
of the transform output_frame -> imu_frame in TF).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

#: Row-major 3x3 matrix, 9 floats.
Mat3 = tuple[float, float, float, float, float, float, float, float, float]
Vec3 = tuple[float, float, float]

IDENTITY: Mat3 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
#: A quaternion given as ``[x, y, z, w]`` must have a norm within this of 1 (it is then normalised): a typo, not
#: rounding (four decimals are 1e-4 off at most), is refused.
UNIT_TOL = 1e-3


def rotation_matrix(name: str, value: Sequence[float]) -> Mat3:
    """The rotation matrix of ``value``: ``[roll, pitch, yaw]`` (rad, fixed X-Y-Z) or ``[x, y, z, w]`` (unit).

    Raises:
        ValueError: not 3 or 4 finite numbers, or a quaternion whose norm is not 1; the message names ``name``.
    """
    v = tuple(value)
    if len(v) not in (3, 4) or not all(
        isinstance(a, (int, float)) and not isinstance(a, bool) and math.isfinite(a) for a in v
    ):
        raise ValueError(f'{name} must be [roll, pitch, yaw] (rad) or a quaternion [x, y, z, w], got {list(v)!r}')
    if len(v) == 3:
        return _rpy_matrix(float(v[0]), float(v[1]), float(v[2]))
    x, y, z, w = (float(a) for a in v)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if abs(n - 1.0) > UNIT_TOL:
        raise ValueError(f'{name}: the quaternion [x, y, z, w] must have norm 1 (within {UNIT_TOL:g}), got '
                         f'{list(v)!r} (norm {n:.6g})')
    return quat_matrix(w / n, x / n, y / n, z / n)


def _rpy_matrix(roll: float, pitch: float, yaw: float) -> Mat3:
    """``Rz(yaw) Ry(pitch) Rx(roll)``."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return (
        cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr,
        sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr,
        -sp, cp * sr, cp * cr,
    )


def quat_matrix(w: float, x: float, y: float, z: float) -> Mat3:
    """Rotation matrix of the unit quaternion ``w + xi + yj + zk``."""
    return (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )


def is_identity(m: Sequence[float], tol: float = 1e-12) -> bool:
    """Whether ``m`` (9 values) is the identity within ``tol`` per entry (then it is skipped: no cost)."""
    return all(abs(a - b) <= tol for a, b in zip(m, IDENTITY, strict=True))


def matmul(a: Sequence[float], b: Sequence[float]) -> Mat3:
    """``a @ b`` of two row-major 3x3 matrices."""
    return (
        a[0] * b[0] + a[1] * b[3] + a[2] * b[6], a[0] * b[1] + a[1] * b[4] + a[2] * b[7],
        a[0] * b[2] + a[1] * b[5] + a[2] * b[8],
        a[3] * b[0] + a[4] * b[3] + a[5] * b[6], a[3] * b[1] + a[4] * b[4] + a[5] * b[7],
        a[3] * b[2] + a[4] * b[5] + a[5] * b[8],
        a[6] * b[0] + a[7] * b[3] + a[8] * b[6], a[6] * b[1] + a[7] * b[4] + a[8] * b[7],
        a[6] * b[2] + a[7] * b[5] + a[8] * b[8],
    )


def transpose(m: Sequence[float]) -> Mat3:
    """The transpose (for a rotation: its inverse)."""
    return (m[0], m[3], m[6], m[1], m[4], m[7], m[2], m[5], m[8])


def apply(m: Sequence[float], v: Sequence[float]) -> Vec3:
    """``m @ v``."""
    return (
        m[0] * v[0] + m[1] * v[1] + m[2] * v[2],
        m[3] * v[0] + m[4] * v[1] + m[5] * v[2],
        m[6] * v[0] + m[7] * v[1] + m[8] * v[2],
    )


def rotate_covariance(m: Sequence[float], cov: Sequence[float]) -> tuple[float, ...]:
    """``m C mᵀ`` of a row-major 3x3 covariance; one with ``cov[0] == -1`` (REP-145: "no estimate") is kept, and so
    is ``c I`` (zeros included: drivers that report none), which every rotation leaves unchanged."""
    c0 = cov[0]
    if c0 == -1.0 or (cov[1] == cov[2] == cov[3] == cov[5] == cov[6] == cov[7] == 0.0 and cov[4] == cov[8] == c0):
        return cov if isinstance(cov, tuple) else tuple(cov)
    return matmul(matmul(m, cov), transpose(m))
