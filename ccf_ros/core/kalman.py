"""Kalman-filter baselines of the paper's comparison (Table 4), in Euler angles like the paper's CCF.

* :class:`Ekf` — extended Kalman filter on the three Euler angles: gyro-driven prediction through the Euler
  kinematics, the accelerometer/magnetometer angles (eqs 4-6) as the measurement.
* :class:`Ckf` — complementary (error-state, "indirect") Kalman filter: the gyro, corrected by the estimated bias,
  is integrated through the Euler kinematics; a 6-state Kalman filter estimates the attitude error and the gyro-bias
  error from the difference between the accelerometer/magnetometer angles and that integral, and feeds both back.

Both are written like the rest of the core (plain Python floats, small matrices as lists), so that the per-sample
cost comparison with the CCF (paper Fig 12) compares algorithms, not implementation styles. Process noise ``Q`` is a
spectral density (per second; ``Q * dt`` is added per sample) so that the filters behave alike at any sample rate;
``R`` is the measurement variance per sample, rad².
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from operator import mul as _mul

from .base import CommonParams, OrientationFilter, floats, param
from .euler_ccf import acc_mag_euler, wrap_euler
from .quaternion import quat_of_rpy

_PI = math.pi
_TWO_PI = 2.0 * math.pi
Matrix = list[list[float]]


@dataclass(frozen=True)
class EkfParams(CommonParams):
    """Parameters of :class:`Ekf` (paper Table 4).

    Attributes:
        ekf_q: process-noise density of (roll, pitch, yaw), rad²/s. Default (5, 0.05, 10).
        ekf_r: measurement variance of the accelerometer/magnetometer (roll, pitch, yaw), rad². Default
            (0.1, 0.001, 0.8).
    """

    ekf_q: tuple[float, float, float] = param(
        (5.0, 0.05, 10.0), 'rad²/s', 'process-noise density of [roll, pitch, yaw], rad^2/s', 0.0, 1e9)
    ekf_r: tuple[float, float, float] = param(
        (0.1, 0.001, 0.8), 'rad²', 'accelerometer/magnetometer angle variance [roll, pitch, yaw], rad^2', 1e-300, 1e9)


@dataclass(frozen=True)
class CkfParams(CommonParams):
    """Parameters of :class:`Ckf` (paper Table 4).

    Attributes:
        ckf_q: process-noise density of (roll, pitch, yaw error, x, y, z gyro-bias error), rad²/s and rad²/s³.
            Default (60, 5, 10, 0, 0, 0): the bias is modelled constant.
        ckf_r: measurement variance of the accelerometer/magnetometer (roll, pitch, yaw), rad². Default
            (0.1, 0.01, 0.8).
        ckf_bias0_rad_s: initial standard deviation of the gyro bias, rad/s. Default 2°/s (not in the paper).
    """

    ckf_q: tuple[float, float, float, float, float, float] = param(
        (60.0, 5.0, 10.0, 0.0, 0.0, 0.0), 'rad²/s, rad²/s³', 'process-noise density of [roll, pitch, yaw error, x, '
        'y, z bias error], rad^2/s, rad^2/s^3', 0.0, 1e9)
    ckf_r: tuple[float, float, float] = param(
        (0.1, 0.01, 0.8), 'rad²', 'accelerometer/magnetometer angle variance [roll, pitch, yaw], rad^2', 1e-300, 1e9)
    ckf_bias0_rad_s: float = param(
        2.0 * math.pi / 180.0, 'rad/s', 'initial gyro-bias standard deviation, rad/s', 0.0, 1.0)


@dataclass(frozen=True, slots=True)
class KalmanNoise:
    """Noise figures derived from :class:`EkfParams` / :class:`CkfParams` as float tuples.

    Attributes: q process-noise density (per second); r measurement variance, rad²; p0 covariance to (re)start from.
    """

    q: tuple[float, ...]
    r: tuple[float, ...]
    p0: tuple[float, ...]

    @classmethod
    def of(cls, p: CommonParams) -> KalmanNoise:
        if isinstance(p, CkfParams):
            r = floats('ckf_r', p.ckf_r, 3, 1e-300, 1e9)
            return cls(floats('ckf_q', p.ckf_q, 6, 0.0, 1e9), r, r + (p.ckf_bias0_rad_s**2,) * 3)
        if isinstance(p, EkfParams):
            r = floats('ekf_r', p.ekf_r, 3, 1e-300, 1e9)
            return cls(floats('ekf_q', p.ekf_q, 3, 0.0, 1e9), r, r)
        raise ValueError(f'no Kalman noise in {type(p).__name__}')


def _kinematics(
    phi: float, theta: float, p: float, q: float, r: float
) -> tuple[tuple[float, float, float], Matrix, Matrix]:
    """Euler rates (rad/s), their Jacobian by (roll, pitch, yaw) (1/s) and the body-rate-to-Euler-rate matrix E."""
    sphi, cphi = math.sin(phi), math.cos(phi)
    ct = math.cos(theta)
    if abs(ct) < 1e-6:
        ct = math.copysign(1e-6, ct)
    tt = math.sin(theta) / ct
    u = q * sphi + r * cphi
    v = q * cphi - r * sphi
    rates = (p + u * tt, v, u / ct)
    jac = [
        [v * tt, u / (ct * ct), 0.0],
        [-u, 0.0, 0.0],
        [v / ct, u * tt / ct, 0.0],
    ]
    e = [
        [1.0, sphi * tt, cphi * tt],
        [0.0, cphi, -sphi],
        [0.0, sphi / ct, cphi / ct],
    ]
    return rates, jac, e


def _mat_mul(a: Matrix, b: Matrix) -> Matrix:
    """``a @ b`` for list matrices."""
    bt = list(zip(*b, strict=True))
    return [[sum(map(_mul, row, col)) for col in bt] for row in a]


def _mat_mul_t(a: Matrix, b: Matrix) -> Matrix:
    """``a @ b.T`` for list matrices."""
    return [[sum(map(_mul, row, col)) for col in b] for row in a]


def _inverse(s: Matrix) -> Matrix | None:
    """Inverse of a symmetric positive-definite 2x2 or 3x3 matrix; None if it is not (determinant not > 0)."""
    if len(s) == 2:
        (a, b), (c, d) = s
        det = a * d - b * c
        if not (det > 0.0 and math.isfinite(det)):
            return None
        return [[d / det, -b / det], [-c / det, a / det]]
    (a, b, c), (d, e, f), (g, h, i) = s
    c00, c01, c02 = e * i - f * h, c * h - b * i, b * f - c * e
    det = a * c00 + b * (f * g - d * i) + c * (d * h - e * g)
    if not (det > 0.0 and math.isfinite(det)):
        return None
    return [
        [c00 / det, c01 / det, c02 / det],
        [(f * g - d * i) / det, (a * i - c * g) / det, (c * d - a * f) / det],
        [(d * h - e * g) / det, (b * g - a * h) / det, (a * e - b * d) / det],
    ]


def _kalman_update(
    p: Matrix, innovation: list[float], idx: tuple[int, ...], r: Sequence[float]
) -> list[float] | None:
    """Measurement update for ``z = x[idx] + noise(r)`` on covariance ``p`` (in place); returns the state
    correction ``K @ innovation`` (length ``len(p)``), or None if the innovation covariance is not positive
    definite (a diverged covariance, e.g. after passing ±90° pitch): then nothing is changed."""
    n = len(p)
    s = [[p[i][j] for j in idx] for i in idx]
    for k, i in enumerate(idx):
        s[k][k] += r[i]
    s_inv = _inverse(s)
    if s_inv is None:
        return None
    p_cols = [[p[i][j] for j in idx] for i in range(n)]  # P H^T, n x m
    gain = _mat_mul(p_cols, s_inv)  # n x m
    p_rows = [p[i] for i in idx]  # H P, m x n
    kp = _mat_mul(gain, p_rows)
    for i in range(n):
        row, kpr = p[i], kp[i]
        for j in range(n):
            row[j] -= kpr[j]
    return [sum(map(_mul, grow, innovation)) for grow in gain]


def _diagonal(values: Sequence[float]) -> Matrix:
    n = len(values)
    return [[float(values[i]) if i == j else 0.0 for j in range(n)] for i in range(n)]


def _measurement(
    x: list[float], ax: float, ay: float, az: float, acc_n2: float, mx: float, my: float, mz: float, mag_n2: float
) -> tuple[list[float], tuple[int, ...]]:
    """Wrapped innovation ``x_a - x`` and the measured axes (roll and pitch; yaw only with a magnetometer)."""
    xa = acc_mag_euler(ax, ay, az, mx, my, mz, mag_n2 != 0.0, x[2])
    idx = (0, 1, 2) if mag_n2 else (0, 1)
    return [(xa[i] - x[i] + _PI) % _TWO_PI - _PI for i in idx], idx


_VARIANCE_FLOOR = 1e-12


class _EulerKalman(OrientationFilter):
    """Shared Kalman step: covariance propagation, measurement update, publication of the angles ``_x``."""

    __slots__ = ('_noise', '_p', '_x')
    _p: Matrix  # covariance, rad² (and rad²/s, rad²/s² for the CKF's bias part)
    _x: list[float]  # roll, pitch, yaw, rad

    def _apply_params(self, params: CommonParams) -> None:
        super()._apply_params(params)
        self._noise = KalmanNoise.of(params)

    @property
    def noise(self) -> KalmanNoise:
        """The noise figures in use (read-only)."""
        return self._noise

    def _predict_correct(
        self, phi: Matrix, q: Sequence[float], r: Sequence[float], p_reset: Sequence[float], dt: float,
        ax: float, ay: float, az: float, acc_n2: float, mx: float, my: float, mz: float, mag_n2: float,
    ) -> list[float] | None:
        """``P = phi P phi^T + Q dt``, then (with an accelerometer) the update by ``x_a - x``; returns the state
        correction, or None without one. A diverged covariance starts again from ``diag(p_reset)``."""
        p = _mat_mul_t(_mat_mul(phi, self._p), phi)
        for i in range(len(p)):
            p[i][i] += q[i] * dt
        dx = None
        if acc_n2:
            innovation, idx = _measurement(self._x, ax, ay, az, acc_n2, mx, my, mz, mag_n2)
            dx = _kalman_update(p, innovation, idx, r)
            if dx is None:
                p = _diagonal(p_reset)
        self._p = p
        return dx

    @property
    def orientation_variance(self) -> tuple[float, float, float]:
        """Diagonal of the angle (error) covariance, rad²."""
        p = self._p
        return (max(p[0][0], _VARIANCE_FLOOR), max(p[1][1], _VARIANCE_FLOOR), max(p[2][2], _VARIANCE_FLOOR))


    def _rotate_about_up(self, angle_rad: float) -> None:
        """set_heading's turn: the Euler state's yaw turns with the orientation."""
        super()._rotate_about_up(angle_rad)
        for x in (self._x,):
            x[2] = (x[2] + angle_rad + _PI) % _TWO_PI - _PI


class Ekf(_EulerKalman):
    """Extended Kalman filter on (roll, pitch, yaw); see the module docstring. State: angles and their 3x3
    covariance (rad²)."""

    name = 'ekf'
    __slots__ = ()
    params: EkfParams

    def __init__(self, params: EkfParams | None = None) -> None:
        super().__init__(params if params is not None else EkfParams())

    def _reset_state(self) -> None:
        self._x = [0.0, 0.0, 0.0]
        self._p = [[0.0] * 3 for _ in range(3)]

    def _init(self, ax: float, ay: float, az: float, mx: float, my: float, mz: float, mag_ok: bool) -> None:
        self._x = list(acc_mag_euler(ax, ay, az, mx, my, mz, mag_ok, 0.0))
        self._p = _diagonal(self._noise.p0)
        self._q = quat_of_rpy(*self._x)

    def _step(
        self, dt: float, gx: float, gy: float, gz: float, ax: float, ay: float, az: float, acc_n2: float,
        mx: float, my: float, mz: float, mag_n2: float,
    ) -> None:
        x = self._x
        rates, jac, _ = _kinematics(x[0], x[1], gx, gy, gz)
        for i in range(3):
            x[i] += rates[i] * dt
        f = [[(1.0 if i == j else 0.0) + jac[i][j] * dt for j in range(3)] for i in range(3)]
        n = self._noise
        dx = self._predict_correct(f, n.q, n.r, n.p0, dt, ax, ay, az, acc_n2, mx, my, mz, mag_n2)
        if dx is not None:
            for i in range(3):
                x[i] += dx[i]
        self._q = wrap_euler(x)

    @property
    def gyro_bias(self) -> tuple[float, float, float]:
        """The EKF of the paper estimates no bias: zeros."""
        return (0.0, 0.0, 0.0)


class Ckf(_EulerKalman):
    """Complementary (error-state) Kalman filter; see the module docstring. State: angles (rad), gyro bias (rad/s),
    6x6 error covariance."""

    name = 'ckf'
    __slots__ = ('_bias',)
    params: CkfParams

    def __init__(self, params: CkfParams | None = None) -> None:
        super().__init__(params if params is not None else CkfParams())

    def _reset_state(self) -> None:
        self._x = [0.0, 0.0, 0.0]
        self._bias = [0.0, 0.0, 0.0]
        self._p = [[0.0] * 6 for _ in range(6)]

    def _init(self, ax: float, ay: float, az: float, mx: float, my: float, mz: float, mag_ok: bool) -> None:
        self._x = list(acc_mag_euler(ax, ay, az, mx, my, mz, mag_ok, 0.0))
        p0 = self._noise.p0
        # A re-initialisation keeps the learnt bias and its uncertainty, as a gap says nothing about the bias.
        if not self.initialized:
            self._p = _diagonal(p0)
        else:
            for i in range(3):
                for j in range(6):
                    self._p[i][j] = self._p[j][i] = 0.0
                self._p[i][i] = p0[i]
        self._q = quat_of_rpy(*self._x)

    def _step(
        self, dt: float, gx: float, gy: float, gz: float, ax: float, ay: float, az: float, acc_n2: float,
        mx: float, my: float, mz: float, mag_n2: float,
    ) -> None:
        x, b = self._x, self._bias
        rates, jac, e = _kinematics(x[0], x[1], gx - b[0], gy - b[1], gz - b[2])
        for i in range(3):
            x[i] += rates[i] * dt
        # Error dynamics: d(angle error)/dt = J angle error - E bias error; the bias error is constant.
        phi = [[0.0] * 6 for _ in range(6)]
        for i in range(3):
            for j in range(3):
                phi[i][j] = (1.0 if i == j else 0.0) + jac[i][j] * dt
                phi[i][j + 3] = -e[i][j] * dt
            phi[i + 3][i + 3] = 1.0
        n = self._noise
        dx = self._predict_correct(phi, n.q, n.r, n.p0, dt, ax, ay, az, acc_n2, mx, my, mz, mag_n2)
        if dx is not None:
            for i in range(3):
                x[i] += dx[i]
                b[i] += dx[i + 3]
        self._q = wrap_euler(x)

    @property
    def gyro_bias(self) -> tuple[float, float, float]:
        """Estimated gyro bias, rad/s, body frame."""
        return (self._bias[0], self._bias[1], self._bias[2])
