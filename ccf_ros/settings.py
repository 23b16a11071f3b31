"""Every user-facing setting of ccf_ros in one place: filter parameters (core) and adapter parameters.

The node, ``ccf replay --param/--params-file`` and ``config/ccf.yaml`` all use these names. No ROS import.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from .core.base import OrientationFilter
from .core.registry import all_param_names, make_filter
from .core.registry import defaults as filter_defaults
from .errors import ParameterError

#: Settings of the adapters (node and replay), with defaults.
ADAPTER_DEFAULTS: dict[str, Any] = {
    'mag_timeout_s': 0.5,
    'constant_dt': 0.0,
    'orientation_stddev': 0.0,
    'publish_debug_topics': False,
    'gyro_bias_rate_hz': 50.0,
    'qos_reliability': 'best_effort',
    'qos_depth': 50,
}

#: One line per setting, for config/ccf.yaml, the node's parameter descriptors and the README.
DESCRIPTIONS: dict[str, str] = {
    'filter': 'filter algorithm: ccf (default), or the paper\'s baselines lcf, ncf, ekf, ckf (euler) and madgwick, mahony',
    'formulation': 'quaternion (default, any attitude) or euler (the paper\'s per-axis form, singular at +-90 deg pitch)',
    'max_dt_s': 'gap longer than this (s) re-initialises from accelerometer/magnetometer instead of integrating',
    'use_mag': 'use the magnetometer for heading (false: 6-D, heading drifts)',
    'world_frame': 'world frame of the output orientation: enu (REP-103), ned or nwu',
    'tau_acc_s': 'quaternion: LCF time constant of the inclination blend towards the filtered gravity, s',
    'tau_mag_s': 'quaternion: LCF time constant of the heading blend towards the magnetometer, s',
    'tau_acc_lp_s': 'quaternion: time constant of the accelerometer low-pass in the gyro-carried (almost inertial) frame, s',
    'tau_ncf_s': 'quaternion: NCF (bias stage) proportional time constant, s',
    'tau_bias_s': 'quaternion: NCF integral time constant, s; a bias is learnt while moving over about this',
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
    'incl_sigma_rad': 'quaternion: reported inclination std while the accelerometer corrects it, rad',
    'heading_sigma_rad': 'quaternion: reported heading std while the magnetometer corrects it, rad',
    'gyro_arw_rad_sqrt_s': 'quaternion: gyro angle random walk, rad/sqrt(s); grows the reported variance without corrections',
    'bias_sigma_init_rad_s': 'quaternion: gyro-bias uncertainty before anything is learnt, rad/s (scales the NCF gain)',
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
    'publish_debug_topics': 'node: also publish imu/rpy (roll, pitch, yaw in rad)',
    'gyro_bias_rate_hz': 'node: highest rate of imu/gyro_bias, Hz (the bias changes over seconds); 0 = every sample',
    'qos_reliability': 'node: input QoS reliability, best_effort (sensor data) or reliable',
    'qos_depth': 'node: input QoS queue depth',
}


def all_defaults() -> dict[str, Any]:
    """Every setting with its default: filter parameters then adapter parameters."""
    out = filter_defaults()
    out.update(ADAPTER_DEFAULTS)
    return out


@dataclass(frozen=True)
class AdapterSettings:
    """Adapter settings shared by node and replay (see :data:`DESCRIPTIONS`)."""

    mag_timeout_s: float = 0.5
    constant_dt: float = 0.0
    orientation_stddev: float = 0.0

    def __post_init__(self) -> None:
        if not self.mag_timeout_s > 0:
            raise ValueError(f'mag_timeout_s must be > 0, got {self.mag_timeout_s!r}')
        if not self.constant_dt >= 0:
            raise ValueError(f'constant_dt must be >= 0, got {self.constant_dt!r}')
        if not self.orientation_stddev >= 0:
            raise ValueError(f'orientation_stddev must be >= 0, got {self.orientation_stddev!r}')


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
        if name in ADAPTER_DEFAULTS:
            adapter[name] = value
        elif name in known:
            filt_part[name] = value
        else:
            raise ValueError(f'unknown parameter {name!r}; known: {", ".join(sorted(known | set(ADAPTER_DEFAULTS)))}')
    filt = make_filter(filt_part, strict=strict)
    kw = {}
    for name in ('mag_timeout_s', 'constant_dt', 'orientation_stddev'):
        if name in adapter:
            try:
                kw[name] = float(adapter[name])
            except (TypeError, ValueError):
                raise ValueError(f'{name} must be a number, got {adapter[name]!r}') from None
    return filt, AdapterSettings(**kw)


def config_yaml() -> str:
    """The text of ``config/ccf.yaml``: every setting with its default and description.

    Regenerate with ``python -m ccf_ros.settings > config/ccf.yaml`` (a test checks the file matches).
    """
    lines = [
        '# ccf_ros parameters: every parameter with its default. Used by',
        '#   ccf_node --ros-args --params-file config/ccf.yaml',
        '#   ccf replay IN -o OUT --params-file config/ccf.yaml',
        'ccf_node:',
        '  ros__parameters:',
    ]
    for name, value in all_defaults().items():
        if isinstance(value, bool):
            text = 'true' if value else 'false'
        elif isinstance(value, float):
            text = repr(round(value, 10))
        elif isinstance(value, tuple):
            text = '[' + ', '.join(repr(round(float(v), 10)) for v in value) + ']'
        else:
            text = str(value)
        lines.append(f'    {name}: {text}  # {DESCRIPTIONS[name]}')
    return '\n'.join(lines) + '\n'


if __name__ == '__main__':
    print(config_yaml(), end='')
