"""The node's debug values as plain code (no ROS import): ``imu/rpy/raw``."""

from __future__ import annotations

import math

from ..core.quaternion import WORLD_FRAMES, quat_from_acc_mag_scalar, quat_mul_scalar, rpy_of

Vec3 = tuple[float, float, float]


def raw_rpy(acc: Vec3, mag: Vec3 | None, world_frame: str) -> Vec3 | None:
    """Roll, pitch, yaw (rad) of the attitude of one accelerometer + (calibrated) magnetometer sample alone, in the
    world frame ``world_frame`` (imu_filter_madgwick's ``imu/rpy/raw``: no filter, no yaw offset); None without a
    magnetometer sample, an unusable accelerometer, or a field too close to the vertical to give a heading."""
    if mag is None:
        return None
    ax, ay, az = acc
    n2 = ax * ax + ay * ay + az * az
    if not (n2 > 1e-12 and math.isfinite(n2)) or not all(math.isfinite(m) for m in mag):
        return None
    q = quat_from_acc_mag_scalar(ax, ay, az, mag[0], mag[1], mag[2], True)
    if q is None:
        return None
    # ENU -> the world frame (as OrientationFilter.quaternion does): q_frame = p ⊗ q_enu.
    return rpy_of(quat_mul_scalar(WORLD_FRAMES[world_frame], q))
