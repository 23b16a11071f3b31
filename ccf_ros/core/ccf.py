"""Cascaded complementary filter on unit quaternions (the ccf_ros default): an NCF stage feeding an LCF stage.

The cascade of Narkhede et al. (Sensors 2021) — a PI stage (NCF) whose integral is the gyroscope bias, followed by a
linear complementary stage (LCF) that integrates the bias-corrected rate and blends it with the
accelerometer/magnetometer attitude — made to work in 3-D, at any sample rate, under linear acceleration:

0. **Gravity low-pass in an almost-inertial frame** (linear-acceleration rejection). The specific force is low-passed
   by a second-order Butterworth filter (group delay ``tau_acc_lp_s``) in the frame that the bias-corrected gyro
   carries along: its two states ``g_lp`` (m/s², body) and ``g_lp'`` (m/s³, body) are rotated with every gyro step
   before the new sample is filtered in. Gravity is constant in that frame, so it passes without attenuation, while
   linear accelerations — whose integral is a bounded velocity change — average out at 12 dB/octave. (The idea is
   VQF's, Laidig & Seel 2023; the code is ours.) ``g_lp`` is "the accelerometer attitude" both stages see.
1. **NCF (bias stage).** Its own attitude ``exp(dn) ⊗ q`` (``dn``: a small world-frame rotation from the LCF
   attitude, tilt and heading) is integrated from the same bias-corrected gyro and corrected towards ``g_lp`` and the
   magnetometer heading with a proportional gain ``K_n = 1/tau_ncf_s``. Its error, times ``K_n``, is the rate at
   which the gyro's attitude drifts away from gravity and north: an observation of the bias error, seen through the
   two low-passes it passed (Butterworth and NCF, tilt) or the NCF's alone (heading). The integral is a Kalman
   filter on that observation (state: the bias, rad/s, body; covariance ``P``, 3x3): its measurement model passes the
   body->world rotation through the same low-passes, so a body that turns while the error builds up is modelled,
   not mistaken for bias. The tilt observations' noise density is ``W = (bias_walk_rad_s_sqrt_s tau_bias_s)²``
   ((rad/s)² s), so in steady motion the bias follows with time constant ``tau_bias_s`` (the Kalman steady state,
   ``P = walk sqrt(W)``); the heading's is ``W / cos²(dip)`` (a magnetometer's heading carries the tilt error times
   tan(dip)); both grow as ``1 + (|w| / bias_rotation_rad_s)²`` with the rotation rate ``|w|`` (scale-factor and
   misalignment errors make a rotation look like bias), so ``tau_bias_s`` holds while the body turns slower than
   that and the estimate is slower while it turns faster (~15 s at 35°/s). An observation further than 3 standard
   deviations from what the bias uncertainty and the references' own errors (``incl_sigma_rad``,
   ``heading_sigma_rad``, over ``tau_ncf_s``) explain is not used once the bias is roughly known (its variance
   below a quarter of the initial): a linear acceleration that lasts seconds (a vehicle drives off, brakes, turns)
   or a shock is no information about the bias. ``P`` starts at
   ``bias_sigma_init_rad_s²``, relaxes to ``bias_sigma_rest_rad_s²`` at rest (where the bias is pulled to the
   low-passed gyro, which is far more informative) and grows with ``bias_walk_rad_s_sqrt_s``, so a bias learnt at
   rest is refined slowly at first and more readily as it ages. The bias update runs once the samples since the
   last span 40 ms.
2. **LCF (output stage).** The published attitude ``q`` integrates the bias-corrected rate and is blended towards
   ``g_lp`` (inclination, time constant ``tau_acc_s``) and towards the magnetometer heading (rotation about world
   up only, ``tau_mag_s``), so a magnetic disturbance never tilts the estimate. A field whose norm or dip departs from
   the reference is ignored for heading until it agrees again (or stays steady for ``mag_reaccept_s``: a new
   normal). The reference is the mean field of the first ``mag_ref_learn_s`` after a (re)initialisation.

Small-angle transfer functions (one tilt axis, see :func:`tilt_transfer`): with the Butterworth low-pass
``B(s) = w_n² / (s² + √2 w_n s + w_n²)``, ``w_n = √2 / tau_acc_lp_s``, the observation filter ``M = B K_n / (s + K_n)``,
``K_a = 1/tau_acc_s`` and the bias gain ``G`` (the Kalman steady state ``bias_walk / sqrt(W) = 1/tau_bias_s`` in
continuous motion), the bias estimate is ``b = G M / (s + G) (w - s x_a)`` and, from the accelerometer angle ``x_a``
and from the measured rate ``w`` to the output ``x``::

    H_a(s) = (F (s + K_a (1 - B)) + K_a B) / (s + K_a)            F = G M / (s + G)
    H_w(s) = (1 - F) (s + K_a (1 - B)) / (s (s + K_a))           with s H_w + H_a = 1 (complementary)

Without the NCF (``G = 0``) ``H_a = K_a B / (s + K_a)``: linear accelerations are attenuated at 18 dB/octave. The
bias path is an open-loop filter of the rate the accelerometer does not confirm (``w - s x_a``): it cannot
oscillate, whatever its gain. With ``G`` the response peaks at +2.9 dB near 0.03 Hz: a tilt that lasts tens of
seconds reads partly as bias, which the gate above bounds. The per-sample gains ``1 - exp(-dt/tau)`` and the
exactly discretised low-pass make the defaults behave the same at 40 Hz and at 1 kHz.

Sample timing. The gyro step uses the rectangle rule: a sample's rate is taken as the mean over the interval before
it (what a MEMS gyro's decimation filter outputs), which carries the frame exactly to the step's end. The
accelerometer and magnetometer samples are the same kind of mean, so they describe gravity and the field in the
frame of mid-interval: the accelerometer sample is rotated forward by half the gyro step before it is filtered in,
the magnetometer sample back by half a step to the attitude it is compared with, the step's start (first order; it
matters at low rates and fast rotation). With instantaneous (point) samples the estimate is therefore the frame half
a step after the stamp.

Reported covariance: continuous-time, so it does not depend on the sample rate. Inclination and heading variances
are a floor (``incl_sigma_rad``, ``heading_sigma_rad``) plus a drift variance that grows while that correction is
missing (accelerometer unusable; magnetometer absent, disturbed or off) from the gyro noise and the bias
uncertainty, and shrinks with the blend's time constant once corrected. Without a magnetometer the heading variance
is the drift since the heading was last known (relative heading, as a 6-D filter can only give).
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Callable
from dataclasses import dataclass
from math import atan2, cos, sin, sqrt
from typing import TypeVar

from .base import CommonParams, OrientationFilter, check_positive, check_range, param
from .quaternion import Quat, level_quat, quat_from_acc_mag_scalar, relevel

_DEG = math.pi / 180.0
_PI = math.pi
_TWO_PI = 2.0 * math.pi
#: Standard gravity, m/s² (REP-145 accelerometers read +g up at rest).
GRAVITY_M_S2 = 9.80665
_INV_G = 1.0 / GRAVITY_M_S2
#: Largest NCF heading error the bias estimate uses, rad (see _step).
_HEAD_ERR_MAX = 5.0 * _DEG
_HEAD_ERR_MAX2 = _HEAD_ERR_MAX * _HEAD_ERR_MAX
#: The new-field timer loses this many seconds per second of samples that disagree with the candidate.
_LEAK = 3.0
#: The NCF's bias update runs once the samples since the last one span this long, s (every sample at 25 Hz and
#: below): the tilt observations are low-passed over seconds and the heading ones averaged over the block, so 25
#: updates a second lose nothing (BROAD's mean error moves by 0.005° between 50 and 25 Hz) and save most of the
#: matrix arithmetic.
BIAS_UPDATE_PERIOD_S = 0.04
#: Due at this span (s), so that rounding in the stamps' differences does not make a block of exactly 0.04 s wait
#: for another sample.
_BLOCK_DUE_S = BIAS_UPDATE_PERIOD_S * (1.0 - 1e-6)
#: The NCF's bias observations are used only within this many standard deviations of what the bias uncertainty and
#: the attitude references' own errors (incl_sigma_rad, heading_sigma_rad, over tau_ncf_s) explain (squared).
_GATE2 = 3.0**2
#: The field's world direction (through the attitude) is band-passed between these time constants, s, to tell a
#: field that stays put from one that changes as the sensor moves (see QuaternionCcf._mag_consistency): the first
#: averages the magnetometer's noise and the wobble its lag gives during hand motion (0.5 Hz and up), the second is
#: the time over which a robot or a hand carries the sensor across a field's structure.
MAG_BAND_S = (1.0, 8.0)
#: ... and its squared deviation low-passed over this, s.
MAG_SCORE_S = 2.0
#: The field's wander (band-passed RMS) in units of half ``mag_consistency_rad`` (sigma0) at which it no longer steers
#: heading at all; below, the heading blend's time constant grows as wander / sigma0 (a noisier heading reference).
MAG_REJECT_SIGMAS = 4.0
_REJECT2 = MAG_REJECT_SIGMAS**2
#: A new field becomes the reference only after the body turned by this much (rad, the gyro's angle) while it was
#: timed: without turning, a field carried by the body (a magnet or motor on the robot) cannot be told from one that
#: is fixed in the world.
NEW_FIELD_TURN_RAD = math.pi / 2
#: Once the bias was seen at rest, a steady gyro rate differing from the estimate by more than this (rad/s, plus 3
#: sigma of the estimate) is a slow turn, not a rest: a MEMS gyro's bias moves by ~0.1°/s between rests minutes apart
#: (bias instability and temperature); a tracked robot turning in place at 1°/s does not look like a rest.
REST_BIAS_TOL_RAD_S = math.radians(0.3)
_REST_TOL2 = REST_BIAS_TOL_RAD_S**2
#: ... unless it stays steady this long, s: a rest learnt wrongly (a slow turn first) must not block later rests.
REST_RELEARN_S = 120.0
#: cos²(dip) is floored at this when the heading observations' noise is scaled by 1/cos²(dip) (near a magnetic pole
#: the horizontal field, and so heading, is lost in the tilt error).
_COS2_DIP_MIN = 0.05


@dataclass(frozen=True)
class CcfParams(CommonParams):
    """Parameters of :class:`QuaternionCcf`. Defaults are chosen from plateaus and physics, meant to need no tuning.

    Attributes:
        tau_acc_s: LCF: time constant of the inclination blend towards the filtered gravity, s. Default 1.0.
        tau_mag_s: LCF: time constant of the heading blend towards the magnetometer, s. Default 15 (the bias is
            learnt from the heading too, so the blend only has to outlast the magnetometer's errors, not the
            gyro's bias).
        tau_acc_lp_s: group delay of the second-order (Butterworth) gravity low-pass in the gyro-carried (almost
            inertial) frame, s; cut-off frequency ``sqrt(2) / (2 pi tau_acc_lp_s)``. Together with ``tau_acc_s`` it
            attenuates linear accelerations at 18 dB/octave; a gyro bias ``b`` (rad/s) leaves a tilt offset of about
            ``b (tau_acc_lp_s + tau_acc_s)`` rad until it is learnt. Default 2.5.
        tau_ncf_s: NCF: time constant of its proportional correction, s. Default 3.
        tau_bias_s: NCF: time constant with which the bias estimate follows the observed drift in continuous
            motion slower than ``bias_rotation_rad_s`` (the Kalman steady state), s: it sets the tilt observations'
            noise density to ``(bias_walk_rad_s_sqrt_s tau_bias_s)²``. Default 5.
        bias_rotation_rad_s: rotation rate at which the NCF's bias observations count half, rad/s (their noise
            grows as ``1 + (|w| / this)²``): a gyro's scale-factor and misalignment errors, ~0.3 %, make a fast
            rotation look like bias. Default 12°/s.
        motion_bias: learn the bias while moving (the NCF integral). Default True.
        rest_bias: learn the bias from the gyro directly while the IMU rests. Default True.
        rest_gyro_rad_s: rest when the gyro stays within this of its low-passed value, rad/s. Default 2°/s.
        rest_acc_m_s2: ... and the accelerometer within this of the filtered gravity, m/s². Default 0.5.
        rest_min_s: for at least this long, s. Default 1.5.
        rest_tau_s: time constant of the rest low-pass and of the rest bias update, s. Default 0.5.
        bias_max_rad_s: the bias estimate is clamped to ±this per axis (anti-windup), rad/s; a low-passed rotation
            faster than this is never taken for rest. Default 15°/s (consumer MEMS gyros' offsets reach 10°/s; a
            slow turn is told from a bias by :meth:`QuaternionCcf._rest_agrees`, not by its size).
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
            initialisation while moving the tilt, and so the dip, converges like 1/t. Default 5.
        mag_consistency_rad: the field's direction in the world (seen through the gyro-carried attitude) may move
            this much (RMS of its band-pass between 1 and 8 s) before the field is taken as one that changes with
            position or time and stops steering heading; 0: no such check. A homogeneous field stays put however
            the body turns; the attitude's own errors move it by about ``incl_sigma_rad`` times
            ``sqrt(1 + tan²(dip))``, ~1° at 60° dip, and this is twice that. Default 2°.
        gyro_range_rad_s: the gyro's measurement range (full scale), rad/s; 0: unknown. A sample with an axis at
            99.8 % of it or beyond is clipped: the rotation it misses is unknown, so the reported variances grow by
            the range times the step, squared, and the blends with accelerometer and magnetometer restart as running
            means (as at start-up), which bring the attitude back within a second or so instead of tau_acc_s and
            tau_mag_s. Counted in :attr:`QuaternionCcf.n_gyro_clipped`. E.g. 2000°/s = 34.9 rad/s. Default 0.
        incl_sigma_rad: reported standard deviation of roll and of pitch while the accelerometer corrects them, rad
            (typical MEMS calibration/alignment error plus residual linear acceleration). Default 0.5°.
        heading_sigma_rad: reported heading standard deviation while the magnetometer corrects it, rad (residual
            hard/soft-iron and local-field errors; the geometric middle of 0.5-6.6° measured on BROAD). Default 1.7°.
        gyro_arw_rad_sqrt_s: gyro angle random walk (noise density), rad/√s; grows the reported variance while a
            correction is missing. Default 3e-4 (0.017 °/s/√Hz, a typical MEMS gyro).
        bias_sigma_init_rad_s: bias uncertainty before anything is learnt, rad/s (the NCF Kalman filter's initial
            ``P``). Default 0.5°/s.
        bias_sigma_rest_rad_s: bias uncertainty after a rest, rad/s: a MEMS gyro's noise (~0.3°/s per sample at
            300 Hz) averaged over the rest low-pass. Default 0.02°/s.
        bias_walk_rad_s_sqrt_s: random walk of the bias, (rad/s)/√s: how fast knowledge of the bias ages (thermal
            drift), which keeps the NCF learning while moving for ever. Default 0.01 (°/s)/√s (0.1°/s after 100 s).
    """

    tau_acc_s: float = param(
        1.0, 's', 'LCF time constant of the inclination blend towards the filtered gravity, s', 0.0, 1e9, above=True)
    tau_mag_s: float = param(
        15.0, 's', 'LCF time constant of the heading blend towards the magnetometer, s', 0.0, 1e9, above=True)
    tau_acc_lp_s: float = param(
        2.5, 's', 'group delay of the 2nd-order gravity low-pass in the gyro-carried (almost '
        'inertial) frame, s', 0.0, 1e9, above=True)
    tau_ncf_s: float = param(3.0, 's', 'NCF (bias stage) proportional time constant, s', 0.0, 1e9, above=True)
    tau_bias_s: float = param(
        5.0, 's', 'NCF: the bias estimate follows the observed drift with this time constant in '
        'steady motion, s', 0.0, 1e9, above=True)
    bias_rotation_rad_s: float = param(
        12.0 * _DEG, 'rad/s', 'NCF: rotation rate at which its bias observations count half (gyro scale '
        'errors), rad/s', 0.0, 1e9, above=True)
    motion_bias: bool = param(True, '-', 'learn the gyro bias while moving (NCF integral)')
    rest_bias: bool = param(True, '-', 'learn the gyro bias from the gyro itself while at rest')
    rest_gyro_rad_s: float = param(
        2.0 * _DEG, 'rad/s', 'rest if the gyro stays within this of its low-pass, rad/s', 0.0, 1e9, above=True)
    rest_acc_m_s2: float = param(
        0.5, 'm/s²', '... and the accelerometer within this of the filtered gravity, m/s^2', 0.0, 1e9, above=True)
    rest_min_s: float = param(1.5, 's', '... for at least this long, s', 0.0, 1e9, above=True)
    rest_tau_s: float = param(
        0.5, 's', 'time constant of the rest low-pass filter and rest bias update, s', 0.0, 1e9, above=True)
    bias_max_rad_s: float = param(
        15.0 * _DEG, 'rad/s', 'the gyro-bias estimate is clamped to +-this per axis, rad/s', 0.0, 1e9, above=True)
    mag_norm_tol: float = param(
        0.05, '-', 'relative magnetometer-norm deviation that counts as disturbed', 0.0, 10.0, above=True)
    mag_dip_tol_rad: float = param(
        5.0 * _DEG, 'rad', 'magnetic dip deviation that counts as disturbed, rad', 0.0, math.pi, above=True)
    mag_reaccept_s: float = param(
        20.0, 's', 'a different but steady field becomes the new reference after this long, s', 0.0, 1e9, above=True)
    mag_ref_learn_s: float = param(
        5.0, 's', 'the reference field of the disturbance gate is the mean over this long after it '
        'is set, s', 0.0, 3600.0)
    mag_consistency_rad: float = param(
        2.0 * _DEG, 'rad', 'a field whose world direction moves more than this (band-passed RMS) does not '
        'steer heading, rad; 0 = off', 0.0, math.pi)
    gyro_range_rad_s: float = param(
        0.0, 'rad/s', "the gyro's full-scale range, rad/s (0 = unknown); samples at it are counted and "
        'the attitude recovers from the accelerometer/magnetometer fast', 0.0, 1000.0)
    incl_sigma_rad: float = param(
        0.5 * _DEG, 'rad', 'reported inclination std while the accelerometer corrects it, rad', 0.0, 1e9, above=True)
    heading_sigma_rad: float = param(
        1.7 * _DEG, 'rad', 'reported heading std while the magnetometer corrects it, rad', 0.0, 1e9, above=True)
    gyro_arw_rad_sqrt_s: float = param(
        3e-4, 'rad/√s', 'gyro angle random walk, rad/sqrt(s); grows the reported variance without '
        'corrections', 0.0, 1e9, above=True)
    bias_sigma_init_rad_s: float = param(
        0.5 * _DEG, 'rad/s', 'gyro-bias uncertainty before anything is learnt, rad/s (the NCF Kalman filter '
        'starts here)', 0.0, 1e9, above=True)
    bias_sigma_rest_rad_s: float = param(
        0.02 * _DEG, 'rad/s', 'gyro-bias uncertainty after a rest, rad/s', 0.0, 1e9, above=True)
    bias_walk_rad_s_sqrt_s: float = param(
        0.01 * _DEG, '(rad/s)/√s', 'random walk of the gyro bias, (rad/s)/sqrt(s)', 0.0, 1e9, above=True)

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in (
            'tau_acc_s', 'tau_mag_s', 'tau_acc_lp_s', 'tau_ncf_s', 'tau_bias_s', 'bias_rotation_rad_s',
            'rest_gyro_rad_s', 'rest_acc_m_s2', 'rest_min_s', 'rest_tau_s', 'bias_max_rad_s', 'mag_norm_tol',
            'mag_dip_tol_rad', 'mag_reaccept_s', 'incl_sigma_rad', 'heading_sigma_rad', 'gyro_arw_rad_sqrt_s',
            'bias_sigma_init_rad_s', 'bias_sigma_rest_rad_s', 'bias_walk_rad_s_sqrt_s',
        ):
            check_positive(name, getattr(self, name))
        check_range('mag_ref_learn_s', self.mag_ref_learn_s, 0.0, 3600.0)
        check_range('mag_consistency_rad', self.mag_consistency_rad, 0.0, math.pi)
        check_range('gyro_range_rad_s', self.gyro_range_rad_s, 0.0, 1000.0)
        check_range('mag_dip_tol_rad', self.mag_dip_tol_rad, 0.0, math.pi)
        for name in ('motion_bias', 'rest_bias'):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f'{name} must be a bool, got {getattr(self, name)!r}')

    @property
    def bias_gain_per_s(self) -> float:
        """Steady-state gain of the NCF's bias estimate in continuous motion, 1/s (``1/tau_bias_s``; 0 without
        ``motion_bias``): the ``G`` of :func:`tilt_transfer`."""
        return 1.0 / self.tau_bias_s if self.motion_bias else 0.0


def butterworth_step(tau_s: float, dt: float) -> tuple[float, float, float, float]:
    """Exact one-step transition ``(p11, p12, p21, p22)`` of the second-order Butterworth low-pass of group delay
    ``tau_s`` (s) over ``dt`` (s), for the state (value, rate) with the input held over the step::

        value' = p11 value + p12 rate + (1 - p11) input,   rate' = p21 (value - input) + p22 rate
    """
    wn = math.sqrt(2.0) / tau_s  # group delay at DC 2 zeta / wn with zeta = 1/sqrt(2)
    sg = wn / math.sqrt(2.0)  # zeta wn; the damped frequency equals it for zeta = 1/sqrt(2)
    e = math.exp(-sg * dt)
    c, s = math.cos(sg * dt), math.sin(sg * dt)
    return e * (c + s), e * s / sg, -e * wn * wn * s / sg, e * (c - s)


@dataclass(frozen=True, slots=True)
class _Coefficients:
    """Per-sample constants derived from :class:`CcfParams` for sample periods in ``[dt_lo, dt_hi]`` (s), computed at
    the bin's middle (see :meth:`of`)."""

    dt_lo: float
    dt_hi: float
    k_acc: float
    k_mag: float
    k_lp: float
    k_min: float
    k_ncf: float
    lp_a: float
    lp12: float
    lp21: float
    lp22: float
    k_rest: float
    rest_gyro2: float
    rest_acc2: float
    bias_max: float
    bias_max2: float
    rest_min_s: float
    rest_bias: bool
    keep_incl: float
    keep_head: float
    r_head: float
    k_band1: float
    k_band2: float
    k_score: float
    sigma_init: float
    var_arw: float
    clip: float
    var_clip: float

    @classmethod
    def of(cls, p: CcfParams, key: int) -> _Coefficients:
        """The coefficients of bin ``key`` of sample periods (:func:`_bin`)."""
        dt_lo, dt, dt_hi = _bin_range(key)
        k_rest = -math.expm1(-dt / p.rest_tau_s)
        # Rest thresholds apply to (sample - new low-pass) = (1 - k_rest) * (sample - old low-pass).
        rest_keep2 = (1.0 - k_rest) ** 2 if k_rest < 1.0 else 1e-300
        lp = butterworth_step(p.tau_acc_lp_s, dt)
        # The start-up hands the blends over to their time constants; without a magnetometer heading has none.
        taus = (p.tau_acc_s, p.tau_acc_lp_s, p.tau_mag_s) if p.use_mag else (p.tau_acc_s, p.tau_acc_lp_s)
        return cls(
            dt_lo=dt_lo,
            dt_hi=dt_hi,
            k_acc=-math.expm1(-dt / p.tau_acc_s),
            k_mag=-math.expm1(-dt / p.tau_mag_s),
            # The low-pass's start-up running mean hands over at the rate of a first-order filter of its delay.
            k_lp=-math.expm1(-dt / p.tau_acc_lp_s),
            k_min=-math.expm1(-dt / max(taus)),
            k_ncf=-math.expm1(-dt / p.tau_ncf_s),
            lp_a=1.0 - lp[0],
            lp12=lp[1],
            lp21=lp[2],
            lp22=lp[3],
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
            # A field sample's heading variance for the re-acquisition gain, rad²: heading_sigma² once per tau_mag_s
            # (its errors are the field's, correlated over the blend's memory, not per sample).
            r_head=p.heading_sigma_rad**2 * p.tau_mag_s / dt,
            k_band1=-math.expm1(-dt / MAG_BAND_S[0]),
            k_band2=-math.expm1(-dt / MAG_BAND_S[1]),
            k_score=-math.expm1(-dt / MAG_SCORE_S),
            sigma_init=p.bias_sigma_init_rad_s,
            var_arw=p.gyro_arw_rad_sqrt_s**2 * dt,
            # (A float compare against inf is all a gyro without a known range costs.)
            clip=0.998 * p.gyro_range_rad_s if p.gyro_range_rad_s > 0.0 else math.inf,
            var_clip=(p.gyro_range_rad_s * dt) ** 2,
        )


@dataclass(frozen=True, slots=True)
class _BlockCoefficients:
    """Constants of one NCF bias update for block spans in ``[t_lo, t_hi]`` (s), computed at the bin's middle (see
    :meth:`QuaternionCcf._ncf_update`)."""

    t_lo: float
    t_hi: float
    m_a: float
    m12: float
    m21: float
    m22: float
    k_ncf: float
    inv_tau_ncf: float
    r_tilt: float
    inv_rot2: float
    walk: float
    p_init: float
    p_rest: float
    keep_rest: float
    gate_tilt: float
    gate_head: float
    gate_p: float
    k_band1: float
    k_band2: float
    k_score: float
    wander_var: float
    drift_var: float

    @classmethod
    def of(cls, p: CcfParams, key: int) -> _BlockCoefficients:
        """The constants of bin ``key`` of block spans (:func:`_bin`)."""
        t_lo, t, t_hi = _bin_range(key)
        m = butterworth_step(p.tau_acc_lp_s, t)
        w = p.bias_walk_rad_s_sqrt_s
        return cls(
            t_lo=t_lo,
            t_hi=t_hi,
            m_a=1.0 - m[0],
            m12=m[1],
            m21=m[2],
            m22=m[3],
            k_ncf=-math.expm1(-t / p.tau_ncf_s),
            inv_tau_ncf=1.0 / p.tau_ncf_s,
            # Variance of one block's tilt observation, (rad/s)²: the noise density (walk tau_bias)² over the block.
            r_tilt=(w * p.tau_bias_s) ** 2 / t,
            inv_rot2=1.0 / p.bias_rotation_rad_s**2,
            walk=w * w * t,
            p_init=p.bias_sigma_init_rad_s**2,
            p_rest=p.bias_sigma_rest_rad_s**2,
            keep_rest=math.exp(-t / p.rest_tau_s),
            # The gate's floors, (rad/s)²: the rate at which the attitude references' own errors would show as drift
            # through the NCF.
            gate_tilt=(p.incl_sigma_rad / p.tau_ncf_s) ** 2,
            gate_head=(p.heading_sigma_rad / p.tau_ncf_s) ** 2,
            # The gate holds once the bias's variance along the observation is below a quarter of the initial one.
            gate_p=0.25 * p.bias_sigma_init_rad_s**2,
            k_band1=-math.expm1(-t / MAG_BAND_S[0]),
            k_band2=-math.expm1(-t / MAG_BAND_S[1]),
            k_score=-math.expm1(-t / MAG_SCORE_S),
            # Hysteresis: inconsistent above the threshold, consistent again below half of it (squared, unit vectors'
            # chord ~ angle); a zero threshold switches the check off.
            # The band-passed wander of a homogeneous field's direction seen through a moving attitude (half the
            # threshold, squared; inf: the check is off) ...
            wander_var=(0.5 * p.mag_consistency_rad) ** 2 if p.mag_consistency_rad > 0.0 else math.inf,
            # ... plus the attitude's drift from a bias error of bias_sigma_init over the band-pass's long time
            # constant (a ramp of rate r shows as r * MAG_BAND_S[1]), scaled by the bias's relative variance.
            drift_var=(2.0 * p.bias_sigma_init_rad_s * MAG_BAND_S[1]) ** 2,
        )


def _bin(dt: float) -> int:
    """The 0.1 % bin of time spans (s, > 0: a sample period, a bias-update block) that holds ``dt``.

    Stamps jitter: float stamps near 1.7e9 s resolve 0.24 µs (dt wobbles by ~1e-4 relative), a driver that stamps on
    arrival by far more. Gains are taken at the bin's middle (a 0.05 % change of a blend gain is immaterial; the
    integration uses the exact dt), so a stream costs as many computations of them as it visits bins, not one per
    sample or block.
    """
    return round(math.log(dt) * 1000.0)


def _bin_range(key: int) -> tuple[float, float, float]:
    """Lower edge, middle and upper edge of bin ``key`` (:func:`_bin`), s."""
    return math.exp((key - 0.5) / 1000.0), math.exp(key / 1000.0), math.exp((key + 0.5) / 1000.0)


_C = TypeVar('_C')


def _cached(cache: dict[int, _C], span_s: float, make: Callable[[int], _C]) -> _C:
    """``make(bin)`` for the bin of ``span_s`` (s), from ``cache`` (kept to 256 bins: jitter or rate changes without
    end must not grow it)."""
    key = _bin(span_s)
    c = cache.get(key)
    if c is None:
        if len(cache) >= 256:
            cache.clear()
        c = cache[key] = make(key)
    return c


def _drift(var: float, bias_step: float, var_arw: float) -> float:
    """Drift variance (rad²) after one uncorrected step: the bias error adds linearly to the error's standard
    deviation (``bias_step`` = bias uncertainty x dt, rad), the gyro noise adds ``var_arw`` (rad²)."""
    return var + var_arw + bias_step * (bias_step + 2.0 * sqrt(var))


def tilt_transfer(p: CcfParams, f_hz: complex | float) -> tuple[complex, complex]:
    """Small-angle transfer functions of one tilt axis at ``f_hz``: ``(H_a, H_w)`` from the accelerometer angle
    (rad/rad) and from the measured rate (rad per rad/s) to the output, with the NCF's bias gain at its steady state
    in continuous motion (:attr:`CcfParams.bias_gain_per_s`); see the module docstring."""
    s = 2j * cmath.pi * f_hz
    wn = math.sqrt(2.0) / p.tau_acc_lp_s
    b = wn * wn / (s * s + math.sqrt(2.0) * wn * s + wn * wn)
    kn, ka, g = 1.0 / p.tau_ncf_s, 1.0 / p.tau_acc_s, p.bias_gain_per_s
    f = g * b * kn / ((s + kn) * (s + g))
    lcf = s + ka * (1.0 - b)
    return (f * lcf + ka * b) / (s + ka), (1.0 - f) * lcf / (s * (s + ka))


class QuaternionCcf(OrientationFilter):
    """NCF -> LCF cascade on unit quaternions; see the module docstring.

    State (all reset by :meth:`reset`): LCF orientation ``q``, gyro bias (rad/s, body) and its covariance ``P``
    (rad²/s², 3x3), filtered gravity ``g_lp`` (m/s², body) and its rate, NCF attitude offset ``dn`` (rad, world
    frame), the NCF observation model's low-pass states, rest-detector low-pass and timer, magnetometer reference
    (with its learning window) and new-field candidate, drift variances (rad²).
    """

    name = 'ccf'
    __slots__ = (
        '_acc_lp',
        '_bcoef',
        '_bcoef_cache',
        '_bias_rested',
        '_coef',
        '_coef_cache',
        '_gyro_lp',
        '_heading_known',
        '_mag_band',
        '_mag_band_t',
        '_mag_bounds',
        '_mag_candidate',
        '_mag_consistent',
        '_mag_have_ref',
        '_mag_learn_n',
        '_mag_learn_s',
        '_mag_new_s',
        '_mag_ref',
        '_mag_rejected_t',
        '_mag_weight',
        '_model',
        '_n_init',
        '_p_bias',
        '_rest_s',
        '_u_bias',
        '_var_head',
        '_var_incl',
        '_x',
        'n_gyro_clipped',
    )
    params: CcfParams

    def __init__(self, params: CcfParams | None = None) -> None:
        super().__init__(params if params is not None else CcfParams())

    def _reset_state(self) -> None:
        # The per-sample state in one tuple (one load and one store per sample): the gyro bias b (rad/s, body), the
        # filtered gravity g_lp (m/s², body), the NCF's offset dn (rad, world) and g_lp's rate (m/s³, body), 3
        # values each; then, for the NCF bias update's current block, the NCF heading errors summed (rad) and how
        # many, the time it spans (s) and its samples; the block's magnetometer samples in world coordinates summed
        # (east, north, up, in the sensor's unit), how many, and the heading corrections applied meanwhile (rad).
        self._x = (0.0, 0.0, 0.0, 0.0, 0.0, GRAVITY_M_S2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0.0, 0,
                   0.0, 0.0, 0.0, 0, 0.0, 0.0, 0.0)
        self._coef_cache: dict[int, _Coefficients] = {}
        self._bcoef_cache: dict[int, _BlockCoefficients] = {}
        self._coef = self._coefficients(0.01)
        self._bcoef = self._block_coefficients(BIAS_UPDATE_PERIOD_S)
        self._gyro_lp = (0.0, 0.0, 0.0)
        self._acc_lp = (0.0, 0.0, 0.0)
        self._rest_s = 0.0
        self._n_init = 0
        self._forget_mag_reference()
        self._var_incl = 0.0
        self._var_head = 0.0
        self._heading_known = False
        # Bias covariance (p00, p01, p02, p11, p12, p22), rad²/s²: nothing learnt yet.
        p0 = self.params.bias_sigma_init_rad_s**2
        self._p_bias = (p0, 0.0, 0.0, p0, 0.0, p0)
        # Mean bias variance relative to bias_sigma_init² (for the drift variances): 1 = nothing learnt yet.
        self._u_bias = 1.0
        # Whether the bias was seen at rest since the start (then a steady rate must agree with it to be a rest).
        self._bias_rested = False
        #: Gyro samples at gyro_range_rad_s since the start.
        self.n_gyro_clipped = 0
        # The NCF observation model's low-pass states (None: seed at the next bias update).
        self._model: tuple[tuple[float, ...], ...] | None = None

    def _forget_mag_reference(self) -> None:
        """No reference field: the next usable magnetometer sample becomes it (see :meth:`_mag_rejected`)."""
        self._mag_ref = (0.0, 0.0)
        # Bounds that accept nothing, so that the first sample goes through _mag_rejected and sets the reference.
        self._mag_bounds = (math.inf, -math.inf, 2.0, -2.0)
        self._mag_candidate = (0.0, 0.0, 0.0, 0.0, (0.0,) * 7)
        self._mag_have_ref = False
        self._mag_new_s = 0.0
        self._mag_rejected_t = -math.inf
        self._mag_learn_s = 0.0
        self._mag_learn_n = 0
        self.mag_disturbed = False
        # The field's world direction band-passed (two unit-vector low-passes and the squared deviation's low-pass;
        # None: seeded by the next block), and the verdict.
        self._mag_band: tuple[float, ...] | None = None
        self._mag_band_t = -math.inf
        self._mag_consistent = True
        # The heading blend's gain relative to tau_mag_s's (1: the field is as steady as a homogeneous one).
        self._mag_weight = 1.0

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
        self._mag_candidate = (0.0, 0.0, 0.0, 0.0, (0.0,) * 7)

    def _coefficients(self, dt: float) -> _Coefficients:
        """The per-sample coefficients for a sample period of ``dt`` s (> 0)."""
        return _cached(self._coef_cache, dt, lambda key: _Coefficients.of(self.params, key))

    def _block_coefficients(self, t: float) -> _BlockCoefficients:
        """The bias update's constants for a block spanning ``t`` s (> 0)."""
        return _cached(self._bcoef_cache, t, lambda key: _BlockCoefficients.of(self.params, key))

    def _params_changed(self) -> None:
        self._coef_cache = {}
        self._bcoef_cache = {}
        # The bins' middles: the same bins as before the change.
        self._coef = self._coefficients(math.sqrt(self._coef.dt_lo * self._coef.dt_hi))
        self._bcoef = self._block_coefficients(math.sqrt(self._bcoef.t_lo * self._bcoef.t_hi))
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
        self._x = (*bias, ax, ay, az, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0.0, 0, 0.0, 0.0, 0.0, 0, 0.0, 0.0, 0.0)
        self._gyro_lp = bias
        self._rest_s = 0.0
        self.at_rest = False
        self._var_incl = 0.0
        # The bias and its covariance are kept; the observation model starts from the new attitude.
        self._model = None
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
            c = self._coef = self._coefficients(dt)
        clip = c.clip
        if gx >= clip or gx <= -clip or gy >= clip or gy <= -clip or gz >= clip or gz <= -clip:
            self._gyro_clipped(c.var_clip)
        qw, qx, qy, qz = self._q
        (bx, by, bz, fx, fy, fz, dnx, dny, dnz, fdx, fdy, fdz, h_sum, h_n, blk_t, blk_n,
         we, wn, wu, w_n, scx, scy, scz) = self._x
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
            # The low-pass starts as a running mean too (0.0: the Butterworth filter has taken over).
            k_lp = kn if kn > c.k_lp else 0.0
            self._n_init = ni if kn > c.k_min else 0
        else:
            k_acc = c.k_acc
            k_mag = c.k_mag
            k_lp = 0.0
        cx = k_acc * ex
        cy = k_acc * ey
        cz = k_acc * ez
        # NCF tilt error: its attitude is exp(dn) ⊗ q (dn: a small world-frame rotation), so its tilt error is e
        # minus the horizontal part of dn seen in the body frame.
        nx = ex - dnx * r0x - dny * r1x
        ny = ey - dnx * r0y - dny * r1y
        nz = ez - dnx * r0z - dny * r1z
        hn = kd = kdn = 0.0
        if mag_n2:
            # The sample is a mean over the step, like the accelerometer's: the field in the frame of mid-interval.
            # The attitude here is the step's start, so carry it back half the gyro step, m' = m + p x m.
            px = (gx - bx) * 0.5 * dt
            py = (gy - by) * 0.5 * dt
            pz = (gz - bz) * 0.5 * dt
            mx, my, mz = mx + (py * mz - pz * my), my + (pz * mx - px * mz), mz + (px * my - py * mx)
            # The field in world coordinates through the attitude: east, north, up.
            me = r0x * mx + r0y * my + r0z * mz
            mn = r1x * mx + r1y * my + r1z * mz
            mu = vx * mx + vy * my + vz * mz
            norm = sqrt(mag_n2)
            sin_dip = mu / norm
            lo2, hi2, lo_dip, hi_dip = self._mag_bounds
            # Whether the field stays put in the world is judged per block on every sample, those the norm and dip
            # gate rejects too: a field that turns as the sensor moves must not look new (and steady) each time it
            # passes the gate again somewhere else.
            we += me
            wn += mn
            wu += mu
            w_n += 1
            if (lo2 <= mag_n2 <= hi2 and lo_dip <= sin_dip <= hi_dip) or self._mag_rejected(
                dt, norm, sin_dip, me, mn, mu, gx - bx, gy - by, gz - bz
            ):
                mag_ok = self._mag_consistent
            else:
                mag_ok = False
            if mag_ok:
                if self.mag_disturbed:
                    self.mag_disturbed = False
                # Horizontal field in the world frame must point to +y (north in ENU). The correction is a rotation
                # about world up (v in body coordinates): heading only, never tilt.
                d = atan2(me, mn)
                kh = k_mag * self._mag_weight
                # The blend's own share of the correction: the NCF's heading moves with the rest (below).
                kdn = kh * d
                vh = self._var_head
                if vh:
                    # The heading has drifted (or was re-set by a new field) since it was last corrected: the blend
                    # takes a field sample with the Kalman gain of that uncertainty against the field's own
                    # (heading_sigma² per tau_mag_s of samples), so that it re-acquires within a second, not tau_mag_s.
                    kv = vh / (vh + c.r_head)
                    if kv > kh:
                        kh = kv
                        vh *= 1.0 - kv
                    else:
                        vh *= c.keep_head
                    # Exactly zero again once negligible, so the common path skips this.
                    self._var_head = vh if vh > 1e-14 else 0.0
                    self._heading_known = True
                kd = kh * d
                # NCF heading error (its heading is the LCF's turned by dnz about world up). Its own heading takes
                # all of it; the bias estimate only what is within ±_HEAD_ERR_MAX while the two stages' headings
                # agree within it too. A larger error, or a larger dnz, means the heading has not converged yet (a
                # start, a new field: the NCF turns faster than the LCF), and the decay would look like bias.
                hn = d - dnz
                if hn > _PI:  # the NCF's heading takes all of it: the short way round
                    hn -= _TWO_PI
                elif hn < -_PI:
                    hn += _TWO_PI
                if hn * hn < _HEAD_ERR_MAX2 and dnz * dnz < _HEAD_ERR_MAX2:
                    h_sum += hn
                    h_n += 1
                cx += kd * vx
                cy += kd * vy
                cz += kd * vz
            else:
                self.mag_disturbed = True
                self._var_head = _drift(self._var_head, c.sigma_init * sqrt(self._u_bias) * dt, c.var_arw)
        else:
            self._var_head = _drift(self._var_head, c.sigma_init * sqrt(self._u_bias) * dt, c.var_arw)
        if acc_n2:
            vi = self._var_incl
            if vi:
                self._var_incl = vi * c.keep_incl if vi > 1e-14 else 0.0
        else:
            self._var_incl = _drift(self._var_incl, c.sigma_init * sqrt(self._u_bias) * dt, c.var_arw)
        # NCF integral: a Kalman update of the bias once the block of samples spans BIAS_UPDATE_PERIOD_S.
        blk_t += dt
        blk_n += 1
        # The LCF's corrections this block (rad, body): they turn the field seen through the attitude.
        scx += cx
        scy += cy
        scz += cz
        if blk_t >= _BLOCK_DUE_S:
            bx, by, bz = self._ncf_update(
                blk_t, blk_n, bx, by, bz, r0x, r0y, r0z, r1x, r1y, r1z, vx, vy, vz, nx, ny, nz, h_sum, h_n,
                gx * gx + gy * gy + gz * gz,
                # Not during the start-up (ni): the errors then are the initial attitude's, not the bias's; not at
                # rest, where the low-passed gyro below is far more informative; not without an accelerometer.
                not (ni or self.at_rest) and acc_n2 != 0.0,
            )
            if w_n and not ni:  # (not during the start-up: the attitude itself is still being found)
                self._mag_consistency(
                    we, wn, wu,
                    r0x * scx + r0y * scy + r0z * scz, r1x * scx + r1y * scy + r1z * scz, vx * scx + vy * scy + vz * scz,
                )
            blk_t = h_sum = we = wn = wu = scx = scy = scz = 0.0
            blk_n = h_n = w_n = 0
        if c.rest_bias and acc_n2:
            # Rest: the accelerometer within rest_acc_m_s2 of its own low-pass in the body (tested first: it fails
            # first while moving; not the gravity the gyro carries, which an unknown offset of several °/s turns
            # away while the IMU lies still), and the gyro within rest_gyro_rad_s of its low-pass. A sample without
            # a usable accelerometer neither extends nor ends a rest (one corrupted message in a hundred would
            # otherwise never let a rest last rest_min_s).
            if self._rest_s:
                alx, aly, alz = self._acc_lp
            else:
                alx, aly, alz = ax, ay, az
            dax = ax - alx
            day = ay - aly
            daz = az - alz
            # A motion hint saying "moving" (odometry) rules rest out: a slow steady turn is not learnt as bias.
            if dax * dax + day * day + daz * daz < c.rest_acc2 and self.still_hint is not False:
                k = c.k_rest
                self._acc_lp = (alx + k * dax, aly + k * day, alz + k * daz)
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
                    if rest_s >= c.rest_min_s and self._rest_agrees(glx - bx, gly - by, glz - bz):
                        # At rest the low-passed gyro *is* the bias: pull the estimate there (its covariance relaxes
                        # to bias_sigma_rest² in _ncf_update).
                        self.at_rest = True
                        bx += k * (glx - bx)
                        by += k * (gly - by)
                        bz += k * (glz - bz)
                    elif self.at_rest:
                        # Steady, but no longer at the bias seen: a slow turn began.
                        self.at_rest = False
                elif self._rest_s:
                    self._rest_s = 0.0
                    self._end_rest()
            elif self._rest_s:
                self._rest_s = 0.0
                self._end_rest()
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
        # g_lp and its rate into the new body frame, v' = R(p)^T v = v - 2 cw (p x v) + 2 p x (p x v).
        tx = 2.0 * (fy * pz - fz * py)
        ty = 2.0 * (fz * px - fx * pz)
        tz = 2.0 * (fx * py - fy * px)
        fx += cw * tx + (ty * pz - tz * py)
        fy += cw * ty + (tz * px - tx * pz)
        fz += cw * tz + (tx * py - ty * px)
        tx = 2.0 * (fdy * pz - fdz * py)
        ty = 2.0 * (fdz * px - fdx * pz)
        tz = 2.0 * (fdx * py - fdy * px)
        fdx += cw * tx + (ty * pz - tz * py)
        fdy += cw * ty + (tz * px - tx * pz)
        fdz += cw * tz + (tx * py - ty * px)
        if acc_n2:
            # The sample is a mean over the step (gravity in the frame of mid-interval): carry it the half step to
            # the step's end, v' = v - p x v (p = r/2 to ~1e-5), then filter it in.
            ax, ay, az = ax - (py * az - pz * ay), ay - (pz * ax - px * az), az - (px * ay - py * ax)
            if k_lp:
                # Start-up: a running mean, no rate yet.
                fx += k_lp * (ax - fx)
                fy += k_lp * (ay - fy)
                fz += k_lp * (az - fz)
                fdx = fdy = fdz = 0.0
            else:
                # Butterworth low-pass, exact for a sample held over the step.
                a, p12, p21, p22 = c.lp_a, c.lp12, c.lp21, c.lp22
                ax = fx - ax
                ay = fy - ay
                az = fz - az
                fx += p12 * fdx - a * ax
                fy += p12 * fdy - a * ay
                fz += p12 * fdz - a * az
                fdx = p21 * ax + p22 * fdx
                fdy = p21 * ay + p22 * fdy
                fdz = p21 * az + p22 * fdz
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
            # (A re-acquisition's share, kd - kdn, turns both stages: it is no drift of the NCF's.)
            dnz + k * hn - kdn,
            fdx, fdy, fdz, h_sum, h_n, blk_t, blk_n, we, wn, wu, w_n, scx, scy, scz,
        )

    def _ncf_update(  # the arguments are the step's locals: one call per block, no attribute traffic
        self,
        t: float,
        n: int,
        bx: float,
        by: float,
        bz: float,
        r0x: float,
        r0y: float,
        r0z: float,
        r1x: float,
        r1y: float,
        r1z: float,
        vx: float,
        vy: float,
        vz: float,
        nx: float,
        ny: float,
        nz: float,
        h_sum: float,
        h_n: int,
        w2: float,
        learn: bool,
    ) -> tuple[float, float, float]:
        """The NCF's bias estimate, once per block of ``n`` samples spanning ``t`` s: returns the new bias (rad/s,
        body).

        Observations: the NCF's tilt error (rad, body; ``nx, ny, nz``) seen in the world frame (east, north) and,
        with a usable magnetometer, its heading error (the mean of the block's ``h_n`` samples that qualified,
        summing to ``h_sum`` rad: a magnetometer sample's heading is noisy, the tilt error is low-passed), times
        ``1/tau_ncf_s``: the rate (rad/s) at which the gyro's attitude drifts from gravity and north. A bias error
        ``db`` (body) shows there as ``M(R db)``, ``M`` the low-passes it passed (Butterworth then NCF for tilt, NCF
        alone for heading), ``R`` the body->world rows ``r0, r1, v``. The model runs the same low-passes on ``R`` and
        on ``R b`` (the estimate's own history), so the innovation is ``y + M(R b) - M(R) b``, and ``M(R)`` is the
        measurement matrix of a Kalman update, one scalar row at a time. ``w2``: the squared gyro rate, rad²/s².
        """
        c = self._bcoef
        if not c.t_lo <= t <= c.t_hi:
            c = self._bcoef = self._block_coefficients(t)
        rb0 = r0x * bx + r0y * by + r0z * bz
        rb1 = r1x * bx + r1y * by + r1z * bz
        rbv = vx * bx + vy * by + vz * bz
        model = self._model
        if model is None:
            # Seed at a standstill of the low-passes: the Butterworth values (and zero rates) of the tilt
            # quantities, the NCF outputs of the tilt quantities, and those of the heading ones.
            tilt = (r0x, r0y, r0z, r1x, r1y, r1z, rb0, rb1)
            model = self._model = (tilt, (0.0,) * 8, tilt, (vx, vy, vz, rbv))
        else:
            # Unrolled (this runs at 25 Hz, and a loop costs half again as much): Butterworth, then NCF low-pass,
            # of the tilt quantities u; NCF low-pass of the heading ones.
            (v0, v1, v2, v3, v4, v5, v6, v7), (d0, d1, d2, d3, d4, d5, d6, d7), mt, mh = model
            a, m12, m21, m22, k = c.m_a, c.m12, c.m21, c.m22, c.k_ncf
            e0, e1, e2, e3 = v0 - r0x, v1 - r0y, v2 - r0z, v3 - r1x
            e4, e5, e6, e7 = v4 - r1y, v5 - r1z, v6 - rb0, v7 - rb1
            v0 += m12 * d0 - a * e0
            v1 += m12 * d1 - a * e1
            v2 += m12 * d2 - a * e2
            v3 += m12 * d3 - a * e3
            v4 += m12 * d4 - a * e4
            v5 += m12 * d5 - a * e5
            v6 += m12 * d6 - a * e6
            v7 += m12 * d7 - a * e7
            o0, o1, o2, o3, o4, o5, o6, o7 = mt
            h0, h1, h2, h3 = mh
            model = self._model = (
                (v0, v1, v2, v3, v4, v5, v6, v7),
                (m21 * e0 + m22 * d0, m21 * e1 + m22 * d1, m21 * e2 + m22 * d2, m21 * e3 + m22 * d3,
                 m21 * e4 + m22 * d4, m21 * e5 + m22 * d5, m21 * e6 + m22 * d6, m21 * e7 + m22 * d7),
                (o0 + k * (v0 - o0), o1 + k * (v1 - o1), o2 + k * (v2 - o2), o3 + k * (v3 - o3),
                 o4 + k * (v4 - o4), o5 + k * (v5 - o5), o6 + k * (v6 - o6), o7 + k * (v7 - o7)),
                (h0 + k * (vx - h0), h1 + k * (vy - h1), h2 + k * (vz - h2), h3 + k * (rbv - h3)),
            )
        p00, p01, p02, p11, p12, p22 = self._p_bias
        if learn and self.params.motion_bias:
            # Observation noise: (walk tau_bias)² per block, growing with the rotation rate; heading's over cos²(dip).
            r = c.r_tilt * (1.0 + w2 * c.inv_rot2)
            k = -c.inv_tau_ncf
            y0 = k * (r0x * nx + r0y * ny + r0z * nz)
            y1 = k * (r1x * nx + r1y * ny + r1z * nz)
            mt, mh = model[2], model[3]
            # (the row's M(R), its M(R b), the observation, its variance, the gate's noise floor)
            rows = [(mt[0], mt[1], mt[2], mt[6], y0, r, c.gate_tilt), (mt[3], mt[4], mt[5], mt[7], y1, r, c.gate_tilt)]
            if h_n:
                # The block's mean heading error; its variance grows as fewer of the block's samples qualified.
                sd = self._mag_ref[1]
                wgt = self._mag_weight
                rows.append((*mh, k * h_sum / h_n, r * n / (h_n * wgt * wgt * max(1.0 - sd * sd, _COS2_DIP_MIN)),
                             c.gate_head))
            for h0, h1, h2, hb, y, ri, floor2 in rows:
                nu = y + hb - (h0 * bx + h1 * by + h2 * bz)
                ph0 = p00 * h0 + p01 * h1 + p02 * h2
                ph1 = p01 * h0 + p11 * h1 + p12 * h2
                ph2 = p02 * h0 + p12 * h1 + p22 * h2
                hph = h0 * ph0 + h1 * ph1 + h2 * ph2
                if nu * nu > _GATE2 * (hph + floor2) and hph < c.gate_p:
                    # More drift than the bias's uncertainty and the accelerometer's (magnetometer's) own error
                    # explain: a linear acceleration that lasts (a vehicle drives off, brakes, turns), a shock. It is
                    # no information about the bias, once the bias is roughly known (before, a bias beyond the
                    # initial uncertainty, a cheap gyro's 2°/s, must still be learnt).
                    continue
                si = 1.0 / (hph + ri)
                k0, k1, k2 = ph0 * si, ph1 * si, ph2 * si
                bx += k0 * nu
                by += k1 * nu
                bz += k2 * nu
                p00 -= k0 * ph0
                p01 -= k0 * ph1
                p02 -= k0 * ph2
                p11 -= k1 * ph1
                p12 -= k1 * ph2
                p22 -= k2 * ph2
        if self.at_rest:
            # At rest the covariance relaxes to bias_sigma_rest² (the low-passed gyro's own uncertainty).
            kr = c.keep_rest
            pr = (1.0 - kr) * c.p_rest
            p00, p11, p22 = p00 * kr + pr, p11 * kr + pr, p22 * kr + pr
            p01 *= kr
            p02 *= kr
            p12 *= kr
        else:
            # The bias random walk: knowledge ages (up to knowing nothing).
            pi, w = c.p_init, c.walk
            if p00 < pi:
                p00 += w
            if p11 < pi:
                p11 += w
            if p22 < pi:
                p22 += w
        # A variance cannot be negative; rounding after an update from far more information than the prior (an
        # extreme bias_sigma_init_rad_s) could leave it so.
        p00 = p00 if p00 > 0.0 else 0.0
        p11 = p11 if p11 > 0.0 else 0.0
        p22 = p22 if p22 > 0.0 else 0.0
        self._p_bias = (p00, p01, p02, p11, p12, p22)
        self._u_bias = (p00 + p11 + p22) / (3.0 * c.p_init)
        return bx, by, bz

    def _gyro_clipped(self, var_clip: float) -> None:
        """A gyro sample at its range: the attitude may be off by up to the range times the step (rad, squared:
        ``var_clip``). Restart the accelerometer's and magnetometer's blends and the gravity low-pass as running
        means from the next sample on, as at start-up (no bias learnt meanwhile), so that they bring the attitude
        back fast; x-io Fusion's angular-rate recovery does the same with a fixed gain."""
        self.n_gyro_clipped += 1
        self._n_init = 1
        self._var_incl += var_clip
        self._var_head += var_clip

    def _end_rest(self) -> None:
        """Motion again. (Whether the bias counts as seen is decided in :meth:`_rest_agrees`, once the estimate
        converged on a rest: a rest too short for that must not lock a half-learnt offset in.)"""
        self.at_rest = False

    def _rest_agrees(self, ex: float, ey: float, ez: float) -> bool:
        """Whether a steady gyro (low-passed minus the bias estimate: ``ex, ey, ez``, rad/s) may be taken for rest.

        A bias does not jump; a rotation does begin. Before the bias was first seen at rest any steady rate within
        ``bias_max_rad_s`` is a bias (a consumer MEMS gyro's offset can be 10°/s); afterwards a steady rate beyond
        what the estimate's uncertainty and a bias's instability between rests (:data:`REST_BIAS_TOL_RAD_S`)
        explain is a slow turn (a tracked robot turning in place), unless it lasts :data:`REST_RELEARN_S`.
        """
        if self.still_hint:
            return True  # odometry says the robot stands still: a steady rate is the bias, whatever it was
        e2 = ex * ex + ey * ey + ez * ez
        if not self._bias_rested:
            # The first rest: once the estimate has converged on it (within the tolerance, two time constants in),
            # it was seen.
            p = self.params
            if e2 < _REST_TOL2 and self._rest_s >= p.rest_min_s + 2.0 * p.rest_tau_s:
                self._bias_rested = True
                bx, by, bz = self._x[:3]
                if bx * bx + by * by + bz * bz > 9.0 * p.bias_sigma_init_rad_s**2:
                    # An offset far beyond the prior (a consumer MEMS gyro): the attitude's blends have averaged
                    # samples carried by the wrong rate since the start. Start them again, now that the rate is right.
                    # The reference field's dip was measured through that attitude too.
                    self._n_init = 1
                    self._forget_mag_reference()
            return True
        p00, _, _, p11, _, p22 = self._p_bias
        return e2 < _REST_TOL2 + 9.0 * (p00 + p11 + p22) or self._rest_s >= REST_RELEARN_S

    def _mag_consistency(self, we: float, wn: float, wu: float, ce: float, cn: float, cu: float) -> None:
        """Whether the field stays put in the world, once per block of ``t`` s: its samples summed in world
        coordinates through the attitude (``we, wn, wu``: east, north, up, sensor unit), and the heading corrections
        the LCF applied meanwhile (``ce, cn, cu``: a rotation vector in world coordinates, rad; they turn the attitude,
        and so the field seen through it).

        A homogeneous field keeps its world direction however the body turns; the attitude carried by the gyro is
        good to about a degree over seconds. A field that varies with position (a structure near the workspace, a
        magnet passed by), one carried by the body (a magnet or motor on it: it turns with the body) or one that
        changes in time moves. The direction's band-pass between ``MAG_BAND_S`` (its deviation RMS over
        ``MAG_SCORE_S``) against ``mag_consistency_rad`` (with hysteresis: half of it to become consistent again)
        decides whether the field may steer heading (and the bias estimate) at all; agreement of norm and dip with
        a reference cannot see a field that turns.
        """
        c = self._bcoef
        n = sqrt(we * we + wn * wn + wu * wu)
        if not n:
            return
        ue, un, uu = we / n, wn / n, wu / n
        band = self._mag_band
        t_now = self._t_last
        gap = t_now - self._mag_band_t > MAG_BAND_S[0]
        self._mag_band_t = t_now
        if band is None or gap:
            # First, or after the field was rejected for a while (the gyro drifted meanwhile): the direction's
            # filters start again from here; the wander score keeps its memory.
            self._mag_band = (ue, un, uu, ue, un, uu, 0.0 if band is None else band[6])
            return
        ae, an, au, be, bn, bu, s2 = band
        # The LCF's corrections turned the field seen through the attitude by (ce, cn, cu): turn the filters' states
        # with them (first order), so that only the field's own motion shows.
        ae, an, au = ae + (cn * au - cu * an), an + (cu * ae - ce * au), au + (ce * an - cn * ae)
        be, bn, bu = be + (cn * bu - cu * bn), bn + (cu * be - ce * bu), bu + (ce * bn - cn * be)
        k1, k2 = c.k_band1, c.k_band2
        ae += k1 * (ue - ae)
        an += k1 * (un - an)
        au += k1 * (uu - au)
        be += k2 * (ae - be)
        bn += k2 * (an - bn)
        bu += k2 * (au - bu)
        de, dn_, du = ae - be, an - bn, au - bu
        s2 += c.k_score * (de * de + dn_ * dn_ + du * du - s2)
        self._mag_band = (ae, an, au, be, bn, bu, s2)
        # The heading reference is as noisy as the field wanders: the blend's time constant (and the bias estimate's
        # heading noise) grows with the wander beyond a homogeneous field's, which includes the drift an unknown
        # bias gives the attitude.
        r2 = s2 / (c.wander_var + c.drift_var * self._u_bias)
        self._mag_weight = 1.0 / sqrt(r2) if r2 > 1.0 else 1.0
        if self._mag_consistent:
            if r2 > _REJECT2:
                self._mag_consistent = False
        elif r2 < 0.25 * _REJECT2:
            self._mag_consistent = True

    def _mag_rejected(self, dt: float, norm: float, sin_dip: float, me: float, mn: float, mu: float, wx: float,
                      wy: float, wz: float) -> bool:
        """Book-keeping for a magnetometer sample outside the acceptance bounds (rare path).

        Returns True if the sample is to be used after all: it began the reference (first usable sample after a
        (re)initialisation), the reference is being learnt (the ``mag_ref_learn_s`` after that), or a new field
        stayed steady long enough, and put in the world while the body turned by :data:`NEW_FIELD_TURN_RAD`, to
        become the reference. ``me, mn, mu``: the sample in world coordinates (east, north, up) through the attitude;
        ``wx, wy, wz``: the bias-corrected rate, rad/s.
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
        # n: a float count (0.0: no candidate yet); turn: rad turned while timed; band: the candidate's world
        # direction band-passed as in _mag_consistency (sample by sample here: no heading corrections meanwhile).
        cn, cs, n, turn, band = self._mag_candidate
        p = self.params
        c = self._coef
        t = self._t_last
        timer = self._mag_new_s - _LEAK * (t - self._mag_rejected_t - dt)
        self._mag_rejected_t = t
        if n and abs(norm - cn) <= p.mag_norm_tol * cn and abs(sin_dip - cs) <= p.mag_dip_tol_rad * sqrt(
            max(1.0 - cs * cs, 1e-6)
        ):
            n += 1.0
            cn += (norm - cn) / n
            cs += (sin_dip - cs) / n
            ae, an, au, be, bn, bu, s2 = band
            k1, k2 = c.k_band1, c.k_band2
            ae += k1 * (me / norm - ae)
            an += k1 * (mn / norm - an)
            au += k1 * (mu / norm - au)
            be += k2 * (ae - be)
            bn += k2 * (an - bn)
            bu += k2 * (au - bu)
            de, dn_, du = ae - be, an - bn, au - bu
            s2 += c.k_score * (de * de + dn_ * dn_ + du * du - s2)
            band = (ae, an, au, be, bn, bu, s2)
            # Timed only while the field stays put in the world (a candidate that moves is no new normal).
            bc = self._bcoef
            if s2 < 0.25 * _REJECT2 * (bc.wander_var + bc.drift_var * self._u_bias):
                timer += dt
                turn += sqrt(wx * wx + wy * wy + wz * wz) * dt
            self._mag_candidate = (cn, cs, n, turn, band)
            if timer > p.mag_reaccept_s and turn >= NEW_FIELD_TURN_RAD:
                # A different field that stayed steady this long is the new normal (moved robot, new mounting). Its
                # mean over the agreeing samples is the reference at once: no learning window, which would average
                # the outliers back in with the gate open.
                self._set_mag_reference(cn, cs, learn=False)
                # Its verdict carries over: it stayed put while timed.
                self._mag_band = band
                self._mag_band_t = t
                self._mag_consistent = True
                self._mag_weight = 1.0
                # The heading kept so far came from the old field (or the gyro since): it is re-acquired from the new
                # one, as at a start.
                self._var_head = max(self._var_head, (0.5 * math.pi) ** 2)
                return True
        else:
            timer -= _LEAK * dt
        if timer <= 0.0:
            # Not steady: start timing a new candidate field from this sample.
            u = (me / norm, mn / norm, mu / norm)
            self._mag_candidate = (norm, sin_dip, 1.0, 0.0, (*u, *u, 0.0))
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
        """1-σ uncertainty of :attr:`gyro_bias`, rad/s, the RMS over the axes of the NCF's covariance:
        ``bias_sigma_init_rad_s`` while nothing is known, ``bias_sigma_rest_rad_s`` after a rest, shrinking as the
        NCF learns and growing back with ``bias_walk_rad_s_sqrt_s`` (it scales the reported drift variance)."""
        return self.params.bias_sigma_init_rad_s * sqrt(self._u_bias)

    @property
    def ncf_quaternion(self) -> Quat:
        """The NCF stage's own attitude ``exp(dn) ⊗ q`` (internal ENU frame), ``(w, x, y, z)``."""
        qw, qx, qy, qz = self._q
        dx, dy, dz = (0.5 * v for v in self._x[6:9])
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

    def set_gyro_bias(self, bias_rad_s: tuple[float, float, float], sigma_rad_s: float) -> bool:
        """Set the bias state (rad/s, body) and its covariance to ``diag(sigma_rad_s²)`` (rad/s): the NCF refines it
        from there as from a rest of that quality. The orientation is kept."""
        bx, by, bz = (float(v) for v in bias_rad_s)
        p = float(sigma_rad_s) ** 2
        self._x = (bx, by, bz, *self._x[3:])
        if not self.initialized:
            self._gyro_lp = (bx, by, bz)  # the rest low-pass starts from it (as _init does from the bias)
        self._p_bias = (p, 0.0, 0.0, p, 0.0, p)
        self._u_bias = p / self.params.bias_sigma_init_rad_s**2
        # A prior only: a consumer MEMS gyro's turn-on bias moves by up to ~1°/s between runs, so the next rest
        # learns it afresh (see _rest_agrees).
        return True

    def magnetometer_changed(self) -> None:
        """The magnetometer's calibration changed (online hard iron applied): the disturbance gate's reference field
        is learnt anew from the next samples instead of rejecting the corrected field for ``mag_reaccept_s``."""
        if self.initialized:
            # (This also restarts the consistency check's band-pass: the field's world direction jumps with the
            # offset. Heading follows over tau_mag_s: snapping it to the first applied offsets, which are refined for
            # a while, measured worse.)
            self._forget_mag_reference()

    def _rotate_about_up(self, angle_rad: float) -> None:
        """:meth:`OrientationFilter.set_heading`'s turn: the LCF orientation and the NCF offset ``dn`` (world frame)
        turn together, so the cascade sees no step (body-frame state: bias, filtered gravity, unchanged)."""
        super()._rotate_about_up(angle_rad)
        c, s = math.cos(angle_rad), math.sin(angle_rad)
        x = self._x
        self._x = (*x[:6], c * x[6] - s * x[7], s * x[6] + c * x[7], *x[8:])
