"""``ccf_node``: the ROS 2 orientation filter. A thin adapter: messages -> :class:`~ccf_ros.engine.ImuEngine` -> messages.

Subscribes ``imu/data_raw`` (sensor_msgs/Imu) and ``imu/mag`` (sensor_msgs/MagneticField); publishes ``imu/data``
(input Imu with orientation and covariance), ``imu/gyro_bias`` (Vector3Stamped, rad/s), optionally ``imu/rpy``
(Vector3Stamped, rad), and ``/diagnostics``. Service ``~/reset`` (std_srvs/Trigger).
"""

from __future__ import annotations

import math
import time
from collections import deque
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
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import Imu, MagneticField
from std_srvs.srv import Trigger

from .core.registry import FILTERS
from .engine import ImuEngine
from .settings import DESCRIPTIONS, all_defaults, build

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
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        reliability = str(self._settings['qos_reliability'])
        if reliability not in ('best_effort', 'reliable'):
            raise ValueError(f'qos_reliability must be best_effort or reliable, got {reliability!r}')
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=int(self._settings['qos_depth']),
            reliability=ReliabilityPolicy.BEST_EFFORT if reliability == 'best_effort' else ReliabilityPolicy.RELIABLE,
            durability=qos_profile_sensor_data.durability,
        )
        self.pub_imu = self.create_publisher(Imu, 'imu/data', 10)
        self.pub_bias = self.create_publisher(Vector3Stamped, 'imu/gyro_bias', 10)
        self.pub_rpy = self.create_publisher(Vector3Stamped, 'imu/rpy', 10)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # The executor serves ready subscriptions in creation order: magnetometer first, so that a magnetometer
        # sample and the IMU sample with the same stamp pair as they do in `ccf replay` (bag order).
        self.sub_mag = self.create_subscription(MagneticField, 'imu/mag', self._on_mag, qos)
        self.sub_imu = self.create_subscription(Imu, 'imu/data_raw', self._on_imu, qos)
        self.srv_reset = self.create_service(Trigger, '~/reset', self._on_reset)
        self.timer_diag = self.create_timer(1.0, self._publish_diagnostics)

        self._bias_msg = Vector3Stamped()
        self._rpy_msg = Vector3Stamped()
        self._arrivals: deque[float] = deque(maxlen=2048)
        self._last_stamp = -math.inf
        self._last_bias_t = -math.inf
        self._last_mag_t = -math.inf
        # Both -inf: the first IMU sample counts as "synced", so it waits (at most HOLD_S, once) for a magnetometer
        # sample to initialise the heading from, as replay does when the magnetometer comes first in the bag.
        self._last_imu_t = -math.inf
        self._held: deque[tuple[float, Imu, float]] = deque()
        self.timer_hold = self.create_timer(self.HOLD_S, self._flush_held)
        self._period_s = 0.0
        self._n_gaps_lost = 0
        self._last_warn = 0.0
        self._last_mag_wall = -math.inf
        self.get_logger().info(
            f'ccf_node: filter={self._settings["filter"]} formulation={self._settings["formulation"]} '
            f'world_frame={self._settings["world_frame"]} use_mag={self._settings["use_mag"]}, '
            f'listening on {self.sub_imu.topic_name} and {self.sub_mag.topic_name}'
        )

    @staticmethod
    def _filter_settings(settings: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in settings.items() if k not in READ_ONLY and k != 'publish_debug_topics'}

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
        changed = {k: v for k, v in self._settings.items() if old.get(k) != v}
        self.get_logger().info(f'parameters applied: {changed}')

    # --- data ---------------------------------------------------------------------------------------------------
    # IMU and magnetometer come on two topics, and DDS does not order delivery across topics. When the
    # magnetometer carries the IMU's stamps (a 9-axis driver), IMU samples whose magnetometer sample has not
    # arrived yet are held, in order, until it does or HOLD_S pass: pairing then matches `ccf replay` (bag order)
    # instead of using an older magnetometer sample. Nothing is held for a magnetometer on its own clock.
    HOLD_S = 0.02

    def _on_mag(self, msg: MagneticField) -> None:
        s = msg.header.stamp
        t = s.sec + s.nanosec * 1e-9
        f = msg.magnetic_field
        self.engine.on_mag(t, (f.x, f.y, f.z))
        self._last_mag_wall = time.monotonic()
        if t > self._last_mag_t:
            self._last_mag_t = t
        held = self._held
        while held and held[0][0] <= t:
            t_imu, imu, _ = held.popleft()
            self._process_imu(t_imu, imu)

    def _on_imu(self, msg: Imu) -> None:
        s = msg.header.stamp
        t = s.sec + s.nanosec * 1e-9
        self._arrivals.append(time.monotonic())
        # Same-stamp magnetometer seen for the previous sample: this one's is expected too.
        synced = self._last_mag_t == self._last_imu_t
        self._last_imu_t = t
        if self._held or (synced and self._last_mag_t < t and self._settings['use_mag']):
            self._held.append((t, msg, time.monotonic()))
            return
        self._process_imu(t, msg)

    def _flush_held(self) -> None:
        """Timer: release samples held longer than HOLD_S (their magnetometer sample is lost or late)."""
        held = self._held
        now = time.monotonic()
        while held and now - held[0][2] >= self.HOLD_S:
            t_imu, imu, _ = held.popleft()
            self._process_imu(t_imu, imu)

    def _process_imu(self, t: float, msg: Imu) -> None:
        self._track_gaps(t)
        g = msg.angular_velocity
        a = msg.linear_acceleration
        out = self.engine.on_imu(t, (g.x, g.y, g.z), (a.x, a.y, a.z))
        if out is None:
            self._warn_throttled(f'sample at t={t:.6f} s skipped; skipped so far: {self.engine.skipped_by_reason()}')
            return
        o = msg.orientation
        o.x, o.y, o.z, o.w = out.orientation_xyzw
        msg.orientation_covariance = list(out.covariance)
        self.pub_imu.publish(msg)
        rate = self._settings['gyro_bias_rate_hz']
        if rate <= 0.0 or t - self._last_bias_t >= 1.0 / rate or t < self._last_bias_t:
            self._last_bias_t = t
            b = self._bias_msg
            b.header = msg.header
            b.vector.x, b.vector.y, b.vector.z = out.bias
            self.pub_bias.publish(b)
        if self._settings['publish_debug_topics']:
            x, y, z, w = out.orientation_xyzw
            r = self._rpy_msg
            r.header = msg.header
            r.vector.x = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
            r.vector.y = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
            r.vector.z = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
            self.pub_rpy.publish(r)

    def _track_gaps(self, t: float) -> None:
        """Estimate messages lost upstream (DDS drops under overload) from holes in the stamp sequence."""
        dt = t - self._last_stamp
        if 0.0 < dt < 1.0:
            # Running estimate of the nominal period; a hole of k periods means k - 1 lost messages.
            self._period_s = dt if self._period_s == 0.0 else min(self._period_s * 1.001, 0.99 * self._period_s + 0.01 * dt)
            if dt > 1.5 * self._period_s > 0.0:
                self._n_gaps_lost += round(dt / self._period_s) - 1
        if t > self._last_stamp:
            self._last_stamp = t

    def _warn_throttled(self, text: str) -> None:
        now = time.monotonic()
        if now - self._last_warn > 5.0:
            self._last_warn = now
            self.get_logger().warning(text)

    def _on_reset(self, _req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        self._held.clear()
        self.engine.reset()
        resp.success = True
        resp.message = 'filter reset; re-initialising from the next sample with a valid accelerometer'
        self.get_logger().info(resp.message)
        return resp

    # --- diagnostics --------------------------------------------------------------------------------------------
    def diagnostic_status(self) -> DiagnosticStatus:
        """Input rate, skipped samples by reason, magnetometer age, bias norm; OK/WARN/ERROR."""
        now = time.monotonic()
        arr = [t for t in self._arrivals if now - t <= 2.0]
        rate = (len(arr) - 1) / (arr[-1] - arr[0]) if len(arr) > 2 and arr[-1] > arr[0] else 0.0
        mag_age = now - self._last_mag_wall
        bias = self.engine.filter.gyro_bias
        bias_deg_s = math.degrees(math.sqrt(sum(b * b for b in bias)))
        skipped = self.engine.skipped_by_reason()
        level, message = DiagnosticStatus.OK, 'ok'
        if not self._arrivals or now - self._arrivals[-1] > 1.0:
            level, message = DiagnosticStatus.ERROR, 'no IMU input for more than 1 s'
        elif not self.engine.filter.initialized:
            level, message = DiagnosticStatus.ERROR, 'waiting for a valid accelerometer sample'
        elif self._settings['use_mag'] and mag_age > float(self._settings['mag_timeout_s']):
            level, message = DiagnosticStatus.WARN, f'no magnetometer for {mag_age:.1f} s: heading runs on the gyro'
        elif getattr(self.engine.filter, 'mag_disturbed', False):
            level, message = DiagnosticStatus.WARN, 'magnetic disturbance: heading runs on the gyro'
        elif self._n_gaps_lost:
            level, message = DiagnosticStatus.WARN, f'{self._n_gaps_lost} input messages lost upstream'
        values = {
            'input rate (Hz)': f'{rate:.1f}',
            'samples in': str(self.engine.n_in),
            'samples answered': str(self.engine.answered()),
            'messages lost upstream (estimated)': str(self._n_gaps_lost),
            'magnetometer age (s)': f'{mag_age:.2f}' if math.isfinite(mag_age) else 'never',
            'gyro bias norm (deg/s)': f'{bias_deg_s:.3f}',
            'resets after clock jumps': str(self.engine.n_resets_jump),
            'gyro-only samples (bad accelerometer)': str(self.engine.n_no_acc),
            'samples without heading (bad magnetometer)': str(self.engine.n_no_mag),
        }
        values.update({f'skipped: {k}': str(v) for k, v in skipped.items()})
        return DiagnosticStatus(
            level=level,
            name=f'{self.get_name()}: orientation filter',
            message=message,
            hardware_id=self.get_fully_qualified_name(),
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
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
