"""The paper's cascaded complementary filter in per-axis Euler angles (``formulation: euler``), for reproduction.

Narkhede et al. (Sensors 2021), eqs 12-14, discretised from the continuous eq 14 with forward Euler, per axis
``i`` in (roll, pitch, yaw)::

    e   = wrap(x_a - x)                    attitude error against the accelerometer/magnetometer angles (eqs 4-6)
    I  += Ki * e * dt                      NCF integral (the bias estimate is -I, in Euler-rate space)
    x_g += (rate + Kp * e + I) * dt        own integrator of the Euler rates
    x   = alpha * x_g + (1 - alpha) * x_a  LCF blend

with the correct Euler kinematics (the paper's eqs 1-3 have typos)::

    phi'   = p + (q sin phi + r cos phi) tan theta
    theta' = q cos phi - r sin phi
    psi'   = (q sin phi + r cos phi) / cos theta

Its transfer function from ``x_a`` to ``x`` is (1-a)s² + a Kp s + a Ki over s² + a Kp s + a Ki (``a`` = alpha), and
from the rate ``a s / (s² + a Kp s + a Ki)`` (eq 15). It is singular at ±90° pitch, like every Euler form.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .base import CommonParams, OrientationFilter, param, per_axis
from .quaternion import quat_of_rpy

_PI = math.pi
_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi


@dataclass(frozen=True)
class NcfParams(CommonParams):
    """Parameters of :class:`EulerNcf`, the paper's non-linear CF (eqs 10-11). Each gain is one value or
    ``(roll, pitch, yaw)``.

    Attributes:
        kp: proportional gain of the PI controller, 1/s. Default 25 (paper).
        ki: integral gain, 1/s². Default 0.1 (paper).
    """

    kp: float | tuple[float, float, float] = param(
        25.0, '1/s', 'NCF proportional gain, 1/s (one value or [roll, pitch, yaw])', 0.0, 1e6, per_axis=True)
    ki: float | tuple[float, float, float] = param(
        0.1, '1/s²', 'NCF integral gain, 1/s^2 (one value or [roll, pitch, yaw])', 0.0, 1e6, per_axis=True)


@dataclass(frozen=True)
class EulerCcfParams(NcfParams):
    """Parameters of :class:`EulerCcf` (paper defaults). Each gain is one value or ``(roll, pitch, yaw)``.

    Attributes:
        kp: proportional gain of the NCF PI controller, 1/s. Default 25 (paper).
        ki: integral gain, 1/s². Default 0.1 (paper).
        alpha: LCF weight of the integrated gyro path, applied per sample as in eq 14, in [0, 1]. Default 0.7.
    """

    alpha: float | tuple[float, float, float] = param(
        0.7, '-', 'LCF weight of the gyro path per sample, 0..1 (one value or [roll, pitch, yaw])', 0.0, 1.0,
        per_axis=True)


@dataclass(frozen=True)
class LcfParams(CommonParams):
    """Parameters of :class:`Lcf`, the paper's linear CF (eqs 7-9).

    Attributes:
        lcf_alpha: per-sample weight of the gyro path, in [0, 1]: ``x = a (x + rate dt) + (1 - a) x_a``, i.e. a time
            constant ``a dt / (1 - a)`` s. Default 0.98 (the textbook value; the paper gives none).
    """

    lcf_alpha: float | tuple[float, float, float] = param(
        0.98, '-', 'per-sample weight of the integrated gyro, 0..1 (one value or [roll, pitch, yaw])', 0.0, 1.0,
        per_axis=True)


@dataclass(frozen=True, slots=True)
class EulerGains:
    """Per-axis ``(roll, pitch, yaw)`` gains derived from the Euler filters' parameters.

    Attributes: kp (1/s), ki (1/s²), alpha (per-sample weight of the gyro path; 1 for the NCF, which has no blend).
    """

    kp: tuple[float, float, float]
    ki: tuple[float, float, float]
    alpha: tuple[float, float, float]

    @classmethod
    def of(cls, p: CommonParams) -> EulerGains:
        if isinstance(p, LcfParams):
            return cls((0.0,) * 3, (0.0,) * 3, per_axis('lcf_alpha', p.lcf_alpha, 0.0, 1.0))
        if not isinstance(p, NcfParams):
            raise ValueError(f'no Euler gains in {type(p).__name__}')
        alpha = per_axis('alpha', p.alpha, 0.0, 1.0) if isinstance(p, EulerCcfParams) else (1.0, 1.0, 1.0)
        return cls(per_axis('kp', p.kp, 0.0, 1e6), per_axis('ki', p.ki, 0.0, 1e6), alpha)


def euler_rates(phi: float, theta: float, p: float, q: float, r: float) -> tuple[float, float, float]:
    """Euler-angle rates (roll, pitch, yaw), rad/s, from body rates ``p, q, r`` (rad/s) at roll ``phi``, pitch
    ``theta`` (rad): the correct kinematics (module docstring). Near ±90° pitch ``cos(theta)`` is clamped to 1e-6."""
    sphi, cphi = math.sin(phi), math.cos(phi)
    ctheta = math.cos(theta)
    if abs(ctheta) < 1e-6:
        ctheta = math.copysign(1e-6, ctheta)
    u = q * sphi + r * cphi
    return (p + u * math.sin(theta) / ctheta, q * cphi - r * sphi, u / ctheta)


def acc_mag_euler(
    ax: float, ay: float, az: float, mx: float, my: float, mz: float, mag_ok: bool, yaw_fallback: float
) -> tuple[float, float, float]:
    """Roll, pitch (eqs 4-5) and tilt-compensated yaw (eq 6, ENU: yaw 0 = body x east), rad."""
    roll = math.atan2(ay, az)
    pitch = math.atan2(-ax, math.sqrt(ay * ay + az * az))
    if not mag_ok:
        return roll, pitch, yaw_fallback
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    # Field rotated into the level (heading) frame: Ry(pitch) Rx(roll) m.
    my_l = my * cr - mz * sr
    mz_r = my * sr + mz * cr
    mx_l = mx * cp + mz_r * sp
    # The level field must point to world +y (north): Rz(yaw) (mx_l, my_l) = (0, +).
    return roll, pitch, math.atan2(mx_l, my_l)


_FIXED_VARIANCE = ((2.0 * math.pi / 180) ** 2,) * 2 + ((5.0 * math.pi / 180) ** 2,)


def wrap_euler(x: list[float]) -> tuple[float, float, float, float]:
    """Wrap roll and yaw to [-pi, pi), clamp pitch to ±pi/2 (in place) and return the quaternion of ``x``."""
    for i in range(3):
        x[i] = (x[i] + _PI) % _TWO_PI - _PI
    x[1] = max(-_HALF_PI, min(_HALF_PI, x[1]))
    return quat_of_rpy(x[0], x[1], x[2])


class EulerCcf(OrientationFilter):
    """The paper's CCF per Euler axis (see module docstring). State: angles, own integrator, integral term."""

    name = 'ccf_euler'
    __slots__ = ('_gains', '_i', '_x', '_xg')
    params: NcfParams

    def __init__(self, params: NcfParams | None = None) -> None:
        super().__init__(params if params is not None else EulerCcfParams())

    def _apply_params(self, params: CommonParams) -> None:
        super()._apply_params(params)
        self._gains = EulerGains.of(params)

    @property
    def gains(self) -> EulerGains:
        """The per-axis gains in use (read-only)."""
        return self._gains

    def _reset_state(self) -> None:
        self._x = [0.0, 0.0, 0.0]
        self._xg = [0.0, 0.0, 0.0]
        self._i = [0.0, 0.0, 0.0]

    def _init(self, ax: float, ay: float, az: float, mx: float, my: float, mz: float, mag_ok: bool) -> None:
        xa = acc_mag_euler(ax, ay, az, mx, my, mz, mag_ok, 0.0)
        self._x = list(xa)
        self._xg = list(xa)
        self._set_q()

    def _set_q(self) -> None:
        self._q = quat_of_rpy(self._x[0], self._x[1], self._x[2])

    def _step(
        self, dt: float, gx: float, gy: float, gz: float, ax: float, ay: float, az: float, acc_n2: float,
        mx: float, my: float, mz: float, mag_n2: float,
    ) -> None:
        x = self._x
        rates = euler_rates(x[0], x[1], gx, gy, gz)
        g = self._gains
        kp, ki, alpha = g.kp, g.ki, g.alpha
        if acc_n2:
            xa = acc_mag_euler(ax, ay, az, mx, my, mz, mag_n2 != 0.0, x[2])
        for i in range(3):
            if acc_n2 and (i < 2 or mag_n2):
                e = (xa[i] - x[i] + _PI) % _TWO_PI - _PI
                self._i[i] += ki[i] * e * dt
                xg = self._xg[i] + (rates[i] + kp[i] * e + self._i[i]) * dt
                xg = (xg + _PI) % _TWO_PI - _PI
                self._xg[i] = xg
                # alpha * x_g + (1 - alpha) * x_a, taken across the +-pi seam
                x[i] = (xa[i] + alpha[i] * ((xg - xa[i] + _PI) % _TWO_PI - _PI) + _PI) % _TWO_PI - _PI
            else:
                # No attitude measurement for this axis: the estimate follows the corrected rate.
                xg = (self._xg[i] + (rates[i] + self._i[i]) * dt + _PI) % _TWO_PI - _PI
                x[i] = (x[i] + (rates[i] + self._i[i]) * dt + _PI) % _TWO_PI - _PI
                self._xg[i] = xg
        x[1] = max(-_HALF_PI, min(_HALF_PI, x[1]))
        self._set_q()

    @property
    def gyro_bias(self) -> tuple[float, float, float]:
        """Bias estimate mapped from Euler-rate space (``-I``) to body rates, rad/s."""
        dphi, dtheta, dpsi = (-self._i[0], -self._i[1], -self._i[2])
        phi, theta = self._x[0], self._x[1]
        sphi, cphi = math.sin(phi), math.cos(phi)
        sth, cth = math.sin(theta), math.cos(theta)
        return (
            dphi - dpsi * sth,
            dtheta * cphi + dpsi * sphi * cth,
            -dtheta * sphi + dpsi * cphi * cth,
        )

    @property
    def orientation_variance(self) -> tuple[float, float, float]:
        """A fixed figure: the Euler form keeps no uncertainty estimate; 2° inclination, 5° heading."""
        return _FIXED_VARIANCE


    def _rotate_about_up(self, angle_rad: float) -> None:
        """set_heading's turn: the Euler state's yaw (and its own integrator's) turns with the orientation."""
        super()._rotate_about_up(angle_rad)
        for x in (self._x, self._xg):
            x[2] = (x[2] + angle_rad + _PI) % _TWO_PI - _PI


class EulerNcf(EulerCcf):
    """The paper's NCF (eqs 10-11): the Euler CCF without the LCF blend (alpha = 1). Per axis
    ``x' = rate + Kp e + Ki ∫e``, ``e = x_a - x``; transfer function from ``x_a``: (Kp s + Ki) / (s² + Kp s + Ki)."""

    name = 'ncf'
    __slots__ = ()
    params: NcfParams

    def __init__(self, params: NcfParams | None = None) -> None:
        super().__init__(params if params is not None else NcfParams())


class Lcf(OrientationFilter):
    """The paper's LCF (eqs 7-9), per Euler axis: ``x = a (x + rate dt) + (1 - a) x_a``. No bias estimate.

    Transfer function (continuous equivalent, ``tau = a dt / (1 - a)``): ``X = (X_a + tau * Rate) / (tau s + 1)``.
    """

    name = 'lcf'
    __slots__ = ('_alpha', '_x')
    params: LcfParams

    def __init__(self, params: LcfParams | None = None) -> None:
        super().__init__(params if params is not None else LcfParams())

    def _apply_params(self, params: CommonParams) -> None:
        super()._apply_params(params)
        self._alpha = EulerGains.of(params).alpha

    def _reset_state(self) -> None:
        self._x = [0.0, 0.0, 0.0]

    def _init(self, ax: float, ay: float, az: float, mx: float, my: float, mz: float, mag_ok: bool) -> None:
        self._x = list(acc_mag_euler(ax, ay, az, mx, my, mz, mag_ok, 0.0))
        self._q = quat_of_rpy(self._x[0], self._x[1], self._x[2])

    def _step(
        self, dt: float, gx: float, gy: float, gz: float, ax: float, ay: float, az: float, acc_n2: float,
        mx: float, my: float, mz: float, mag_n2: float,
    ) -> None:
        # The same first lines as EulerCcf._step, written out: a shared helper would add a call per sample on the
        # hot path (a repeat on purpose).
        x = self._x
        rates = euler_rates(x[0], x[1], gx, gy, gz)
        alpha = self._alpha
        if acc_n2:
            xa = acc_mag_euler(ax, ay, az, mx, my, mz, mag_n2 != 0.0, x[2])
        for i in range(3):
            xg = x[i] + rates[i] * dt
            if acc_n2 and (i < 2 or mag_n2):
                # a * x_g + (1 - a) * x_a across the ±pi seam
                xg = xa[i] + alpha[i] * ((xg - xa[i] + _PI) % _TWO_PI - _PI)
            x[i] = xg
        self._q = wrap_euler(x)

    @property
    def gyro_bias(self) -> tuple[float, float, float]:
        """The LCF estimates no bias: zeros."""
        return (0.0, 0.0, 0.0)

    @property
    def orientation_variance(self) -> tuple[float, float, float]:
        """A fixed figure (no uncertainty estimate): 2° inclination, 5° heading, rad²."""
        return _FIXED_VARIANCE

    def _rotate_about_up(self, angle_rad: float) -> None:
        """set_heading's turn: the Euler state's yaw turns with the orientation."""
        super()._rotate_about_up(angle_rad)
        self._x[2] = (self._x[2] + angle_rad + _PI) % _TWO_PI - _PI
