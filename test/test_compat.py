"""imu_tools drop-in profiles (ROS-free parts): names, defaults, read-only flags, gain notices, TF; and the node's
ROS-free helpers for them (parameter values, imu/rpy/raw, the header TF needs)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ccf_ros.core.quaternion import quat_mul, quat_to_euler, rpy_of
from ccf_ros.engine import ImuEngine
from ccf_ros.errors import ParameterError
from ccf_ros.messages.cdr import header as imu_header
from ccf_ros.node.compat import (
    MEANINGLESS_GAINS,
    PROFILES,
    apply_do_bias_estimation,
    bias_estimation_notice,
    bias_estimation_off,
    defaults_for,
    gain_notices,
    tf_transform,
)
from ccf_ros.node.debug import raw_rpy
from ccf_ros.node.parameters import coerce_parameter, parameter_range
from ccf_ros.settings import IMU_TOOLS_GAINS, all_defaults, build


def test_profiles_match_the_anchor_nodes():
    m = PROFILES['imu_filter_madgwick_node']
    assert m.node_name == 'imu_filter_madgwick' and m.imu_topic == 'imu/data_raw' and m.out_topic == 'imu/data'
    assert (m.rpy_filtered_topic, m.rpy_raw_topic) == ('imu/rpy/filtered', 'imu/rpy/raw')
    assert m.defaults['publish_tf'] is True and {'yaw_offset', 'declination', 'stateless'} <= m.read_only
    assert 'gain' not in m.read_only and 'mag_bias_x' not in m.read_only and 'orientation_stddev' not in m.read_only
    assert not m.qos_overrides and m.steady_state_topic is None
    c = PROFILES['complementary_filter_node']
    # Jazzy's complementary filter (2.1.5) uses relative names; in the root namespace they resolve to /imu/...
    assert c.node_name == 'ComplementaryFilterROS' and (c.imu_topic, c.mag_topic) == ('imu/data_raw', 'imu/mag')
    assert (c.rpy_filtered_topic, c.rpy_raw_topic, c.steady_state_topic) == ('imu/rpy/filtered', None,
                                                                            'imu/steady_state')
    assert c.defaults['use_mag'] is False and c.defaults['bias_corrected_rate'] is True and c.qos_overrides
    assert 'orientation_stddev' not in c.read_only and 'gain_acc' in c.read_only
    names = set(all_defaults())
    for p in PROFILES.values():
        assert set(p.defaults) <= names and p.read_only <= names
        assert {'qos_reliability', 'qos_depth'} <= p.read_only  # the subscriptions are made with them
        d = defaults_for(p)
        assert set(d) == names and all(d[k] == v for k, v in p.defaults.items())


def test_ccf_node_changes_everything_at_run_time_but_its_input_qos():
    ccf = PROFILES['ccf_node']
    assert ccf.read_only == {'qos_reliability', 'qos_depth'} and ccf.qos_overrides
    assert (ccf.rpy_filtered_topic, ccf.rpy_raw_topic, ccf.steady_state_topic) == ('imu/rpy/filtered', 'imu/rpy/raw',
                                                                                  None)


def test_gain_notices_name_the_ccf_parameter_that_plays_the_role():
    assert gain_notices({'gain': 0.1, 'zeta': 0.0, 'gain_acc': 0.01}) == []  # anchors' defaults: silent
    notes = gain_notices({'gain': 0.05, 'do_adaptive_gain': False, 'bias_alpha': 1})
    assert len(notes) == 3 and any('tau_acc_s' in n for n in notes) and any('rest_tau_s' in n for n in notes)
    assert gain_notices({'gain': 0, 'bias_alpha': 0.01}) == [gain_notices({'gain': 0})[0]]  # int 0 is not 0.1
    # do_bias_estimation has a ccf meaning: not "ignored".
    assert gain_notices({'do_bias_estimation': False}) == []
    assert set(MEANINGLESS_GAINS) == set(IMU_TOOLS_GAINS) - {'do_bias_estimation'}


def test_do_bias_estimation_false_switches_bias_learning_off():
    v = {'do_bias_estimation': False, 'bias_corrected_rate': True}
    apply_do_bias_estimation(v, PROFILES['complementary_filter_node'])
    assert v['rest_bias'] is False and v['motion_bias'] is False and v['bias_corrected_rate'] is False
    v = {'do_bias_estimation': True}
    apply_do_bias_estimation(v, PROFILES['complementary_filter_node'])
    assert 'rest_bias' not in v
    v = {'do_bias_estimation': False, 'bias_corrected_rate': True}
    apply_do_bias_estimation(v, PROFILES['ccf_node'])
    assert v['rest_bias'] is False and v['bias_corrected_rate'] is True  # ccf_node: the rate is its own setting
    assert 'bias_corrected_rate' in bias_estimation_notice({'do_bias_estimation': False},
                                                           PROFILES['complementary_filter_node'])
    assert bias_estimation_notice({'do_bias_estimation': True}, PROFILES['ccf_node']) is None
    # A parameter file's text means the same everywhere (switch, notice, the steady_state topic).
    for text in ('false', 'False', ' off', 'no', '0'):
        assert bias_estimation_off({'do_bias_estimation': text}), text
        assert bias_estimation_notice({'do_bias_estimation': text}, PROFILES['ccf_node']) is not None
    for value in (True, 'true', 'yes', 1):
        assert not bias_estimation_off({'do_bias_estimation': value}), value
    assert not bias_estimation_off({})


def test_tf_is_the_orientation_or_its_inverse():
    q = (0.1, -0.2, 0.3, math.sqrt(1 - 0.14))
    assert tf_transform(q, 'imu_link', 'odom', False) == ('odom', 'imu_link', q)
    parent, child, r = tf_transform(q, 'imu_link', 'odom', True)
    assert (parent, child) == ('imu_link', 'odom')
    # q ⊗ r = identity
    x1, y1, z1, w1 = q
    x2, y2, z2, w2 = r
    assert w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2 == pytest.approx(1.0)


def test_scalar_rpy_equals_the_vectorised_conversion():
    rng = np.random.default_rng(1)
    q = rng.standard_normal((50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    np.testing.assert_allclose([rpy_of(tuple(v)) for v in q], quat_to_euler(q), atol=1e-12)


def test_real_parameters_take_integers_and_refuse_non_numbers():
    assert coerce_parameter('yaw_offset', 1, 0.0) == 1.0 and isinstance(coerce_parameter('yaw_offset', 1, 0.0), float)
    assert coerce_parameter('yaw_offset', -6, 0.0) == -6.0
    assert coerce_parameter('mag_bias_x', -3e-5, 0.0) == -3e-5
    assert coerce_parameter('mag_soft_iron', [1, 0, 0, 0, 1, 0, 0, 0, 1], (1.0,) * 9) == (1.0, 0.0, 0.0, 0.0, 1.0,
                                                                                          0.0, 0.0, 0.0, 1.0)
    assert coerce_parameter('kp', 3, 25.0) == 3.0 and coerce_parameter('kp', [1, 2, 3], 25.0) == (1.0, 2.0, 3.0)
    assert coerce_parameter('use_mag', True, True) is True and coerce_parameter('qos_depth', 7, 50) == 7
    for name, value in (('tau_acc_s', 'fast'), ('tau_acc_s', True), ('tau_acc_s', None), ('tau_acc_s', math.nan),
                        ('yaw_offset', 7.0), ('mag_bias_y', -10.5), ('tau_acc_s', -1), ('mag_soft_iron', 'abc'),
                        ('ekf_q', [1.0, 'x', 2.0]), ('kp', [True, 1, 2]),
                        # per-axis gains of a filter that is not selected: checked all the same
                        ('kp', [1, 2]), ('ki', [1.0, 2.0, 3.0, 4.0]), ('alpha', [0.5, 1.5, 0.5]), ('lcf_alpha', -0.1)):
        with pytest.raises(ParameterError, match=name):
            coerce_parameter(name, value, all_defaults()[name])
    # imu_tools' own ranges: signed angles and offsets.
    assert parameter_range('yaw_offset') == (-2 * math.pi, 2 * math.pi) and parameter_range('mag_bias_z') == (-10, 10)
    assert parameter_range('gain') == (0.0, 1.0) and parameter_range('zeta') == (-1.0, 1.0)


def test_raw_rpy_is_the_stateless_attitude_in_the_world_frame():
    rng = np.random.default_rng(3)
    for frame in ('enu', 'ned', 'nwu'):
        eng = ImuEngine(*build({'stateless': True, 'world_frame': frame}))
        for _ in range(20):
            acc = tuple(rng.normal(0, 3, 3) + [0, 0, 9.8])
            mag = tuple(rng.normal(0, 1, 3) * 2e-5 + [0, 2e-5, -4e-5])
            eng.on_mag(1.0, mag)
            out = eng.on_imu(1.0, (0.0, 0.0, 0.0), acc)
            x, y, z, w = out.orientation_xyzw
            np.testing.assert_allclose(raw_rpy(acc, mag, frame), rpy_of((w, x, y, z)), atol=1e-12)
    assert raw_rpy((0.0, 0.0, 9.8), None, 'enu') is None  # no magnetometer sample
    assert raw_rpy((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 'enu') is None  # free fall
    assert raw_rpy((0.0, 0.0, 9.8), (0.0, 0.0, 1.0), 'enu') is None  # field along gravity: no heading
    assert raw_rpy((0.0, 0.0, 9.8), (math.nan, 0.0, 1.0), 'enu') is None
    # Level, magnetic north along body y: ENU yaw 0.
    np.testing.assert_allclose(raw_rpy((0.0, 0.0, 9.8), (0.0, 2e-5, -4e-5), 'enu'), (0.0, 0.0, 0.0), atol=1e-12)


def test_imu_header_reads_stamp_and_frame_of_serialized_messages():
    from ccf_ros.offline.bagio import typestore

    ts = typestore()
    Imu = ts.types['sensor_msgs/msg/Imu']
    Header = ts.types['std_msgs/msg/Header']
    Time = ts.types['builtin_interfaces/msg/Time']
    Quat = ts.types['geometry_msgs/msg/Quaternion']
    Vec = ts.types['geometry_msgs/msg/Vector3']
    zeros = np.zeros(9)
    for frame in ('imu_link', '', 'x' * 13):
        msg = Imu(Header(Time(1700000123, 456789), frame), Quat(0.0, 0.0, 0.0, 1.0), zeros, Vec(0.0, 0.0, 0.0), zeros,
                  Vec(0.0, 0.0, 9.8), zeros)
        assert imu_header(bytes(ts.serialize_cdr(msg, 'sensor_msgs/msg/Imu'))) == (1700000123, 456789, frame)


def test_yaw_turn_of_the_transform_is_the_outputs():
    # TF carries the output orientation: turned by yaw_offset - declination about world up, as imu/data.
    eng = ImuEngine(*build({'yaw_offset': 0.3, 'declination': 0.1}))
    plain = ImuEngine(*build({}))
    for e in (eng, plain):
        e.on_mag(1.0, (0.0, 2e-5, -4e-5))
    a, b = eng.on_imu(1.0, (0, 0, 0), (0.5, 0.2, 9.7)), plain.on_imu(1.0, (0, 0, 0), (0.5, 0.2, 9.7))
    _, _, q = tf_transform(a.orientation_xyzw, 'imu_link', 'odom', False)
    x, y, z, w = b.orientation_xyzw
    turned = quat_mul([math.cos(0.1), 0, 0, math.sin(0.1)], [w, x, y, z])
    np.testing.assert_allclose([q[3], q[0], q[1], q[2]], turned, atol=1e-12)
