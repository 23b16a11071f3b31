"""Baseline filters the paper compares against, behind the same interface as the CCF (for ``ccf study``).

* :class:`Madgwick` — gradient-descent MARG filter (Madgwick 2010), 9-D with magnetometer, 6-D without.
* :class:`Mahony` — explicit complementary filter with PI correction (Mahony 2008), 9-D/6-D.

Both run internally in Madgwick's frame (x = magnetic north, z = up: NWU) and are converted to ENU like every
core filter. Defaults are BROAD's best common parameters (shared/data/broad/published).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .base import CommonParams, OrientationFilter, param
from .quaternion import WORLD_FRAMES, quat_from_acc_mag, quat_mul, quat_mul_scalar

_S = math.sqrt(0.5)
# q_nwu = Q_NWU_FROM_ENU ⊗ q_enu (its inverse, (cos 45°, 0, 0, sin 45°), is applied in _publish).
_Q_NWU_FROM_ENU = WORLD_FRAMES['nwu']


@dataclass(frozen=True)
class MadgwickParams(CommonParams):
    """Attributes: madgwick_beta: gradient-descent gain, rad/s. Default 0.12 (BROAD's best common value)."""

    madgwick_beta: float = param(0.12, 'rad/s', 'gradient-descent gain, rad/s', 0.0, 100.0)


@dataclass(frozen=True)
class MahonyParams(CommonParams):
    """Attributes: mahony_kp: proportional gain, 1/s (default 0.74); mahony_ki: integral gain, 1/s² (default
    0.0012) — BROAD's best common values."""

    mahony_kp: float = param(0.74, '1/s', 'proportional gain, 1/s', 0.0, 1e4)
    mahony_ki: float = param(0.0012, '1/s²', 'integral gain, 1/s^2', 0.0, 1e4)


def _earth_field(
    q0: float, q1: float, q2: float, q3: float, mx: float, my: float, mz: float, mag_n2: float
) -> tuple[float, float, float, float, float]:
    """Normalised field (body) and its earth-frame reference (north ``bx``, up ``bz``) for orientation ``q`` (NWU).

    The field is rotated into the earth frame (q ⊗ m ⊗ q*) and its horizontal part folded onto north, as both
    Madgwick and Mahony do to be insensitive to the declination.
    """
    n = 1.0 / math.sqrt(mag_n2)
    mx, my, mz = mx * n, my * n, mz * n
    hx = (1 - 2 * (q2 * q2 + q3 * q3)) * mx + 2 * (q1 * q2 - q0 * q3) * my + 2 * (q1 * q3 + q0 * q2) * mz
    hy = 2 * (q1 * q2 + q0 * q3) * mx + (1 - 2 * (q1 * q1 + q3 * q3)) * my + 2 * (q2 * q3 - q0 * q1) * mz
    bz = 2 * (q1 * q3 - q0 * q2) * mx + 2 * (q2 * q3 + q0 * q1) * my + (1 - 2 * (q1 * q1 + q2 * q2)) * mz
    return mx, my, mz, math.sqrt(hx * hx + hy * hy), bz


class _NwuFilter(OrientationFilter):
    """Shared state handling for filters written in the NWU frame (``self._qn``)."""

    __slots__ = ('_qn',)

    def _reset_state(self) -> None:
        self._qn = (1.0, 0.0, 0.0, 0.0)

    def _init(self, ax: float, ay: float, az: float, mx: float, my: float, mz: float, mag_ok: bool) -> None:
        q = quat_from_acc_mag((ax, ay, az), (mx, my, mz) if mag_ok else None)
        qn = quat_mul(_Q_NWU_FROM_ENU, q)
        self._qn = (float(qn[0]), float(qn[1]), float(qn[2]), float(qn[3]))
        self._nwu_to_enu()

    def _nwu_to_enu(self) -> None:
        # q_enu = (cos 45°, 0, 0, sin 45°) ⊗ q_nwu, written out: a product with a constant, no numpy per sample.
        w, x, y, z = self._qn
        self._q = (_S * (w - z), _S * (x - y), _S * (y + x), _S * (z + w))

    @property
    def orientation_variance(self) -> tuple[float, float, float]:
        """A fixed figure (these filters keep no uncertainty): 2° inclination, 5° heading, as rad²."""
        return ((2.0 * math.pi / 180) ** 2,) * 2 + ((5.0 * math.pi / 180) ** 2,)


    def _rotate_about_up(self, angle_rad: float) -> None:
        """set_heading's turn on the NWU state (NWU's z is ENU's: the same turn)."""
        c, s = math.cos(0.5 * angle_rad), math.sin(0.5 * angle_rad)
        self._qn = quat_mul_scalar((c, 0.0, 0.0, s), self._qn)
        self._nwu_to_enu()


class Madgwick(_NwuFilter):
    """Madgwick's gradient-descent filter; see the module docstring."""

    name = 'madgwick'
    params: MadgwickParams

    def __init__(self, params: MadgwickParams | None = None) -> None:
        super().__init__(params if params is not None else MadgwickParams())

    def _step(
        self, dt: float, gx: float, gy: float, gz: float, ax: float, ay: float, az: float, acc_n2: float,
        mx: float, my: float, mz: float, mag_n2: float,
    ) -> None:
        q0, q1, q2, q3 = self._qn
        # Quaternion rate from the gyro: 0.5 q ⊗ (0, w)
        d0 = 0.5 * (-q1 * gx - q2 * gy - q3 * gz)
        d1 = 0.5 * (q0 * gx + q2 * gz - q3 * gy)
        d2 = 0.5 * (q0 * gy - q1 * gz + q3 * gx)
        d3 = 0.5 * (q0 * gz + q1 * gy - q2 * gx)
        if acc_n2:
            n = 1.0 / math.sqrt(acc_n2)
            ax, ay, az = ax * n, ay * n, az * n
            # Objective: gravity (0, 0, 1) seen in the body, minus the measurement; Jacobian rows alongside.
            f1 = 2.0 * (q1 * q3 - q0 * q2) - ax
            f2 = 2.0 * (q0 * q1 + q2 * q3) - ay
            f3 = 2.0 * (0.5 - q1 * q1 - q2 * q2) - az
            s0 = -2.0 * q2 * f1 + 2.0 * q1 * f2
            s1 = 2.0 * q3 * f1 + 2.0 * q0 * f2 - 4.0 * q1 * f3
            s2 = -2.0 * q0 * f1 + 2.0 * q3 * f2 - 4.0 * q2 * f3
            s3 = 2.0 * q1 * f1 + 2.0 * q2 * f2
            if mag_n2:
                mx, my, mz, bx, bz = _earth_field(q0, q1, q2, q3, mx, my, mz, mag_n2)
                f4 = 2 * bx * (0.5 - q2 * q2 - q3 * q3) + 2 * bz * (q1 * q3 - q0 * q2) - mx
                f5 = 2 * bx * (q1 * q2 - q0 * q3) + 2 * bz * (q0 * q1 + q2 * q3) - my
                f6 = 2 * bx * (q0 * q2 + q1 * q3) + 2 * bz * (0.5 - q1 * q1 - q2 * q2) - mz
                s0 += -2 * bz * q2 * f4 + (-2 * bx * q3 + 2 * bz * q1) * f5 + 2 * bx * q2 * f6
                s1 += 2 * bz * q3 * f4 + (2 * bx * q2 + 2 * bz * q0) * f5 + (2 * bx * q3 - 4 * bz * q1) * f6
                s2 += (-4 * bx * q2 - 2 * bz * q0) * f4 + (2 * bx * q1 + 2 * bz * q3) * f5 + (2 * bx * q0 - 4 * bz * q2) * f6
                s3 += (-4 * bx * q3 + 2 * bz * q1) * f4 + (-2 * bx * q0 + 2 * bz * q2) * f5 + 2 * bx * q1 * f6
            sn = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2 + s3 * s3)
            if sn > 0.0:
                b = self.params.madgwick_beta / sn
                d0 -= b * s0
                d1 -= b * s1
                d2 -= b * s2
                d3 -= b * s3
        q0 += d0 * dt
        q1 += d1 * dt
        q2 += d2 * dt
        q3 += d3 * dt
        n = 1.0 / math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        self._qn = (q0 * n, q1 * n, q2 * n, q3 * n)
        self._nwu_to_enu()

    @property
    def gyro_bias(self) -> tuple[float, float, float]:
        """Madgwick's filter estimates no bias: zeros."""
        return (0.0, 0.0, 0.0)


class Mahony(_NwuFilter):
    """Mahony's explicit complementary filter; see the module docstring."""

    name = 'mahony'
    params: MahonyParams
    __slots__ = ('_integral',)

    def __init__(self, params: MahonyParams | None = None) -> None:
        super().__init__(params if params is not None else MahonyParams())

    def _reset_state(self) -> None:
        super()._reset_state()
        self._integral = (0.0, 0.0, 0.0)

    def _step(
        self, dt: float, gx: float, gy: float, gz: float, ax: float, ay: float, az: float, acc_n2: float,
        mx: float, my: float, mz: float, mag_n2: float,
    ) -> None:
        q0, q1, q2, q3 = self._qn
        ex = ey = ez = 0.0
        if acc_n2:
            n = 1.0 / math.sqrt(acc_n2)
            ax, ay, az = ax * n, ay * n, az * n
            # Estimated up in the body frame; error = measured x estimated.
            vx = 2 * (q1 * q3 - q0 * q2)
            vy = 2 * (q0 * q1 + q2 * q3)
            vz = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
            ex, ey, ez = ay * vz - az * vy, az * vx - ax * vz, ax * vy - ay * vx
            if mag_n2:
                mx, my, mz, bx, bz = _earth_field(q0, q1, q2, q3, mx, my, mz, mag_n2)
                # Expected field direction in the body frame: R^T (bx, 0, bz).
                wx = bx * (1 - 2 * (q2 * q2 + q3 * q3)) + bz * 2 * (q1 * q3 - q0 * q2)
                wy = bx * 2 * (q1 * q2 - q0 * q3) + bz * 2 * (q0 * q1 + q2 * q3)
                wz = bx * 2 * (q0 * q2 + q1 * q3) + bz * (1 - 2 * (q1 * q1 + q2 * q2))
                ex += my * wz - mz * wy
                ey += mz * wx - mx * wz
                ez += mx * wy - my * wx
        p = self.params
        ix, iy, iz = self._integral
        if p.mahony_ki > 0.0:
            ix += p.mahony_ki * ex * dt
            iy += p.mahony_ki * ey * dt
            iz += p.mahony_ki * ez * dt
            self._integral = (ix, iy, iz)
        gx += p.mahony_kp * ex + ix
        gy += p.mahony_kp * ey + iy
        gz += p.mahony_kp * ez + iz
        h = 0.5 * dt
        q0, q1, q2, q3 = (
            q0 + h * (-q1 * gx - q2 * gy - q3 * gz),
            q1 + h * (q0 * gx + q2 * gz - q3 * gy),
            q2 + h * (q0 * gy - q1 * gz + q3 * gx),
            q3 + h * (q0 * gz + q1 * gy - q2 * gx),
        )
        n = 1.0 / math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        self._qn = (q0 * n, q1 * n, q2 * n, q3 * n)
        self._nwu_to_enu()

    @property
    def gyro_bias(self) -> tuple[float, float, float]:
        """Bias estimate (minus the integral term), rad/s, body frame."""
        ix, iy, iz = self._integral
        return (-ix, -iy, -iz)

