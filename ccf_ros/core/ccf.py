"""Cascaded complementary filter on unit quaternions (the ccf_ros default).

The cascade of Narkhede et al. (Sensors 2021) kept, made to work in 3-D at any sample rate:

1. **NCF stage (PI bias estimator).** The error between the current estimate and the accelerometer/magnetometer
   attitude drives an integral term that estimates the gyroscope bias (the paper's ``Ki/s``). While the IMU rests,
   the bias is instead pulled towards the low-passed gyro reading, which is far more informative.
2. **LCF stage (blend).** The bias-corrected rate is integrated and blended with the accelerometer/magnetometer
   attitude. The paper's per-sample weight ``alpha`` (and ``Kp``, which acts the same way) become *time constants*:
   with ``k = 1 - exp(-dt / tau)`` the blend is identical at 50 Hz and at 1 kHz. Equivalently, the paper's ``alpha``
   at sample period ``T`` is ``tau = alpha * T / (1 - alpha)``.

Inclination is corrected from the accelerometer only and heading from the magnetometer only (about world up), so a
magnetic disturbance never tilts the estimate. A magnetometer whose norm or dip angle departs from the values learnt
while it looked undisturbed is ignored for heading until it agrees again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from math import atan2, cos, sin, sqrt

from .base import CommonParams, OrientationFilter, check_positive, check_range
from .quaternion import quat_from_acc_mag

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class CcfParams(CommonParams):
    """Parameters of :class:`QuaternionCcf`. Defaults are meant to need no tuning.

    Attributes:
        tau_acc_s: LCF time constant of the inclination (accelerometer) blend, s. Longer rejects more linear
            acceleration, shorter follows a drifting gyro faster. Default 3.0.
        tau_mag_s: LCF time constant of the heading (magnetometer) blend, s. Default 9.0.
        tau_bias_s: NCF integral time constant, s: bias gain ``Ki = 1 / tau_bias_s**2`` on the attitude error
            (rad) while moving. The bias then converges with a time constant of about ``tau_bias_s**2 / tau_acc_s``
            (20 min at the defaults): slow on purpose, as faster learning while moving lets linear accelerations
            into the bias (``ccf study`` shows both sides). At rest the bias is learnt within seconds. Default 60.0.
        rest_bias: estimate the bias from the gyro directly while the IMU rests. Default True.
        rest_gyro_rad_s: rest when the gyro stays within this of its low-passed value, rad/s. Default 2°/s.
        rest_acc_m_s2: ... and the accelerometer within this of its low-passed value, m/s². Default 0.5.
        rest_min_s: for at least this long, s. Default 1.5.
        rest_tau_s: time constant of the rest-detection low-pass filters and of the rest bias estimate, s.
            Default 0.5.
        bias_max_rad_s: largest bias the filter will believe, rad/s (also: faster low-passed rotation is never
            taken for rest). Default 2°/s.
        mag_norm_tol: relative deviation of the magnetometer norm from its reference that counts as disturbed.
            Default 0.05 (a calibrated magnetometer stays well within it).
        mag_dip_tol_rad: deviation of the magnetic dip angle that counts as disturbed, rad. Default 5°.
        gyro_noise_rad_s: gyro noise standard deviation per sample, rad/s; only feeds the reported covariance.
            Default 0.005.
        mag_reaccept_s: a different field that stays steady (within the tolerances) this long becomes the new
            reference, s: a moved robot or a new mounting does not disable heading forever. Default 60.
    """

    tau_acc_s: float = 3.0
    tau_mag_s: float = 9.0
    tau_bias_s: float = 60.0
    rest_bias: bool = True
    rest_gyro_rad_s: float = 2.0 * _DEG
    rest_acc_m_s2: float = 0.5
    rest_min_s: float = 1.5
    rest_tau_s: float = 0.5
    bias_max_rad_s: float = 2.0 * _DEG
    mag_norm_tol: float = 0.05
    mag_dip_tol_rad: float = 5.0 * _DEG
    gyro_noise_rad_s: float = 0.005
    mag_reaccept_s: float = 60.0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in (
            'tau_acc_s',
            'tau_mag_s',
            'tau_bias_s',
            'rest_gyro_rad_s',
            'rest_acc_m_s2',
            'rest_min_s',
            'rest_tau_s',
            'bias_max_rad_s',
            'mag_norm_tol',
            'mag_dip_tol_rad',
            'gyro_noise_rad_s',
            'mag_reaccept_s',
        ):
            check_positive(name, getattr(self, name))
        check_range('mag_dip_tol_rad', self.mag_dip_tol_rad, 0.0, math.pi)
        if not isinstance(self.rest_bias, bool):
            raise ValueError(f'rest_bias must be a bool, got {self.rest_bias!r}')


@dataclass(frozen=True, slots=True)
class _Coefficients:
    """Per-sample constants derived from :class:`CcfParams` for one sample period ``dt`` (s)."""

    dt: float
    dt_lo: float
    dt_hi: float
    k_acc: float
    k_mag: float
    k_bias: float
    k_rest: float
    var_gyro: float
    rest_gyro2: float
    rest_acc2: float
    bias_max2: float
    rest_min_s: float
    rest_bias: bool
    keep_acc2: float
    var_acc: float
    keep_mag2: float
    var_mag: float

    @classmethod
    def of(cls, p: CcfParams, dt: float) -> _Coefficients:
        k_rest = -math.expm1(-dt / p.rest_tau_s)
        # Rest thresholds apply to (sample - new low-pass) = (1 - k_rest) * (sample - old low-pass).
        keep2 = (1.0 - k_rest) ** 2 if k_rest < 1.0 else 1e-300
        return cls(
            dt=dt,
            # Float stamps near 1.7e9 s resolve 0.24 µs, so dt wobbles by ~1e-4 relative: gains are reused while dt
            # stays within 0.1 % (a 0.1 % change of a blend gain is immaterial; integration uses the exact dt).
            dt_lo=dt * (1.0 - 1e-3),
            dt_hi=dt * (1.0 + 1e-3),
            k_acc=-math.expm1(-dt / p.tau_acc_s),
            k_mag=-math.expm1(-dt / p.tau_mag_s),
            k_bias=dt / (p.tau_bias_s * p.tau_bias_s),
            k_rest=k_rest,
            var_gyro=(p.gyro_noise_rad_s * dt) ** 2 + (p.bias_max_rad_s * dt) ** 2 * 0.01,
            rest_gyro2=p.rest_gyro_rad_s**2 / keep2,
            rest_acc2=p.rest_acc_m_s2**2 / keep2,
            bias_max2=p.bias_max_rad_s**2,
            rest_min_s=p.rest_min_s,
            rest_bias=p.rest_bias,
            # Variance after a blend with gain k: (1 - k)² · prior + k² · measurement variance (0.05 rad accelerometer
            # inclination noise, 0.1 rad magnetometer heading noise).
            keep_acc2=math.exp(-2.0 * dt / p.tau_acc_s),
            var_acc=math.expm1(-dt / p.tau_acc_s) ** 2 * 0.0025,
            keep_mag2=math.exp(-2.0 * dt / p.tau_mag_s),
            var_mag=math.expm1(-dt / p.tau_mag_s) ** 2 * 0.01,
        )


class QuaternionCcf(OrientationFilter):
    """Cascaded complementary filter on unit quaternions; see the module docstring.

    State (all reset by :meth:`reset`): orientation, gyro bias (rad/s, body), rest-detector low-pass values,
    magnetometer reference (norm, dip), error variances (rad²).
    """

    name = 'ccf'
    __slots__ = (
        '_alp', '_b', '_c', '_glp', '_inv_g', '_mag_bounds', '_mag_candidate', '_mag_disturbed_s', '_mag_have_ref',
        '_rest_s', '_var_head', '_var_incl', 'at_rest', 'mag_disturbed', '_mag_ref',
    )
    params: CcfParams

    def __init__(self, params: CcfParams | None = None) -> None:
        super().__init__(params if params is not None else CcfParams())

    def _reset_state(self) -> None:
        self._b = (0.0, 0.0, 0.0)
        self._c = _Coefficients.of(self.params, 0.0)
        self._glp = (0.0, 0.0, 0.0)
        self._alp = (0.0, 0.0, 0.0)
        self._rest_s = 0.0
        self.at_rest = False
        #: True while the magnetometer disagrees with its reference (heading then runs on the gyro).
        self.mag_disturbed = False
        self._mag_bounds = (0.0, math.inf, -2.0, 2.0)
        self._mag_have_ref = False
        self._mag_disturbed_s = 0.0
        self._var_incl = 0.0
        self._var_head = 0.0
        self._mag_candidate = self._mag_bounds
        self._inv_g = 1.0 / 9.80665

    def _bounds(self, norm: float, sin_dip: float) -> tuple[float, float, float, float]:
        """Acceptance bounds (squared norm, sin(dip)) around a field of ``norm`` and dip ``asin(sin_dip)``.

        Comparing squared norms and sines keeps sqrt and asin out of the per-sample path.
        """
        p = self.params
        dip = math.asin(max(-1.0, min(1.0, sin_dip)))
        lo = norm * (1.0 - p.mag_norm_tol)
        hi = norm * (1.0 + p.mag_norm_tol)
        return (
            lo * lo,
            hi * hi,
            math.sin(max(-math.pi / 2, dip - p.mag_dip_tol_rad)),
            math.sin(min(math.pi / 2, dip + p.mag_dip_tol_rad)),
        )

    def _set_mag_reference(self, norm: float, sin_dip: float) -> None:
        """Accept a field of ``norm`` (sensor unit) and dip ``asin(sin_dip)`` as undisturbed."""
        self._mag_ref = (norm, sin_dip)
        self._mag_bounds = self._bounds(norm, sin_dip)
        self._mag_candidate = self._mag_bounds
        self._mag_have_ref = True
        self._mag_disturbed_s = 0.0

    def _params_changed(self) -> None:
        self._c = _Coefficients.of(self.params, 0.0)
        if self._mag_have_ref:
            self._mag_bounds = self._bounds(*self._mag_ref)
            self._mag_candidate = self._mag_bounds

    def _init(self, ax: float, ay: float, az: float, mx: float, my: float, mz: float, mag_ok: bool) -> None:
        q = quat_from_acc_mag((ax, ay, az), (mx, my, mz) if mag_ok else None)
        self._q = (float(q[0]), float(q[1]), float(q[2]), float(q[3]))
        self._glp = self._b
        self._alp = (ax, ay, az)
        self._rest_s = 0.0
        an = math.sqrt(ax * ax + ay * ay + az * az)
        self._inv_g = 1.0 / an
        self._var_incl = (2.0 * _DEG) ** 2
        self._var_head = (5.0 * _DEG) ** 2 if mag_ok else (math.pi / 2) ** 2
        if mag_ok and not self._mag_have_ref:
            n = math.sqrt(mx * mx + my * my + mz * mz)
            self._set_mag_reference(n, (mx * ax + my * ay + mz * az) / (n * an))

    def _step(
        self,
        dt: float,
        gx: float,
        gy: float,
        gz: float,
        ax: float,
        ay: float,
        az: float,
        acc_n2: float,
        mx: float,
        my: float,
        mz: float,
        mag_n2: float,
    ) -> None:
        c = self._c
        if not c.dt_lo <= dt <= c.dt_hi:
            c = self._c = _Coefficients.of(self.params, dt)
        qw, qx, qy, qz = self._q
        bx, by, bz = self._b
        # World up expressed in the body frame (third row of the body->world rotation matrix).
        vx = 2.0 * (qx * qz - qw * qy)
        vy = 2.0 * (qy * qz + qw * qx)
        vz = qw * qw - qx * qx - qy * qy + qz * qz
        # ex, ey, ez: attitude error (rad, body frame) driving the bias integrator; cx, cy, cz: LCF correction.
        var_incl = self._var_incl + c.var_gyro
        if acc_n2:
            # a x v / g: rotation taking the measured up direction onto the estimated one. Dividing by the gravity
            # reference rather than |a| keeps the correction linear in the specific force, so linear
            # accelerations, whose integral is a bounded velocity change, average out over tau_acc_s.
            inv = self._inv_g
            ex = (ay * vz - az * vy) * inv
            ey = (az * vx - ax * vz) * inv
            ez = (ax * vy - ay * vx) * inv
            k = c.k_acc
            cx = k * ex
            cy = k * ey
            cz = k * ez
            var_incl = c.keep_acc2 * var_incl + c.var_acc
        else:
            ex = ey = ez = cx = cy = cz = 0.0
        self._var_incl = var_incl
        if mag_n2:
            norm = sqrt(mag_n2)
            sin_dip = (vx * mx + vy * my + vz * mz) / norm
            lo2, hi2, lo_dip, hi_dip = self._mag_bounds
            if lo2 <= mag_n2 <= hi2 and lo_dip <= sin_dip <= hi_dip:
                self.mag_disturbed = False
                self._mag_disturbed_s = 0.0
                # Horizontal field in the world frame; it must point to +y (north in ENU). The correction is a
                # rotation about world up (v in body coordinates): heading only, never tilt.
                d = atan2(
                    (1.0 - 2.0 * (qy * qy + qz * qz)) * mx + 2.0 * ((qx * qy - qw * qz) * my + (qx * qz + qw * qy) * mz),
                    2.0 * ((qx * qy + qw * qz) * mx + (qy * qz - qw * qx) * mz) + (1.0 - 2.0 * (qx * qx + qz * qz)) * my,
                )
                ex += d * vx
                ey += d * vy
                ez += d * vz
                k = c.k_mag
                kd = k * d
                cx += kd * vx
                cy += kd * vy
                cz += kd * vz
                self._var_head = c.keep_mag2 * (self._var_head + c.var_gyro) + c.var_mag
            else:
                self._mag_rejected(dt, mag_n2, norm, sin_dip)
                self._var_head += c.var_gyro
        else:
            self._var_head += c.var_gyro
        # NCF: integral action on the attitude error estimates the bias (b = -Ki * integral(e)).
        kb = c.k_bias
        bx -= kb * ex
        by -= kb * ey
        bz -= kb * ez
        if c.rest_bias:
            k = c.k_rest
            glx, gly, glz = self._glp
            alx, aly, alz = self._alp
            # d = sample - previous low-pass; the deviation from the updated low-pass is (1 - k) d, which the
            # thresholds in c already account for.
            dgx = gx - glx
            dgy = gy - gly
            dgz = gz - glz
            dax = ax - alx
            day = ay - aly
            daz = az - alz
            glx += k * dgx
            gly += k * dgy
            glz += k * dgz
            self._glp = (glx, gly, glz)
            self._alp = (alx + k * dax, aly + k * day, alz + k * daz)
            if (
                acc_n2
                and dgx * dgx + dgy * dgy + dgz * dgz < c.rest_gyro2
                and dax * dax + day * day + daz * daz < c.rest_acc2
                and glx * glx + gly * gly + glz * glz < c.bias_max2
            ):
                self._rest_s += dt
                if self._rest_s >= c.rest_min_s:
                    # At rest the low-passed gyro *is* the bias: pull the estimate there.
                    self.at_rest = True
                    bx += k * (glx - bx)
                    by += k * (gly - by)
                    bz += k * (glz - bz)
            else:
                self._rest_s = 0.0
                self.at_rest = False
        self._b = (bx, by, bz)
        # LCF: integrate the bias-corrected rate plus the blend towards the accelerometer/magnetometer attitude.
        hx = 0.5 * ((gx - bx) * dt + cx)
        hy = 0.5 * ((gy - by) * dt + cy)
        hz = 0.5 * ((gz - bz) * dt + cz)
        n2 = hx * hx + hy * hy + hz * hz
        if n2 < 1e-4:
            # Taylor series of cos(x) and sin(x)/x; the first omitted terms are below 2e-15 for |x| < 0.01.
            cw = 1.0 - n2 * (0.5 - n2 * (1.0 / 24.0))
            s = 1.0 - n2 * (1.0 / 6.0 - n2 * (1.0 / 120.0))
        else:
            n = sqrt(n2)
            cw = cos(n)
            s = sin(n) / n
        hx *= s
        hy *= s
        hz *= s
        w = qw * cw - qx * hx - qy * hy - qz * hz
        x = qw * hx + qx * cw + qy * hz - qz * hy
        y = qw * hy - qx * hz + qy * cw + qz * hx
        z = qw * hz + qx * hy - qy * hx + qz * cw
        inv = 1.0 / sqrt(w * w + x * x + y * y + z * z)
        self._q = (w * inv, x * inv, y * inv, z * inv)

    def _mag_rejected(self, dt: float, mag_n2: float, norm: float, sin_dip: float) -> None:
        """Book-keeping for a magnetometer sample that disagrees with the reference (rare path)."""
        if not self._mag_have_ref:
            self._set_mag_reference(norm, sin_dip)
            return
        self.mag_disturbed = True
        lo2, hi2, lo_dip, hi_dip = self._mag_candidate
        if lo2 <= mag_n2 <= hi2 and lo_dip <= sin_dip <= hi_dip:
            self._mag_disturbed_s += dt
            if self._mag_disturbed_s > self.params.mag_reaccept_s:
                # A different field that stayed steady this long is the new normal (moved robot, new mounting).
                self._set_mag_reference(norm, sin_dip)
        else:
            # Not steady: start timing a new candidate field.
            self._mag_candidate = self._bounds(norm, sin_dip)
            self._mag_disturbed_s = 0.0

    @property
    def gyro_bias(self) -> tuple[float, float, float]:
        """Gyroscope bias estimate, rad/s, body frame."""
        return self._b

    @property
    def orientation_variance(self) -> tuple[float, float, float]:
        """Variance of roll, pitch, yaw errors, rad²."""
        return (self._var_incl, self._var_incl, self._var_head)
