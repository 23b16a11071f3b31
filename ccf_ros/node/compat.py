"""Drop-in profiles for imu_tools users: the executables' node names, topics, parameter defaults and read-only flags.

A user of ``imu_filter_madgwick`` or ``imu_complementary_filter`` (ROS 2 Jazzy) changes ``package=`` in the launch
file to ``ccf_ros`` and keeps everything else: executable name, node name, topic names, the YAML (keyed by the node
name), QoS overrides. Each executable runs the ccf filter; the anchors' parameter names are declared with the
anchors' types, defaults and read-only flags, and every ccf parameter is accepted too. No ROS import here (the node
reads these tables; tests check them without DDS).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ..core.fields import parse_bool
from ..settings import IMU_TOOLS_GAINS, all_defaults

#: Parameters of imu_filter_madgwick (Jazzy) that are read-only there.
_MADGWICK_READ_ONLY = frozenset({
    'stateless', 'use_mag', 'publish_tf', 'reverse_tf', 'fixed_frame', 'constant_dt', 'remove_gravity_vector',
    'publish_debug_topics', 'yaw_offset', 'declination', 'world_frame',
})
#: Parameters of imu_complementary_filter (Jazzy); all read-only there except orientation_stddev.
_COMPLEMENTARY_READ_ONLY = frozenset({
    'fixed_frame', 'use_mag', 'publish_tf', 'reverse_tf', 'constant_dt', 'publish_debug_topics', 'gain_acc',
    'gain_mag', 'do_bias_estimation', 'bias_alpha', 'do_adaptive_gain',
})
#: ccf_node: only the input QoS is fixed at start-up (the subscriptions are made with it). Everything else applies
#: while running, the TF and debug publishers included (made when first switched on).
_CCF_READ_ONLY = frozenset({'qos_reliability', 'qos_depth'})
#: The imu_tools gains that have no ccf meaning: accepted, and a notice is logged when one is set to a value other
#: than its imu_tools default. (``do_bias_estimation`` has a meaning: :func:`apply_do_bias_estimation`.)
MEANINGLESS_GAINS = ('gain', 'zeta', 'gain_acc', 'gain_mag', 'bias_alpha', 'do_adaptive_gain')


@dataclass(frozen=True)
class NodeProfile:
    """How one executable presents itself.

    Attributes:
        executable: console script / ``lib/ccf_ros/`` executable name.
        node_name: default node name (a launch file's ``name=`` overrides it, as usual).
        imu_topic, mag_topic, out_topic: input and output topics (relative: they resolve in the node's namespace).
        rpy_filtered_topic, rpy_raw_topic: debug topics (roll, pitch, yaw of the output / of the accelerometer and
            magnetometer alone), published with ``publish_debug_topics``; None: not published.
        steady_state_topic: std_msgs/Bool "at rest" debug topic (complementary filter, with ``publish_debug_topics``
            and ``do_bias_estimation``), or None.
        defaults: parameter defaults that differ from :func:`ccf_ros.settings.all_defaults` for this executable.
        read_only: parameters that cannot change after start-up. When ``use_mag`` is among them and false at
            start-up, the magnetometer is not subscribed (as in imu_tools).
        qos_overrides: input subscriptions accept rclpy's standard ``qos_overrides.<topic>.subscription.*``
            (depth, durability, history, reliability), ``<topic>`` being the resolved name (``/imu/data_raw``).
        bias_from_do_bias_estimation: ``do_bias_estimation`` also switches the bias-corrected ``angular_velocity``
            (the complementary filter's behaviour).
    """

    executable: str
    node_name: str
    imu_topic: str = 'imu/data_raw'
    mag_topic: str = 'imu/mag'
    out_topic: str = 'imu/data'
    rpy_filtered_topic: str | None = 'imu/rpy/filtered'
    rpy_raw_topic: str | None = 'imu/rpy/raw'
    steady_state_topic: str | None = None
    defaults: Mapping[str, Any] = field(default_factory=dict)
    read_only: frozenset[str] = _CCF_READ_ONLY
    qos_overrides: bool = False
    bias_from_do_bias_estimation: bool = False


PROFILES: dict[str, NodeProfile] = {
    'ccf_node': NodeProfile(executable='ccf_node', node_name='ccf_node', qos_overrides=True),
    'imu_filter_madgwick_node': NodeProfile(
        executable='imu_filter_madgwick_node',
        node_name='imu_filter_madgwick',
        defaults={'use_mag': True, 'publish_tf': True, 'fixed_frame': 'odom', 'world_frame': 'enu'},
        read_only=_MADGWICK_READ_ONLY | {'qos_reliability', 'qos_depth'},
    ),
    'complementary_filter_node': NodeProfile(
        executable='complementary_filter_node',
        node_name='ComplementaryFilterROS',
        # Jazzy's imu_complementary_filter (2.1.5) subscribes the relative imu/data_raw and imu/mag (older ROS 2
        # releases used /imu/data_raw, /imu/mag, /imu/steady_state); in the root namespace both resolve to
        # /imu/..., the names its filter_config.yaml's qos_overrides./imu/... keys use.
        rpy_raw_topic=None,
        steady_state_topic='imu/steady_state',
        # Its world frame with a magnetometer is North-West-Up (x towards magnetic north); without, yaw is relative.
        defaults={'use_mag': False, 'publish_tf': False, 'fixed_frame': 'odom', 'world_frame': 'nwu',
                  'bias_corrected_rate': True, 'qos_reliability': 'reliable', 'qos_depth': 10},
        read_only=_COMPLEMENTARY_READ_ONLY | {'qos_reliability', 'qos_depth', 'world_frame'},
        qos_overrides=True,
        bias_from_do_bias_estimation=True,
    ),
}


def gain_notices(values: Mapping[str, Any]) -> list[str]:
    """One line per imu_tools gain of :data:`MEANINGLESS_GAINS` in ``values`` with a value other than its imu_tools
    default: that it is ignored, and which ccf parameter plays that role instead."""
    out = []
    for name in MEANINGLESS_GAINS:
        default, role = IMU_TOOLS_GAINS[name]
        if name in values and values[name] != default and not (
            isinstance(default, float) and isinstance(values[name], (int, float)) and
            math.isclose(float(values[name]), default)
        ):
            out.append(f'{name}={values[name]!r} has no meaning for the ccf filter (ignored); ccf uses {role}')
    return out


def defaults_for(profile: NodeProfile) -> dict[str, Any]:
    """Every parameter an executable declares, with its default there: :func:`ccf_ros.settings.all_defaults`, the
    profile's own defaults over them."""
    out = all_defaults()
    out.update(profile.defaults)
    return out


def bias_estimation_off(values: Mapping[str, Any]) -> bool:
    """True if ``values`` say ``do_bias_estimation: false`` (a bool, or as text in a parameter file)."""
    try:
        return not parse_bool('do_bias_estimation', values.get('do_bias_estimation', True))
    except ValueError:
        return False  # not a flag: refused where the settings are checked (ccf_ros.settings.coerce)


def apply_do_bias_estimation(values: dict[str, Any], profile: NodeProfile) -> None:
    """imu_tools' ``do_bias_estimation: false`` switches bias learning off (and, for the complementary filter, the
    bias-corrected rate). Edits ``values`` in place."""
    if bias_estimation_off(values):
        values['rest_bias'] = False
        values['motion_bias'] = False
        if profile.bias_from_do_bias_estimation:
            values['bias_corrected_rate'] = False


def bias_estimation_notice(values: Mapping[str, Any], profile: NodeProfile) -> str | None:
    """What ``do_bias_estimation: false`` switches off (see :func:`apply_do_bias_estimation`), or None."""
    if not bias_estimation_off(values):
        return None
    also = ' and bias_corrected_rate' if profile.bias_from_do_bias_estimation else ''
    return f'do_bias_estimation=false: gyro-bias learning off (rest_bias and motion_bias false{also})'


def tf_transform(q_xyzw: tuple[float, float, float, float], imu_frame: str, fixed_frame: str, reverse: bool
                 ) -> tuple[str, str, tuple[float, float, float, float]]:
    """``(parent, child, rotation x, y, z, w)`` of the orientation as a transform: ``fixed_frame -> imu_frame``, or
    with ``reverse`` its inverse ``imu_frame -> fixed_frame`` (the conjugate, as imu_filter_madgwick does)."""
    if reverse:
        x, y, z, w = q_xyzw
        return imu_frame, fixed_frame, (-x, -y, -z, w)
    return fixed_frame, imu_frame, q_xyzw
