"""Cascaded complementary filter on unit quaternions (the ccf_ros default): an NCF stage feeding an LCF stage.

The cascade of Narkhede et al. (Sensors 2021) — a PI stage (NCF) that estimates the gyroscope bias, followed by a
linear complementary stage (LCF) that integrates the bias-corrected rate and blends it with the
accelerometer/magnetometer attitude — made to work in 3-D, at any sample rate, under linear acceleration:

0. **Accelerometer low-pass in an almost-inertial frame** (linear-acceleration rejection). The specific force is
   low-passed (time constant ``tau_acc_lp_s``) in the frame that the bias-corrected gyro carries along: the filter
   state ``g_lp`` (m/s², body frame) is rotated with every gyro step before the new sample is blended in. Gravity
   is constant in that frame, so it passes unattenuated and without lag, while linear accelerations — whose
   integral is a bounded velocity change — average out. (The idea is VQF's, Laidig & Seel 2023; the code is ours.)
   ``g_lp`` is "the accelerometer attitude" both stages see.
1. **NCF (bias stage).** Its own attitude ``exp(dn) ⊗ q`` (``dn``: a small world-frame rotation from the LCF
   attitude, tilt and heading) is integrated from the same bias-corrected gyro and corrected towards ``g_lp`` and the
   magnetometer heading with a proportional gain ``1/tau_ncf_s``; the integral of its error, gain
   ``u/(tau_ncf_s * tau_bias_s)``, is the gyro-bias estimate. ``u`` is the bias variance relative to
   ``bias_sigma_init_rad_s²`` (Kalman-like: 1 while nothing is known, small after a rest, growing back with
   ``bias_walk_rad_s_sqrt_s``). With ``tau_bias_s >= 4 tau_ncf_s`` the bias loop is (over)damped and, at ``u = 1``, a
   bias converges with a time constant of about ``tau_bias_s`` while moving. ``tau_ncf_s`` must be shorter than the
   time the body takes to turn, or the integral sees an error that the rotation has turned away. At rest the bias is
   instead pulled to the low-passed gyro (much more informative).
2. **LCF (output stage).** The published attitude ``q`` integrates the bias-corrected rate and is blended towards
   ``g_lp`` (inclination, time constant ``tau_acc_s``) and towards the magnetometer heading (rotation about world
   up only, ``tau_mag_s``), so a magnetic disturbance never tilts the estimate. A field whose norm or dip departs from
   the reference is ignored for heading until it agrees again (or stays steady for ``mag_reaccept_s``: a new
   normal). The reference is the mean field of the first ``mag_ref_learn_s`` after a (re)initialisation.

Small-angle transfer functions (one tilt axis; ``k_f = 1/tau_acc_lp_s``, ``K_n = 1/tau_ncf_s``,
``K_i = 1/(tau_ncf_s tau_bias_s)``, ``K_a = 1/tau_acc_s``, ``P = (s + k_f)(s + K_n)``, ``Q = s P + K_i k_f``), from the
accelerometer angle ``x_a`` and from the measured rate ``w`` to the output ``x`` (see :func:`tilt_transfer`)::

    H_a(s) = (K_a k_f Q + K_i k_f s (s + k_f + K_a)) / ((s + k_f)(s + K_a) Q)
    H_w(s) = s (s + k_f + K_a) P / ((s + k_f)(s + K_a) Q)        with s H_w + H_a = 1 (complementary)

Without the NCF (``K_i = 0``) ``H_a = k_f K_a / ((s + k_f)(s + K_a))``: linear accelerations are attenuated at
12 dB/octave, twice the rate of a single blend. The per-sample gains ``1 - exp(-dt/tau)`` make the defaults behave
the same at 40 Hz and at 1 kHz.

Sample timing. The gyro step uses the rectangle rule: a sample's rate is taken as the mean over the interval before
it (what a MEMS gyro's decimation filter outputs), which carries the frame exactly to the step's end. The
accelerometer sample is the same kind of mean, so it describes gravity in the frame of mid-interval: it is rotated
forward by half the gyro step before it is blended (first order; it matters at low rates and fast rotation). With
instantaneous (point) samples the estimate is therefore the frame half a step after the stamp.

Reported covariance: continuous-time, so it does not depend on the sample rate. Inclination and heading variances
are a floor (``incl_sigma_rad``, ``heading_sigma_rad``) plus a drift variance that grows while that correction is
missing (accelerometer unusable; magnetometer absent, disturbed or off) from the gyro noise and the bias
uncertainty, and shrinks with the blend's time constant once corrected. Without a magnetometer the heading variance
is the drift since the heading was last known (relative heading, as a 6-D filter can only give).
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass
from math import atan2, cos, sin, sqrt

from .base import CommonParams, OrientationFilter, check_positive, check_range
from .quaternion import Quat, level_quat, quat_from_acc_mag_scalar, relevel

_DEG = math.pi / 180.0
_PI = math.pi
_TWO_PI = 2.0 * math.pi
#: Standard gravity, m/s² (REP-145 accelerometers read +g up at rest).
GRAVITY_M_S2 = 9.80665
_INV_G = 1.0 / GRAVITY_M_S2
#: Largest NCF heading error the bias integral uses, rad (see _step).
_HEAD_ERR_MAX = 5.0 * _DEG
_HEAD_ERR_MAX2 = _HEAD_ERR_MAX * _HEAD_ERR_MAX
#: The new-field timer loses this many seconds per second of samples that disagree with the candidate.
_LEAK = 3.0


@dataclass(frozen=True)
class CcfParams(CommonParams):
    """Parameters of :class:`QuaternionCcf`. Defaults are chosen from plateaus and physics, meant to need no tuning.

    Attributes:
        tau_acc_s: LCF: time constant of the inclination blend towards the filtered gravity, s. Default 2.5.
        tau_mag_s: LCF: time constant of the heading blend towards the magnetometer, s. Default 9.0.
        tau_acc_lp_s: time constant of the accelerometer low-pass in the gyro-carried (almost inertial) frame, s.
            Together with ``tau_acc_s`` it attenuates linear accelerations at 12 dB/octave. Default 2.5.
        tau_ncf_s: NCF: time constant of its proportional correction, s; shorter than the body takes to turn.
            Default 3.
        tau_bias_s: NCF: integral time constant, s (gain ``u/(tau_ncf_s tau_bias_s)``); a constant bias is learnt
            while moving with a time constant of about this (critically damped at ``4 tau_ncf_s``). Default 30.
        motion_bias: learn the bias while moving (the NCF integral). Default True.
        rest_bias: learn the bias from the gyro directly while the IMU rests. Default True.
        rest_gyro_rad_s: rest when the gyro stays within this of its low-passed value, rad/s. Default 2°/s.
        rest_acc_m_s2: ... and the accelerometer within this of the filtered gravity, m/s². Default 0.5.
        rest_min_s: for at least this long, s. Default 1.5.
        rest_tau_s: time constant of the rest low-pass and of the rest bias update, s. Default 0.5.
        bias_max_rad_s: the bias estimate is clamped to ±this per axis (anti-windup), rad/s; a low-passed rotation
            faster than this is never taken for rest. Default 2°/s.
        mag_norm_tol: relative deviation of the magnetometer norm from its reference that counts as disturbed.
            Default 0.05 (a calibrated magnetometer stays well within it).
        mag_dip_tol_rad: deviation of the magnetic dip angle that counts as disturbed, rad. Default 5°.
        mag_reaccept_s: a different field that stays steady (within the tolerances, most of the time) this long
            becomes the new reference, s: a moved robot, a new mounting or a reference learnt while the tilt was
            still wrong does not disable heading for long. Default 20 (VQF's choice for the same rule).
        mag_ref_learn_s: the reference field (norm and dip) is the mean of the samples of this long after it is
            first set (after a (re)initialisation or a new field), s, all of them used for heading meanwhile; 0: the
            first sample alone. One sample is a lottery: a MEMS magnetometer's norm scatters by ~1.5 % per sample,
            a third of the 5 % tolerance. The mean weights the samples linearly in time, because after an
            initialisation while moving the tilt, and so the dip, converges like 1/t. Default 5 (twice tau_acc_s).
        incl_sigma_rad: reported standard deviation of roll and of pitch while the accelerometer corrects them, rad
            (typical MEMS calibration/alignment error plus residual linear acceleration). Default 0.5°.
        heading_sigma_rad: reported heading standard deviation while the magnetometer corrects it, rad (residual
            hard/soft-iron and local-field errors; the geometric middle of 0.5-6.6° measured on BROAD). Default 1.7°.
        gyro_arw_rad_sqrt_s: gyro angle random walk (noise density), rad/√s; grows the reported variance while a
            correction is missing. Default 3e-4 (0.017 °/s/√Hz, a typical MEMS gyro).
        bias_sigma_init_rad_s: bias uncertainty before anything is learnt, rad/s. The NCF integral gain is scaled
            by the bias variance relative to this (a Kalman-like schedule): fast learning while the bias is unknown,
            slow refinement once it is. Default 0.5°/s.
        bias_sigma_rest_rad_s: bias uncertainty after a rest, rad/s: a MEMS gyro's noise (~0.3°/s per sample at
            300 Hz) averaged over the rest low-pass. Default 0.02°/s.
        bias_walk_rad_s_sqrt_s: random walk of the bias, (rad/s)/√s: how fast knowledge of the bias ages, which keeps
            the NCF learning while moving for ever. Default 0.01 (°/s)/√s (0.1°/s after 100 s).
    """

    tau_acc_s: float = 2.5
    tau_mag_s: float = 9.0
    tau_acc_lp_s: float = 2.5
    tau_ncf_s: float = 3.0
    tau_bias_s: float = 30.0
    motion_bias: bool = True
    rest_bias: bool = True
    rest_gyro_rad_s: float = 2.0 * _DEG
    rest_acc_m_s2: float = 0.5
    rest_min_s: float = 1.5
    rest_tau_s: float = 0.5
    bias_max_rad_s: float = 2.0 * _DEG
    mag_norm_tol: float = 0.05
    mag_dip_tol_rad: float = 5.0 * _DEG
    mag_reaccept_s: float = 20.0
    mag_ref_learn_s: float = 5.0
    incl_sigma_rad: float = 0.5 * _DEG
    heading_sigma_rad: float = 1.7 * _DEG
    gyro_arw_rad_sqrt_s: float = 3e-4
    bias_sigma_init_rad_s: float = 0.5 * _DEG
    bias_sigma_rest_rad_s: float = 0.02 * _DEG
    bias_walk_rad_s_sqrt_s: float = 0.01 * _DEG

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in (
            'tau_acc_s', 'tau_mag_s', 'tau_acc_lp_s', 'tau_ncf_s', 'tau_bias_s', 'rest_gyro_rad_s', 'rest_acc_m_s2',
            'rest_min_s', 'rest_tau_s', 'bias_max_rad_s', 'mag_norm_tol', 'mag_dip_tol_rad', 'mag_reaccept_s',
            'incl_sigma_rad', 'heading_sigma_rad', 'gyro_arw_rad_sqrt_s', 'bias_sigma_init_rad_s', 'bias_sigma_rest_rad_s',
            'bias_walk_rad_s_sqrt_s',
        ):
            check_positive(name, getattr(self, name))
        check_range('mag_ref_learn_s', self.mag_ref_learn_s, 0.0, 3600.0)
        check_range('mag_dip_tol_rad', self.mag_dip_tol_rad, 0.0, math.pi)
        for name in ('motion_bias', 'rest_bias'):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f'{name} must be a bool, got {getattr(self, name)!r}')


@dataclass(frozen=True, slots=True)
class _Coefficients:
    """Per-sample constants derived from :class:`CcfParams` for one sample period ``dt`` (s)."""

    dt: float
    dt_lo: float
    dt_hi: float
    k_acc: float
    k_mag: float
    k_lp: float
    k_min: float
    k_ncf: float
    k_int: float
    k_rest: float
    rest_gyro2: float
    rest_acc2: float
    bias_max: float
    bias_max2: float
    rest_min_s: float
    rest_bias: bool
    keep_incl: float
    keep_head: float
    keep_bias_rest: float
    u_rest_gain: float
    u_walk: float
    sigma_init: float
    var_arw: float

    @classmethod
    def of(cls, p: CcfParams, dt: float) -> _Coefficients:
        k_rest = -math.expm1(-dt / p.rest_tau_s)
        # Rest thresholds apply to (sample - new low-pass) = (1 - k_rest) * (sample - old low-pass).
        rest_keep2 = (1.0 - k_rest) ** 2 if k_rest < 1.0 else 1e-300
        return cls(
            dt=dt,
            # Float stamps near 1.7e9 s resolve 0.24 µs, so dt wobbles by ~1e-4 relative: gains are reused while dt
            # stays within 0.1 % (a 0.1 % change of a blend gain is immaterial; integration uses the exact dt).
            dt_lo=dt * (1.0 - 1e-3),
            dt_hi=dt * (1.0 + 1e-3),
            k_acc=-math.expm1(-dt / p.tau_acc_s),
            k_mag=-math.expm1(-dt / p.tau_mag_s),
            k_lp=-math.expm1(-dt / p.tau_acc_lp_s),
            k_min=-math.expm1(-dt / max(p.tau_acc_s, p.tau_mag_s, p.tau_acc_lp_s)),
            k_ncf=-math.expm1(-dt / p.tau_ncf_s),
            k_int=dt / (p.tau_ncf_s * p.tau_bias_s) if p.motion_bias else 0.0,
            k_rest=k_rest,
            rest_gyro2=p.rest_gyro_rad_s**2 / rest_keep2,
            rest_acc2=p.rest_acc_m_s2**2,
            bias_max=p.bias_max_rad_s,
            bias_max2=p.bias_max_rad_s**2,
            rest_min_s=p.rest_min_s,
            rest_bias=p.rest_bias,
            # Drift variances decay with the blends' (combined) time constants once corrected again.
            keep_incl=math.exp(-2.0 * dt / (p.tau_acc_s + p.tau_acc_lp_s)),
            keep_head=math.exp(-2.0 * dt / p.tau_mag_s),
            keep_bias_rest=math.exp(-dt / p.rest_tau_s),
            u_rest_gain=(p.bias_sigma_rest_rad_s / p.bias_sigma_init_rad_s) ** 2 * -math.expm1(-dt / p.rest_tau_s),
            u_walk=(p.bias_walk_rad_s_sqrt_s / p.bias_sigma_init_rad_s) ** 2 * dt,
            sigma_init=p.bias_sigma_init_rad_s,
            var_arw=p.gyro_arw_rad_sqrt_s**2 * dt,
        )


def _drift(var: float, bias_step: float, var_arw: float) -> float:
    """Drift variance (rad²) after one uncorrected step: the bias error adds linearly to the error's standard
    deviation (``bias_step`` = bias uncertainty x dt, rad), the gyro noise adds ``var_arw`` (rad²)."""
    return var + var_arw + bias_step * (bias_step + 2.0 * sqrt(var))


def tilt_transfer(p: CcfParams, f_hz: complex | float) -> tuple[complex, complex]:
    """Small-angle transfer functions of one tilt axis at ``f_hz``: ``(H_a, H_w)`` from the accelerometer angle
    (rad/rad) and from the measured rate (rad per rad/s) to the output; see the module docstring."""
    s = 2j * cmath.pi * f_hz
    kf, kn, ka = 1.0 / p.tau_acc_lp_s, 1.0 / p.tau_ncf_s, 1.0 / p.tau_acc_s
    ki = 1.0 / (p.tau_ncf_s * p.tau_bias_s) if p.motion_bias else 0.0
    pp = (s + kf) * (s + kn)
    qq = s * pp + ki * kf
    den = (s + kf) * (s + ka) * qq
    return (ka * kf * qq + ki * kf * s * (s + kf + ka)) / den, s * (s + kf + ka) * pp / den


class QuaternionCcf(OrientationFilter):
    """NCF -> LCF cascade on unit quaternions; see the module docstring.

    State (all reset by :meth:`reset`): LCF orientation ``q``, gyro bias (rad/s, body), filtered gravity ``g_lp``
    (m/s², body), NCF attitude offset ``dn`` (rad, world frame), rest-detector low-pass and timer, magnetometer reference
    (with its learning window) and new-field candidate, drift variances (rad²) and bias uncertainty (rad/s).
    """

    name = 'ccf'
    __slots__ = (
        '_coef', '_gyro_lp', '_heading_known', '_mag_bounds', '_mag_candidate', '_mag_have_ref', '_mag_learn_n',
        '_mag_learn_s', '_mag_new_s', '_mag_ref', '_mag_rejected_t', '_n_init', '_rest_s', '_u_bias', '_var_head',
        '_var_incl', '_x',
    )
    params: CcfParams

    def __init__(self, params: CcfParams | None = None) -> None:
        super().__init__(params if params is not None else CcfParams())

    def _reset_state(self) -> None:
        # The per-sample state in one tuple (one load and one store per sample): the gyro bias b (rad/s, body), the
        # filtered gravity g_lp (m/s², body) and the NCF's offset dn (rad, world), 3 values each.
        self._x = (0.0, 0.0, 0.0, 0.0, 0.0, GRAVITY_M_S2, 0.0, 0.0, 0.0)
        self._coef = _Coefficients.of(self.params, 0.0)
        self._gyro_lp = (0.0, 0.0, 0.0)
        self._rest_s = 0.0
        self._n_init = 0
        self._forget_mag_reference()
        self._var_incl = 0.0
        self._var_head = 0.0
        self._heading_known = False
        # Bias variance relative to bias_sigma_init_rad_s²: 1 = nothing learnt yet.
        self._u_bias = 1.0

    def _forget_mag_reference(self) -> None:
        """No reference field: the next usable magnetometer sample becomes it (see :meth:`_mag_rejected`)."""
        self._mag_ref = (0.0, 0.0)
        # Bounds that accept nothing, so that the first sample goes through _mag_rejected and sets the reference.
        self._mag_bounds = (math.inf, -math.inf, 2.0, -2.0)
        self._mag_candidate = (0.0, 0.0, 0.0)
        self._mag_have_ref = False
        self._mag_new_s = 0.0
        self._mag_rejected_t = -math.inf
        self._mag_learn_s = 0.0
        self._mag_learn_n = 0
        self.mag_disturbed = False

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

    def _set_mag_reference(self, norm: float, sin_dip: float, *, learn: bool = True) -> None:
        """Accept a field of ``norm`` (sensor unit) and dip ``asin(sin_dip)`` as undisturbed; with ``learn``, as the
        first sample of the mean over the next ``mag_ref_learn_s`` that becomes the reference."""
        self._mag_ref = (norm, sin_dip)
        self._mag_have_ref = True
        self._mag_new_s = 0.0
        self.mag_disturbed = False
        self._mag_learn_n = 1
        self._mag_learn_s = self.params.mag_ref_learn_s if learn else 0.0
        if self._mag_learn_s > 0.0:
            # Learning: the reference is the mean of the samples of the next mag_ref_learn_s, all accepted; bounds
            # that accept nothing route them through _mag_rejected, off the common path.
            self._mag_bounds = (math.inf, -math.inf, 2.0, -2.0)
        else:
            self._mag_bounds = self._bounds(norm, sin_dip)
        self._mag_candidate = (0.0, 0.0, 0.0)

    def _params_changed(self) -> None:
        self._coef = _Coefficients.of(self.params, 0.0)
        if not self.params.rest_bias:
            self.at_rest = False
            self._rest_s = 0.0
        elif self._rest_s < self.params.rest_min_s:
            # A longer rest_min_s: not at rest until the timer reaches it (the NCF integral runs meanwhile).
            self.at_rest = False
        if self._mag_have_ref and self._mag_learn_s <= 0.0:
            self._mag_bounds = self._bounds(*self._mag_ref)

    def _init(self, ax: float, ay: float, az: float, mx: float, my: float, mz: float, mag_ok: bool) -> None:
        q: Quat | None = quat_from_acc_mag_scalar(ax, ay, az, mx, my, mz, mag_ok)
        p = self.params
        if q is not None:
            # The field at (re)initialisation begins the reference of the disturbance gate (a mean, see above).
            an = sqrt(ax * ax + ay * ay + az * az)
            n = sqrt(mx * mx + my * my + mz * mz)
            self._set_mag_reference(n, (mx * ax + my * ay + mz * az) / (n * an))
            self._var_head = 0.0
            self._heading_known = True
        else:
            # No heading from this sample: a re-initialisation keeps the heading it had (6-D: relative heading goes
            # on), a first initialisation starts at heading zero. The reference field is learnt from the next
            # usable magnetometer samples.
            q = relevel(self._q, ax, ay, az) if self.initialized else level_quat(ax, ay, az)
            self._forget_mag_reference()
            if not self.initialized:
                self._var_head = 0.0 if not p.use_mag else (math.pi / 2) ** 2
                self._heading_known = False
        self._q = q
        bias = self._x[:3]
        self._x = (*bias, ax, ay, az, 0.0, 0.0, 0.0)
        self._gyro_lp = bias
        self._rest_s = 0.0
        self.at_rest = False
        self._var_incl = 0.0
        # Start-up: the blends begin as running means (gain 1/n) and hand over to their time constants once 1/n
        # falls below them, so the first seconds average the samples instead of trusting the first one.
        self._n_init = 1

    def _heading_absolute(self) -> bool:
        return self._heading_known

    def _step(  # noqa: C901 - the per-sample hot path, one function on purpose (calls cost as much as the maths)
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
        c = self._coef
        if not c.dt_lo <= dt <= c.dt_hi:
            c = self._coef = _Coefficients.of(self.params, dt)
        qw, qx, qy, qz = self._q
        bx, by, bz, fx, fy, fz, dnx, dny, dnz = self._x
        # Rows of the body->world rotation matrix: world east (r0), north (r1) and up (v) in body coordinates.
        # (Twice the products: x2 = 2 qx etc. saves the factor 2 of every matrix element.)
        x2, y2, z2 = qx + qx, qy + qy, qz + qz
        xx, yy, zz = qx * x2, qy * y2, qz * z2
        xy, xz, yz = qx * y2, qx * z2, qy * z2
        wx, wy, wz = qw * x2, qw * y2, qw * z2
        r0x, r0y, r0z = 1.0 - (yy + zz), xy - wz, xz + wy
        r1x, r1y, r1z = xy + wz, 1.0 - (xx + zz), yz - wx
        vx, vy, vz = xz - wy, yz + wx, 1.0 - (xx + yy)
        # LCF tilt error e: rotation (rad, body) taking the filtered gravity direction onto the estimated up;
        # divided by standard gravity, not |g_lp|, so the correction stays linear in the specific force.
        ig = _INV_G
        ex = (fy * vz - fz * vy) * ig
        ey = (fz * vx - fx * vz) * ig
        ez = (fx * vy - fy * vx) * ig
        ni = self._n_init
        if ni:
            ni += 1
            kn = 1.0 / ni
            k_acc = kn if kn > c.k_acc else c.k_acc
            k_mag = kn if kn > c.k_mag else c.k_mag
            k_lp = kn if kn > c.k_lp else c.k_lp
            self._n_init = ni if kn > c.k_min else 0
        else:
            k_acc = c.k_acc
            k_mag = c.k_mag
            k_lp = c.k_lp
        cx = k_acc * ex
        cy = k_acc * ey
        cz = k_acc * ez
        # NCF tilt error: its attitude is exp(dn) ⊗ q (dn: a small world-frame rotation), so its tilt error is e
        # minus the horizontal part of dn seen in the body frame.
        nx = ex - dnx * r0x - dny * r1x
        ny = ey - dnx * r0y - dny * r1y
        nz = ez - dnx * r0z - dny * r1z
        hn = kd = 0.0
        if mag_n2:
            norm = sqrt(mag_n2)
            sin_dip = (vx * mx + vy * my + vz * mz) / norm
            lo2, hi2, lo_dip, hi_dip = self._mag_bounds
            if (lo2 <= mag_n2 <= hi2 and lo_dip <= sin_dip <= hi_dip) or self._mag_rejected(
                dt, mag_n2, norm, sin_dip
            ):
                if self.mag_disturbed:
                    self.mag_disturbed = False
                # Horizontal field in the world frame must point to +y (north in ENU). The correction is a rotation
                # about world up (v in body coordinates): heading only, never tilt.
                d = atan2(r0x * mx + r0y * my + r0z * mz, r1x * mx + r1y * my + r1z * mz)
                kd = k_mag * d
                # NCF heading error (its heading is the LCF's turned by dnz about world up). Its own heading takes
                # all of it; the bias integral only what is within ±_HEAD_ERR_MAX: a larger one means the heading
                # has not converged yet (a start, a new field), which is no information about the bias.
                hn = d - dnz
                if hn > _PI:  # the NCF's heading takes all of it: the short way round
                    hn -= _TWO_PI
                elif hn < -_PI:
                    hn += _TWO_PI
                hi = hn if hn * hn < _HEAD_ERR_MAX2 else 0.0
                nx += hi * vx
                ny += hi * vy
                nz += hi * vz
                cx += kd * vx
                cy += kd * vy
                cz += kd * vz
                vh = self._var_head
                if vh:
                    # Exactly zero again once negligible, so the common path skips this.
                    self._var_head = vh * c.keep_head if vh > 1e-14 else 0.0
                    self._heading_known = True
            else:
                self._var_head = _drift(self._var_head, c.sigma_init * sqrt(self._u_bias) * dt, c.var_arw)
        else:
            self._var_head = _drift(self._var_head, c.sigma_init * sqrt(self._u_bias) * dt, c.var_arw)
        if acc_n2:
            vi = self._var_incl
            if vi:
                self._var_incl = vi * c.keep_incl if vi > 1e-14 else 0.0
        else:
            self._var_incl = _drift(self._var_incl, c.sigma_init * sqrt(self._u_bias) * dt, c.var_arw)
        # NCF integral: the bias estimate (tilt and, with a usable magnetometer, heading). Its gain is scaled by the
        # bias variance u relative to bias_sigma_init² (Kalman-like): a rest makes u small, so a precise rest estimate
        # is refined only slowly while moving; u grows back as that knowledge ages (bias random walk).
        u = self._u_bias
        # Not during the start-up (ni): the errors then are the initial attitude's, not the bias's; not at rest,
        # where the low-passed gyro below is far more informative.
        if not (ni or self.at_rest):
            k = c.k_int * u
            bx -= k * nx
            by -= k * ny
            bz -= k * nz
        if c.rest_bias:
            # Rest: the accelerometer within rest_acc_m_s2 of the filtered gravity (tested first: it fails first
            # while moving, and then nothing else is needed), and the gyro within rest_gyro_rad_s of its low-pass.
            dax = ax - fx
            day = ay - fy
            daz = az - fz
            if dax * dax + day * day + daz * daz < c.rest_acc2 and acc_n2:
                k = c.k_rest
                if self._rest_s:
                    glx, gly, glz = self._gyro_lp
                else:
                    # A possible rest begins: the gyro low-pass starts from here (it is not kept while moving).
                    glx, gly, glz = gx, gy, gz
                # d = sample - previous low-pass; the deviation from the updated low-pass is (1 - k) d, which the
                # gyro threshold in c accounts for.
                dgx = gx - glx
                dgy = gy - gly
                dgz = gz - glz
                glx += k * dgx
                gly += k * dgy
                glz += k * dgz
                self._gyro_lp = (glx, gly, glz)
                m2 = c.bias_max2
                # The low-passed gyro must be a believable bias: within the clamp, per axis as the clamp is.
                if (
                    dgx * dgx + dgy * dgy + dgz * dgz < c.rest_gyro2
                    and glx * glx < m2
                    and gly * gly < m2
                    and glz * glz < m2
                ):
                    # 1e-12 s keeps the timer non-zero (the low-pass continues) from the first sample on.
                    rest_s = self._rest_s = self._rest_s + dt + 1e-12
                    if rest_s >= c.rest_min_s:
                        # At rest the low-passed gyro *is* the bias: pull the estimate there.
                        self.at_rest = True
                        bx += k * (glx - bx)
                        by += k * (gly - by)
                        bz += k * (glz - bz)
                        # u relaxes to u_rest: u_rest + (u - u_rest) keep.
                        self._u_bias = u = u * c.keep_bias_rest + c.u_rest_gain
                elif self._rest_s:
                    self._rest_s = 0.0
                    self.at_rest = False
            elif self._rest_s:
                self._rest_s = 0.0
                self.at_rest = False
        if u < 1.0 and not self.at_rest:
            u += c.u_walk
            self._u_bias = u if u < 1.0 else 1.0
        # Anti-windup: the estimate never leaves ±bias_max per axis (tested per axis only when the norm says it may).
        if bx * bx + by * by + bz * bz > c.bias_max2:
            m = c.bias_max
            bx = max(-m, min(m, bx))
            by = max(-m, min(m, by))
            bz = max(-m, min(m, bz))
        # LCF: integrate the bias-corrected rate plus the blend correction: q <- q ⊗ exp(h).
        rx = (gx - bx) * dt
        ry = (gy - by) * dt
        rz = (gz - bz) * dt
        hx = 0.5 * (rx + cx)
        hy = 0.5 * (ry + cy)
        hz = 0.5 * (rz + cz)
        n2 = hx * hx + hy * hy + hz * hz
        if n2 < 1e-4:
            # Taylor series of cos(x) and sin(x)/x to x⁴; the first omitted terms are below 2e-15 for |x| < 0.01.
            # (Not shorter: the published quaternion's norm is exp(h)'s, and a deficit of even 1e-10 reads as a 1e-3°
            # rotation to anyone who takes the angle between two quaternions as 2 acos|q1·q2|.)
            cw = 1.0 - n2 * (0.5 - n2 * (1.0 / 24.0))
            s = 1.0 - n2 * (1.0 / 6.0 - n2 * (1.0 / 120.0))
        else:
            n = sqrt(n2)
            cw = cos(n)
            s = sin(n) / n
        # The gyro's share of the step alone, p (g_lp follows the gyro only, not the LCF correction c, ~1e-5 rad).
        # Its cos is taken as the full step's cw, which leaves the rotation orthogonal to second order in |c| (and
        # more exact than rotating by h and undoing c, which left ~|r x c| / 2).
        s2 = 0.5 * s
        px = s2 * rx
        py = s2 * ry
        pz = s2 * rz
        # q's norm is 1 to rounding (a product of unit quaternions): its first-order inverse 1.5 - 0.5 |q|² (exact
        # to ~1e-30 there, no square root), folded into exp(h), renormalises the product.
        inv = 1.5 - 0.5 * qw * qw - 0.25 * (xx + yy + zz)
        hw = cw * inv
        s *= inv
        hx *= s
        hy *= s
        hz *= s
        self._q = (
            qw * hw - qx * hx - qy * hy - qz * hz,
            qw * hx + qx * hw + qy * hz - qz * hy,
            qw * hy - qx * hz + qy * hw + qz * hx,
            qw * hz + qx * hy - qy * hx + qz * hw,
        )
        # g_lp into the new body frame, v' = R(p)^T v = v - 2 cw (p x v) + 2 p x (p x v).
        tx = 2.0 * (fy * pz - fz * py)
        ty = 2.0 * (fz * px - fx * pz)
        tz = 2.0 * (fx * py - fy * px)
        fx += cw * tx + (ty * pz - tz * py)
        fy += cw * ty + (tz * px - tx * pz)
        fz += cw * tz + (tx * py - ty * px)
        if acc_n2:
            # The sample is a mean over the step (gravity in the frame of mid-interval): carry it the half step to
            # the step's end, v' = v - p x v (p = r/2 to ~1e-5), then blend.
            fx += k_lp * (ax - (py * az - pz * ay) - fx)
            fy += k_lp * (ay - (pz * ax - px * az) - fy)
            fz += k_lp * (az - (px * ay - py * ax) - fz)
        # NCF offset (world frame, unchanged by the common gyro step): dn += R (c_ncf - c_lcf); its vertical part is
        # the NCF's own heading (moved by the magnetometer only).
        k = c.k_ncf
        ux = k * nx - cx
        uy = k * ny - cy
        uz = k * nz - cz
        self._x = (
            bx, by, bz, fx, fy, fz,
            dnx + r0x * ux + r0y * uy + r0z * uz,
            dny + r1x * ux + r1y * uy + r1z * uz,
            dnz + k * hn - kd,
        )

    def _mag_rejected(self, dt: float, mag_n2: float, norm: float, sin_dip: float) -> bool:
        """Book-keeping for a magnetometer sample outside the acceptance bounds (rare path).

        Returns True if the sample is to be used after all: it began the reference (first usable sample after a
        (re)initialisation), the reference is being learnt (the ``mag_ref_learn_s`` after that), or a new field
        stayed steady long enough to become the reference.
        """
        if not self._mag_have_ref:
            self._set_mag_reference(norm, sin_dip)
            return True
        if self._mag_learn_s > 0.0:
            # Weights growing linearly with the sample's index: after a (re)initialisation while moving, the tilt
            # (and so the dip) converges like 1/t, and the early samples count least.
            i = self._mag_learn_n = self._mag_learn_n + 1
            k = 2.0 / (i + 1)
            rn, rs = self._mag_ref
            self._mag_ref = (rn + k * (norm - rn), rs + k * (sin_dip - rs))
            self._mag_learn_s -= dt
            if self._mag_learn_s <= 0.0:
                self._mag_bounds = self._bounds(*self._mag_ref)
            return True
        self.mag_disturbed = True
        # The candidate new field: the mean (norm, sin dip) of the rejected samples that agree with it, n of them,
        # and a leaky timer: + dt per agreeing sample, - _LEAK x the time of anything else (an outlier, accepted
        # samples or no magnetometer since the last rejection). A field that agrees for mag_reaccept_s net becomes
        # the reference (with a fraction f of outliers after mag_reaccept_s / (1 - f (1 + _LEAK))); single
        # outliers (noise, a tilt error while moving) do not restart it.
        cn, cs, n = self._mag_candidate  # n: a float count (0.0: no candidate yet)
        p = self.params
        t = self._t_last
        timer = self._mag_new_s - _LEAK * (t - self._mag_rejected_t - dt)
        self._mag_rejected_t = t
        if n and abs(norm - cn) <= p.mag_norm_tol * cn and abs(sin_dip - cs) <= p.mag_dip_tol_rad * sqrt(
            max(1.0 - cs * cs, 1e-6)
        ):
            n += 1.0
            cn += (norm - cn) / n
            cs += (sin_dip - cs) / n
            self._mag_candidate = (cn, cs, n)
            timer += dt
            if timer > p.mag_reaccept_s:
                # A different field that stayed steady this long is the new normal (moved robot, new mounting). Its
                # mean over the agreeing samples is the reference at once: no learning window, which would average
                # the outliers back in with the gate open.
                self._set_mag_reference(cn, cs, learn=False)
                return True
        else:
            timer -= _LEAK * dt
        if timer <= 0.0:
            # Not steady: start timing a new candidate field from this sample.
            self._mag_candidate = (norm, sin_dip, 1.0)
            timer = 0.0
        self._mag_new_s = timer
        return False

    @property
    def gyro_bias(self) -> tuple[float, float, float]:
        """Gyroscope bias estimate, rad/s, body frame."""
        b = self._x
        return (b[0], b[1], b[2])

    @property
    def gyro_bias_sigma_rad_s(self) -> float:
        """1-σ uncertainty of :attr:`gyro_bias` per axis, rad/s: ``bias_sigma_init_rad_s`` while nothing is known,
        ``bias_sigma_rest_rad_s`` after a rest, growing back with ``bias_walk_rad_s_sqrt_s`` (it scales the NCF's
        integral gain and the reported drift variance)."""
        return self.params.bias_sigma_init_rad_s * sqrt(self._u_bias)

    @property
    def ncf_quaternion(self) -> Quat:
        """The NCF stage's own attitude ``exp(dn) ⊗ q`` (internal ENU frame), ``(w, x, y, z)``."""
        qw, qx, qy, qz = self._q
        dx, dy, dz = (0.5 * v for v in self._x[6:])
        # (1, dx, dy, dz) ⊗ q, normalised: first order in the small world-frame rotation dn.
        w = qw - dx * qx - dy * qy - dz * qz
        x = qx + dx * qw + dy * qz - dz * qy
        y = qy - dx * qz + dy * qw + dz * qx
        z = qz + dx * qy - dy * qx + dz * qw
        n = 1.0 / sqrt(w * w + x * x + y * y + z * z)
        return (w * n, x * n, y * n, z * n)

    @property
    def orientation_variance(self) -> tuple[float, float, float]:
        """Variance of roll, pitch, yaw errors, rad² (yaw relative to the start without a magnetometer)."""
        p = self.params
        vi = p.incl_sigma_rad * p.incl_sigma_rad + self._var_incl
        vh = self._var_head + (p.heading_sigma_rad * p.heading_sigma_rad if self._heading_known else 0.0)
        return (vi, vi, vh)
