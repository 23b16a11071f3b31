"""Parameters of :class:`~ccf_ros.core.ccf.QuaternionCcf` and the cascade's fixed constants (SI units; the algorithm:
doc/algorithm.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..base import CommonParams, check_positive, check_range

_DEG = math.pi / 180.0
#: Standard gravity, m/s² (REP-145 accelerometers read +g up at rest).
GRAVITY_M_S2 = 9.80665
#: The NCF's bias update runs once the samples since the last one span this long, s (every sample at 25 Hz and
#: below): the tilt observations are low-passed over seconds and the heading ones averaged over the block, so 25
#: updates a second lose nothing (BROAD's mean error moves by 0.005° between 50 and 25 Hz) and save most of the
#: matrix arithmetic.
BIAS_UPDATE_PERIOD_S = 0.04
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

    tau_acc_s: float = 1.0
    tau_mag_s: float = 15.0
    tau_acc_lp_s: float = 2.5
    tau_ncf_s: float = 3.0
    tau_bias_s: float = 5.0
    bias_rotation_rad_s: float = 12.0 * _DEG
    motion_bias: bool = True
    rest_bias: bool = True
    rest_gyro_rad_s: float = 2.0 * _DEG
    rest_acc_m_s2: float = 0.5
    rest_min_s: float = 1.5
    rest_tau_s: float = 0.5
    bias_max_rad_s: float = 15.0 * _DEG
    mag_norm_tol: float = 0.05
    mag_dip_tol_rad: float = 5.0 * _DEG
    mag_reaccept_s: float = 20.0
    mag_ref_learn_s: float = 5.0
    mag_consistency_rad: float = 2.0 * _DEG
    gyro_range_rad_s: float = 0.0
    incl_sigma_rad: float = 0.5 * _DEG
    heading_sigma_rad: float = 1.7 * _DEG
    gyro_arw_rad_sqrt_s: float = 3e-4
    bias_sigma_init_rad_s: float = 0.5 * _DEG
    bias_sigma_rest_rad_s: float = 0.02 * _DEG
    bias_walk_rad_s_sqrt_s: float = 0.01 * _DEG

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

