"""ccf_node over DDS: set_pose sets the heading (6-D: the state, 9-D: an offset), motion_hint_topic subscribed with
the type the graph shows (nav_msgs/Odometry or geometry_msgs/TwistStamped)."""

from __future__ import annotations

import math

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rosutil import read_inputs  # noqa: E402
from test_node import Harness, _ref_xyzw, _replay_reference, _xyzw, reliable_node  # noqa: E402

from ccf_ros.core.quaternion import from_xyzw, rpy_of  # noqa: E402
from ccf_ros.engine import ImuEngine  # noqa: E402
from ccf_ros.settings import build  # noqa: E402


@pytest.fixture(scope='module')
def inputs(sim_bag):
    return read_inputs(sim_bag, 4.0)


def _set_pose_publisher(h):
    """A set_pose publisher matched with the node's subscription, the node's IMU topics connected."""
    pub = h.io.create_publisher(PoseWithCovarianceStamped, 'set_pose', 10)
    h.wait_connected()
    assert h.spin_until(lambda: pub.get_subscription_count() > 0)
    return pub


@pytest.mark.parametrize(('use_mag', 'how'), [(False, 'state'), (True, 'offset')])
def test_set_pose_sets_the_heading_as_the_engine_does(context, inputs, use_mag, how):
    node = reliable_node(context, use_mag=use_mag)
    h = Harness(context, node)
    try:
        pub = _set_pose_publisher(h)
        first, second = inputs[:800], inputs[800:1200]
        h.feed(first, 400)
        pose = PoseWithCovarianceStamped()
        pose.header.frame_id = 'map'
        pose.pose.pose.orientation.z, pose.pose.pose.orientation.w = math.sin(0.5), math.cos(0.5)  # yaw 1 rad
        pub.publish(pose)
        assert h.spin_until(lambda: node.n_set_pose == 1), 'set_pose not received'
        h.feed(second, 600)
        yaw = rpy_of(from_xyzw(*_xyzw(h.out[400:401])[0]))[2]
        assert yaw == pytest.approx(1.0, abs=0.01)  # one sample after
        eng = ImuEngine(*build({'use_mag': use_mag}, strict=False))
        ref = _replay_reference(first, engine=eng)
        assert eng.set_heading(1.0) == how
        ref += _replay_reference(second, engine=eng)
        np.testing.assert_array_equal(_xyzw(h.out), _ref_xyzw(ref))
    finally:
        h.close()


def test_set_pose_before_the_imu_streams_is_kept_and_its_quaternion_normalised(context, inputs):
    """A bring-up publishes the initial pose before the IMU streams: it is applied when the filter initialises (was:
    dropped). The orientation is normalised before its yaw is taken: {z: 1, w: 1} is 90° (was: 116.6°), and a
    quaternion of norm 3 for 1 rad is 1 rad (was: 1.96 rad)."""
    node = reliable_node(context, use_mag=False)
    h = Harness(context, node)
    try:
        pub = _set_pose_publisher(h)

        def send(z, w):
            pose = PoseWithCovarianceStamped()
            pose.pose.pose.orientation.z, pose.pose.pose.orientation.w = z, w
            n = node.n_set_pose
            pub.publish(pose)
            assert h.spin_until(lambda: node.n_set_pose == n + 1), 'set_pose not received'

        send(1.0, 1.0)
        first, second = inputs[:800], inputs[800:1200]
        h.feed(first, 400)
        yaws = [rpy_of(from_xyzw(*q))[2] for q in _xyzw(h.out[:400])]
        assert yaws[0] == pytest.approx(0.5 * math.pi, abs=1e-9)
        # (measured at most 0.005 rad off over the 2 s: the simulated motion)
        assert max(abs(y - 0.5 * math.pi) for y in yaws) < 0.006
        send(3.0 * math.sin(0.5), 3.0 * math.cos(0.5))
        h.feed(second, 600)
        assert rpy_of(from_xyzw(*_xyzw(h.out[400:401])[0]))[2] == pytest.approx(1.0, abs=0.01)  # one sample after
    finally:
        h.close()


@pytest.mark.parametrize('msg_type', [Odometry, TwistStamped])
def test_motion_hint_topic_is_subscribed_with_its_graph_type(context, msg_type):
    node = reliable_node(context, motion_hint_topic='odom')
    h = Harness(context, node)
    try:
        assert node.sub_hint is None  # nothing on the graph yet
        pub = h.io.create_publisher(msg_type, '/odom', 10)
        assert h.spin_until(lambda: node.sub_hint is not None, 10.0), 'motion hint not subscribed'
        assert node.sub_hint.msg_type is msg_type
        assert h.spin_until(lambda: pub.get_subscription_count() > 0)

        def send(turn_rad_s):
            msg = msg_type()
            msg.header.stamp.sec = 100
            twist = msg.twist.twist if msg_type is Odometry else msg.twist
            twist.angular.z = turn_rad_s
            pub.publish(msg)

        send(math.radians(1.0))  # a slow turn: moving
        assert h.spin_until(lambda: node.engine.filter.still_hint is False)
        send(0.0)
        assert h.spin_until(lambda: node.engine.filter.still_hint is True)
    finally:
        h.close()


def test_motion_hint_with_a_non_finite_twist_is_ignored_and_a_far_stamp_is_counted(context, inputs):
    """A NaN twist says nothing (was: read as "moving"); a hint stamped far from the IMU's clock (0: a driver that
    does not stamp) is counted and warned about (it expires at the next IMU sample)."""
    node = reliable_node(context, motion_hint_topic='odom', use_mag=False)
    h = Harness(context, node)
    try:
        pub = h.io.create_publisher(TwistStamped, '/odom', 10)
        assert h.spin_until(lambda: node.sub_hint is not None, 10.0), 'motion hint not subscribed'
        assert h.spin_until(lambda: pub.get_subscription_count() > 0)
        h.wait_connected()
        first = inputs[:200]
        h.feed(first, sum(topic == '/imu/data_raw' for topic, _ in first))
        stamp = next(m for topic, m in reversed(first) if topic == '/imu/data_raw').header.stamp

        def send(turn_rad_s, sec, nanosec=0):
            msg = TwistStamped()
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
            msg.twist.angular.z = turn_rad_s
            pub.publish(msg)

        send(math.nan, stamp.sec, stamp.nanosec)
        assert h.spin_until(lambda: getattr(node, 'n_hints_ignored', 0) == 1
                            or node.engine.filter.still_hint is not None), 'non-finite hint not seen'
        assert node.engine.filter.still_hint is None  # (the old code: False, "moving")
        assert node.n_hints_ignored == 1
        send(0.0, stamp.sec, stamp.nanosec)
        assert h.spin_until(lambda: node.engine.filter.still_hint is True)
        assert getattr(node, 'n_hints_far', 0) == 0
        send(math.radians(1.0), 0)
        assert h.spin_until(lambda: getattr(node, 'n_hints_far', 0) == 1), 'hint stamped 0 not counted'
        assert node.engine.filter.still_hint is False and node.n_hints_ignored == 1
    finally:
        h.close()
