"""Parameters of :class:`~ccf_ros.core.ccf.QuaternionCcf` and the cascade's fixed constants (SI units; the algorithm:
doc/algorithm.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..base import CommonParams, param

_DEG = math.pi / 180.0
#: Standard gravity, m/s² (REP-145 accelerometers read +g up at rest).
GRAVITY_M_S2 = 9.80665
#: The NCF's bias update runs once the samples since the last one span this long, s (every sample at 25 Hz and
#: below): the tilt observations are low-passed over seconds and the heading ones averaged over the block, so 25
#: updates a second lose nothing (BROAD's mean error moves by 0.005° between 50 and 25 Hz) and save most of the
#: matrix arithmetic.
BIAS_UPDATE_PERIOD_S = 0.04
#: The NCF's bias observations are used only within this many standard deviations of what the bias uncertainty and
#: the attitude references' own errors explain (BiasKalman.update's gate), and in a 6-D start-up only while the tilt
#: error is within this many of the prior's (``_BlockCoefficients.start_tilt2``).
BIAS_GATE_SIGMAS = 3.0
#: The field's world direction (through the attitude) is band-passed between these time constants, s, to tell a
#: field that stays put from one that changes as the sensor moves (see MagGate._mag_consistency): the first
#: averages the magnetometer's noise and the wobble its lag gives during hand motion (0.5 Hz and up), the second is
#: the time over which a robot or a hand carries the sensor across a field's structure.
MAG_BAND_S = (1.0, 8.0)
#: ... and its squared deviation low-passed over this, s.
MAG_SCORE_S = 2.0
#: The field's wander (band-passed RMS) in units of half ``mag_consistency_rad`` (sigma0) at which it no longer steers
#: heading at all; below, the heading blend's time constant grows as wander / sigma0 (a noisier heading reference).
MAG_REJECT_SIGMAS = 4.0
#: A new field becomes the reference only after the body turned by this much (rad, the gyro's angle) while it was
#: timed: without turning, a field carried by the body (a magnet or motor on the robot) cannot be told from one that
#: is fixed in the world.
NEW_FIELD_TURN_RAD = math.pi / 2
#: Once the bias was seen at rest, a steady gyro rate differing from the estimate by more than this (rad/s, plus 3
#: sigma of the estimate) is a slow turn, not a rest: a MEMS gyro's bias moves by ~0.1°/s between rests minutes apart
#: (bias instability and temperature); a tracked robot turning in place at 1°/s does not look like a rest.
REST_BIAS_TOL_RAD_S = math.radians(0.3)
#: ... unless it stays steady this long, s: a rest learnt wrongly (a slow turn first) must not block later rests.
REST_RELEARN_S = 120.0
#: A gyro reading at this share of ``gyro_range_rad_s`` or beyond (per axis) is at the range: clipped (a sensor's
#: full scale is rarely the exact nominal value).
CLIP_FRACTION = 0.998


@dataclass(frozen=True)
class CcfParams(CommonParams):
    """Parameters of :class:`QuaternionCcf`: each field's unit, range and description are in its definition
    below (``ccf params`` prints them); why each default is what it is: doc/tuning.md#the-filter-parameters."""

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
    bias_from_mag: bool = param(
        True, '-', "while moving, learn the gyro bias from the magnetometer's heading errors too (false: from gravity "
        'and rests only, for a field that varies with position, e.g. steel beside the workspace)')
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

    @property
    def bias_gain_per_s(self) -> float:
        """Steady-state gain of the NCF's bias estimate in continuous motion, 1/s (``1/tau_bias_s``; 0 without
        ``motion_bias``): the ``G`` of :func:`tilt_transfer`."""
        return 1.0 / self.tau_bias_s if self.motion_bias else 0.0

