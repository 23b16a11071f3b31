"""Quaternion, Euler-angle and frame helpers (numpy, vectorised).

Conventions used throughout the core:

* quaternions are ``[w, x, y, z]``, unit norm, and rotate body-frame vectors into the world frame
  (``v_world = q ⊗ v_body ⊗ q*``);
* Euler angles are intrinsic Z-Y-X (yaw ``psi``, pitch ``theta``, roll ``phi``), in rad,
  ``q = Rz(psi) Ry(theta) Rx(phi)``;
* the internal world frame is ENU (REP-103); an accelerometer at rest reads ``+g`` along world up (REP-145).

Every function accepts a single ``(4,)``/``(3,)`` array or a stack ``(N, 4)``/``(N, 3)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: Rotation from ENU to the supported world frames, ``q_frame_from_enu`` in ``[w, x, y, z]``.
#: NED: x=north, y=east, z=down; NWU: x=north, y=west, z=up.
_S = math.sqrt(0.5)
WORLD_FRAMES: dict[str, tuple[float, float, float, float]] = {
    'enu': (1.0, 0.0, 0.0, 0.0),
    # v_ned = (v_n, v_e, -v_u): 180 deg about the (1, 1, 0)/sqrt(2) axis.
    'ned': (0.0, _S, _S, 0.0),
    # v_nwu = (v_n, -v_e, v_u): -90 deg about z.
    'nwu': (_S, 0.0, 0.0, -_S),
}


def quat_mul(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """Hamilton product ``p ⊗ q``; shapes ``(..., 4)``."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        (
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ),
        axis=-1,
    )


def quat_conj(q: ArrayLike) -> FloatArray:
    """Conjugate (inverse of a unit quaternion); shape ``(..., 4)``."""
    q = np.array(q, dtype=float)
    q[..., 1:] *= -1.0
    return q


def quat_normalize(q: ArrayLike) -> FloatArray:
    """Unit quaternion with non-negative ``w`` (one representative of ``±q``)."""
    a = np.asarray(q, dtype=float)
    u = a / np.linalg.norm(a, axis=-1, keepdims=True)
    out: FloatArray = np.where(u[..., :1] < 0.0, -u, u)
    return out


def quat_rotate(q: ArrayLike, v: ArrayLike) -> FloatArray:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4): body -> world."""
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    u = q[..., 1:]
    w = q[..., :1]
    t = 2.0 * np.cross(u, v)
    out: FloatArray = v + w * t + np.cross(u, t)
    return out


def quat_angle(q: ArrayLike) -> FloatArray:
    """Rotation angle of unit quaternions in rad, in ``[0, pi]``."""
    q = np.asarray(q, dtype=float)
    out: FloatArray = 2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))
    return out


def quat_from_rotvec(r: ArrayLike) -> FloatArray:
    """Quaternion of rotation vectors ``r`` (..., 3), angle = norm in rad."""
    r = np.asarray(r, dtype=float)
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a with its limit 1/2 at a=0
    k = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    return np.concatenate((np.cos(half), k * r), axis=-1)


def quat_to_rotvec(q: ArrayLike) -> FloatArray:
    """Rotation vectors (..., 3) of quaternions ``q`` (..., 4), angle in ``[0, pi]`` rad (the short way round)."""
    q = np.asarray(q, dtype=float)
    q = q * np.where(q[..., :1] < 0.0, -1.0, 1.0)
    v = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(v, q[..., 0])
    # angle / v with its limit 2 (a unit quaternion's w is then 1) at v = 0
    scale = np.where(v > 1e-12, angle / np.maximum(v, 1e-12), 2.0)
    out: FloatArray = q[..., 1:] * scale[..., None]
    return out


def euler_to_quat(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> FloatArray:
    """ZYX Euler angles (rad) -> quaternions ``(..., 4)``."""
    cr, sr = np.cos(np.multiply(roll, 0.5)), np.sin(np.multiply(roll, 0.5))
    cp, sp = np.cos(np.multiply(pitch, 0.5)), np.sin(np.multiply(pitch, 0.5))
    cy, sy = np.cos(np.multiply(yaw, 0.5)), np.sin(np.multiply(yaw, 0.5))
    return np.stack(
        (
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ),
        axis=-1,
    )


def quat_to_euler(q: ArrayLike) -> FloatArray:
    """Quaternions ``(..., 4)`` -> ZYX Euler angles ``(..., 3)`` as ``[roll, pitch, yaw]`` in rad."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = np.moveaxis(q, -1, 0)
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.stack((roll, pitch, yaw), axis=-1)


def wrap_angle(a: ArrayLike) -> FloatArray:
    """Wrap angles (rad) into ``[-pi, pi)``."""
    return (np.asarray(a, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def quat_slerp(q0: ArrayLike, q1: ArrayLike, f: ArrayLike) -> FloatArray:
    """Spherical interpolation from ``q0`` to ``q1`` at fraction ``f`` in ``[0, 1]``; shapes broadcast."""
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float)
    f = np.asarray(f, dtype=float)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0.0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_t = np.sin(theta)
    small = sin_t < 1e-9
    safe = np.where(small, 1.0, sin_t)
    w0 = np.where(small, 1.0 - f, np.sin((1.0 - f) * theta) / safe)
    w1 = np.where(small, f, np.sin(f * theta) / safe)
    return quat_normalize(w0 * q0 + w1 * q1)


def enu_to_frame(q_enu: ArrayLike, world_frame: str) -> FloatArray:
    """Re-express body->ENU orientations as body->``world_frame`` (``enu``, ``ned`` or ``nwu``)."""
    try:
        f = WORLD_FRAMES[world_frame]
    except KeyError:
        raise ValueError(f'world_frame must be one of {sorted(WORLD_FRAMES)}, got {world_frame!r}') from None
    return quat_mul(f, q_enu)


def frame_to_enu(q_frame: ArrayLike, world_frame: str) -> FloatArray:
    """Inverse of :func:`enu_to_frame`."""
    if world_frame not in WORLD_FRAMES:
        raise ValueError(f'world_frame must be one of {sorted(WORLD_FRAMES)}, got {world_frame!r}')
    return quat_mul(quat_conj(WORLD_FRAMES[world_frame]), q_frame)


def quat_from_acc_mag(acc: ArrayLike, mag: ArrayLike | None = None) -> FloatArray:
    """Body->ENU orientation from accelerometer (m/s², +g up at rest) and magnetometer (any unit).

    Without a magnetometer (or with one parallel to gravity) the heading is set to zero.
    Shapes ``(..., 3)`` -> ``(..., 4)``.
    """
    acc = np.asarray(acc, dtype=float)
    up = acc / np.linalg.norm(acc, axis=-1, keepdims=True)
    if mag is None:
        ref = np.broadcast_to([1.0, 0.0, 0.0], up.shape)
        # a body x axis that is not vertical defines "north" arbitrarily: yaw 0
        east_guess = np.cross(np.cross(up, ref), up)
        alt = np.cross(np.cross(up, [0.0, 1.0, 0.0]), up)
        east_guess = np.where(np.linalg.norm(east_guess, axis=-1, keepdims=True) > 1e-6, east_guess, alt)
        east = east_guess / np.linalg.norm(east_guess, axis=-1, keepdims=True)
    else:
        m = np.asarray(mag, dtype=float)
        east = np.cross(m, up)
        en = np.linalg.norm(east, axis=-1, keepdims=True)
        # A field (nearly) along gravity has no horizontal part: fall back to heading zero there instead of 0/0.
        ok = en > MAG_PARALLEL_SIN * np.linalg.norm(m, axis=-1, keepdims=True)
        fallback = quat_from_acc_mag(acc)
        if not np.all(ok):
            east = np.where(ok, east / np.where(ok, en, 1.0), 0.0)
            north = np.cross(up, east)
            q = rotmat_to_quat(np.stack((east, north, up), axis=-2))
            return np.where(ok, q, fallback)
        east = east / en
    north = np.cross(up, east)
    # Rows of R (world from body) are the world axes expressed in body coordinates.
    r = np.stack((east, north, up), axis=-2)
    return rotmat_to_quat(r)


def rotmat_to_quat(r: ArrayLike) -> FloatArray:
    """Rotation matrices ``(..., 3, 3)`` -> unit quaternions ``(..., 4)`` with ``w >= 0``."""
    r = np.asarray(r, dtype=float)
    m00, m01, m02 = r[..., 0, 0], r[..., 0, 1], r[..., 0, 2]
    m10, m11, m12 = r[..., 1, 0], r[..., 1, 1], r[..., 1, 2]
    m20, m21, m22 = r[..., 2, 0], r[..., 2, 1], r[..., 2, 2]
    # Four candidate formulas; pick the numerically largest denominator per element.
    cand = np.stack(
        (
            np.stack((1.0 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01), axis=-1),
            np.stack((m21 - m12, 1.0 + m00 - m11 - m22, m01 + m10, m02 + m20), axis=-1),
            np.stack((m02 - m20, m01 + m10, 1.0 - m00 + m11 - m22, m12 + m21), axis=-1),
            np.stack((m10 - m01, m02 + m20, m12 + m21, 1.0 - m00 - m11 + m22), axis=-1),
        ),
        axis=-2,
    )
    diag = np.stack((m00 + m11 + m22, m00, m11, m22), axis=-1)
    idx = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cand, idx[..., None, None], axis=-2)[..., 0, :]
    return quat_normalize(q)


def to_xyzw(q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """Core ``(w, x, y, z)`` -> ROS message order ``(x, y, z, w)``: the one place the order flips."""
    return (q[1], q[2], q[3], q[0])


def from_xyzw(x: float, y: float, z: float, w: float) -> tuple[float, float, float, float]:
    """ROS message order ``(x, y, z, w)`` -> core ``(w, x, y, z)``."""
    return (w, x, y, z)


# --- scalar helpers for the per-sample path (plain floats: several times faster than numpy on one sample) ---------

Quat = tuple[float, float, float, float]

#: A magnetometer closer than this (sine of the angle) to the gravity direction gives no heading.
MAG_PARALLEL_SIN = math.sin(math.radians(5.0))


def quat_from_acc_mag_scalar(
    ax: float, ay: float, az: float, mx: float, my: float, mz: float, use_mag: bool
) -> Quat | None:
    """Body->ENU ``(w, x, y, z)`` from a specific force (m/s², any non-zero norm) and a field (any unit).

    Returns None when the magnetometer cannot give a heading (``use_mag`` false, or the field within 5° of the
    gravity direction, where ``mag x up`` vanishes); the caller then chooses the heading.
    """
    if not use_mag:
        return None
    n = math.sqrt(ax * ax + ay * ay + az * az)
    ux, uy, uz = ax / n, ay / n, az / n
    # east = mag x up (body coordinates)
    ex, ey, ez = my * uz - mz * uy, mz * ux - mx * uz, mx * uy - my * ux
    en = math.sqrt(ex * ex + ey * ey + ez * ez)
    mn = math.sqrt(mx * mx + my * my + mz * mz)
    if not en > MAG_PARALLEL_SIN * mn:
        return None
    ex, ey, ez = ex / en, ey / en, ez / en
    nx, ny, nz = uy * ez - uz * ey, uz * ex - ux * ez, ux * ey - uy * ex
    return _rows_to_quat(ex, ey, ez, nx, ny, nz, ux, uy, uz)


def _rows_to_quat(
    m00: float, m01: float, m02: float, m10: float, m11: float, m12: float, m20: float, m21: float, m22: float
) -> Quat:
    """Unit quaternion (w >= 0) of the rotation matrix with these rows (world axes in body coordinates)."""
    tr = m00 + m11 + m22
    if tr > 0.0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = (0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s)
    elif m00 > m11 and m00 > m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        q = ((m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s)
    elif m11 > m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        q = ((m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        q = ((m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s)
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    sign = 1.0 / n if q[0] >= 0.0 else -1.0 / n
    return (q[0] * sign, q[1] * sign, q[2] * sign, q[3] * sign)


def relevel(q: Quat, ax: float, ay: float, az: float) -> Quat:
    """``q`` turned by the smallest body rotation that makes its gravity direction the measured one (``a``, any
    norm > 0): the tilt is re-levelled, the heading kept (no rotation about world up)."""
    qw, qx, qy, qz = q
    # estimated up in the body frame
    vx = 2.0 * (qx * qz - qw * qy)
    vy = 2.0 * (qy * qz + qw * qx)
    vz = qw * qw - qx * qx - qy * qy + qz * qz
    n = math.sqrt(ax * ax + ay * ay + az * az)
    ux, uy, uz = ax / n, ay / n, az / n
    # The body rotation d with R(d) u = v: q' = q ⊗ d gives R(q')^T z = R(d)^T v = u.
    c = ux * vx + uy * vy + uz * vz
    wx, wy, wz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    if c < -0.999999:
        # Opposite directions: any axis perpendicular to u (half turn).
        wx, wy, wz = (0.0, -uz, uy) if abs(ux) < 0.9 else (-uz, 0.0, ux)
        wn = math.sqrt(wx * wx + wy * wy + wz * wz)
        d = (0.0, wx / wn, wy / wn, wz / wn)
    else:
        # Half-angle quaternion of the shortest arc: (1 + c, u x v) normalised.
        dn = math.sqrt(2.0 * (1.0 + c))
        d = (0.5 * dn, wx / dn, wy / dn, wz / dn)
    dw, dx, dy, dz = d
    w = qw * dw - qx * dx - qy * dy - qz * dz
    x = qw * dx + qx * dw + qy * dz - qz * dy
    y = qw * dy - qx * dz + qy * dw + qz * dx
    z = qw * dz + qx * dy - qy * dx + qz * dw
    s = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    return (w * s, x * s, y * s, z * s)


def level_quat(ax: float, ay: float, az: float) -> Quat:
    """Body->ENU orientation of a specific force ``a`` (any norm > 0): the smallest rotation from the identity that
    levels it (no turn about the vertical; the heading is arbitrary), the first-sample initialisation without a
    usable magnetometer."""
    return relevel((1.0, 0.0, 0.0, 0.0), ax, ay, az)


def rpy_of(q: Quat) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad, intrinsic Z-Y-X as :func:`quat_to_euler`) of one ``(w, x, y, z)``, on plain floats."""
    w, x, y, z = q
    return (
        math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)),
        math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x)))),
        math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)),
    )


def quat_of_rpy(roll: float, pitch: float, yaw: float) -> Quat:
    """``(w, x, y, z)`` of roll, pitch, yaw (rad, intrinsic Z-Y-X as :func:`euler_to_quat`), on plain floats."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def quat_mul_scalar(p: Quat, q: Quat) -> Quat:
    """Hamilton product ``p ⊗ q`` of two ``(w, x, y, z)`` on plain floats (e.g. ENU -> another world frame:
    ``quat_mul_scalar(WORLD_FRAMES[frame], q)``)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    )
