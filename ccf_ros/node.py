"""``ccf_node``: the ROS 2 orientation filter. A thin adapter: messages -> :class:`~ccf_ros.engine.ImuEngine` -> messages.

Subscribes ``imu/data_raw`` (sensor_msgs/Imu) and ``imu/mag`` (sensor_msgs/MagneticField); publishes ``imu/data``
(input Imu with orientation and covariance), ``imu/gyro_bias`` (Vector3Stamped, rad/s), optionally ``imu/rpy``
(Vector3Stamped, rad), and ``/diagnostics``. Service ``~/reset`` (std_srvs/Trigger).

This module keeps only what needs ROS: callbacks, message conversion, publishers and parameters. The IMU/magnetometer
delivery order is :mod:`ccf_ros.sync`, input statistics and diagnostics rules are :mod:`ccf_ros.node_support`.

Messages are taken serialized (``raw=True``): stamp, rate and specific force are read from the little-endian CDR
bytes, the output is the input's bytes with orientation and covariance patched in, and the gyro-bias message is the
input's header bytes plus a vector (:mod:`ccf_ros.offline.fastcdr`). Anything else (big-endian CDR) is deserialized
and answered as a message. Either way the values are exactly the engine's, as in ``ccf replay``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Vector3Stamped
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.serialization import deserialize_message
from rclpy.subscription import Subscription
from sensor_msgs.msg import Imu, MagneticField
from std_srvs.srv import Trigger

from .core.base import ANSWERED_BELOW
from .core.registry import FILTERS
from .engine import ImuEngine, Output
from .node_support import Diagnostics, InputStats, diagnostics
from .offline.fastcdr import (
    LINEAR_ACCELERATION,
    LITTLE_ENDIAN_CDR,
    patch_imu,
    patch_imu_vectors,
    read_imu,
    read_mag,
    vector3_stamped,
)
from .offline.messages import fill_imu, stamp_s
from .settings import DESCRIPTIONS, all_defaults, build
from .sync import HOLD_S, ImuMagSync

#: Parameters that only make sense at start-up.
READ_ONLY = {'qos_reliability', 'qos_depth'}
#: Parameters whose value may be a number or a list of three (per axis).
PER_AXIS = {'kp', 'ki', 'alpha', 'lcf_alpha'}
#: Upper bounds of positive real parameters (descriptors show them; the core validates precisely).
_RANGES: dict[str, tuple[float, float]] = {
    'alpha': (0.0, 1.0),
    'mag_norm_tol': (0.0, 10.0),
    'mag_dip_tol_rad': (0.0, math.pi),
    'constant_dt': (0.0, 10.0),
    'orientation_stddev': (0.0, math.pi),
    'gyro_bias_rate_hz': (0.0, 100000.0),
}


#: Depth of the output publishers (reliable, volatile: the rclpy defaults).
OUTPUT_DEPTH = 10


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


Vec3 = tuple[float, float, float]
#: Bytes of an Imu from ``orientation`` on: 4 + 9 + 3 + 9 + 3 + 9 float64.
_IMU_TAIL = LINEAR_ACCELERATION + 96
#: A held IMU sample: stamp, serialized bytes (or the deserialized message, then offset -1), orientation offset,
#: rate, specific force.
Held = tuple[float, bytes | Imu, int, Vec3, Vec3]


def _rpy(xyzw: tuple[float, float, float, float]) -> Vec3:
    """Roll, pitch, yaw (rad) of an orientation in message order."""
    x, y, z, w = xyzw
    return (
        math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)),
        math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x)))),
        math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)),
    )


def _descriptor(name: str, default: Any) -> ParameterDescriptor:
    d = ParameterDescriptor(description=DESCRIPTIONS.get(name, ''), read_only=name in READ_ONLY)
    if name in PER_AXIS:
        d.dynamic_typing = True
    elif isinstance(default, tuple):
        d.additional_constraints = f'{len(default)} numbers >= 0'
    elif isinstance(default, float):
        lo, hi = _RANGES.get(name, (0.0, 1e9))
        d.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]
    elif isinstance(default, int) and not isinstance(default, bool):
        d.integer_range = [IntegerRange(from_value=1, to_value=100000, step=1)]
    elif name == 'formulation':
        d.additional_constraints = 'one of: ' + ', '.join(sorted({f for _, f in FILTERS}))
    elif name == 'world_frame':
        d.additional_constraints = 'one of: enu, ned, nwu'
    elif name == 'qos_reliability':
        d.additional_constraints = 'one of: best_effort, reliable'
    return d


class CcfNode(Node):
    """The orientation filter node; all filtering is done by the shared engine, exactly as ``ccf replay`` does."""

    #: Longest wait (s) of an IMU sample for its same-stamp magnetometer sample (see :mod:`ccf_ros.sync`).
    HOLD_S = HOLD_S
    #: Period of /diagnostics, s.
    DIAGNOSTICS_PERIOD_S = 1.0

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('ccf_node', **kwargs)
        for name, default in all_defaults().items():
            # Tuples (noise vectors) are declared as double arrays.
            value = list(default) if isinstance(default, tuple) else default
            self.declare_parameter(name, value, _descriptor(name, default))
        self._settings = {name: self.get_parameter(name).value for name in all_defaults()}
        # Invalid start-up values: say which and stop, rather than run with something else.
        filt, adapter = build(self._filter_settings(self._settings), strict=False)
        self.engine = ImuEngine(filt, adapter)
        self.sync: ImuMagSync[Held] = ImuMagSync(self.HOLD_S)
        self.stats = InputStats()
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        # Every entity is in the executor's wait set, rebuilt in Python for every message: the node has few. The
        # secondary publishers go without rclpy's default QoS-event handlers (two waitables each, which only log),
        # imu/rpy exists only when asked for, and one timer serves diagnostics and held samples.
        quiet = PublisherEventCallbacks(use_default_callbacks=False)
        qos = input_qos(str(self._settings['qos_reliability']), int(self._settings['qos_depth']))
        self.pub_imu = self.create_publisher(Imu, 'imu/data', OUTPUT_DEPTH)
        self.pub_bias = self.create_publisher(Vector3Stamped, 'imu/gyro_bias', OUTPUT_DEPTH, event_callbacks=quiet)
        self.pub_rpy: Publisher | None = None
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10, event_callbacks=quiet)
        self._cache_settings()
        # The executor serves ready subscriptions in creation order: magnetometer first, so that a magnetometer
        # sample and the IMU sample with the same stamp pair as they do in `ccf replay` (bag order).
        self.sub_mag = self.create_subscription(MagneticField, 'imu/mag', self._on_mag_raw, qos, raw=True)
        self.sub_imu = self.create_subscription(Imu, 'imu/data_raw', self._on_imu_raw, qos, raw=True)
        self._take_mag, self._take_imu = self._taker(self.sub_mag), self._taker(self.sub_imu)
        self.srv_reset = self.create_service(Trigger, '~/reset', self._on_reset)
        self._last_diag = time.monotonic()
        # A steady clock: held samples and diagnostics keep their pace with use_sim_time too.
        self.timer = self.create_timer(self.DIAGNOSTICS_PERIOD_S, self._on_timer,
                                       clock=Clock(clock_type=ClockType.STEADY_TIME))

        self._last_bias_t = -math.inf
        self._last_warn = 0.0
        self.get_logger().info(
            f'ccf_node: filter={self._settings["filter"]} formulation={self._settings["formulation"]} '
            f'world_frame={self._settings["world_frame"]} use_mag={self._settings["use_mag"]}, '
            f'listening on {self.sub_imu.topic_name} and {self.sub_mag.topic_name}'
        )

    @staticmethod
    def _filter_settings(settings: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in settings.items() if k not in READ_ONLY and k != 'publish_debug_topics'}

    def _cache_settings(self) -> None:
        """Settings read per message, as attributes (a dict lookup per message is measurable)."""
        rate = float(self._settings['gyro_bias_rate_hz'])
        self._bias_period = 1.0 / rate if rate > 0.0 else 0.0
        self._debug = bool(self._settings['publish_debug_topics'])
        use_mag = bool(self._settings['use_mag'])
        if use_mag and not self.sync.enabled:
            self.sync.reset()  # switched on: learn the magnetometer's timing from scratch
        self.sync.enabled = use_mag
        if self._debug and self.pub_rpy is None:
            self.pub_rpy = self.create_publisher(Vector3Stamped, 'imu/rpy', OUTPUT_DEPTH,
                                                 event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))

    # --- parameters -------------------------------------------------------------------------------------------
    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        merged = dict(self._settings)
        for p in params:
            if p.name in merged:
                merged[p.name] = p.value
        try:
            build(self._filter_settings(merged), strict=False)
        except ValueError as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        old = dict(self._settings)
        for p in params:
            if p.name in self._settings:
                self._settings[p.name] = p.value
        filt, adapter = build(self._filter_settings(self._settings), strict=False)
        if type(filt) is type(self.engine.filter):
            # Same filter: new gains apply from the next sample, the orientation is kept.
            self.engine.filter.set_params(filt.params)
        else:
            self.engine.filter = filt
            self.get_logger().info(f'filter changed to {type(filt).__name__}: restarting the estimate')
        self.engine.set_settings(adapter)
        self._cache_settings()
        if not self.sync.enabled:
            self._answer_all(self.sync.flush(time.monotonic()))
        changed = {k: v for k, v in self._settings.items() if old.get(k) != v}
        self.get_logger().info(f'parameters applied: {changed}')

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

    def _take_mags(self) -> None:
        take_mag = self._take_mag
        mag = take_mag()
        while mag is not None:
            self._mag(mag)
            mag = take_mag()

    def _drain(self) -> None:
        """Take the messages already queued, magnetometer first, in this callback.

        Every executor cycle rebuilds the wait set in Python (about as costly as everything else per message); under
        load, when messages queue up, this serves them in one cycle instead of one cycle each. Magnetometer samples
        taken ahead of the IMU wait in the pairer for their stamp, so taking them first pairs as in bag order.
        """
        take_imu = self._take_imu
        for _ in range(self.DRAIN_MAX):
            self._take_mags()
            imu = take_imu()
            if imu is None:
                return
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
            if data[:2] == LITTLE_ENDIAN_CDR:
                t, field = read_mag(data)
            else:
                msg = deserialize_message(data, MagneticField)
                f = msg.magnetic_field
                t, field = stamp_s(msg.header), (f.x, f.y, f.z)
        except Exception as err:  # a truncated or foreign payload must not stop the node
            self.stats.n_unreadable += 1
            self._warn_throttled(f'unreadable magnetometer message ({len(data)} bytes) dropped: {err}')
            return
        now = time.monotonic()
        self.engine.on_mag(t, field)
        self.stats.on_mag(now)
        released = self.sync.on_mag(t, now)
        if released:
            self._answer_all(released)

    def _imu(self, data: bytes) -> None:
        now = time.monotonic()
        try:
            if data[:2] == LITTLE_ENDIAN_CDR:
                t, off, gyr, acc = read_imu(data)
                if len(data) < off + _IMU_TAIL:
                    raise ValueError('too short for an Imu')
                item: Held = (t, data, off, gyr, acc)
            else:
                # Big-endian (or otherwise unusual) CDR: deserialize, answer with a message.
                msg = deserialize_message(data, Imu)
                g, a = msg.angular_velocity, msg.linear_acceleration
                t = stamp_s(msg.header)
                item = (t, msg, -1, (g.x, g.y, g.z), (a.x, a.y, a.z))
        except Exception as err:  # a truncated or foreign payload must not stop the node
            self.stats.n_unreadable += 1
            self._warn_throttled(f'unreadable IMU message ({len(data)} bytes) dropped: {err}')
            return
        self.stats.on_imu(t, now)
        sync = self.sync
        if sync.on_imu(t, item, now):
            self._answer(*item)
        elif len(sync) == 1:
            self._arm_timer()

    def _arm_timer(self) -> None:
        """A first sample is held: make the timer fire by its deadline (HOLD_S from now), unless it fires sooner."""
        timer = self.timer
        if timer.time_until_next_call() > self.HOLD_S * 1e9:
            timer.timer_period_ns = round(self.HOLD_S * 1e9)
            timer.reset()

    def _on_timer(self) -> None:
        """Release held samples whose magnetometer sample did not come within HOLD_S (lost, late or none), publish
        diagnostics once a second, and set the next wake-up: the earlier of the two."""
        now = time.monotonic()
        self._answer_all(self.sync.expire(now))
        if now - self._last_diag >= self.DIAGNOSTICS_PERIOD_S - 0.002:
            self._last_diag = now
            self._publish_diagnostics()
        wake = self._last_diag + self.DIAGNOSTICS_PERIOD_S
        deadline = self.sync.deadline
        if deadline is not None:
            wake = min(wake, deadline)
        period = round(max(wake - time.monotonic(), 0.001) * 1e9)
        timer = self.timer
        if period != timer.timer_period_ns:
            timer.timer_period_ns = period
            timer.reset()

    def _answer_all(self, items: Any) -> None:
        for item in items:
            self._answer(*item)

    def _answer(self, t: float, data: bytes | Imu, off: int, gyr: Vec3, acc: Vec3) -> None:
        """Run one IMU sample through the engine and publish its answer (same bytes + orientation + covariance)."""
        out = self.engine.on_imu(t, gyr, acc)
        if out is None:
            self._warn_throttled(f'sample at t={t:.6f} s skipped: no orientation yet (no valid accelerometer sample)')
            return
        if out.status >= ANSWERED_BELOW:
            self._warn_throttled(f'sample at t={t:.6f} s could not advance the filter (answered with the current '
                                 f'orientation); so far: {self.engine.skipped_by_reason()}')
        if isinstance(data, bytes):
            buf = bytearray(data)
            patch_imu(buf, off, out.orientation_xyzw, out.covariance)
            if out.angular_velocity is not None or out.linear_acceleration is not None:
                patch_imu_vectors(buf, off, out.angular_velocity, out.linear_acceleration)
            self.pub_imu.publish(bytes(buf))
            if self._bias_due(t):
                self.pub_bias.publish(vector3_stamped(data, off, out.bias))
            if self._debug and self.pub_rpy is not None:
                self.pub_rpy.publish(vector3_stamped(data, off, _rpy(out.orientation_xyzw)))
        else:
            self._answer_msg(t, data, out)

    def _answer_msg(self, t: float, msg: Imu, out: Output) -> None:
        """The same answer built as messages (input that is not little-endian CDR)."""
        fill_imu(msg, out, list(out.covariance))
        self.pub_imu.publish(msg)
        if self._bias_due(t):
            b = Vector3Stamped(header=msg.header)
            b.vector.x, b.vector.y, b.vector.z = out.bias
            self.pub_bias.publish(b)
        if self._debug and self.pub_rpy is not None:
            r = Vector3Stamped(header=msg.header)
            r.vector.x, r.vector.y, r.vector.z = _rpy(out.orientation_xyzw)
            self.pub_rpy.publish(r)

    def _bias_due(self, t: float) -> bool:
        """imu/gyro_bias at up to gyro_bias_rate_hz (by stamp; a stamp going back publishes at once)."""
        if t - self._last_bias_t >= self._bias_period or t < self._last_bias_t:
            self._last_bias_t = t
            return True
        return False

    def _warn_throttled(self, text: str) -> None:
        now = time.monotonic()
        if now - self._last_warn > 5.0:
            self._last_warn = now
            self.get_logger().warning(text)

    def _on_reset(self, _req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        # Samples waiting for their magnetometer sample are answered first: they came before the reset.
        self._answer_all(self.sync.flush(time.monotonic()))
        self.engine.reset()
        self.sync.reset()
        resp.success = True
        resp.message = 'filter reset; re-initialising from the next sample with a valid accelerometer'
        self.get_logger().info(resp.message)
        return resp

    # --- diagnostics --------------------------------------------------------------------------------------------
    def diagnostics(self) -> Diagnostics:
        """Level, message and values of the node's status (rules in :func:`ccf_ros.node_support.diagnostics`)."""
        return diagnostics(time.monotonic(), self.stats, self.engine, self.sync.stats(),
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


def main(args: list[str] | None = None) -> None:
    """Entry point of ``ccf_node`` / ``ros2 run ccf_ros ccf_node``."""
    node = None
    try:
        rclpy.init(args=args)
        node = CcfNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ValueError as err:
        # Invalid parameters at start-up: one clear line, non-zero exit.
        print(f'ccf_node: error: {err}', flush=True)
        raise SystemExit(2) from None
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
