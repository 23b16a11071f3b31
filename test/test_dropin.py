"""imu_tools drop-in over real rclpy on loopback: imu_tools' own YAML files on the compatibility executables, their
parameter names, types, defaults and read-only flags, QoS overrides, integers for reals, TF, debug topics, one
output per input, gain notices. In-process nodes (CcfNode with a profile) except one test of the real executable."""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from geometry_msgs.msg import Vector3Stamped  # noqa: E402
from rcl_interfaces.msg import ParameterType  # noqa: E402
from rclpy.parameter import Parameter, parameter_value_to_python  # noqa: E402
from rclpy.parameter_client import AsyncParameterClient  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy  # noqa: E402
from rosutil import stop_node  # noqa: E402
from std_msgs.msg import Bool  # noqa: E402
from test_node import IMU, MAG, RELIABLE, Harness, _imu_only, _ref_xyzw, _replay_reference, _xyzw  # noqa: E402

import ccf_ros.node.node  # noqa: E402
from ccf_ros.core.quaternion import from_xyzw, rpy_of  # noqa: E402
from ccf_ros.node import TF_UNAVAILABLE, CcfNode, tf_message_type  # noqa: E402
from ccf_ros.node.compat import PROFILES, defaults_for, tf_transform  # noqa: E402
from ccf_ros.node.debug import raw_rpy  # noqa: E402
from ccf_ros.offline.params_file import load_params_file  # noqa: E402

DATA = Path(__file__).resolve().parent / 'data'
#: imu_tools' own files, verbatim: imu_filter_madgwick/config/imu_filter.yaml and
#: imu_complementary_filter/config/filter_config.yaml (Jazzy).
MADGWICK_YAML = DATA / 'imu_filter.yaml'
COMPLEMENTARY_YAML = DATA / 'filter_config.yaml'

#: imu_filter_madgwick (Jazzy): every parameter it declares -> (default, read-only).
MADGWICK = {
    'stateless': (False, True), 'use_mag': (True, True), 'publish_tf': (True, True), 'reverse_tf': (False, True),
    'fixed_frame': ('odom', True), 'constant_dt': (0.0, True), 'remove_gravity_vector': (False, True),
    'publish_debug_topics': (False, True), 'yaw_offset': (0.0, True), 'declination': (0.0, True),
    'world_frame': ('enu', True), 'gain': (0.1, False), 'zeta': (0.0, False), 'mag_bias_x': (0.0, False),
    'mag_bias_y': (0.0, False), 'mag_bias_z': (0.0, False), 'orientation_stddev': (0.0, False),
}
#: imu_complementary_filter (Jazzy 2.1.5): every parameter it declares -> (default, read-only).
COMPLEMENTARY = {
    'fixed_frame': ('odom', True), 'use_mag': (False, True), 'publish_tf': (False, True), 'reverse_tf': (False, True),
    'constant_dt': (0.0, True), 'publish_debug_topics': (False, True), 'gain_acc': (0.01, True),
    'gain_mag': (0.01, True), 'do_bias_estimation': (True, True), 'bias_alpha': (0.01, True),
    'do_adaptive_gain': (True, True), 'orientation_stddev': (0.0, False),
}
TYPES = {bool: ParameterType.PARAMETER_BOOL, str: ParameterType.PARAMETER_STRING,
         float: ParameterType.PARAMETER_DOUBLE}


@pytest.fixture(scope='module')
def inputs(sim_bag):
    from rosutil import read_inputs

    return read_inputs(sim_bag, 4.0)


class Logs:
    """Stands in for the node's logger: records (level, text)."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def _add(self, level: str, text: str, **_kw) -> bool:
        self.lines.append((level, text))
        return True

    def info(self, text, **kw):
        return self._add('info', text, **kw)

    def warning(self, text, **kw):
        return self._add('warning', text, **kw)

    warn = warning

    def error(self, text, **kw):
        return self._add('error', text, **kw)

    def debug(self, text, **kw):
        return self._add('debug', text, **kw)

    def warnings(self, part: str = '') -> list[str]:
        return [t for level, t in self.lines if level == 'warning' and part in t]


@pytest.fixture
def logs(monkeypatch):
    rec = Logs()
    monkeypatch.setattr(CcfNode, 'get_logger', lambda self: rec)
    return rec


def make(context, profile='ccf_node', reliable=True, cli_args=None, **params):
    """A node of ``profile``; ``reliable``: lossless input QoS (the tests need every message)."""
    overrides = [Parameter('qos_reliability', value='reliable'), Parameter('qos_depth', value=5000)] if reliable else []
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    return CcfNode(profile, context=context, parameter_overrides=overrides, cli_args=cli_args)


class DropinHarness(Harness):
    """The test_node harness for a node that may not subscribe the magnetometer (use_mag read-only and false)."""

    def wait_connected(self, timeout=10.0):
        if self.node is None or self.node.sub_mag is not None:
            super().wait_connected(timeout)
            return
        deadline = time.time() + timeout
        while time.time() < deadline and (self.pub_imu.get_subscription_count() == 0
                                          or self.io.count_publishers('imu/data') == 0):
            self.ex.spin_once(timeout_sec=0.05)
        assert self.pub_imu.get_subscription_count() > 0, 'node did not subscribe'

    def feed_paced(self, messages, chunk=8):
        """Publish ``chunk`` messages at a time, each chunk answered before the next (a reader queue of depth 10, as
        the complementary filter's own QoS override has, must not overflow)."""
        n = len(self.out)
        for i in range(0, len(messages), chunk):
            part = messages[i:i + chunk]
            for topic, msg in part:
                self.publish(topic, msg)
            n += sum(1 for t, _ in part if t == IMU)
            assert self.spin_until(lambda n=n: len(self.out) >= n), f'{len(self.out)} answers, expected {n}'


def declared(node, names):
    return {n: node.get_parameter(n).value for n in names}


# --- parameters: imu_tools' own files, names, types, defaults, read-only ------------------------------------------

@pytest.mark.parametrize(('profile', 'anchor'), [('imu_filter_madgwick_node', MADGWICK),
                                                 ('complementary_filter_node', COMPLEMENTARY)])
def test_every_imu_tools_parameter_with_its_type_default_and_read_only_flag(context, profile, anchor):
    node = CcfNode(profile, context=context)
    try:
        assert node.get_name() == PROFILES[profile].node_name
        for name, (default, read_only) in anchor.items():
            p = node.get_parameter(name)
            assert p.value == default, name
            assert p.type_.value == TYPES[type(default)], name
            assert node.describe_parameter(name).read_only is read_only, name
        # ... and every ccf parameter too (names the anchor does not have are not read-only unless compat says so).
        names = set(defaults_for(PROFILES[profile]))
        assert all(node.has_parameter(n) for n in names)
        for name in names - set(anchor):
            assert node.describe_parameter(name).read_only is (name in PROFILES[profile].read_only), name
    finally:
        node.destroy_node()


def test_complementary_filter_config_yaml_declared_and_its_qos_override_applied(context, inputs):
    """filter_config.yaml (keyed complementary_filter_gain_node) through rcl's own YAML parser, on the executable
    renamed as imu_tools' launch file does."""
    cli = ['--ros-args', '-r', '__node:=complementary_filter_gain_node', '--params-file', str(COMPLEMENTARY_YAML)]
    node = CcfNode('complementary_filter_node', context=context, cli_args=cli)
    h = DropinHarness(context, node)
    try:
        assert node.get_name() == 'complementary_filter_gain_node'
        expected = load_params_file(COMPLEMENTARY_YAML)
        # use_mag false: like imu_complementary_filter it does not subscribe imu/mag, so the /imu/mag overrides are
        # not declared (see the next test); everything else of the file is, with the file's value.
        mag_keys = {k for k in expected if k.startswith('qos_overrides./imu/mag.')}
        assert len(mag_keys) == 4 and node.sub_mag is None
        for name, value in expected.items():
            if name not in mag_keys:
                assert node.get_parameter(name).value == value, name
        qos = node.sub_imu.qos_profile
        assert (qos.reliability, qos.depth, qos.history, qos.durability) == (
            ReliabilityPolicy.RELIABLE, 10, HistoryPolicy.KEEP_LAST, DurabilityPolicy.VOLATILE)
        assert node.sub_imu.topic_name == '/imu/data_raw'
        # It runs: every IMU sample answered, as the engine computes with this executable's settings.
        h.wait_connected()
        imu_only = [(IMU, m) for m in _imu_only(inputs[:800])]
        h.feed_paced(imu_only)
        ref = _replay_reference(imu_only, node._effective(node._settings))
        assert len(h.out) == len(ref) == len(imu_only) == 400
        np.testing.assert_array_equal(_xyzw(h.out), _ref_xyzw(ref))
        # The complementary filter's output rate is bias-corrected (do_bias_estimation true).
        assert node.engine.settings.bias_corrected_rate
        # `ccf replay --profile complementary_filter_node --params-file filter_config.yaml` runs the same engine.
        from ccf_ros.cli import build_parser, engine_settings, make_engine

        args = build_parser().parse_args(['replay', 'in', '-o', 'out', '--profile', 'complementary_filter_node',
                                           '--params-file', str(COMPLEMENTARY_YAML)])
        offline = _replay_reference(imu_only, engine=make_engine(*engine_settings(args)))
        np.testing.assert_array_equal(_xyzw(h.out), _ref_xyzw(offline))
        rates = np.array([(m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) for m in h.out])
        np.testing.assert_array_equal(rates, [o.angular_velocity for o in offline])
    finally:
        h.close()


def test_qos_override_parameters_take_effect_on_both_serialized_subscriptions(context):
    """ccf_node takes rclpy's standard qos_overrides too, on its raw (serialized) subscriptions; the override wins over
    qos_reliability/qos_depth, and each subscription gets its own."""
    cli = ['--ros-args', '-p', 'qos_overrides./imu/data_raw.subscription.reliability:=reliable',
           '-p', 'qos_overrides./imu/data_raw.subscription.depth:=7',
           '-p', 'qos_overrides./imu/mag.subscription.depth:=3']
    node = make(context, reliable=False, cli_args=cli)
    probe = rclpy.create_node('probe', context=context)
    try:
        assert node.get_parameter('qos_reliability').value == 'best_effort'
        imu, mag = node.sub_imu.qos_profile, node.sub_mag.qos_profile
        assert (imu.reliability, imu.depth) == (ReliabilityPolicy.RELIABLE, 7)
        assert (mag.reliability, mag.depth) == (ReliabilityPolicy.BEST_EFFORT, 3)
        assert node.get_parameter('qos_overrides./imu/mag.subscription.reliability').value == 'best_effort'
        assert node.describe_parameter('qos_overrides./imu/data_raw.subscription.depth').read_only
        # What DDS was given, as other participants see it.
        seen = {i.qos_profile.reliability for i in probe.get_subscriptions_info_by_topic('/imu/data_raw')}
        assert seen == {ReliabilityPolicy.RELIABLE}
        # The complementary filter with use_mag: both subscriptions take the file's overrides.
        cli = ['--ros-args', '-r', '__node:=complementary_filter_gain_node', '--params-file', str(COMPLEMENTARY_YAML),
               '-p', 'use_mag:=true']
        comp = CcfNode('complementary_filter_node', context=context, cli_args=cli)
        try:
            assert comp.sub_mag is not None and comp.sub_mag.topic_name == '/imu/mag'
            expected = load_params_file(COMPLEMENTARY_YAML)
            assert declared(comp, [k for k in expected if k.startswith('qos_overrides.')]) == {
                k: v for k, v in expected.items() if k.startswith('qos_overrides.')}
            assert (comp.sub_mag.qos_profile.reliability, comp.sub_mag.qos_profile.depth) == (
                ReliabilityPolicy.RELIABLE, 10)
        finally:
            comp.destroy_node()
        # Madgwick has no QoS overrides (as imu_filter_madgwick).
        cli = ['--ros-args', '-p', 'qos_overrides./imu/data_raw.subscription.depth:=7']
        madg = CcfNode('imu_filter_madgwick_node', context=context, cli_args=cli)
        try:
            assert not madg.has_parameter('qos_overrides./imu/data_raw.subscription.depth')
            assert madg.sub_imu.qos_profile.depth == 50
        finally:
            madg.destroy_node()
    finally:
        probe.destroy_node()
        node.destroy_node()


def test_integers_for_real_parameters_negative_offsets_and_non_numbers(context):
    node = make(context, 'imu_filter_madgwick_node', yaw_offset=1, declination=-2, mag_bias_x=-3, mag_bias_y=0,
                orientation_stddev=0, mag_soft_iron=[1, 0, 0, 0, 2, 0, 0, 0, 1])
    try:
        s = node.engine.settings
        assert (s.yaw_offset, s.declination, s.mag_bias, s.orientation_stddev) == (1.0, -2.0, (-3.0, 0.0, 0.0), 0.0)
        assert s.mag_soft_iron == (1.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 1.0)
        assert isinstance(s.yaw_offset, float)
        # At run time: integers accepted, non-numbers and out-of-range values refused with a reason.
        assert node.set_parameters([Parameter('tau_acc_s', value=3)])[0].successful
        assert node.engine.filter.params.tau_acc_s == 3.0
        assert node.set_parameters([Parameter('mag_bias_z', value=-0.00004)])[0].successful
        assert node.engine.settings.mag_bias == (-3.0, 0.0, -0.00004)
        for name, value in (('tau_acc_s', 'fast'), ('tau_acc_s', True), ('mag_bias_x', 11.0), ('gain', 2),
                            ('mag_bias_y', [1.0]), ('orientation_stddev', -1)):
            r = node.set_parameters([Parameter(name, value=value)])[0]
            assert not r.successful and name in r.reason, (name, value, r.reason)
        r = node.set_parameters([Parameter('mag_soft_iron', value=['a'] * 9)])[0]
        assert not r.successful and 'mag_soft_iron' in r.reason
        # Read-only as in imu_filter_madgwick.
        assert not node.set_parameters([Parameter('yaw_offset', value=0.5)])[0].successful
    finally:
        node.destroy_node()
    with pytest.raises(ValueError, match='yaw_offset'):
        make(context, 'imu_filter_madgwick_node', yaw_offset='north')


def test_madgwick_offsets_and_gravity_removal_go_to_the_engine(context, inputs):
    settings = {'yaw_offset': 0.3, 'declination': 0.1, 'mag_bias_x': 2e-6, 'mag_bias_y': -1e-6, 'mag_bias_z': 0,
                'remove_gravity_vector': True}
    node = make(context, 'imu_filter_madgwick_node', **settings)
    h = DropinHarness(context, node)
    try:
        h.wait_connected()
        h.feed(inputs[:800], 400)
        ref = _replay_reference(inputs[:800], node._effective(node._settings))
        plain = _replay_reference(inputs[:800], {'mag_bias_x': 2e-6, 'mag_bias_y': -1e-6})
        assert len(h.out) == len(ref) == 400
        np.testing.assert_array_equal(_xyzw(h.out), _ref_xyzw(ref))
        # q_out = Rz(yaw_offset - declination) ⊗ q
        turn = np.array([math.cos(0.1), 0.0, 0.0, math.sin(0.1)])
        from ccf_ros.core.quaternion import quat_mul

        expect = quat_mul(turn, np.array([from_xyzw(*o.orientation_xyzw) for o in plain]))
        got = np.array([from_xyzw(m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w) for m in h.out])
        np.testing.assert_allclose(np.abs(np.sum(got * expect, axis=1)), 1.0, atol=1e-12)
        lin = np.array([(m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z) for m in h.out])
        assert np.abs(lin[:300]).max() < 0.3  # at rest (the first 5 s of the simulation): gravity removed
    finally:
        h.close()


def test_do_bias_estimation_false_switches_bias_learning_off(context, logs):
    node = make(context, 'complementary_filter_node', do_bias_estimation=False)
    try:
        p = node.engine.filter.params
        assert (p.rest_bias, p.motion_bias, node.engine.settings.bias_corrected_rate) == (False, False, False)
        assert any('do_bias_estimation=false' in t for _, t in logs.lines)
    finally:
        node.destroy_node()
    node = make(context, do_bias_estimation=False)  # ccf_node: at run time too, and the rate stays as it was
    try:
        assert not node.engine.filter.params.rest_bias and not node.engine.settings.bias_corrected_rate
        assert node.set_parameters([Parameter('do_bias_estimation', value=True)])[0].successful
        assert node.engine.filter.params.rest_bias and node.engine.filter.params.motion_bias
    finally:
        node.destroy_node()


def test_gain_notices_logged_once_at_start_up_and_when_set_later(context, logs):
    node = make(context, 'imu_filter_madgwick_node', gain=0.3)
    try:
        assert len(logs.warnings('gain=0.3')) == 1 and 'tau_acc_s' in logs.warnings('gain=0.3')[0]
        assert not logs.warnings('zeta')  # its default: silent
        assert node.set_parameters([Parameter('zeta', value=0.5)])[0].successful
        assert node.set_parameters([Parameter('zeta', value=0.6)])[0].successful
        assert node.set_parameters([Parameter('gain', value=0.4)])[0].successful
        assert len(logs.warnings('zeta=')) == 1 and len(logs.warnings('gain=')) == 1
    finally:
        node.destroy_node()


# --- TF ---------------------------------------------------------------------------------------------------------

def test_publish_tf_without_tf2_msgs_warns_once_and_the_node_runs_on(context, inputs, logs, monkeypatch):
    monkeypatch.setattr(ccf_ros.node.node, 'tf_message_type', lambda: None)
    node = make(context, 'imu_filter_madgwick_node')  # publish_tf defaults to true there
    h = DropinHarness(context, node)
    try:
        assert logs.warnings(TF_UNAVAILABLE) == [TF_UNAVAILABLE] and node.pub_tf is None
        h.wait_connected()
        h.feed(inputs[:400], 200)
        assert len(h.out) == 200
        assert '/tf' not in dict(node.get_topic_names_and_types())
    finally:
        h.close()
    # ccf_node switches publish_tf at run time: still the one warning.
    node = make(context)
    try:
        for value in (True, False, True):
            assert node.set_parameters([Parameter('publish_tf', value=value)])[0].successful
        assert len(logs.warnings(TF_UNAVAILABLE)) == 2  # one per node
    finally:
        node.destroy_node()


class _TFMessage:
    """A stand-in for tf2_msgs/TFMessage (not installable here)."""

    def __init__(self, transforms):
        self.transforms = transforms


def test_transform_is_the_output_orientation_stamped_and_framed(context, inputs, monkeypatch):
    """With tf2_msgs the node publishes, per answer, fixed_frame -> IMU frame with the output orientation (yaw offset
    included, as imu/data), or its inverse with reverse_tf. The /tf publisher is recorded, as TFMessage is absent."""
    sent = []

    class Pub:
        def publish(self, msg):
            sent.append(msg)

    real = CcfNode.create_publisher
    monkeypatch.setattr(ccf_ros.node.node, 'tf_message_type', lambda: _TFMessage)
    monkeypatch.setattr(CcfNode, 'create_publisher',
                        lambda self, t, topic, *a, **k: Pub() if topic == '/tf' else real(self, t, topic, *a, **k))
    node = make(context, 'imu_filter_madgwick_node', yaw_offset=0.25)
    h = DropinHarness(context, node)
    try:
        h.wait_connected()
        h.feed(inputs[:200], 100)
        assert len(sent) == len(h.out) == 100
        for tf, out in zip(sent, h.out, strict=True):
            (tr,) = tf.transforms
            assert (tr.header.frame_id, tr.child_frame_id) == ('odom', 'imu_link')
            assert tr.header.stamp == out.header.stamp
            r, o = tr.transform.rotation, out.orientation
            assert (r.x, r.y, r.z, r.w) == (o.x, o.y, o.z, o.w)
            t = tr.transform.translation
            assert (t.x, t.y, t.z) == (0.0, 0.0, 0.0)
    finally:
        h.close()
    sent.clear()
    node = make(context, publish_tf=True, reverse_tf=True, fixed_frame='world')  # ccf_node: publish_tf default false
    h = DropinHarness(context, node)
    try:
        h.wait_connected()
        h.feed(inputs[:200], 100)
        (tr,) = sent[-1].transforms
        o = h.out[-1].orientation
        assert (tr.header.frame_id, tr.child_frame_id) == ('imu_link', 'world')
        r = tr.transform.rotation
        assert (r.x, r.y, r.z, r.w) == tf_transform((o.x, o.y, o.z, o.w), 'imu_link', 'world', True)[2]
    finally:
        h.close()


# --- debug topics, one output per input --------------------------------------------------------------------------

@pytest.mark.parametrize(('profile', 'topics'), [
    ('ccf_node', {'/imu/rpy/filtered', '/imu/rpy/raw'}),
    ('imu_filter_madgwick_node', {'/imu/rpy/filtered', '/imu/rpy/raw'}),
    ('complementary_filter_node', {'/imu/rpy/filtered', '/imu/steady_state'}),
])
def test_debug_topics_have_the_anchors_names_and_values(context, inputs, profile, topics):
    node = make(context, profile, publish_debug_topics=True)
    h = DropinHarness(context, node)
    got: dict[str, list] = {t: [] for t in topics}
    for t in topics:
        h.io.create_subscription(Bool if t.endswith('steady_state') else Vector3Stamped, t, got[t].append, RELIABLE)
    try:
        names = set(dict(node.get_topic_names_and_types()))
        assert topics <= names and '/imu/rpy' not in names
        assert not ({'/imu/rpy/filtered', '/imu/rpy/raw', '/imu/steady_state'} - topics) & names
        h.wait_connected()
        assert h.spin_until(lambda: all(h.io.count_publishers(t) > 0 for t in topics))
        # 600 samples (2.1 s) of the simulation's rest: longer than the rest detector's 1.5 s.
        msgs = inputs[:1200] if node.sub_mag is not None else [(IMU, m) for m in _imu_only(inputs[:1200])]
        h.feed(msgs, 600)
        assert h.spin_until(lambda: all(len(v) == 600 for v in got.values())), {k: len(v) for k, v in got.items()}
        q = [(m.orientation.w, m.orientation.x, m.orientation.y, m.orientation.z) for m in h.out]
        filtered = np.array([(v.vector.x, v.vector.y, v.vector.z) for v in got['/imu/rpy/filtered']])
        np.testing.assert_allclose(filtered, [rpy_of(x) for x in q], rtol=0, atol=1e-12)
        assert all(v.header == m.header for v, m in zip(got['/imu/rpy/filtered'], h.out, strict=True))
        if '/imu/rpy/raw' in topics:
            # The accelerometer + magnetometer attitude of each sample alone (the simulation's mag is in lock-step).
            mags = [m.magnetic_field for t, m in msgs if t == MAG]
            accs = [m.linear_acceleration for t, m in msgs if t == IMU]
            expect = [raw_rpy((a.x, a.y, a.z), (f.x, f.y, f.z), 'enu') for a, f in zip(accs, mags, strict=True)]
            raw = np.array([(v.vector.x, v.vector.y, v.vector.z) for v in got['/imu/rpy/raw']])
            np.testing.assert_allclose(raw, expect, rtol=0, atol=1e-12)
            # At rest (start of the simulation) the raw attitude is the filtered one, within noise.
            assert np.abs(np.degrees(raw[:100, :2] - filtered[:100, :2])).max() < 2.0
        if '/imu/steady_state' in topics:
            # The simulation starts at rest: not steady until the rest detector's minimum time has passed, then
            # steady; each message carries the flag after its own sample.
            steady = [m.data for m in got['/imu/steady_state']]
            assert steady[0] is False and steady[-1] == node.engine.filter.flags.at_rest
            assert steady.index(True) == 429  # 1.5 s at 286 Hz
            assert all(steady[steady.index(True):])  # and stays steady while the body rests
    finally:
        h.close()


@pytest.mark.parametrize('profile', sorted(PROFILES))
def test_every_input_answered_repeated_stamp_included(context, inputs, profile):
    node = make(context, profile)
    h = DropinHarness(context, node)
    try:
        h.wait_connected()
        msgs = inputs[:200] if node.sub_mag is not None else [(IMU, m) for m in _imu_only(inputs[:200])]
        n_imu = sum(1 for t, _ in msgs if t == IMU)
        last = msgs[-1][1]
        h.feed(msgs, n_imu)
        # The same IMU message again: same stamp, it cannot advance the filter; answered with the orientation.
        h.feed([(IMU, last), (IMU, last)], n_imu + 2)
        assert len(h.out) == n_imu + 2
        assert h.out[-1].header == h.out[-2].header == last.header
        assert h.out[-1].orientation == h.out[-2].orientation == h.out[-3].orientation
        v = node.diagnostics().values
        assert v['samples answered'] == str(n_imu + 2)
        assert v['samples answered with the current orientation (could not advance the filter)'] == '2'
        assert v['skipped: skipped_stamp'] == '2'
    finally:
        h.close()


def test_ccf_node_switches_debug_topics_at_run_time(context):
    node = make(context)
    try:
        assert not node.describe_parameter('publish_debug_topics').read_only
        assert node.pub_rpy is None
        assert node.set_parameters([Parameter('publish_debug_topics', value=True)])[0].successful
        assert node.pub_rpy.topic_name == '/imu/rpy/filtered' and node.pub_rpy_raw.topic_name == '/imu/rpy/raw'
    finally:
        node.destroy_node()


def test_launch_files_name_the_executables_as_imu_tools_launch_files_do():
    """launch_ros is not in the pip install: the files are checked as Python and for what they launch."""
    import ast

    launch = Path(__file__).resolve().parents[1] / 'launch'
    for path in sorted(launch.glob('*.launch.py')):
        compile(path.read_text(), str(path), 'exec')
    for file, executable, name in (('imu_filter.launch.py', 'imu_filter_madgwick_node', 'imu_filter'),
                                   ('complementary_filter.launch.py', 'complementary_filter_node',
                                    'complementary_filter_gain_node')):
        calls = [n for n in ast.walk(ast.parse((launch / file).read_text()))
                 if isinstance(n, ast.Call) and getattr(n.func, 'id', '') == 'Node']
        (node,) = calls
        kw = {k.arg: k.value.value for k in node.keywords if isinstance(k.value, ast.Constant)}
        assert kw == {'package': 'ccf_ros', 'executable': executable, 'name': name, 'output': 'screen'}
        assert executable in PROFILES
    setup = (launch.parent / 'setup.py').read_text()
    for profile in PROFILES.values():
        assert f"'{profile.executable} = ccf_ros.node:" in setup


# --- the real executable with imu_tools' own file -----------------------------------------------------------------

def _executable(name: str, func: str) -> list[str]:
    exe = shutil.which(name, path=str(Path(sys.executable).parent))
    return [exe] if exe else [sys.executable, '-c', f'from ccf_ros.node import {func}; {func}()']


def test_imu_filter_yaml_on_the_installed_madgwick_executable(context, inputs):
    """What a user of imu_filter_madgwick's launch file gets: the executable renamed imu_filter with
    config/imu_filter.yaml; every parameter of the file declared with the file's value; inputs answered."""
    cmd = _executable('imu_filter_madgwick_node', 'imu_filter_madgwick_main') + [
        '--ros-args', '-r', '__node:=imu_filter', '--params-file', str(MADGWICK_YAML)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    h = DropinHarness(context, None)
    client = AsyncParameterClient(h.io, 'imu_filter')
    try:
        h.wait_connected(timeout=30)
        assert client.wait_for_services(timeout_sec=20)
        expected = load_params_file(MADGWICK_YAML)
        fut = client.get_parameters(list(expected))
        h.ex.spin_until_future_complete(fut, timeout_sec=10)
        values = [parameter_value_to_python(v) for v in fut.result().values]
        assert dict(zip(expected, values, strict=True)) == expected
        fut = client.describe_parameters(list(MADGWICK))
        h.ex.spin_until_future_complete(fut, timeout_sec=10)
        assert {d.name: d.read_only for d in fut.result().descriptors} == {k: ro for k, (_, ro) in MADGWICK.items()}
        # Best-effort input (its default, as imu_filter_madgwick's sensor-data QoS): one sample at a time, each
        # answered before the next (no queue can overflow), magnetometer first as in the bag.
        msgs = inputs[:120]
        h.feed_paced(msgs, chunk=2)
        assert len(h.out) == 60
        np.testing.assert_array_equal(_xyzw(h.out), _ref_xyzw(_replay_reference(msgs)))
    finally:
        out = stop_node(proc, h)
    assert '[imu_filter]' in out
    if tf_message_type() is None:
        assert out.count(TF_UNAVAILABLE) == 1, out
