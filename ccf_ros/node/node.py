"""``ccf_node`` and the imu_tools drop-ins: the ROS 2 orientation filter. A thin adapter: messages ->
:class:`~ccf_ros.engine.ImuEngine` -> messages.

Subscribes ``imu/data_raw`` (sensor_msgs/Imu) and ``imu/mag`` (sensor_msgs/MagneticField); publishes ``imu/data``
(input Imu with orientation and covariance), ``imu/gyro_bias`` (Vector3Stamped, rad/s), with ``publish_debug_topics``
``imu/rpy/filtered`` and ``imu/rpy/raw`` (Vector3Stamped, rad; the complementary drop-in: ``imu/rpy/filtered`` and
``imu/steady_state``, std_msgs/Bool), with ``publish_tf`` the orientation on ``/tf`` (needs tf2_msgs), and
``/diagnostics``. Service ``~/reset`` (std_srvs/Trigger).

One class, three executables: ``ccf_node``, ``imu_filter_madgwick_node`` and ``complementary_filter_node`` differ
only by their :class:`~ccf_ros.node.compat.NodeProfile` (default node name, topics, parameter defaults and read-only
flags, QoS overrides). Every executable declares every parameter (:func:`ccf_ros.settings.all_defaults`).

This module keeps only what needs ROS: callbacks, publishers and parameters. The IMU/magnetometer delivery order
is :mod:`ccf_ros.node.sync`; parameter values, input statistics and diagnostics rules are :mod:`.parameters`,
:mod:`.stats` and :mod:`.diagnostics`; the profiles are :mod:`ccf_ros.node.compat`; the managed node and the
executables are :mod:`.lifecycle` and :mod:`.entry`.

Messages are taken serialized (``raw=True``) and go down one of the two paths :mod:`ccf_ros.messages.paths` has, as
in ``ccf replay``, picked by the bytes' encapsulation: little-endian CDR is read and patched as bytes (the output is
the input's bytes with orientation and covariance patched in, the gyro-bias message the input's header bytes plus a
vector); anything else (big-endian CDR) is deserialized and answered as a message. Either way the values are exactly
the engine's.
"""

from __future__ import annotations

import importlib
import math
import time
from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped, TwistStamped, Vector3Stamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSPolicyKind,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import deserialize_message
from rclpy.subscription import Subscription
from sensor_msgs.msg import Imu, MagneticField
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from ..core.base import ANSWERED_BELOW
from ..core.pairing import MagPairer
from ..core.quaternion import from_xyzw, rpy_of
from ..engine import JUMP_BACK_RESET_S, ImuEngine, Output
from ..errors import ParameterError
from ..frames import apply
from ..messages.cdr import LINEAR_ACCELERATION, LITTLE_ENDIAN_CDR
from ..messages.convert import stamp_s
from ..messages.paths import FastCdrPath, MessagePath, Path
from ..settings import build, schema
from .compat import (
    MEANINGLESS_GAINS,
    PROFILES,
    NodeProfile,
    apply_do_bias_estimation,
    bias_estimation_notice,
    bias_estimation_off,
    defaults_for,
    gain_notices,
    tf_transform,
)
from .debug import raw_rpy
from .diagnostics import Diagnostics, diagnostics
from .parameters import coerce_parameter
from .stats import PENDING_MAX, InputStats
from .sync import HOLD_S, ImuMagSync

#: A magnetometer stamp up to this much after an IMU stamp pairs with it (MagPairer's default tolerance_s), s.
MAG_TOLERANCE_S = MagPairer().tolerance_s
#: Depth of the output publishers (reliable, volatile: the rclpy defaults).
OUTPUT_DEPTH = 10
#: QoS of /tf, as tf2_ros' TransformBroadcaster (DynamicBroadcasterQoS: reliable, volatile, keep last 100).
TF_QOS = QoSProfile(depth=100)
#: The QoS policies a profile with ``qos_overrides`` lets a parameters file override on its input subscriptions
#: (imu_complementary_filter's set).
QOS_OVERRIDE_POLICIES = (QoSPolicyKind.DEPTH, QoSPolicyKind.DURABILITY, QoSPolicyKind.HISTORY,
                         QoSPolicyKind.RELIABILITY)
#: The one warning when publish_tf is asked for and tf2_msgs cannot be imported.
TF_UNAVAILABLE = ('publish_tf is true but tf2_msgs cannot be imported (a plain pip install has no tf2_msgs; in a '
                  'sourced ROS 2 workspace it is there): no transform is published on /tf; everything else runs')


def input_qos(reliability: str, depth: int) -> QoSProfile:
    """The input QoS: keep-last ``depth``, ``best_effort`` or ``reliable``, sensor-data durability (volatile)."""
    if reliability not in ('best_effort', 'reliable'):
        raise ValueError(f'qos_reliability must be best_effort or reliable, got {reliability!r}')
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.BEST_EFFORT if reliability == 'best_effort' else ReliabilityPolicy.RELIABLE,
        durability=qos_profile_sensor_data.durability,
    )


def endpoint_mismatch(info: Any, msg_type: str, requested: QoSProfile, offered: QoSProfile | None = None) -> str:
    """Why a remote endpoint (rclpy TopicEndpointInfo) cannot match ours ('' if it can): another message type, or
    (DDS request/offer) a best-effort writer for a reliable reader, a volatile writer for a transient-local reader,
    a longer deadline or liveliness lease offered than requested, automatic liveliness for a manual-by-topic reader.
    ``requested``: the reader's QoS (ours, or the remote's with ``offered`` ours)."""
    if info.topic_type != msg_type:
        return f'type {info.topic_type}, not {msg_type}'
    req, off = (requested, info.qos_profile) if offered is None else (info.qos_profile, offered)
    if req.reliability == ReliabilityPolicy.RELIABLE and off.reliability == ReliabilityPolicy.BEST_EFFORT:
        return 'best-effort delivery offered, reliable requested'
    if req.durability == DurabilityPolicy.TRANSIENT_LOCAL and off.durability == DurabilityPolicy.VOLATILE:
        return 'volatile durability offered, transient-local requested'
    if _period_s(off.deadline) > _period_s(req.deadline):
        return f'deadline {_period_s(off.deadline):g} s offered, {_period_s(req.deadline):g} s requested'
    if req.liveliness == LivelinessPolicy.MANUAL_BY_TOPIC and off.liveliness != LivelinessPolicy.MANUAL_BY_TOPIC:
        return 'automatic liveliness offered, manual-by-topic requested'
    if _period_s(off.liveliness_lease_duration) > _period_s(req.liveliness_lease_duration):
        return (f'liveliness lease {_period_s(off.liveliness_lease_duration):g} s offered, '
                f'{_period_s(req.liveliness_lease_duration):g} s requested')
    return ''


def _period_s(d: Any) -> float:
    """A QoS deadline or lease duration, s: 0 (the default) and the largest duration mean none (infinite)."""
    ns = d.nanoseconds
    return math.inf if ns <= 0 or ns >= _INFINITE_NS else ns * 1e-9


#: rmw's infinite duration (2^63 - 1 ns, as rclpy reports it), and anything beyond ~292 years.
_INFINITE_NS = 9_223_372_036_854_775_807


def tf_message_type() -> type[Any] | None:
    """tf2_msgs/TFMessage, or None where tf2_msgs is not installed (the PyPI wheels have no tf2_msgs)."""
    try:
        msg_type: type[Any] = importlib.import_module('tf2_msgs.msg').TFMessage
    except (ImportError, AttributeError):
        return None
    return msg_type


Vec3 = tuple[float, float, float]
#: Bytes of an Imu from ``orientation`` on: 4 + 9 + 3 + 9 + 3 + 9 float64.
_IMU_TAIL = LINEAR_ACCELERATION + 96
#: A held IMU sample: stamp, its path (:mod:`ccf_ros.messages.paths`), what the path answers from (the serialized
#: bytes, or the deserialized message), orientation offset, rate, specific force.
Held = tuple[float, Path[Any], Any, int, Vec3, Vec3]


def _descriptor(name: str, read_only: bool) -> ParameterDescriptor:
    """The declaration of ``name`` from its definition (:func:`ccf_ros.settings.schema`): description, range,
    choices; values are checked by :func:`.parameters.coerce_parameter` in the on-set callback."""
    p = schema()[name]
    d = ParameterDescriptor(description=p.description, read_only=read_only)
    if p.per_axis:
        d.dynamic_typing = True
        d.additional_constraints = 'a number or a list of 3 numbers'
    elif isinstance(p.default, tuple):
        # Dynamic: [1, 0, 0] (integers) is as good as [1.0, 0.0, 0.0]; the node checks the values.
        d.dynamic_typing = True
        d.additional_constraints = ('[roll, pitch, yaw] (rad) or [x, y, z, w]' if name.endswith('_rotation')
                                    else f'{len(p.default)} numbers')
    elif isinstance(p.default, float):
        # Dynamic: rclpy refuses an integer for a double-typed parameter; the node accepts and converts it.
        d.dynamic_typing = True
        lo, hi = p.range or (-1e300, 1e300)
        d.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]
        d.additional_constraints = 'a number (an integer is accepted)'
    elif isinstance(p.default, int) and not isinstance(p.default, bool) and p.range:
        d.integer_range = [IntegerRange(from_value=int(p.range[0]), to_value=int(p.range[1]), step=1)]
    elif p.choices:
        d.additional_constraints = 'one of: ' + ', '.join(p.choices)
    return d


class CcfNode(Node):
    """The orientation filter node; all filtering is done by the shared engine, exactly as ``ccf replay`` does.

    Args:
        profile: the executable it presents itself as (a :data:`ccf_ros.node.compat.PROFILES` key or a profile).
        node_name: node name instead of the profile's default (a ``__node:=`` remap still wins).
        **kwargs: passed to :class:`rclpy.node.Node` (``context``, ``parameter_overrides``, ...).

    Raises:
        ParameterError: an invalid start-up parameter value (rclpy's ParameterException for a wrong type).
    """

    #: Longest wait (s) of an IMU sample for its same-stamp magnetometer sample (see :mod:`ccf_ros.node.sync`).
    HOLD_S = HOLD_S
    #: Period of /diagnostics, s.
    DIAGNOSTICS_PERIOD_S = 1.0

    def __init__(self, profile: NodeProfile | str = 'ccf_node', *, node_name: str | None = None,
                 **kwargs: Any) -> None:
        self._init_profile(profile)
        super().__init__(node_name or self.profile.node_name, **kwargs)
        self._configure_ccf()
        self._open_ccf()

    def _init_profile(self, profile: NodeProfile | str) -> None:
        """Before the rclpy node exists: the profile, and no entities yet."""
        self.profile = PROFILES[profile] if isinstance(profile, str) else profile
        self._callbacks_added = False
        #: start-up values rclpy refused to declare, its reason by name; None: raised at once. A lifecycle node
        #: declares the default instead, so that the parameter can be set, and fails configure until it is.
        self._refused: dict[str, str] | None = None
        #: publishers, subscriptions, service and timer exist (between _open_ccf and _close_ccf)
        self.is_open = False
        self.pub_rpy: Publisher | None = None
        self.pub_rpy_raw: Publisher | None = None
        self.pub_steady: Publisher | None = None
        self.pub_tf: Publisher | None = None
        self.sub_mag: Subscription | None = None
        self.sub_hint: Subscription | None = None
        #: the motion hint topic subscribed (resolved name), or waited for on the graph ('' none)
        self._hint_topic = ''
        #: set_pose messages applied
        self.n_set_pose = 0
        #: motion hints ignored (non-finite twist), and those stamped beyond motion_hint_timeout_s from the IMU's
        self.n_hints_ignored = 0
        self.n_hints_far = 0

    def _configure_ccf(self) -> None:
        """Declare the parameters (once), validate them and build the engine.

        Raises:
            ValueError: an invalid parameter value (rclpy's ParameterException for a wrong type).
        """
        self._defaults = defaults_for(self.profile)
        read_only = self.profile.read_only
        for name, default in self._defaults.items():
            if self.has_parameter(name):  # a lifecycle node configured again after a cleanup
                continue
            # Tuples (noise vectors) are declared as arrays.
            value = list(default) if isinstance(default, tuple) else default
            descriptor = _descriptor(name, name in read_only)
            try:
                self.declare_parameter(name, value, descriptor)
            except ParameterException as err:  # rclpy refused the start-up value (its range, its type)
                if self._refused is None:
                    raise
                fix = ('read-only: start the node again with another value' if name in read_only
                       else 'set it, then configure again')
                self._refused[name] = f'{err} ({fix})'
                self.declare_parameter(name, value, descriptor, ignore_override=True)
        if not self._callbacks_added:  # (after the declarations, which rclpy passes through them)
            self._callbacks_added = True
            self.add_on_set_parameters_callback(self._validate_parameters)
            self.add_post_set_parameters_callback(self._apply_parameters)
        # Invalid start-up values: say which and stop, rather than run with something else.
        if self._refused:
            raise ParameterError('; '.join(self._refused.values()))
        self._settings = {name: coerce_parameter(name, self.get_parameter(name).value) for name in self._defaults}
        filt, adapter = build(self._effective(self._settings), strict=False)
        self.engine = ImuEngine(filt, adapter)
        #: whether to ask the engine per sample if it wants the sensor frame (narrowed by _cache_settings)
        self._frame_wanted = True
        # The bias_file's warnings: those of the load (above) now, later ones as they come.
        for text in self.engine.warnings:
            self.get_logger().warning(text)
        self.engine.on_warning = self.get_logger().warning
        if getattr(self, '_save_timer', None) is not None:  # a lifecycle node configured again
            self.destroy_timer(self._save_timer)
        self._save_timer: Any = None
        self._save_every: tuple[str | None, float] = (None, 0.0)
        self.sync: ImuMagSync[Held] = ImuMagSync(self.HOLD_S)
        # The two paths a message can take, by its encapsulation; their output frame is set in _cache_settings.
        self._fast = FastCdrPath(tail=_IMU_TAIL)
        self._slow = MessagePath(_deserialize_imu, _deserialize_mag, _vector3_stamped, list)
        self.stats = InputStats()
        self._noticed: set[str] = set()
        self._last_bias_t = -math.inf
        #: the magnetometer's latest stamp, s: one far behind it is the magnetometer's clock jumping back
        self._mag_prev_t = -math.inf
        #: the engine's timeline restarts when the magnetometer's clock jumped back ahead of the IMU's (-1: not now)
        self._mag_clock_back = -1
        #: when each kind of throttled warning was last logged (time.monotonic(), s)
        self._last_warn: dict[str, float] = {}

    def _open_ccf(self) -> None:
        """Create the publishers, subscriptions, reset service and timer: messages flow from here on."""
        self.is_open = True
        read_only = self.profile.read_only
        # Every entity is in the executor's wait set, rebuilt in Python for every message: the node has few. The
        # secondary publishers go without rclpy's default QoS-event handlers (two waitables each, which only log),
        # debug and TF publishers exist only when asked for, and one timer serves diagnostics and held samples.
        self._quiet = PublisherEventCallbacks(use_default_callbacks=False)
        self.pub_imu = self.create_publisher(Imu, self.profile.out_topic, OUTPUT_DEPTH, event_callbacks=self._quiet)
        self.pub_bias = self.create_publisher(Vector3Stamped, 'imu/gyro_bias', OUTPUT_DEPTH,
                                              event_callbacks=self._quiet)
        self._tf_type: type[Any] | None = None
        self._tf_warned = False
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10, event_callbacks=self._quiet)
        self._cache_settings()
        # The executor serves ready subscriptions in creation order: magnetometer first, so that a magnetometer
        # sample and the IMU sample with the same stamp pair as they do in `ccf replay` (bag order). A profile whose
        # use_mag is read-only and false does not subscribe it (as imu_tools).
        # Without rclpy's default QoS-event handlers either (two waitables each, rebuilt into the wait set on every
        # wake-up): the timer checks the graph for endpoints that cannot match instead (_check_endpoints).
        self._quiet_sub = SubscriptionEventCallbacks(use_default_callbacks=False)
        self._mismatched: set[tuple[str, bytes]] = set()
        if self._settings['use_mag'] or 'use_mag' not in read_only:
            self.sub_mag = self.create_subscription(MagneticField, self.profile.mag_topic, self._on_mag_raw,
                                                    self._input_qos(), raw=True, event_callbacks=self._quiet_sub,
                                                    qos_overriding_options=self._qos_overrides())
        self.sub_imu = self.create_subscription(Imu, self.profile.imu_topic, self._on_imu_raw, self._input_qos(),
                                                raw=True, event_callbacks=self._quiet_sub,
                                                qos_overriding_options=self._qos_overrides())
        self._take_mag = self._taker(self.sub_mag) if self.sub_mag is not None else _nothing
        self._take_imu = self._taker(self.sub_imu)
        self._pairer_full = False  # a take stopped on the pairer's room (_take_mags)
        self.srv_reset = self.create_service(Trigger, '~/reset', self._on_reset)
        # robot_localization's idiom: a pose on set_pose sets the heading (its orientation's yaw).
        self.sub_set_pose = self.create_subscription(PoseWithCovarianceStamped, 'set_pose', self._on_set_pose, 10,
                                                     event_callbacks=self._quiet_sub)
        self._last_diag = time.monotonic()
        # A steady clock: held samples and diagnostics keep their pace with use_sim_time too.
        self.timer = self.create_timer(self.DIAGNOSTICS_PERIOD_S, self._on_timer,
                                       clock=Clock(clock_type=ClockType.STEADY_TIME))

        self._log_notices(MEANINGLESS_GAINS)
        if self.engine.output_rotation is not None and not self._settings['output_frame_id']:
            # Turned into the output frame's axes but still labelled with the IMU's frame: a consumer that applies
            # the output -> IMU transform (robot_localization) would turn it twice (doc/frames.md).
            self.get_logger().warning('mount_rotation is set but output_frame_id is empty: imu/data keeps the input '
                                      'frame_id although it is in the output frame; set output_frame_id (e.g. base_link)')
        notice = bias_estimation_notice(self._settings, self.profile)
        if notice:
            self.get_logger().info(notice)
        inputs = self.sub_imu.topic_name + (f' and {self.sub_mag.topic_name}' if self.sub_mag is not None else '')
        self.get_logger().info(
            f'{self.profile.executable}: filter={self._settings["filter"]} '
            f'formulation={self._settings["formulation"]} world_frame={self._settings["world_frame"]} '
            f'use_mag={self._settings["use_mag"]}, listening on {inputs}'
        )

    def _close_ccf(self) -> None:
        """Answer the held samples, then destroy what :meth:`_open_ccf` made (and the debug/TF publishers)."""
        if not self.is_open:
            return
        self._answer_all(self.sync.flush(time.monotonic()))
        self.is_open = False
        for sub in (self.sub_mag, self.sub_imu, self.sub_set_pose, self.sub_hint):
            if sub is not None:
                self.destroy_subscription(sub)
        self.sub_mag = self.sub_hint = None
        self._hint_topic = ''
        for pub in (self.pub_imu, self.pub_bias, self.pub_diag, self.pub_rpy, self.pub_rpy_raw, self.pub_steady,
                    self.pub_tf):
            if pub is not None:
                self.destroy_publisher(pub)
        self.pub_rpy = self.pub_rpy_raw = self.pub_steady = self.pub_tf = None
        self.destroy_service(self.srv_reset)
        self.destroy_timer(self.timer)
        if self._save_timer is not None:  # (made again by the next _open_ccf's _cache_settings)
            self.destroy_timer(self._save_timer)
            self._save_timer = None
            self._save_every = (None, 0.0)

    def _resolved_hint_topic(self) -> str:
        topic = str(self._settings['motion_hint_topic'])
        return self.resolve_topic_name(topic) if topic else ''

    def _subscribe_motion_hint(self) -> None:
        """Subscribe motion_hint_topic with the type it has on the graph (nav_msgs/Odometry or
        geometry_msgs/TwistStamped); until a publisher shows it, the timer tries again."""
        if self.sub_hint is not None:
            self.destroy_subscription(self.sub_hint)
            self.sub_hint = None
            self.engine.filter.still_hint = None
        topic = self._hint_topic = self._resolved_hint_topic()
        if not topic:
            return
        types = dict(self.get_topic_names_and_types()).get(topic, [])
        # A best-effort reader matches reliable and best-effort writers alike.
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
        if 'nav_msgs/msg/Odometry' in types:
            self.sub_hint = self.create_subscription(Odometry, topic, self._on_odometry, qos)
        elif 'geometry_msgs/msg/TwistStamped' in types:
            self.sub_hint = self.create_subscription(TwistStamped, topic, self._on_twist, qos)
        elif types:
            self._warn_throttled(f'motion_hint_topic {topic} has type {types}: nav_msgs/msg/Odometry or '
                                 'geometry_msgs/msg/TwistStamped expected; no motion hint')
            return
        if self.sub_hint is not None:
            self.get_logger().info(f'motion hint from {topic} ({types[0]})')

    def _on_odometry(self, msg: Odometry) -> None:
        self._motion_hint(msg.header, msg.twist.twist)

    def _on_twist(self, msg: TwistStamped) -> None:
        self._motion_hint(msg.header, msg.twist)

    def _motion_hint(self, header: Any, twist: Any) -> None:
        """Still: speed below motion_hint_linear_m_s and turn rate below motion_hint_angular_rad_s. A non-finite
        twist says nothing (ignored, not "moving"); a stamp far from the IMU's is warned about (throttled)."""
        v, w = twist.linear, twist.angular
        v2 = v.x * v.x + v.y * v.y + v.z * v.z
        w2 = w.x * w.x + w.y * w.y + w.z * w.z
        if not (math.isfinite(v2) and math.isfinite(w2)):
            self.n_hints_ignored += 1
            self._warn_throttled(f'motion hint ignored: non-finite twist (linear {v.x, v.y, v.z}, angular '
                                 f'{w.x, w.y, w.z}); {self.n_hints_ignored} so far', 'hint')
            return
        t = stamp_s(header)
        age = self.engine.on_motion_hint(t, v2 < self._hint_lin2 and w2 < self._hint_ang2, self._hint_timeout)
        # (NaN before the first IMU sample: no judgement; a timeout of 0 makes every hint expire at once, as chosen)
        if self._hint_timeout > 0.0 and abs(age) > self._hint_timeout:
            self.n_hints_far += 1
            self._warn_throttled(
                f'motion hint stamped {t:.3f} s, {age:+.3f} s from the latest IMU stamp (beyond motion_hint_timeout_s '
                f'{self._hint_timeout:g} s): it ' + ('expires at once' if age > 0.0 else 'counts until the IMU stamps '
                'reach it') + '; the hint must be stamped on the IMU\'s clock (a stamp of 0: an odometry driver that '
                f'does not stamp); {self.n_hints_far} so far', 'hint')

    def _on_set_pose(self, msg: PoseWithCovarianceStamped) -> None:
        """Set the output's heading to the yaw of the pose's orientation (roll, pitch and position ignored); the
        quaternion is normalised first. Before the filter initialised (a bring-up publishes the initial pose before
        the IMU streams) the heading is kept and applied when it does."""
        o = msg.pose.pose.orientation
        n2 = o.x * o.x + o.y * o.y + o.z * o.z + o.w * o.w
        if not (math.isfinite(n2) and n2 > 1e-6):
            self.get_logger().warning(f'set_pose ignored: orientation {o.x, o.y, o.z, o.w} is not a rotation')
            return
        n = 1.0 / math.sqrt(n2)
        yaw = rpy_of(from_xyzw(o.x * n, o.y * n, o.z * n, o.w * n))[2]
        # Samples held for their magnetometer sample came before the pose: answered with the old heading.
        self._answer_all(self.sync.flush(time.monotonic()))
        replaced = self.engine.pending_pose
        how = self.engine.set_heading(yaw)
        self.n_set_pose += 1
        if how == 'pending':
            self.get_logger().info(f'set_pose: heading {yaw:.4f} rad kept until the filter initialises' + (
                f' (replaces the pending {replaced:.4f} rad)' if replaced is not None else ''))
        elif how.startswith('ignored'):
            self.get_logger().warning(f'set_pose: heading {yaw:.4f} rad {how}')
        else:
            self.get_logger().info(f'set_pose: heading {yaw:.4f} rad ({how})')

    def _drop_pending_pose(self, why: str) -> None:
        """A set_pose heading still waiting for the filter to initialise is lost (``why``): one warning."""
        engine = getattr(self, 'engine', None)
        if engine is not None and engine.pending_pose is not None:
            self.get_logger().warning(f'set_pose heading {engine.pending_pose:.4f} rad lost: {why} before the '
                                      'filter initialised (no IMU sample with a usable accelerometer)')
            engine.pending_pose = None

    def _input_qos(self) -> QoSProfile:
        """A new input profile per subscription (rclpy writes the overrides into the profile it is given)."""
        return input_qos(str(self._settings['qos_reliability']), int(self._settings['qos_depth']))

    def _qos_overrides(self) -> QoSOverridingOptions | None:
        return QoSOverridingOptions(QOS_OVERRIDE_POLICIES) if self.profile.qos_overrides else None

    def _effective(self, settings: dict[str, Any]) -> dict[str, Any]:
        """The settings the engine is built from: imu_tools' do_bias_estimation applied."""
        values = dict(settings)
        apply_do_bias_estimation(values, self.profile)
        return values

    def _cache_settings(self) -> None:
        """Settings read per message, as attributes (a dict lookup per message is measurable); publishers that
        were switched on are made here."""
        st = self._settings
        # False only where the engine surely does not want the sensor frame (no state file): the property is not
        # asked per message then.
        self._frame_wanted = bool(self.engine.settings.bias_file)
        rate = float(st['gyro_bias_rate_hz'])
        self._bias_period = 1.0 / rate if rate > 0.0 else 0.0
        use_mag = bool(st['use_mag'])
        if use_mag and not self.sync.enabled:
            self.sync.reset()  # switched on: learn the magnetometer's timing from scratch
        self.sync.enabled = use_mag
        self._use_mag = use_mag
        self._world_frame = str(st['world_frame'])
        debug = bool(st['publish_debug_topics'])
        prof = self.profile
        self._hint_lin2 = float(st['motion_hint_linear_m_s']) ** 2
        self._hint_ang2 = float(st['motion_hint_angular_rad_s']) ** 2
        self._hint_timeout = float(st['motion_hint_timeout_s'])
        if not self.is_open:  # a lifecycle node not active: the publishers are made on activation
            self._debug = self._steady = self._tf = self._extras = False
            return
        if self._hint_topic != self._resolved_hint_topic():
            self._subscribe_motion_hint()
        if debug and self.pub_rpy is None and prof.rpy_filtered_topic:
            self.pub_rpy = self._quiet_publisher(Vector3Stamped, prof.rpy_filtered_topic)
        if debug and self.pub_rpy_raw is None and prof.rpy_raw_topic:
            self.pub_rpy_raw = self._quiet_publisher(Vector3Stamped, prof.rpy_raw_topic)
        steady = debug and not bias_estimation_off(st) and prof.steady_state_topic is not None
        if steady and self.pub_steady is None and prof.steady_state_topic:
            self.pub_steady = self._quiet_publisher(Bool, prof.steady_state_topic)
        self._debug = debug
        self._steady = steady
        self._fixed_frame = str(st['fixed_frame'])
        self._reverse_tf = bool(st['reverse_tf'])
        if st['publish_tf'] and self.pub_tf is None and not self._tf_warned:
            self._tf_type = tf_message_type()
            if self._tf_type is None:
                self._tf_warned = True
                self.get_logger().warning(TF_UNAVAILABLE)
            else:
                self.pub_tf = self.create_publisher(self._tf_type, '/tf', TF_QOS, event_callbacks=self._quiet)
        self._tf = bool(st['publish_tf']) and self.pub_tf is not None
        self._extras = self._debug or self._tf  # (one test per message instead of two)
        # Output frame: the engine turns the vectors; the messages get the new frame_id and turned covariances.
        out_frame = str(st['output_frame_id'])
        self._rot = self.engine.output_rotation
        # Set on the path objects, not replaced: held samples keep their path and take the new frame, as before.
        self._fast.set_output(out_frame, self._rot)
        self._slow.set_output(out_frame, self._rot)
        every = (str(st['bias_file']) or None, float(st['bias_save_interval_s']))
        if every != self._save_every:
            self._save_every = every
            if self._save_timer is not None:
                self.destroy_timer(self._save_timer)
                self._save_timer = None
            if every[0] and every[1] > 0.0:
                self._save_timer = self.create_timer(every[1], self.save_state,
                                                     clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _quiet_publisher(self, msg_type: Any, topic: str) -> Publisher:
        return self.create_publisher(msg_type, topic, OUTPUT_DEPTH, event_callbacks=self._quiet)

    # --- parameters -------------------------------------------------------------------------------------------
    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        merged = dict(self._settings)
        try:
            for p in params:
                if p.name in self._defaults:
                    merged[p.name] = coerce_parameter(p.name, p.value)
            build(self._effective(merged), strict=False)
        except ValueError as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        names = [p.name for p in params if p.name in self._defaults]
        if not names:
            return  # e.g. the QoS override parameters, declared when the subscriptions are made
        old = dict(self._settings)
        for p in params:
            if p.name in self._defaults:
                self._settings[p.name] = coerce_parameter(p.name, p.value)
        filt, adapter = build(self._effective(self._settings), strict=False)
        if type(filt) is type(self.engine.filter):
            # Same filter: new gains apply from the next sample, the orientation is kept.
            self.engine.filter.set_params(filt.params)
        else:
            self.engine.replace_filter(filt)
            self.get_logger().info(f'filter changed to {type(filt).__name__}: restarting the estimate')
        self.engine.set_settings(adapter)
        self._cache_settings()
        if not self.sync.enabled:
            self._answer_all(self.sync.flush(time.monotonic()))
        changed = {k: v for k, v in self._settings.items() if old.get(k) != v}
        self.get_logger().info(f'parameters applied: {changed}')
        self._log_notices(names)
        if 'do_bias_estimation' in changed:
            notice = bias_estimation_notice(self._settings, self.profile)
            self.get_logger().info(notice or 'do_bias_estimation=true: rest_bias and motion_bias apply')

    def _log_notices(self, names: Any) -> None:
        """Each imu_tools gain without a ccf meaning: one warning the first time it is set to a non-default value."""
        for name in names:
            if name in MEANINGLESS_GAINS and name not in self._noticed:
                for line in gain_notices({name: self._settings[name]}):
                    self._noticed.add(name)
                    self.get_logger().warning(line)

    # --- data ---------------------------------------------------------------------------------------------------
    #: Most messages taken in one callback (then the executor serves timers and services again).
    DRAIN_MAX = 64

    def _on_mag_raw(self, data: bytes) -> None:
        self._mag(data)
        self._drain()

    def _on_imu_raw(self, data: bytes) -> None:
        # A magnetometer sample that arrived since the executor looked goes first (it may be this one's).
        self._take_mags()
        self._imu(data)
        self._drain()

    #: Room left in the pairer's queue when the node takes a backlog: for the magnetometer samples the executor
    #: hands over meanwhile (one per wake-up), which must not push out the oldest either.
    PAIRER_MARGIN = 64

    def _take_mags(self) -> None:
        """Take the queued magnetometer samples, as many as the pairer's queue holds without pushing out its oldest
        (less :attr:`PAIRER_MARGIN`). A stalled topic's backlog taken whole could push out those the next IMU
        samples use; the rest stays in the reader queue (a KEEP_LAST reader drops its oldest when full) until the
        pairer has used some."""
        if self._pairer_full:  # (a take stopped on the room: none until the pairer has used some)
            if self.engine.pairer.room <= self.PAIRER_MARGIN:
                return
            self._pairer_full = False
        take_mag = self._take_mag
        mag = take_mag()
        if mag is None:
            return
        room = self.engine.pairer.room - self.PAIRER_MARGIN
        while True:
            self._mag(mag)
            room -= 1
            if room <= 0:
                self._pairer_full = True
                return
            mag = take_mag()
            if mag is None:
                return

    def _drain(self) -> None:
        """Take the messages already queued, magnetometer first, in this callback.

        Every executor cycle rebuilds the wait set in Python (about as costly as everything else per message); under
        load, when messages queue up, this serves them in one cycle instead of one cycle each. Magnetometer samples
        taken ahead of the IMU wait in the pairer for their stamp, so taking them first pairs as in bag order.
        """
        take_imu = self._take_imu
        for _ in range(self.DRAIN_MAX):
            imu = take_imu()
            if imu is None:
                return  # (no magnetometer take first: at low rates every take here finds nothing, and costs)
            # Magnetometer samples that arrived by now go first (as if the IMU sample had been taken after them).
            self._take_mags()
            self._imu(imu)

    @staticmethod
    def _taker(sub: Subscription) -> Callable[[], bytes | None]:
        """Take one serialized message from ``sub`` without the executor (None if its queue is empty)."""
        handle, msg_type = sub.handle, sub.msg_type

        def take() -> bytes | None:
            with handle:
                taken = handle.take_message(msg_type, True)
            return None if taken is None else taken[0]

        return take

    def _mag(self, data: bytes) -> None:
        try:
            t, field = (self._fast if data[:2] == LITTLE_ENDIAN_CDR else self._slow).read_mag(data)
        except Exception as err:  # a truncated or foreign payload must not stop the node
            self.stats.n_unreadable += 1
            self._warn_throttled(f'unreadable magnetometer message ({len(data)} bytes) dropped: {err}')
            return
        now = time.monotonic()
        if t <= self.engine.latest_stamp_s + MAG_TOLERANCE_S:
            self._mag_late(t)
        elif self._mag_clock_back >= 0:
            self._mag_clock_back = -1  # ahead of the IMU's stamps: the magnetometer is on the IMU's timeline again
        self._mag_prev_t = t
        self.engine.on_mag(t, field)
        stats = self.stats
        stats.last_mag = now  # InputStats.on_mag written out (changes together with it)
        stats.n_mag += 1
        released = self.sync.on_mag(t, now)
        if released:
            self._answer_all(released)

    def _forget_mag_clock(self) -> None:
        """Forget the magnetometer's timeline (a reset, a cleanup): as at the start."""
        self._mag_prev_t = -math.inf
        self._mag_clock_back = -1

    def _mag_late(self, t: float) -> None:
        """A magnetometer sample comes after the IMU sample with its stamp (or a later one) was processed: replay
        would have paired it with that one (it timed out, or the sample overtook it over DDS). Counted; at debug
        level logged with where it landed, so that a test can rebuild the node's order exactly."""
        engine = self.engine
        if t < engine.latest_stamp_s - JUMP_BACK_RESET_S and (
                t < self._mag_prev_t - JUMP_BACK_RESET_S or self._mag_clock_back == engine.n_resets_jump):
            # Far behind the IMU stamps, and the magnetometer's own clock jumped back (bag loop): a new timeline whose
            # IMU samples have not come yet, not a late sample, until the engine restarts on them. (A sample late
            # by more than a second, or across a gap of the IMU stamps, keeps to its own clock: late.)
            self._mag_clock_back = engine.n_resets_jump
            return
        self.stats.n_mag_late += 1
        self.get_logger().debug(f'late magnetometer sample t={t!r} after IMU sample {self.engine.n_in}')

    def _imu(self, data: bytes) -> None:
        now = time.monotonic()
        # Little-endian CDR: the bytes are read and patched; else (big-endian) deserialized, answered as a message.
        path: Path[Any] = self._fast if data[:2] == LITTLE_ENDIAN_CDR else self._slow
        try:
            item: Held = path.read_imu(data)
        except Exception as err:  # a truncated or foreign payload must not stop the node
            self.stats.n_unreadable += 1
            self._warn_throttled(f'unreadable IMU message ({len(data)} bytes) dropped: {err}')
            return
        t, _, src, off, gyr, acc = item
        stats = self.stats
        pending = stats.pending  # InputStats.on_imu written out (changes together with it)
        pending.append((t, now))
        if len(pending) >= PENDING_MAX:
            stats.catch_up()
        sync = self.sync
        if not sync.on_imu(t, item, now):
            if len(sync) == 1:
                self._arm_timer()
            return
        # Not held (the common case): _answer's steps written out, as a call per message costs about as much as the
        # node's own steps; this copy and _answer change together.
        engine = self.engine
        if self._frame_wanted and engine.wants_sensor_frame:
            engine.set_sensor_frame(path.frame_id(src))
        out = engine.on_imu(t, gyr, acc)
        if out is None:
            self._warn_unadvanced(t, out)
            return
        if out.status >= ANSWERED_BELOW:
            self._warn_unadvanced(t, out)
        imu, src, off = path.answer(src, off, out)
        self.pub_imu.publish(imu)
        clock = engine.clock_s
        if clock - self._last_bias_t >= self._bias_period or clock < self._last_bias_t:
            self._publish_bias(clock, path, src, off, out)
        if self._extras:
            self._publish_extras(path, src, off, out, acc)

    def _arm_timer(self) -> None:
        """A first sample is held: make the timer fire by its deadline (HOLD_S from now), unless it fires sooner."""
        timer = self.timer
        if timer.time_until_next_call() > self.HOLD_S * 1e9:
            timer.timer_period_ns = round(self.HOLD_S * 1e9)
            timer.reset()

    def _on_timer(self) -> None:
        """Release held samples whose magnetometer sample did not come within HOLD_S (lost, late or none), publish
        diagnostics once a second, and set the next wake-up: the earlier of the two."""
        if self.sync.holding:
            # rclpy's executor hands out a node's ready timers before its ready subscriptions (Jazzy, rclpy 7:
            # executors.py, _wait_for_ready_callbacks): after the process was descheduled for more than HOLD_S, this
            # timer runs while the magnetometer sample a held IMU sample waits for is already in the reader queue.
            # Taken first, it pairs as in replay; only what is still missing times out.
            self._take_mags()
        now = time.monotonic()
        self._answer_all(self.sync.expire(now))
        if self._hint_topic and self.sub_hint is None:
            self._subscribe_motion_hint()
        if now - self._last_diag >= self.DIAGNOSTICS_PERIOD_S - 0.002:
            self._last_diag = now
            self._publish_diagnostics()
            self._check_endpoints()
        wake = self._last_diag + self.DIAGNOSTICS_PERIOD_S
        deadline = self.sync.deadline
        if deadline is not None:
            wake = min(wake, deadline)
        period = round(max(wake - time.monotonic(), 0.001) * 1e9)
        timer = self.timer
        if period != timer.timer_period_ns:
            timer.timer_period_ns = period
            timer.reset()

    def _check_endpoints(self) -> list[str]:
        """Warn once per remote endpoint that cannot match one of ours (what rclpy's default QoS-event handlers
        report, looked up here once a second instead of in every wake-up's wait set). Returns the new warnings."""
        new = []
        ours: list[tuple[Any, str, bool]] = [(self.sub_imu, 'sensor_msgs/msg/Imu', True),
                                             (self.sub_set_pose, 'geometry_msgs/msg/PoseWithCovarianceStamped', True),
                                             (self.pub_imu, 'sensor_msgs/msg/Imu', False),
                                             (self.pub_bias, 'geometry_msgs/msg/Vector3Stamped', False)]
        if self.sub_mag is not None:
            ours.append((self.sub_mag, 'sensor_msgs/msg/MagneticField', True))
        if self.pub_tf is not None:
            ours.append((self.pub_tf, 'tf2_msgs/msg/TFMessage', False))
        for entity, msg_type, is_sub in ours:
            topic = entity.topic_name
            if is_sub:
                remote, role = self.get_publishers_info_by_topic(topic), 'publisher'
            else:
                remote, role = self.get_subscriptions_info_by_topic(topic), 'subscriber'
            for info in remote:
                key = (topic, bytes(info.endpoint_gid))
                if key in self._mismatched:
                    continue
                why = (endpoint_mismatch(info, msg_type, entity.qos_profile) if is_sub else
                       endpoint_mismatch(info, msg_type, info.qos_profile, offered=entity.qos_profile))
                if why:
                    self._mismatched.add(key)
                    who = ('of a node not known yet' if info.node_name.startswith('_NODE_NAME_UNKNOWN')
                           else f'{info.node_namespace.rstrip("/")}/{info.node_name}')
                    text = (f'{role} {who} on {topic} cannot match: {why}; '
                            'no messages flow between them' + ('; see qos_reliability' if is_sub and 'reliable' in why
                                                               and entity is not self.sub_set_pose else ''))
                    new.append(text)
                    self.get_logger().warning(text)
        return new

    def _answer_all(self, items: Any) -> None:
        for item in items:
            self._answer(*item)

    def _answer(self, t: float, path: Path[Any], src: Any, off: int, gyr: Vec3, acc: Vec3) -> None:
        """Run one IMU sample through the engine and publish its answer (same bytes + orientation + covariance).

        Every sample is answered once an orientation exists: one that cannot advance the filter (repeated or
        backward stamp, non-finite rate) with the current orientation, counted in the diagnostics. (Written out in
        :meth:`_imu` for a sample that is not held: the two change together.)
        """
        engine = self.engine
        if self._frame_wanted and engine.wants_sensor_frame:
            engine.set_sensor_frame(path.frame_id(src))
        out = engine.on_imu(t, gyr, acc)
        if out is None:
            self._warn_unadvanced(t, out)
            return
        if out.status >= ANSWERED_BELOW:
            self._warn_unadvanced(t, out)
        # In the output frame if one is set; the bias, debug and TF messages take the answer's header.
        imu, src, off = path.answer(src, off, out)
        self.pub_imu.publish(imu)
        # imu/gyro_bias at up to gyro_bias_rate_hz by the filter's clock (the stamps, or constant_dt's clock when the
        # stamps are not used); a clock going back publishes at once.
        clock = engine.clock_s
        if clock - self._last_bias_t >= self._bias_period or clock < self._last_bias_t:
            self._publish_bias(clock, path, src, off, out)
        if self._extras:
            self._publish_extras(path, src, off, out, acc)

    def _warn_unadvanced(self, t: float, out: Output | None) -> None:
        """The (throttled) warning for a sample at ``t`` (s) without an answer (``out`` None: no orientation yet) or
        answered with the current orientation (it could not advance the filter)."""
        if out is None:
            self._warn_throttled(f'sample at t={t:.6f} s skipped: no orientation yet (no valid accelerometer sample)')
        else:
            self._warn_throttled(f'sample at t={t:.6f} s could not advance the filter (answered with the current '
                                 f'orientation); so far: {self.engine.skipped_by_reason()}')

    def _publish_bias(self, clock: float, path: Path[Any], src: Any, off: int, out: Output) -> None:
        """imu/gyro_bias is due at the filter's clock ``clock`` (s): published only while someone subscribes (a DDS
        write costs as much as the rest of a message at 200 Hz, and a volatile topic gives a later subscriber nothing
        from before anyway); the cadence is kept either way."""
        self._last_bias_t = clock
        if self.pub_bias.get_subscription_count() > 0:
            self.pub_bias.publish(path.stamped(src, off, out.bias))

    def _publish_extras(self, path: Path[Any], src: Any, off: int, out: Output, acc: Vec3) -> None:
        """The debug topics and the TF, as switched on (publish_debug_topics, publish_tf)."""
        if self._debug:
            self._publish_debug(path, src, off, out, acc)
        if self._tf:
            sec, nanosec, frame_id = path.header(src)
            self._publish_tf(sec, nanosec, frame_id, out)

    def _publish_debug(self, path: Path[Any], src: Any, off: int, out: Output, acc: Vec3) -> None:
        """imu/rpy/filtered (the output's roll, pitch, yaw), imu/rpy/raw (those of this sample's accelerometer and
        magnetometer alone) and imu/steady_state (at rest), as the profile has them, with the answer's header."""
        if self.pub_rpy is not None:
            self.pub_rpy.publish(path.stamped(src, off, rpy_of(from_xyzw(*out.orientation_xyzw))))
        if self.pub_rpy_raw is not None and self._use_mag:
            # The magnetometer sample the engine paired with this one (calibrated; asking the pairer again with the
            # header stamp could consume samples the engine did not, after a stamp it skipped as far ahead).
            if self._rot is not None:
                acc = apply(self._rot, acc)  # the output frame, as the paired magnetometer sample is
            rpy = raw_rpy(acc, self.engine.paired_mag, self._world_frame)
            if rpy is not None:
                self.pub_rpy_raw.publish(path.stamped(src, off, rpy))
        if self._steady and self.pub_steady is not None:
            self.pub_steady.publish(Bool(data=bool(self.engine.filter.flags.at_rest)))

    def _publish_tf(self, sec: int, nanosec: int, frame_id: str, out: Output) -> None:
        """The output orientation (yaw offset included, as imu/data) as the transform fixed_frame -> IMU frame (or
        its inverse with reverse_tf), stamped with the input's stamp."""
        parent, child, (x, y, z, w) = tf_transform(out.orientation_xyzw, frame_id, self._fixed_frame,
                                                   self._reverse_tf)
        tr = TransformStamped()
        tr.header.stamp.sec, tr.header.stamp.nanosec = sec, nanosec
        tr.header.frame_id, tr.child_frame_id = parent, child
        r = tr.transform.rotation
        r.x, r.y, r.z, r.w = x, y, z, w
        if self.pub_tf is None or self._tf_type is None:  # publish_tf without tf2_msgs: warned once, no TF
            return
        self.pub_tf.publish(self._tf_type(transforms=[tr]))

    def _warn_throttled(self, text: str, kind: str = '') -> None:
        """A warning at most every 5 s per ``kind`` (one kind's flood does not hide another's)."""
        now = time.monotonic()
        if now - self._last_warn.get(kind, -math.inf) > 5.0:
            self._last_warn[kind] = now
            self.get_logger().warning(text)

    def save_state(self) -> None:
        """Write bias_file now (atomically); a failure is a warning (the node runs on). Nothing before the node has
        settings and an engine (a lifecycle node that was never configured)."""
        settings = getattr(self, '_settings', None)
        path = str(settings['bias_file']) if settings is not None else ''
        if not path or getattr(self, 'engine', None) is None:
            return
        try:
            self.engine.save_state(path)
        except OSError as err:
            self._warn_throttled(f'cannot write bias_file {path}: {err}')

    def destroy_node(self) -> None:
        """Write bias_file (shutdown), then destroy the node."""
        self._drop_pending_pose('the node shuts down')
        self.save_state()
        super().destroy_node()

    def _on_reset(self, _req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        # Samples waiting for their magnetometer sample are answered first: they came before the reset.
        self._answer_all(self.sync.flush(time.monotonic()))
        self.engine.reset()
        self.sync.reset()
        self._forget_mag_clock()
        resp.success = True
        resp.message = 'filter reset; re-initialising from the next sample with a valid accelerometer'
        self.get_logger().info(resp.message)
        return resp

    # --- diagnostics --------------------------------------------------------------------------------------------
    def diagnostics(self, now: float | None = None) -> Diagnostics:
        """Level, message and values of the node's status (rules in :func:`ccf_ros.node.diagnostics.diagnostics`) at
        ``now`` (s, time.monotonic; None: now)."""
        return diagnostics(time.monotonic() if now is None else now, self.stats, self.engine, self.sync.stats(),
                           use_mag=bool(self._settings['use_mag']),
                           mag_timeout_s=float(self._settings['mag_timeout_s']))

    def diagnostic_status(self) -> DiagnosticStatus:
        """The status published on /diagnostics."""
        d = self.diagnostics()
        return DiagnosticStatus(
            level=bytes([d.level]),
            name=f'{self.get_name()}: orientation filter',
            message=d.message,
            hardware_id=self.get_fully_qualified_name(),
            values=[KeyValue(key=k, value=v) for k, v in d.values.items()],
        )

    def _publish_diagnostics(self) -> None:
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [self.diagnostic_status()]
        self.pub_diag.publish(arr)


def _nothing() -> None:
    return None


# The message path's calls into rclpy, looked up when called (a test wraps deserialize_message).
def _deserialize_imu(data: bytes) -> Any:
    return deserialize_message(data, Imu)


def _deserialize_mag(data: bytes) -> Any:
    return deserialize_message(data, MagneticField)


def _vector3_stamped(header: Any, v: Vec3) -> Vector3Stamped:
    m = Vector3Stamped(header=header)
    m.vector.x, m.vector.y, m.vector.z = v
    return m
