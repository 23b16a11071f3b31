"""Every user-facing setting of ccf_ros in one place: filter parameters (core) and adapter parameters.

The node, ``ccf replay --param/--params-file`` and ``config/ccf.yaml`` all use these names. No ROS import.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from .core.base import OrientationFilter
from .core.registry import all_param_names, make_filter
from .core.registry import defaults as filter_defaults
from .errors import ParameterError
from .frames import Mat3, rotation_matrix

_IDENTITY3 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)

#: Settings of the shared engine (node and replay alike), with defaults.
ENGINE_DEFAULTS: dict[str, Any] = {
    'mag_timeout_s': 0.5,
    'constant_dt': 0.0,
    'orientation_stddev': 0.0,
    'mag_bias_x': 0.0,
    'mag_bias_y': 0.0,
    'mag_bias_z': 0.0,
    'mag_soft_iron': _IDENTITY3,
    'yaw_offset': 0.0,
    'declination': 0.0,
    'remove_gravity_vector': False,
    'stateless': False,
    'bias_corrected_rate': False,
    'mount_rotation': (0.0, 0.0, 0.0),
    'mag_rotation': (0.0, 0.0, 0.0),
    'output_frame_id': '',
    'gyro_offset_rad_s': (0.0, 0.0, 0.0),
    'bias_file': '',
    'bias_file_heading': False,
    'mag_online_calibration': False,
    'mag_online_memory_rad': 60.0,
}

#: Settings only the node uses (replay accepts and ignores them, so one parameters file serves both).
NODE_DEFAULTS: dict[str, Any] = {
    'publish_debug_topics': False,
    'gyro_bias_rate_hz': 50.0,
    'qos_reliability': 'best_effort',
    'qos_depth': 50,
    'publish_tf': False,
    'fixed_frame': 'odom',
    'reverse_tf': False,
    'bias_save_interval_s': 60.0,
    'motion_hint_topic': '',
    'motion_hint_linear_m_s': 0.01,
    'motion_hint_angular_rad_s': 0.01,
    'motion_hint_timeout_s': 0.5,
}

#: imu_tools gains with no ccf meaning: accepted (a YAML written for imu_tools applies unchanged) and, when set to a
#: value other than this default, logged once by the node with the ccf parameter that plays that role.
IMU_TOOLS_GAINS: dict[str, tuple[Any, str]] = {
    'gain': (0.1, 'tau_acc_s and tau_mag_s (time constants, s, instead of a gradient gain)'),
    'zeta': (0.0, 'tau_bias_s and motion_bias (the NCF learns the gyro bias)'),
    'gain_acc': (0.01, 'tau_acc_s (inclination time constant, s)'),
    'gain_mag': (0.01, 'tau_mag_s (heading time constant, s)'),
    'bias_alpha': (0.01, 'rest_tau_s (bias update at rest, s)'),
    'do_adaptive_gain': (True, 'tau_acc_lp_s (linear accelerations are always rejected by the inertial-frame low-pass)'),
    'do_bias_estimation': (True, 'rest_bias and motion_bias; with the complementary-filter executable it also '
                                 'sets bias_corrected_rate'),
}

#: Every non-filter setting (engine, node, accepted imu_tools gains) with its default.
ADAPTER_DEFAULTS: dict[str, Any] = {**ENGINE_DEFAULTS, **NODE_DEFAULTS, **{k: v for k, (v, _) in IMU_TOOLS_GAINS.items()}}

#: One line per setting, for config/ccf.yaml, the node's parameter descriptors and the README.
DESCRIPTIONS: dict[str, str] = {
    'filter': 'filter algorithm: ccf (default), or the paper\'s baselines lcf, ncf, ekf, ckf (euler) and madgwick, mahony',
    'formulation': 'quaternion (default, any attitude) or euler (the paper\'s per-axis form, singular at +-90 deg pitch)',
    'max_dt_s': 'gap longer than this (s) re-initialises from accelerometer/magnetometer instead of integrating',
    'use_mag': 'use the magnetometer for heading (false: 6-D, heading drifts)',
    'world_frame': 'world frame of the output orientation: enu (REP-103), ned or nwu',
    'tau_acc_s': 'quaternion: LCF time constant of the inclination blend towards the filtered gravity, s',
    'tau_mag_s': 'quaternion: LCF time constant of the heading blend towards the magnetometer, s',
    'tau_acc_lp_s': 'quaternion: group delay of the 2nd-order gravity low-pass in the gyro-carried (almost inertial) frame, s',
    'tau_ncf_s': 'quaternion: NCF (bias stage) proportional time constant, s',
    'tau_bias_s': 'quaternion: NCF: the bias estimate follows the observed drift with this time constant in steady motion, s',
    'bias_rotation_rad_s': 'quaternion: NCF: rotation rate at which its bias observations count half (gyro scale errors), rad/s',
    'motion_bias': 'quaternion: learn the gyro bias while moving (NCF integral)',
    'rest_bias': 'quaternion: learn the gyro bias from the gyro itself while at rest',
    'rest_gyro_rad_s': 'quaternion: rest if the gyro stays within this of its low-pass, rad/s',
    'rest_acc_m_s2': 'quaternion: ... and the accelerometer within this of the filtered gravity, m/s^2',
    'rest_min_s': 'quaternion: ... for at least this long, s',
    'rest_tau_s': 'quaternion: time constant of the rest low-pass filter and rest bias update, s',
    'bias_max_rad_s': 'quaternion: the gyro-bias estimate is clamped to +-this per axis, rad/s',
    'mag_norm_tol': 'quaternion: relative magnetometer-norm deviation that counts as disturbed',
    'mag_dip_tol_rad': 'quaternion: magnetic dip deviation that counts as disturbed, rad',
    'mag_reaccept_s': 'quaternion: a different but steady field becomes the new reference after this long, s',
    'mag_ref_learn_s': 'quaternion: the reference field of the disturbance gate is the mean over this long after it is set, s',
    'mag_consistency_rad': 'quaternion: a field whose world direction moves more than this (band-passed RMS) does not steer heading, rad; 0 = off',
    'gyro_range_rad_s': 'quaternion: the gyro\'s full-scale range, rad/s (0 = unknown); samples at it are counted and the attitude recovers from the accelerometer/magnetometer fast',
    'incl_sigma_rad': 'quaternion: reported inclination std while the accelerometer corrects it, rad',
    'heading_sigma_rad': 'quaternion: reported heading std while the magnetometer corrects it, rad',
    'gyro_arw_rad_sqrt_s': 'quaternion: gyro angle random walk, rad/sqrt(s); grows the reported variance without corrections',
    'bias_sigma_init_rad_s': 'quaternion: gyro-bias uncertainty before anything is learnt, rad/s (the NCF Kalman filter starts here)',
    'bias_sigma_rest_rad_s': 'quaternion: gyro-bias uncertainty after a rest, rad/s',
    'bias_walk_rad_s_sqrt_s': 'quaternion: random walk of the gyro bias, (rad/s)/sqrt(s)',
    'kp': 'euler: NCF proportional gain, 1/s (one value or [roll, pitch, yaw])',
    'ki': 'euler: NCF integral gain, 1/s^2 (one value or [roll, pitch, yaw])',
    'alpha': 'euler: LCF weight of the gyro path per sample, 0..1 (one value or [roll, pitch, yaw])',
    'lcf_alpha': 'lcf: per-sample weight of the integrated gyro, 0..1 (one value or [roll, pitch, yaw])',
    'ekf_q': 'ekf: process-noise density of [roll, pitch, yaw], rad^2/s',
    'ekf_r': 'ekf: accelerometer/magnetometer angle variance [roll, pitch, yaw], rad^2',
    'ckf_q': 'ckf: process-noise density of [roll, pitch, yaw error, x, y, z bias error], rad^2/s, rad^2/s^3',
    'ckf_r': 'ckf: accelerometer/magnetometer angle variance [roll, pitch, yaw], rad^2',
    'ckf_bias0_rad_s': 'ckf: initial gyro-bias standard deviation, rad/s',
    'madgwick_beta': 'madgwick: gradient-descent gain, rad/s',
    'mahony_kp': 'mahony: proportional gain, 1/s',
    'mahony_ki': 'mahony: integral gain, 1/s^2',
    'mag_timeout_s': 'magnetometer samples older than this (s) are not paired with an IMU sample',
    'constant_dt': 'fixed sample period (s) instead of header stamps; 0 = use header stamps',
    'orientation_stddev': 'fixed orientation std (rad) for the covariance; 0 = the filter\'s own estimate',
    'mag_bias_x': 'magnetometer hard-iron offset, x, T (subtracted before everything else; ccf calibrate-mag)',
    'mag_bias_y': 'magnetometer hard-iron offset, y, T',
    'mag_bias_z': 'magnetometer hard-iron offset, z, T',
    'mag_soft_iron': 'magnetometer soft-iron matrix, row-major 3x3, applied after the offset: m = S (m_raw - b)',
    'mag_online_calibration': 'estimate the magnetometer hard-iron offset while the sensor turns (gyro-paired, a field '
                              'fixed in the world is not followed) and subtract it once determined, after mag_bias_*',
    'mag_online_memory_rad': 'rotation the online hard-iron estimate remembers, rad (1 to 1e6; older pairs fade by '
                             'exp(-turn / this))',
    'yaw_offset': 'output turned by yaw_offset - declination about world z (down in ned), rad (imu_tools semantics)',
    'declination': 'local magnetic declination, rad (east positive); see yaw_offset',
    'remove_gravity_vector': 'publish linear_acceleration with gravity (9.80665 m/s^2, up) removed',
    'stateless': 'publish the orientation computed from each accelerometer (+ magnetometer) sample alone (debug)',
    'bias_corrected_rate': 'publish angular_velocity minus the gyro-bias estimate',
    'mount_rotation': 'rotation of the IMU frame in the output frame: [roll, pitch, yaw] rad (fixed axes X-Y-Z, as '
                      'static_transform_publisher) or [x, y, z, w]; gyro, accelerometer, magnetometer and the output are '
                      'turned into the output frame (doc/frames.md)',
    'mag_rotation': 'rotation of the magnetometer frame in the IMU frame (after mag_bias/mag_soft_iron): [roll, pitch, '
                    'yaw] rad or [x, y, z, w]',
    'output_frame_id': 'header.frame_id of the output (imu/data, imu/gyro_bias, TF child); empty = the input\'s',
    'gyro_offset_rad_s': 'known gyro offset [x, y, z], rad/s, IMU frame, subtracted from the rate before anything else '
                         '(datasheet, calibration)',
    'bias_file': 'JSON file of the learnt gyro bias (IMU frame, with its sigma and frame_id): loaded at start, written '
                 'atomically on shutdown (and every bias_save_interval_s by the node, at the end by replay); empty = none',
    'bias_file_heading': '6-D: also keep the heading in bias_file, so that a restart goes on from the heading it had '
                         '(the robot must not have turned while the node was down)',
    'publish_debug_topics': 'node: also publish imu/rpy/filtered and imu/rpy/raw (roll, pitch, yaw in rad)',
    'gyro_bias_rate_hz': 'node: highest rate of imu/gyro_bias, Hz (the bias changes over seconds); 0 = every sample',
    'qos_reliability': 'node: input QoS reliability, best_effort (sensor data) or reliable',
    'qos_depth': 'node: input QoS queue depth',
    'publish_tf': 'node: broadcast the orientation as a transform fixed_frame -> IMU frame on /tf',
    'fixed_frame': 'node: parent frame of the published transform',
    'reverse_tf': 'node: publish the inverse transform (IMU frame -> fixed_frame)',
    'bias_save_interval_s': 'node: write bias_file this often, s (and on shutdown); 0 = only on shutdown',
    'motion_hint_topic': 'node: nav_msgs/Odometry or geometry_msgs/TwistStamped topic (type found on the graph) '
                         'saying whether the robot moves: the gyro bias is learnt at rest only when it says still; '
                         '"" = none',
    'motion_hint_linear_m_s': 'node: the hint says still below this speed, m/s ...',
    'motion_hint_angular_rad_s': 'node: ... and below this turn rate, rad/s',
    'motion_hint_timeout_s': 'node: a hint older than this (s, by stamps) no longer counts (rest from the IMU alone)',
    **{name: f'imu_tools gain, accepted; ccf uses {role}' for name, (_, role) in IMU_TOOLS_GAINS.items()},
}


def all_defaults() -> dict[str, Any]:
    """Every setting with its default: filter parameters then adapter parameters."""
    out = filter_defaults()
    out.update(ADAPTER_DEFAULTS)
    return out


@dataclass(frozen=True)
class AdapterSettings:
    """Engine settings shared by node and replay (see :data:`DESCRIPTIONS` for each)."""

    mag_timeout_s: float = 0.5
    constant_dt: float = 0.0
    orientation_stddev: float = 0.0
    mag_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_soft_iron: tuple[float, ...] = _IDENTITY3
    yaw_offset: float = 0.0
    declination: float = 0.0
    remove_gravity_vector: bool = False
    stateless: bool = False
    bias_corrected_rate: bool = False
    mount_rotation: tuple[float, ...] = (0.0, 0.0, 0.0)
    mag_rotation: tuple[float, ...] = (0.0, 0.0, 0.0)
    output_frame_id: str = ''
    gyro_offset_rad_s: tuple[float, ...] = (0.0, 0.0, 0.0)
    bias_file: str = ''
    bias_file_heading: bool = False
    mag_online_calibration: bool = False
    mag_online_memory_rad: float = 60.0

    def __post_init__(self) -> None:
        for name in ('mag_timeout_s', 'constant_dt', 'orientation_stddev', 'yaw_offset', 'declination',
                     'mag_online_memory_rad'):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
                raise ValueError(f'{name} must be a finite number, got {value!r}')
        if not self.mag_timeout_s > 0:
            raise ValueError(f'mag_timeout_s must be > 0, got {self.mag_timeout_s!r}')
        if not self.constant_dt >= 0:
            raise ValueError(f'constant_dt must be >= 0, got {self.constant_dt!r}')
        if not self.orientation_stddev >= 0:
            raise ValueError(f'orientation_stddev must be >= 0, got {self.orientation_stddev!r}')
        if len(self.mag_bias) != 3 or not all(math.isfinite(v) for v in self.mag_bias):
            raise ValueError(f'mag_bias_x/y/z must be finite numbers, got {self.mag_bias!r}')
        if len(self.mag_soft_iron) != 9 or not all(math.isfinite(v) for v in self.mag_soft_iron):
            raise ValueError(f'mag_soft_iron must be 9 finite numbers (row-major 3x3), got {self.mag_soft_iron!r}')
        if not 1.0 <= self.mag_online_memory_rad <= 1e6:
            raise ValueError(f'mag_online_memory_rad must be within [1, 1e6] rad, got {self.mag_online_memory_rad!r}')
        for name in ('remove_gravity_vector', 'stateless', 'bias_corrected_rate', 'mag_online_calibration',
                     'bias_file_heading'):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f'{name} must be a bool, got {getattr(self, name)!r}')
        rotation_matrix('mount_rotation', self.mount_rotation)
        rotation_matrix('mag_rotation', self.mag_rotation)
        if len(self.gyro_offset_rad_s) != 3 or not all(math.isfinite(v) for v in self.gyro_offset_rad_s):
            raise ValueError(f'gyro_offset_rad_s must be 3 finite numbers [x, y, z] (rad/s), got '
                             f'{list(self.gyro_offset_rad_s)!r}')
        for name in ('output_frame_id', 'bias_file'):
            if not isinstance(getattr(self, name), str):
                raise ValueError(f'{name} must be a string, got {getattr(self, name)!r}')

    @property
    def mount_matrix(self) -> Mat3:
        """Row-major rotation matrix of :attr:`mount_rotation` (IMU frame -> output frame)."""
        return rotation_matrix('mount_rotation', self.mount_rotation)

    @property
    def mag_matrix(self) -> Mat3:
        """Row-major rotation matrix of :attr:`mag_rotation` (magnetometer frame -> IMU frame)."""
        return rotation_matrix('mag_rotation', self.mag_rotation)

    @property
    def yaw_turn_rad(self) -> float:
        """The output's turn about the world frame's z axis, rad: ``yaw_offset - declination`` (imu_tools')."""
        return self.yaw_offset - self.declination


def _number(name: str, value: Any) -> float:
    """``value`` as a float (ints from YAML/ROS integer parameters included), or ValueError naming ``name``."""
    if isinstance(value, bool):
        raise ValueError(f'{name} must be a number, got {value!r}')
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be a number, got {value!r}') from None


def _flag(name: str, value: Any) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.strip().lower() in ('true', 'false', '1', '0', 'yes', 'no', 'on', 'off'):
        return value.strip().lower() in ('true', '1', 'yes', 'on')
    raise ValueError(f'{name} must be true or false, got {value!r}')


def _numbers(name: str, value: Any, what: str) -> tuple[float, ...]:
    """A list of numbers (``[1, 0, 0]`` as text from ``--param`` too) as floats, or ValueError naming ``name``."""
    m = value
    if isinstance(m, str):
        m = [v for v in m.strip().strip('[]()').split(',') if v.strip()]
    try:
        return tuple(_number(name, v) for v in m)
    except TypeError:
        raise ValueError(f'{name} must be {what}, got {value!r}') from None


def adapter_settings(values: Mapping[str, Any]) -> AdapterSettings:
    """:class:`AdapterSettings` from flat settings (missing names keep their defaults; others are ignored)."""
    kw: dict[str, Any] = {}
    for name in ('mag_timeout_s', 'constant_dt', 'orientation_stddev', 'yaw_offset', 'declination',
                 'mag_online_memory_rad'):
        if name in values:
            kw[name] = _number(name, values[name])
    if any(f'mag_bias_{a}' in values for a in 'xyz'):
        kw['mag_bias'] = tuple(_number(f'mag_bias_{a}', values.get(f'mag_bias_{a}', 0.0)) for a in 'xyz')
    for name, what in (('mag_soft_iron', '9 numbers'), ('mount_rotation', '3 or 4 numbers'),
                       ('mag_rotation', '3 or 4 numbers'), ('gyro_offset_rad_s', '3 numbers')):
        if name in values:
            kw[name] = _numbers(name, values[name], what)
    for name in ('output_frame_id', 'bias_file'):
        if name in values:
            v = values[name]
            kw[name] = '' if v is None else v  # an empty YAML value is None
    for name in ('remove_gravity_vector', 'stateless', 'bias_corrected_rate', 'mag_online_calibration',
                 'bias_file_heading'):
        if name in values:
            kw[name] = _flag(name, values[name])
    return AdapterSettings(**kw)


def build(settings: Mapping[str, Any], *, strict: bool = True) -> tuple[OrientationFilter, AdapterSettings]:
    """Filter and adapter settings from a flat mapping.

    Raises:
        ParameterError: an unknown, inapplicable or invalid setting (its name and value in the message).
    """
    try:
        return _build(settings, strict=strict)
    except ParameterError:
        raise
    except ValueError as err:
        # The core and the params dataclasses raise ValueError naming the value; users get one error type.
        raise ParameterError(str(err)) from err


def _build(settings: Mapping[str, Any], *, strict: bool) -> tuple[OrientationFilter, AdapterSettings]:
    filt_part: dict[str, Any] = {}
    adapter: dict[str, Any] = {}
    known = all_param_names()
    for name, value in settings.items():
        if name.startswith('qos_overrides.'):
            continue  # rclpy's QoS override parameters: the node's business (a YAML written for it replays too)
        if name in ADAPTER_DEFAULTS:
            adapter[name] = value
        elif name in known:
            filt_part[name] = value
        else:
            raise ValueError(f'unknown parameter {name!r}; known: {", ".join(sorted(known | set(ADAPTER_DEFAULTS)))}')
    filt = make_filter(filt_part, strict=strict)
    return filt, adapter_settings(adapter)


def config_yaml() -> str:
    """The text of ``config/ccf.yaml``: every setting with its default and description.

    Regenerate with ``python -m ccf_ros.settings > config/ccf.yaml`` (a test checks the file matches).
    """
    lines = [
        '# ccf_ros parameters: every parameter with its default. Used by',
        '#   ccf_node --ros-args --params-file config/ccf.yaml',
        '#   ccf replay IN -o OUT --params-file config/ccf.yaml',
        '# Keyed /** so that it applies to the node under any name and namespace.',
        '/**:',
        '  ros__parameters:',
    ]
    for name, value in all_defaults().items():
        if isinstance(value, bool):
            text = 'true' if value else 'false'
        elif isinstance(value, float):
            text = repr(round(value, 10))
        elif isinstance(value, str) and not value:
            text = "''"
        elif isinstance(value, tuple):
            text = '[' + ', '.join(repr(round(float(v), 10)) for v in value) + ']'
        else:
            text = str(value)
        lines.append(f'    {name}: {text}  # {DESCRIPTIONS[name]}')
    return '\n'.join(lines) + '\n'


if __name__ == '__main__':
    print(config_yaml(), end='')
