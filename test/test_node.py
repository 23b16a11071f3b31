"""ccf_node over real rclpy on loopback: same output as replay, parameters, reset, diagnostics, clean exit."""

from __future__ import annotations

import copy
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import Vector3Stamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rosutil import read_inputs  # noqa: E402
from sensor_msgs.msg import Imu, MagneticField  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from ccf_ros.core import make_filter  # noqa: E402
from ccf_ros.engine import ImuEngine  # noqa: E402
from ccf_ros.node import CcfNode  # noqa: E402

RELIABLE = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture
def context():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(os.environ['ROS_DOMAIN_ID']))
    yield ctx
    rclpy.try_shutdown(context=ctx)


class Harness:
    """A feeder/recorder node and the node under test on one executor."""

    def __init__(self, ctx, node, ns=''):
        self.ex = SingleThreadedExecutor(context=ctx)
        self.node = node
        self.io = rclpy.create_node('feeder', context=ctx, namespace=ns)
        self.pub_imu = self.io.create_publisher(Imu, 'imu/data_raw', RELIABLE)
        self.pub_mag = self.io.create_publisher(MagneticField, 'imu/mag', RELIABLE)
        self.out, self.bias, self.diag = [], [], []
        self.io.create_subscription(Imu, 'imu/data', self.out.append, RELIABLE)
        self.io.create_subscription(Vector3Stamped, 'imu/gyro_bias', self.bias.append, RELIABLE)
        self.io.create_subscription(DiagnosticArray, '/diagnostics', self.diag.append, 10)
        if node is not None:
            self.ex.add_node(node)
        self.ex.add_node(self.io)

    def wait_connected(self, timeout=10.0):
        deadline = time.time() + timeout
        while time.time() < deadline and (self.pub_imu.get_subscription_count() == 0
                                          or self.pub_mag.get_subscription_count() == 0
                                          or self.io.count_publishers('imu/data') == 0):
            self.ex.spin_once(timeout_sec=0.05)
        assert self.pub_imu.get_subscription_count() > 0 and self.pub_mag.get_subscription_count() > 0, \
            'node did not subscribe'

    def feed(self, messages, n_expected, timeout=60.0, n_bias=0):
        for i, (topic, msg) in enumerate(messages):
            (self.pub_mag if topic == '/imu/mag' else self.pub_imu).publish(msg)
            if i % 8 == 0:
                self.ex.spin_once(timeout_sec=0)
        deadline = time.time() + timeout
        while (len(self.out) < n_expected or len(self.bias) < n_bias) and time.time() < deadline:
            self.ex.spin_once(timeout_sec=0.05)

    def close(self):
        self.ex.shutdown()
        self.io.destroy_node()
        if self.node is not None:
            self.node.destroy_node()


def _replay_reference(messages, settings=None):
    """What `ccf replay` computes for the same messages in the same order (the shared engine)."""
    eng = ImuEngine(make_filter(settings))
    out = []
    for topic, msg in messages:
        s = msg.header.stamp
        t = s.sec + s.nanosec * 1e-9
        if topic == '/imu/mag':
            f = msg.magnetic_field
            eng.on_mag(t, (f.x, f.y, f.z))
        else:
            g, a = msg.angular_velocity, msg.linear_acceleration
            o = eng.on_imu(t, (g.x, g.y, g.z), (a.x, a.y, a.z))
            if o is not None:
                out.append(o.orientation_xyzw)
    return np.array(out)


def reliable_node(context, **params):
    """The node with lossless input QoS (and any extra parameters), as the tests need every message."""
    overrides = [Parameter('qos_reliability', value='reliable'), Parameter('qos_depth', value=5000)]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    return CcfNode(context=context, parameter_overrides=overrides)


@pytest.fixture(scope='module')
def inputs(broad_trial):
    return read_inputs(broad_trial, 8.0)


def test_node_publishes_exactly_what_replay_computes(context, inputs):
    node = reliable_node(context, gyro_bias_rate_hz=0.0)
    h = Harness(context, node)
    try:
        h.wait_connected()
        n_imu = sum(1 for t, _ in inputs if t == '/imu/data_raw')
        h.feed(inputs, n_imu, n_bias=n_imu)
        assert len(h.out) == n_imu
        got = np.array([(m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w) for m in h.out])
        np.testing.assert_array_equal(got, _replay_reference(inputs))
        assert len(h.bias) == n_imu and all(np.isfinite(b.vector.x) for b in h.bias)
        assert h.out[5].orientation_covariance[0] > 0 and h.out[5].header.frame_id == 'imu_link'
    finally:
        h.close()


def test_parameters_validated_live_and_applied_without_reset(context, inputs):
    node = reliable_node(context)
    h = Harness(context, node)
    try:
        h.wait_connected()
        h.feed(inputs[:2000], 1000)
        assert node.engine.filter.initialized
        q_before = node.engine.filter.quaternion
        r = node.set_parameters([Parameter('tau_acc_s', value=0.0)])[0]
        assert not r.successful and 'tau_acc_s' in r.reason
        r = node.set_parameters([Parameter('world_frame', value='sideways')])[0]
        assert not r.successful and 'world_frame' in r.reason
        r = node.set_parameters([Parameter('qos_depth', value=3)])[0]
        assert not r.successful  # read-only
        assert node.engine.filter.params.tau_acc_s == 3.0
        r = node.set_parameters([Parameter('tau_acc_s', value=1.5)])[0]
        assert r.successful
        assert node.engine.filter.params.tau_acc_s == 1.5
        assert node.engine.filter.initialized and node.engine.filter.quaternion == q_before
        r = node.set_parameters([Parameter('formulation', value='euler'), Parameter('kp', value=[1.0, 2.0, 3.0])])[0]
        assert r.successful and node.engine.filter.params._kp3 == (1.0, 2.0, 3.0)
    finally:
        h.close()


def test_reset_service_and_diagnostics(context, inputs):
    node = reliable_node(context)
    h = Harness(context, node)
    try:
        h.wait_connected()
        h.feed(inputs[:1000], 500, n_bias=5)
        # default gyro_bias_rate_hz 50: 500 samples at 286 Hz span 1.75 s -> about 88 bias messages, not 500
        assert 80 <= len(h.bias) <= 90
        status = node.diagnostic_status()
        values = {kv.key: kv.value for kv in status.values}
        assert values['samples answered'] == str(len(h.out)) and float(values['input rate (Hz)']) > 0
        deadline = time.time() + 3
        while not h.diag and time.time() < deadline:
            h.ex.spin_once(timeout_sec=0.1)
        assert h.diag and h.diag[-1].status[0].name.startswith('ccf_node')
        cli = h.io.create_client(Trigger, '/ccf_node/reset')
        assert cli.wait_for_service(timeout_sec=5)
        fut = cli.call_async(Trigger.Request())
        h.ex.spin_until_future_complete(fut, timeout_sec=5)
        assert fut.result().success and not node.engine.filter.initialized
    finally:
        h.close()


def _node_command():
    exe = shutil.which('ccf_node', path=os.path.dirname(sys.executable))
    return [exe] if exe else [sys.executable, '-m', 'ccf_ros.node']


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_installed_node_in_a_namespace_answers_and_exits_cleanly(context, inputs, sig):
    ns = f'robot{sig.value}'
    proc = subprocess.Popen(_node_command() + ['--ros-args', '-r', f'__ns:=/{ns}', '-p', 'qos_reliability:=reliable',
                                               '-p', 'qos_depth:=5000'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    h = Harness(context, None, ns=ns)
    try:
        h.wait_connected(timeout=20)
        h.feed(inputs[:1200], 600)
        assert len(h.out) == 600
        assert all(np.isfinite([m.orientation.w for m in h.out]))
    finally:
        proc.send_signal(sig)
        try:
            out, _ = proc.communicate(timeout=20)
        finally:
            h.close()
    assert proc.returncode == 0, out
    assert 'Traceback' not in out


def test_node_rejects_invalid_startup_parameters():
    r = subprocess.run(_node_command() + ['--ros-args', '-p', 'tau_acc_s:=0.0'], capture_output=True, text=True,
                       timeout=30)
    assert r.returncode != 0 and 'tau_acc_s' in (r.stdout + r.stderr)


def test_live_node_matches_replay_on_fast_rotation(tmp_path):
    """Fast rotation (up to ~800 deg/s) makes any IMU/magnetometer mis-pairing visible."""
    from conftest import SHARED, copy_bag

    from ccf_ros.offline.bagio import read_imu_arrays
    from ccf_ros.offline.evaluate import align
    from ccf_ros.offline.live import run_live

    trial = SHARED / '07_undisturbed_fast_rotation_B'
    if not trial.exists():
        pytest.skip('shared BROAD data not found')
    start = {}

    def from_45s(topic, msg, t):
        start.setdefault('t', t)
        return [(msg, t)] if t - start['t'] > 45e9 else []

    bag = copy_bag(trial, tmp_path / 'fast', stop_s=60.0, edit=from_45s)
    res = run_live(bag, rate=2.0)
    assert res.exit_code == 0 and len(res.t_s) == res.n_imu_sent > 4000
    imu = read_imu_arrays(bag)
    eng = ImuEngine(make_filter())
    ref = []
    for t, g, a, m in zip(imu.t_s.tolist(), imu.gyr.tolist(), imu.acc.tolist(), imu.mag.tolist(), strict=True):
        eng.on_mag(t, tuple(m))
        x, y, z, w = eng.on_imu(t, tuple(g), tuple(a)).orientation_xyzw
        ref.append((w, x, y, z))
    q = align(res.t_s, res.quat, imu.t_s, np.array(ref))
    diff = 2 * np.arccos(np.clip(np.abs(np.sum(q * np.array(ref), axis=1)), 0, 1))
    assert np.nanmax(diff) < 1e-3


def test_live_node_survives_faults_and_answers_every_valid_sample(faulty_trial):
    """NaN/Inf, zero vectors, duplicated/backward stamps, a 30 s gap and 10 s of silent magnetometer, over DDS."""
    from ccf_ros.offline.live import run_live

    path, injected = faulty_trial
    res = run_live(path, rate=4.0)
    assert res.exit_code == 0
    assert np.all(np.isfinite(res.quat))
    np.testing.assert_allclose(np.linalg.norm(res.quat, axis=1), 1.0, atol=1e-9)
    n_invalid = injected['nan_gyro'] + injected['inf_gyro'] + injected['dup'] + injected['back']
    assert len(res.t_s) == res.n_imu_sent - n_invalid


def test_debug_topic_fixed_covariance_and_constant_dt(context, inputs):
    node = reliable_node(context, publish_debug_topics=True, orientation_stddev=0.02, constant_dt=1 / 286.0)
    h = Harness(context, node)
    rpy = []
    h.io.create_subscription(Vector3Stamped, 'imu/rpy', rpy.append, RELIABLE)
    try:
        h.wait_connected()
        # With constant_dt the header stamps are ignored: zeroed stamps must not stop the filter.
        msgs = [(topic, copy.deepcopy(msg)) for topic, msg in inputs[:1000]]
        for _, msg in msgs:
            msg.header.stamp.sec = msg.header.stamp.nanosec = 0
        h.feed(msgs, 500)
        assert len(h.out) == 500
        assert h.out[-1].orientation_covariance[0] == pytest.approx(0.02**2)
        deadline = time.time() + 5
        while len(rpy) < 500 and time.time() < deadline:
            h.ex.spin_once(timeout_sec=0.05)
        q = h.out[-1].orientation
        roll = np.arctan2(2 * (q.w * q.x + q.y * q.z), 1 - 2 * (q.x**2 + q.y**2))
        assert len(rpy) == 500 and rpy[-1].vector.x == pytest.approx(roll)
    finally:
        h.close()


def test_first_imu_before_its_magnetometer_sample_pairs_as_in_replay(context, inputs):
    """Delivery order across topics is not guaranteed: the node must still initialise heading as replay does."""
    node = reliable_node(context)
    h = Harness(context, node)
    try:
        h.wait_connected()
        msgs = list(inputs[:600])
        assert msgs[0][0] == '/imu/mag' and msgs[1][0] == '/imu/data_raw'
        swapped = [msgs[1], msgs[0]] + msgs[2:]  # the IMU sample overtakes its magnetometer sample
        h.feed(swapped, 300)
        got = np.array([(m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w) for m in h.out])
        np.testing.assert_array_equal(got, _replay_reference(msgs))
    finally:
        h.close()


def test_node_runs_the_kalman_baselines_with_array_parameters(context, inputs):
    node = reliable_node(context, filter='ckf', ckf_r=[0.2, 0.02, 1.0])
    assert node.engine.filter.name == 'ckf' and node.engine.filter.params.ckf_r == (0.2, 0.02, 1.0)
    r = node.set_parameters([Parameter('ckf_r', value=[1.0])])[0]
    assert not r.successful and 'ckf_r' in r.reason
    r = node.set_parameters([Parameter('filter', value='ekf'), Parameter('ekf_q', value=[1.0, 2.0, 3.0])])[0]
    assert r.successful and node.engine.filter.name == 'ekf' and node.engine.filter.params.ekf_q == (1.0, 2.0, 3.0)
    h = Harness(context, node)
    try:
        h.wait_connected()
        h.feed(inputs[:1000], 500)
        assert len(h.out) == 500
        got = np.array([(m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w) for m in h.out])
        assert np.isfinite(got).all() and np.allclose(np.linalg.norm(got, axis=1), 1.0)
        # The node's EKF answers exactly what the core's EKF computes from the same messages.
        np.testing.assert_array_equal(got, _replay_reference(inputs[:1000], {'filter': 'ekf', 'ekf_q': (1, 2, 3)}))
    finally:
        h.close()
