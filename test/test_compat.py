"""imu_tools drop-in profiles (ROS-free parts): names, defaults, read-only flags, gain notices, TF."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ccf_ros.compat import PROFILES, apply_do_bias_estimation, gain_notices, tf_transform
from ccf_ros.core.quaternion import quat_to_euler, rpy_of
from ccf_ros.settings import all_defaults


def test_profiles_match_the_anchor_nodes():
    m = PROFILES['imu_filter_madgwick_node']
    assert m.node_name == 'imu_filter_madgwick' and m.imu_topic == 'imu/data_raw' and m.out_topic == 'imu/data'
    assert (m.rpy_filtered_topic, m.rpy_raw_topic) == ('imu/rpy/filtered', 'imu/rpy/raw')
    assert m.defaults['publish_tf'] is True and {'yaw_offset', 'declination', 'stateless'} <= m.read_only
    assert 'gain' not in m.read_only and 'mag_bias_x' not in m.read_only and 'orientation_stddev' not in m.read_only
    c = PROFILES['complementary_filter_node']
    assert c.node_name == 'ComplementaryFilterROS' and (c.imu_topic, c.mag_topic) == ('/imu/data_raw', '/imu/mag')
    assert c.defaults['use_mag'] is False and c.defaults['bias_corrected_rate'] is True and c.qos_overrides
    assert 'orientation_stddev' not in c.read_only and 'gain_acc' in c.read_only
    names = set(all_defaults())
    for p in PROFILES.values():
        assert set(p.defaults) <= names and p.read_only <= names | {'qos_reliability', 'qos_depth'}


def test_gain_notices_name_the_ccf_parameter_that_plays_the_role():
    assert gain_notices({'gain': 0.1, 'zeta': 0.0, 'gain_acc': 0.01}) == []  # anchors' defaults: silent
    notes = gain_notices({'gain': 0.05, 'do_adaptive_gain': False, 'bias_alpha': 1})
    assert len(notes) == 3 and any('tau_acc_s' in n for n in notes) and any('rest_tau_s' in n for n in notes)


def test_do_bias_estimation_false_switches_bias_learning_off():
    v = {'do_bias_estimation': False, 'bias_corrected_rate': True}
    apply_do_bias_estimation(v, PROFILES['complementary_filter_node'])
    assert v['rest_bias'] is False and v['motion_bias'] is False and v['bias_corrected_rate'] is False
    v = {'do_bias_estimation': True}
    apply_do_bias_estimation(v, PROFILES['complementary_filter_node'])
    assert 'rest_bias' not in v


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
