"""The node with mount_rotation, output_frame_id and bias_file: the engine's answer in the output frame, the bias
file written on shutdown and read at start. Real DDS on loopback (conftest)."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from rosutil import big_endian_cdr, read_inputs  # noqa: E402
from test_node import MAG, Harness, _imu_only, _ref_xyzw, _replay_reference, _xyzw, reliable_node  # noqa: E402

from ccf_ros.frames import rotation_matrix  # noqa: E402
from ccf_ros.state_file import read_state  # noqa: E402

MOUNT = [0.3, -1.1, 2.5]


@pytest.fixture(scope='module')
def inputs(sim_bag):
    """8 s of the simulated bag (as test_node's)."""
    return read_inputs(sim_bag, 8.0)


def mounted(messages):
    """The messages as an IMU mounted with MOUNT measures them (gyro, accelerometer, magnetometer turned), with
    non-trivial rate and acceleration covariances."""
    R = np.array(rotation_matrix('m', MOUNT)).reshape(3, 3)
    out = []
    for topic, msg in messages:
        m = copy.deepcopy(msg)
        if topic == MAG:
            f = m.magnetic_field
            f.x, f.y, f.z = R.T @ (f.x, f.y, f.z)
        else:
            for v in (m.angular_velocity, m.linear_acceleration):
                v.x, v.y, v.z = R.T @ (v.x, v.y, v.z)
            m.angular_velocity_covariance = [1e-4, 0, 0, 0, 2e-4, 0, 0, 0, 3e-4]
        out.append((topic, m))
    return out


@pytest.mark.parametrize('big_endian', [False, True])
def test_node_answers_in_the_output_frame_as_replay_does(context, inputs, big_endian):
    node = reliable_node(context, mount_rotation=MOUNT, output_frame_id='base_link')
    h = Harness(context, node)
    try:
        h.wait_connected()
        msgs = mounted(inputs[:1200])
        h.feed([(t, big_endian_cdr(m)) for t, m in msgs] if big_endian else msgs, 600)
        ref = _replay_reference(inputs[:1200])
        assert len(h.out) == len(ref) == 600
        assert np.max(np.abs(_xyzw(h.out) - _ref_xyzw(ref))) < 1e-9
        rate = np.array([(m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) for m in h.out])
        raw = np.array([(m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z)
                        for m in _imu_only(inputs[:1200])])
        assert np.max(np.abs(rate - raw)) < 1e-12  # turned back into the output frame
        assert {m.header.frame_id for m in h.out} == {'base_link'}
        R = np.array(rotation_matrix('m', MOUNT)).reshape(3, 3)
        cov = R @ np.diag([1e-4, 2e-4, 3e-4]) @ R.T
        assert np.allclose(np.array(h.out[-1].angular_velocity_covariance).reshape(3, 3), cov, atol=1e-18)
    finally:
        h.close()


def test_node_writes_the_bias_file_on_shutdown_and_starts_from_it(context, inputs, tmp_path):
    path = tmp_path / 'bias.json'
    node = reliable_node(context, bias_file=str(path), gyro_bias_rate_hz=0.0)
    h = Harness(context, node)
    try:
        h.wait_connected()
        h.feed(inputs, len(_imu_only(inputs)))
        learnt = node.engine.filter.gyro_bias
    finally:
        h.close()  # destroy_node writes the file
    st = read_state(path)
    assert st.frame_id == 'imu_link' and np.allclose(st.gyro_bias()[0], learnt, atol=1e-15)
    assert np.linalg.norm(learnt) > math.radians(0.05)
    node = reliable_node(context, bias_file=str(path), gyro_bias_rate_hz=0.0)
    h = Harness(context, node)
    try:
        h.wait_connected()
        h.feed(inputs[:20], 10, n_bias=10)
        first = np.array([h.bias[0].vector.x, h.bias[0].vector.y, h.bias[0].vector.z])
        assert np.linalg.norm(first - learnt) < 0.02 * np.linalg.norm(learnt)
        assert not node.engine.warnings
    finally:
        h.close()


def test_node_refuses_a_bad_mount_at_start_and_while_running(context):
    from rclpy.parameter import Parameter

    from ccf_ros.errors import ParameterError
    from ccf_ros.node import CcfNode

    with pytest.raises(ParameterError, match='mount_rotation: the quaternion'):
        CcfNode(context=context, parameter_overrides=[Parameter('mount_rotation', value=[0.0, 0.0, 0.5, 0.5])])
    node = CcfNode(context=context)
    try:
        result = node.set_parameters([Parameter('mag_rotation', value=[1.0, 2.0])])[0]
        assert not result.successful and 'mag_rotation must be' in result.reason
        assert node.set_parameters([Parameter('mag_rotation', value=[0, 0, 1])])[0].successful  # integers accepted
        assert node.engine.settings.mag_rotation == (0.0, 0.0, 1.0)
    finally:
        node.destroy_node()


def test_node_writes_the_bias_file_every_interval_while_running(context, inputs, tmp_path):
    path = tmp_path / 'bias.json'
    node = reliable_node(context, bias_file=str(path), bias_save_interval_s=0.2)
    h = Harness(context, node)
    try:
        h.wait_connected()
        h.feed(inputs[:600], 300)
        assert h.spin_until(path.exists, 5.0), 'not written while running'
        first = read_state(path).stamp
        assert h.spin_until(lambda: read_state(path).stamp > first, 5.0), 'not written again'
        assert [p.name for p in tmp_path.iterdir()] == ['bias.json']  # no temporary left behind
    finally:
        h.close()
