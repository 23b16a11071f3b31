"""Every user-facing setting of ccf_ros, each defined once: the schema every executable is generated from.

A parameter is one dataclass field (:func:`ccf_ros.core.fields.param`: default, SI unit, range, description): the
filters' in the core params dataclasses, the engine's in :class:`EngineSettings`, the node's in
:class:`NodeSettings`, imu_tools' accepted gains in :class:`ImuToolsGains`. :func:`schema` collects them into
:class:`Parameter` entries, from which come the node's declarations (descriptors with ranges), the validation of a
value everywhere (:func:`coerce`: node on-set callback, ``ccf replay``, ``ccf fleet``), ``ccf params``,
``config/ccf.yaml`` (``python -m ccf_ros.settings > config/ccf.yaml``) and the README's parameter table
(``python -m ccf_ros.settings --markdown``); tests check both generated files are current. No ROS import.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from .core.base import OrientationFilter, check_params, per_axis
from .core.fields import param, parse_bool, parse_number, parse_numbers
from .core.registry import FILTERS, SELECTORS, make_filter, param_fields
from .errors import ParameterError
from .frames import Mat3, rotation_matrix

_IDENTITY3 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
_ANY = (0.0, 1e9)  # a positive real, the range of most


@dataclass(frozen=True)
class EngineSettings:
    """Settings of the shared engine (node, drop-ins, replay and fleet alike); each field's description is its
    documentation (``ccf params``)."""

    mag_timeout_s: float = param(
        0.5, 's', 'magnetometer samples older than this (s) are not paired with an IMU sample', *_ANY, above=True)
    constant_dt: float = param(
        0.0, 's', 'fixed sample period (s) instead of header stamps; 0 = use header stamps', 0.0, 10.0)
    orientation_stddev: float = param(
        0.0, 'rad', "fixed orientation std (rad) for the covariance; 0 = the filter's own estimate", 0.0, math.pi)
    # imu_tools' own ranges: hard-iron offsets (T) and signed angles (rad).
    mag_bias_x: float = param(
        0.0, 'T', 'magnetometer hard-iron offset, x, T (subtracted before everything else; ccf calibrate-mag)',
        -10.0, 10.0)
    mag_bias_y: float = param(0.0, 'T', 'magnetometer hard-iron offset, y, T', -10.0, 10.0)
    mag_bias_z: float = param(0.0, 'T', 'magnetometer hard-iron offset, z, T', -10.0, 10.0)
    mag_soft_iron: tuple[float, ...] = param(
        _IDENTITY3, '-', 'magnetometer soft-iron matrix, row-major 3x3, invertible, applied after the offset: m = S (m_raw - b)',
        -1e9, 1e9, what='9 finite numbers (row-major 3x3)')
    yaw_offset: float = param(
        0.0, 'rad', 'output turned by yaw_offset - declination about world z (down in ned), rad (imu_tools semantics)',
        -2.0 * math.pi, 2.0 * math.pi)
    declination: float = param(
        0.0, 'rad', 'local magnetic declination, rad (east positive); see yaw_offset', -2.0 * math.pi, 2.0 * math.pi)
    remove_gravity_vector: bool = param(
        False, '-', 'publish linear_acceleration with gravity (9.80665 m/s^2, up) removed')
    stateless: bool = param(
        False, '-', 'publish the orientation computed from each accelerometer (+ magnetometer) sample alone (debug)')
    bias_corrected_rate: bool = param(False, '-', 'publish angular_velocity minus the gyro-bias estimate')
    mount_rotation: tuple[float, ...] = param(
        (0.0, 0.0, 0.0), 'rad|quat', 'rotation of the IMU frame in the output frame: [roll, pitch, yaw] rad (fixed '
        'axes X-Y-Z, as static_transform_publisher) or [x, y, z, w]; gyro, accelerometer, magnetometer and the output '
        'are turned into the output frame (doc/frames.md)',
        lengths=(3, 4), what='[roll, pitch, yaw] (rad) or a quaternion [x, y, z, w]')
    mag_rotation: tuple[float, ...] = param(
        (0.0, 0.0, 0.0), 'rad|quat', 'rotation of the magnetometer frame in the IMU frame (after '
        'mag_bias_*/mag_soft_iron): [roll, pitch, yaw] rad or [x, y, z, w]',
        lengths=(3, 4), what='[roll, pitch, yaw] (rad) or a quaternion [x, y, z, w]')
    output_frame_id: str = param(
        '', '-', "header.frame_id of the output (imu/data, imu/gyro_bias, TF child); empty = the input's")
    gyro_offset_rad_s: tuple[float, ...] = param(
        (0.0, 0.0, 0.0), 'rad/s', 'known gyro offset [x, y, z], rad/s, IMU frame, subtracted from the rate before '
        'anything else (datasheet, calibration)', -1e9, 1e9, what='3 finite numbers [x, y, z] (rad/s)')
    bias_file: str = param(
        '', '-', 'JSON file of the learnt gyro bias (IMU frame, with its sigma and frame_id): loaded at start, '
        'written atomically on shutdown (and every bias_save_interval_s by the node, at the end by replay); '
        'empty = none')
    bias_file_heading: bool = param(
        False, '-', '6-D: also keep the heading in bias_file, so that a restart goes on from the heading it had '
        '(the robot must not have turned while the node was down)')
    mag_online_calibration: bool = param(
        True, '-', 'estimate the magnetometer hard-iron offset while the sensor turns (samples paired through '
        "the filter's orientation; a field fixed in the world is not followed) and subtract it once determined, "
        'after mag_bias_*')
    mag_online_memory_rad: float = param(
        60.0, 'rad', 'rotation the online hard-iron estimate remembers, rad (1 to 1e6; older pairs fade by '
        'exp(-turn / this))', 1.0, 1e6)

    def __post_init__(self) -> None:
        check_params(self)
        rotation_matrix('mount_rotation', self.mount_rotation)
        rotation_matrix('mag_rotation', self.mag_rotation)
        s = self.mag_soft_iron
        det = s[0] * (s[4] * s[8] - s[5] * s[7]) - s[1] * (s[3] * s[8] - s[5] * s[6]) + s[2] * (s[3] * s[7] - s[4] * s[6])
        # A calibration scales and shears the field; a singular matrix flattens it, and heading is lost for good
        # (every sample would read as a field in one plane or none at all).
        if not abs(det) > 1e-9 * max(abs(a) for a in s) ** 3:
            raise ValueError(f'mag_soft_iron must be an invertible 3x3 matrix (row-major), got {list(s)!r} '
                             f'(determinant {det:.3g})')

    @classmethod
    def from_values(cls, values: Mapping[str, Any]) -> EngineSettings:
        """From flat settings (text included; missing names keep their defaults, other names are ignored)."""
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{name: coerce(name, v) for name, v in values.items() if name in names})

    @property
    def mag_bias(self) -> tuple[float, float, float]:
        """Hard-iron offset ``(x, y, z)``, T."""
        return (self.mag_bias_x, self.mag_bias_y, self.mag_bias_z)

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


@dataclass(frozen=True)
class NodeSettings:
    """Settings only the node uses (replay accepts them, so that one parameters file serves both, and uses the
    motion hint's)."""

    publish_debug_topics: bool = param(
        False, '-', 'also publish imu/rpy/filtered and imu/rpy/raw (roll, pitch, yaw in rad)')
    gyro_bias_rate_hz: float = param(
        50.0, 'Hz', 'highest rate of imu/gyro_bias, Hz (the bias changes over seconds); 0 = every sample',
        0.0, 100000.0)
    qos_reliability: str = param(
        'best_effort', '-', 'input QoS reliability, best_effort (sensor data) or reliable',
        choices=('best_effort', 'reliable'))
    qos_depth: int = param(50, '-', 'input QoS queue depth', 1, 100000)
    publish_tf: bool = param(False, '-', 'broadcast the orientation as a transform fixed_frame -> IMU frame on /tf')
    fixed_frame: str = param('odom', '-', 'parent frame of the published transform')
    reverse_tf: bool = param(False, '-', 'publish the inverse transform (IMU frame -> fixed_frame)')
    bias_save_interval_s: float = param(
        60.0, 's', 'write bias_file this often, s (and on shutdown); 0 = only on shutdown', *_ANY)
    motion_hint_topic: str = param(
        '', '-', 'nav_msgs/Odometry or geometry_msgs/TwistStamped topic (type found on the graph) saying whether '
        'the robot moves: the gyro bias is learnt at rest only when it says still; "" = none')
    motion_hint_linear_m_s: float = param(0.01, 'm/s', 'the hint says still below this speed, m/s ...', *_ANY)
    motion_hint_angular_rad_s: float = param(0.01, 'rad/s', '... and below this turn rate, rad/s', *_ANY)
    motion_hint_timeout_s: float = param(
        0.5, 's', 'a hint older than this (s, by stamps) no longer counts (rest from the IMU alone)', *_ANY)

    def __post_init__(self) -> None:
        check_params(self)


@dataclass(frozen=True)
class ImuToolsGains:
    """imu_tools gains with no ccf meaning: accepted (a YAML written for imu_tools applies unchanged) and, set to a
    value other than the default, logged once by the node; each description names the ccf parameter playing that
    role. (``do_bias_estimation`` has a meaning: :func:`ccf_ros.compat.apply_do_bias_estimation`.)"""

    gain: float = param(0.1, '-', 'tau_acc_s and tau_mag_s (time constants, s, instead of a gradient gain)', 0.0, 1.0)
    zeta: float = param(0.0, '-', 'tau_bias_s and motion_bias (the NCF learns the gyro bias)', -1.0, 1.0)
    # No range: the complementary filter accepts any value, warns and keeps its default.
    gain_acc: float = param(0.01, '-', 'tau_acc_s (inclination time constant, s)', -1e9, 1e9)
    gain_mag: float = param(0.01, '-', 'tau_mag_s (heading time constant, s)', -1e9, 1e9)
    bias_alpha: float = param(0.01, '-', 'rest_tau_s (bias update at rest, s)', -1e9, 1e9)
    do_adaptive_gain: bool = param(
        True, '-', 'tau_acc_lp_s (linear accelerations are always rejected by the inertial-frame low-pass)')
    do_bias_estimation: bool = param(
        True, '-', 'rest_bias and motion_bias; with the complementary-filter executable it also sets '
        'bias_corrected_rate')

    def __post_init__(self) -> None:
        check_params(self)


#: Where each group of settings applies (the filter parameters: the filters that have them).
APPLIES_TO = {
    'selector': 'every executable', 'engine': 'node, drop-ins, replay, fleet',
    'node': 'node, drop-ins', 'imu_tools': 'node, drop-ins, replay, fleet (accepted)',
}
#: Where a setting applies when not where its group's do: the motion hint is replay's too (a topic of the bag); the
#: bias file is one IMU's state, which ``ccf fleet`` refuses.
APPLIES_TO_SETTING = {
    **dict.fromkeys(('motion_hint_topic', 'motion_hint_linear_m_s', 'motion_hint_angular_rad_s',
                     'motion_hint_timeout_s'), 'node, drop-ins, replay'),
    **dict.fromkeys(('bias_file', 'bias_file_heading'), 'node, drop-ins, replay'),
}
_DESCRIPTION_PREFIX = {'node': 'node: ', 'imu_tools': 'imu_tools gain, accepted; ccf uses '}


@dataclass(frozen=True)
class Parameter:
    """One setting as every executable sees it.

    Attributes:
        name, default, unit (SI; ``-`` none), description: as in ``ccf params``.
        group: ``selector`` (filter, formulation), ``filter``, ``engine``, ``node`` or ``imu_tools``.
        range: inclusive ``(lo, hi)`` of a number (each element of a list), or None; ``above``: ``lo`` excluded.
        choices: allowed strings; per_axis: a number or ``[roll, pitch, yaw]``; lengths: allowed list lengths;
            what: how a list is described in an error.
        read_only: executables (profiles) in which it cannot change after start-up.
        applies_to: the executables (and for a filter parameter, the filters) it applies to.
    """

    name: str
    default: Any
    unit: str
    description: str
    group: str
    range: tuple[float, float] | None = None
    above: bool = False
    choices: tuple[str, ...] = ()
    per_axis: bool = False
    lengths: tuple[int, ...] = ()
    what: str = ''
    read_only: frozenset[str] = frozenset()
    applies_to: str = ''


def _from_field(f: dataclasses.Field[Any], group: str, prefix: str = '') -> Parameter:
    m = f.metadata
    return Parameter(f.name, f.default, m['unit'], prefix + m['description'], group, m['range'], m['above'],
                     m['choices'], m['per_axis'], m['lengths'], m['what'],
                     applies_to=APPLIES_TO_SETTING.get(f.name, APPLIES_TO.get(group, '')))


def _users(name: str) -> list[tuple[str, str]]:
    """The ``(filter, formulation)`` pairs whose parameters include ``name``."""
    return [key for key, (cls, _) in FILTERS.items() if name in param_fields(cls)]


def _filter_label(name: str) -> str:
    """``quaternion: `` for a parameter of one formulation of the ccf, ``ekf: `` for a baseline's, ``''`` for one
    every filter has."""
    users = _users(name)
    if len(users) == len(FILTERS):
        return ''
    ccf = [form for kind, form in users if kind == 'ccf']
    return f'{ccf[0] if ccf else users[0][0]}: '


def _filter_applies(name: str) -> str:
    users = _users(name)
    which = 'every filter' if len(users) == len(FILTERS) else ', '.join(f'{k} ({f})' for k, f in users)
    return f'{which}; node, drop-ins, replay, fleet'


@functools.cache
def schema() -> dict[str, Parameter]:
    """Every setting by name, in the order of ``config/ccf.yaml``: selectors, filter parameters (first filter that
    has it), engine, node, imu_tools gains."""
    from .compat import PROFILES  # the drop-ins' read-only flags (imu_tools'); compat reads this module

    kinds = ', '.join(sorted({k for k, _ in FILTERS}))
    out = {
        'filter': Parameter('filter', SELECTORS['filter'], '-', "filter algorithm: ccf (default), or the paper's "
                            'baselines lcf, ncf, ekf, ckf (euler) and madgwick, mahony', 'selector',
                            choices=tuple(kinds.split(', ')), applies_to=APPLIES_TO['selector']),
        'formulation': Parameter('formulation', SELECTORS['formulation'], '-', "quaternion (default, any attitude) "
                                 "or euler (the paper's per-axis form, singular at +-90 deg pitch)", 'selector',
                                 choices=tuple(sorted({f for _, f in FILTERS})), applies_to=APPLIES_TO['selector']),
    }
    for params_cls, _ in FILTERS.values():
        for name, f in param_fields(params_cls).items():
            if name not in out:
                out[name] = dataclasses.replace(_from_field(f, 'filter', _filter_label(name)),
                                                applies_to=_filter_applies(name))
    for cls, group in ((EngineSettings, 'engine'), (NodeSettings, 'node'), (ImuToolsGains, 'imu_tools')):
        for f in dataclasses.fields(cls):
            # (no 'node: ' for a node setting that applies beyond the node)
            prefix = '' if f.name in APPLIES_TO_SETTING else _DESCRIPTION_PREFIX.get(group, '')
            out[f.name] = _from_field(f, group, prefix)
    for name, p in out.items():
        ro = frozenset(exe for exe, prof in PROFILES.items() if name in prof.read_only)
        if ro:
            out[name] = dataclasses.replace(p, read_only=ro)
    return out


def names(group: str) -> list[str]:
    """The names of one group of settings (``engine``, ``node``, ...), in schema order."""
    return [n for n, p in schema().items() if p.group == group]


def all_defaults() -> dict[str, Any]:
    """Every setting with its default, in schema order."""
    return {name: p.default for name, p in schema().items()}


def coerce(name: str, value: Any) -> Any:
    """``value`` of the setting ``name`` checked against its definition and converted, from whatever carries it:
    YAML, ``--param`` text, a ROS parameter (an integer for a real parameter included). The one validation of a
    single value, used by the node's on-set callback, replay and fleet.

    Raises:
        ParameterError: an unknown name, or a value of the wrong type or out of range; the message names both.
    """
    p = schema().get(name)
    if p is None:
        raise ParameterError(f'unknown parameter {name!r}; known: {", ".join(sorted(schema()))}')
    try:
        return _coerce(p, value)
    except ParameterError:
        raise
    except ValueError as err:
        raise ParameterError(str(err)) from None


def refuse_text(name: str, value: Any) -> None:
    """Refuse text (a string, or a list holding one) for a setting that is not text, as a ROS parameter's type does.

    A value that has a type (a ROS parameter, YAML) is taken as typed: only ``--param`` gives text to convert
    (:func:`coerce` converts it). An unknown name is left to :func:`coerce`.

    Raises:
        ParameterError: text for a setting that is not text; the message names the setting and the value.
    """
    p = schema().get(name)
    if p is not None and not isinstance(p.default, str) and _has_text(value):
        raise ParameterError(f'{name} must be {_kind(p)}, not text: got {value!r}')


def _has_text(value: Any) -> bool:
    """A string, or a list holding one (rclpy's string array)."""
    return isinstance(value, str) or (isinstance(value, (list, tuple)) and any(isinstance(v, str) for v in value))


def _kind(p: Parameter) -> str:
    """What a value of ``p`` is, in an error."""
    if isinstance(p.default, bool):
        return 'true or false'
    if p.per_axis:
        return 'a number or 3 numbers'
    return p.what if isinstance(p.default, tuple) else 'a number'


def _coerce(p: Parameter, value: Any) -> Any:
    name = p.name
    lo, hi = p.range or (-math.inf, math.inf)
    if isinstance(p.default, bool):
        return parse_bool(name, value)
    if p.per_axis:
        # Checked whichever filter is selected: a malformed value for an inactive one would otherwise be taken,
        # and refuse a later, unrelated change (the selection of that filter).
        if isinstance(value, str) and not value.strip().startswith('['):
            value = parse_number(name, value)
        v: Any = (float(value) if isinstance(value, (int, float)) and not isinstance(value, bool)
                  else parse_numbers(name, value, 'a number or 3 numbers (roll, pitch, yaw)'))
        per_axis(name, v, lo, hi)
        return v
    if isinstance(p.default, tuple):
        vals = parse_numbers(name, value, p.what)
        if len(vals) not in p.lengths:  # whichever filter is selected, as per_axis above
            raise ParameterError(f'{name} must be {p.what}, got {value!r}')
        if p.range and not all(lo <= x <= hi for x in vals):
            raise ParameterError(f'{name} must be within {_range_text(p)} each, got {value!r}')
        return vals
    if isinstance(p.default, str):
        value = '' if value is None else value  # an empty YAML value is None
        if not isinstance(value, str):
            raise ParameterError(f'{name} must be a string, got {value!r}')
        if p.choices and value not in p.choices:
            raise ParameterError(f'{name} must be one of: {", ".join(p.choices)}; got {value!r}')
        return value
    number = parse_number(name, value)
    if isinstance(p.default, int):
        if not math.isfinite(number) or number != int(number):
            raise ParameterError(f'{name} must be an integer, got {value!r}')
        number = int(number)
    if not lo <= number <= hi or (p.above and number <= lo):  # NaN too
        unit = '' if p.unit == '-' else f' {p.unit}'
        raise ParameterError(f'{name} must be within {_range_text(p)}{unit}, got {value!r}')
    return number


def build(settings: Mapping[str, Any], *, strict: bool = True) -> tuple[OrientationFilter, EngineSettings]:
    """The filter and the engine settings from a flat mapping: every value checked by :func:`coerce`.

    ``strict``: a filter parameter the selected filter does not use is an error (else ignored: a parameters file
    holds every filter's). Settings of the node and imu_tools' gains are checked and not used here.

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


def _build(settings: Mapping[str, Any], *, strict: bool) -> tuple[OrientationFilter, EngineSettings]:
    filt_part: dict[str, Any] = {}
    engine: dict[str, Any] = {}
    sch = schema()
    for name, value in settings.items():
        if name.startswith('qos_overrides.') or name == 'use_sim_time':
            continue  # rclpy's own parameters: the node's business (a YAML written for it replays too)
        v = coerce(name, value)
        group = sch[name].group
        if group in ('selector', 'filter'):
            filt_part[name] = v
        elif group == 'engine':
            engine[name] = v
    return make_filter(filt_part, strict=strict), EngineSettings.from_values(engine)


# --- names kept for existing imports ---------------------------------------------------------------------------
#: Old name of :class:`EngineSettings` ("adapter" named three things; this one is the engine's settings).
AdapterSettings = EngineSettings


def adapter_settings(values: Mapping[str, Any]) -> EngineSettings:
    """Old name of :meth:`EngineSettings.from_values`."""
    return EngineSettings.from_values(values)


def _defaults_of(cls: type[Any]) -> dict[str, Any]:
    return {f.name: f.default for f in dataclasses.fields(cls)}


#: Defaults of the engine's, the node's settings and of the accepted imu_tools gains (read-only views).
ENGINE_DEFAULTS: dict[str, Any] = _defaults_of(EngineSettings)
NODE_DEFAULTS: dict[str, Any] = _defaults_of(NodeSettings)
#: The motion hint's thresholds by default (speed m/s, turn rate rad/s, timeout s), as replay and fleet take them.
MOTION_HINT_DEFAULT: tuple[float, float, float] = (
    NODE_DEFAULTS['motion_hint_linear_m_s'], NODE_DEFAULTS['motion_hint_angular_rad_s'], NODE_DEFAULTS['motion_hint_timeout_s'])
#: imu_tools gain -> (its imu_tools default, the ccf parameter that plays its role).
IMU_TOOLS_GAINS: dict[str, tuple[Any, str]] = {
    f.name: (f.default, f.metadata['description']) for f in dataclasses.fields(ImuToolsGains)}
#: Every setting that is not a filter parameter (engine, node, imu_tools gains) with its default.
NON_FILTER_DEFAULTS: dict[str, Any] = {**ENGINE_DEFAULTS, **NODE_DEFAULTS, **{k: v for k, (v, _) in IMU_TOOLS_GAINS.items()}}
ADAPTER_DEFAULTS = NON_FILTER_DEFAULTS


def __getattr__(name: str) -> Any:
    # DESCRIPTIONS is read from the schema when asked for (the schema needs compat, which imports this module).
    if name == 'DESCRIPTIONS':
        return {n: p.description for n, p in schema().items()}
    raise AttributeError(name)


def format_value(value: Any) -> str:
    """A default as it is written in a parameters file or ``--param``: ``true``, ``2.5``, ``[1, 0, 0]``, ``''``."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return f'{value:g}'
    if isinstance(value, (tuple, list)):
        return '[' + ', '.join(format_value(v) for v in value) + ']'
    if value == '':
        return "''"
    return str(value)


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
    for name, p in schema().items():
        value = p.default
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
        lines.append(f'    {name}: {text}  # {p.description}')
    return '\n'.join(lines) + '\n'


#: The generated parameter tables lie between these lines: the README's (``python -m ccf_ros.settings --markdown``:
#: the default filter's parameters, the engine's and the node's) and doc/parameters.md's (``--markdown-all``: every one).
README_BEGIN = '<!-- parameters:begin (generated by python -m ccf_ros.settings; do not edit) -->'
README_END = '<!-- parameters:end -->'
#: Groups the README's table leaves to doc/parameters.md (as it leaves the baselines' gains): imu_tools' names.
_README_SKIPS = ('imu_tools',)


def _num(x: float) -> str:
    """A range bound as a reader writes it: 1e9, 3.14159, -10."""
    return f'{x:.0e}'.replace('e+0', 'e') if abs(x) >= 1e4 or 0 < abs(x) < 1e-4 else f'{x:g}'


def _range_text(p: Parameter) -> str:
    if p.choices:
        return ', '.join(p.choices)
    if p.range is None:
        return ''
    lo, hi = p.range
    return f'{"(" if p.above else "["}{_num(lo)}, {_num(hi)}]'


def _in_readme(p: Parameter) -> bool:
    """The default filter's parameters (and those of every filter), the engine's and the node's."""
    if p.group in _README_SKIPS:
        return False
    return p.group != 'filter' or p.applies_to.startswith(('every filter', 'ccf (quaternion)'))


def markdown_table(full: bool = False) -> str:
    """A parameter table between :data:`README_BEGIN` and :data:`README_END` (both included): the README's, or with
    ``full`` doc/parameters.md's (every parameter)."""
    lines = [README_BEGIN, '', '| name | default | unit | range | applies to | description |', '|---|---|---|---|---|---|']
    for name, p in schema().items():
        if not (full or _in_readme(p)):
            continue
        ro = f' (read-only in {", ".join(sorted(p.read_only))})' if p.read_only else ''
        cells = (f'`{name}`', f'`{format_value(p.default)}`', p.unit, _range_text(p), p.applies_to + ro,
                 p.description)
        lines.append('| ' + ' | '.join(c.replace('|', '\\|') for c in cells) + ' |')
    return '\n'.join([*lines, '', README_END]) + '\n'


def readme_table_is_current(readme_text: str, full: bool = False) -> bool | None:
    """Whether the table between the markers in ``readme_text`` is :func:`markdown_table`'s; None: no markers."""
    if README_BEGIN not in readme_text or README_END not in readme_text.partition(README_BEGIN)[2]:
        return None
    a = readme_text.index(README_BEGIN)
    b = readme_text.index(README_END, a) + len(README_END)
    return readme_text[a:b] + '\n' == markdown_table(full)


def main(argv: list[str] | None = None) -> int:
    """``python -m ccf_ros.settings`` prints config/ccf.yaml; ``--markdown`` the README's table, ``--markdown-all``
    doc/parameters.md's."""
    args = sys.argv[1:] if argv is None else argv
    if args not in ([], ['--markdown'], ['--markdown-all']):
        print('usage: python -m ccf_ros.settings [--markdown | --markdown-all]', file=sys.stderr)
        return 2
    print(markdown_table(args == ['--markdown-all']) if args else config_yaml(), end='')
    return 0


if __name__ == '__main__':
    sys.exit(main())
