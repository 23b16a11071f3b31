"""The node's bookkeeping as plain code: parameter values, input statistics, diagnostics, debug values. No ROS import.

:func:`coerce_parameter` checks and converts a parameter value as the node receives it (an integer for a real
parameter included); :class:`InputStats` counts what arrives (IMU arrival times -> input rate, holes in the stamp
sequence -> messages lost upstream, magnetometer arrival time); :func:`diagnostics` turns those, the engine and the
IMU/magnetometer sync into the values and the OK / WARN / ERROR level of the node's ``/diagnostics`` status;
:func:`raw_rpy` is the ``imu/rpy/raw`` debug value and :func:`imu_header` reads what TF needs from a serialized Imu.
Times are plain floats: stamps in s, ``now`` from a monotonic clock in s, passed in by the caller.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from typing import Any, NamedTuple

from .core.quaternion import WORLD_FRAMES, quat_from_acc_mag_scalar, quat_mul_scalar, rpy_of
from .engine import ImuEngine
from .settings import coerce, schema
from .sync import HoldStats

Vec3 = tuple[float, float, float]

# --- parameters -------------------------------------------------------------------------------------------------

# The parameters' definitions, ranges and validation are in ccf_ros.settings (one schema); these names stay for
# existing imports.
#: Parameters whose value may be a number or a list of three (per axis).
PER_AXIS = frozenset(name for name, p in schema().items() if p.per_axis)
#: Range of a real parameter without its own.
DEFAULT_RANGE = (0.0, 1e9)


def parameter_range(name: str) -> tuple[float, float]:
    """The inclusive range of the real parameter ``name`` (its definition's)."""
    return schema()[name].range or DEFAULT_RANGE


def coerce_parameter(name: str, value: Any, default: Any = None) -> Any:
    """``value`` of the parameter ``name`` as the settings take it: :func:`ccf_ros.settings.coerce` (``default``,
    the executable's, is not needed: the definition has the type).

    Raises:
        ParameterError: not of the parameter's type, or out of range; the message names the parameter.
    """
    return coerce(name, value)


# --- debug values and TF ------------------------------------------------------------------------------------------

def raw_rpy(acc: Vec3, mag: Vec3 | None, world_frame: str) -> Vec3 | None:
    """Roll, pitch, yaw (rad) of the attitude of one accelerometer + (calibrated) magnetometer sample alone, in the
    world frame ``world_frame`` (imu_filter_madgwick's ``imu/rpy/raw``: no filter, no yaw offset); None without a
    magnetometer sample, an unusable accelerometer, or a field too close to the vertical to give a heading."""
    if mag is None:
        return None
    ax, ay, az = acc
    n2 = ax * ax + ay * ay + az * az
    if not (n2 > 1e-12 and math.isfinite(n2)) or not all(math.isfinite(m) for m in mag):
        return None
    q = quat_from_acc_mag_scalar(ax, ay, az, mag[0], mag[1], mag[2], True)
    if q is None:
        return None
    # ENU -> the world frame (as OrientationFilter.quaternion does): q_frame = p ⊗ q_enu.
    return rpy_of(quat_mul_scalar(WORLD_FRAMES[world_frame], q))


_HEADER = struct.Struct('<iII')  # after the 4-byte encapsulation: sec, nanosec, frame_id length (with its NUL)


def imu_header(data: bytes) -> tuple[int, int, str]:
    """``(sec, nanosec, frame_id)`` of a little-endian CDR message that starts with a std_msgs/Header."""
    sec, nanosec, n = _HEADER.unpack_from(data, 4)
    return sec, nanosec, data[16:16 + max(n - 1, 0)].decode('utf-8', 'replace')


#: Levels as in diagnostic_msgs/DiagnosticStatus.
OK, WARN, ERROR = 0, 1, 2
#: No IMU sample for this long (s) is an error.
NO_INPUT_S = 1.0
#: Input rate over the arrivals of this window (s).
RATE_WINDOW_S = 2.0
#: Messages lost upstream within this long (s) warn.
LOSS_WARN_S = 10.0
#: Stamp intervals of this many latest IMU samples make the statistics of the normal interval ...
INTERVAL_WINDOW = 256
#: ... taken again every this many samples (and first after INTERVAL_MIN): sorting each time would cost per message.
INTERVAL_REFRESH = 32
INTERVAL_MIN = 16
#: More than this share of the latest answers with a held orientation warns (the output is frozen).
STALE_WARN = 0.5
#: An interval longer than this many times the nominal one is a hole (messages lost) ...
HOLE_FACTOR = 1.5
#: ... and longer than the nominal one by this many robust standard deviations of the nominal intervals (jitter).
HOLE_SIGMAS = 4.0


class InputStats:
    """What arrives at the node: IMU arrival times, the nominal period and holes in the stamp sequence."""

    def __init__(self) -> None:
        self._arrivals: deque[float] = deque(maxlen=4096)
        self._last_stamp = -math.inf
        #: the stamp intervals of the latest IMU samples, s, and how many came since the statistics were taken
        self._intervals: deque[float] = deque(maxlen=INTERVAL_WINDOW)
        self._n_since = 0
        self._period_s = 0.0
        self._nominal_s = 0.0
        self._hole_s = 0.0
        self._per_read = 1
        #: messages lost upstream (DDS drops under overload), estimated from holes in the IMU stamp sequence
        self.n_lost = 0
        #: ``now`` of the latest detected loss, of the latest IMU and magnetometer arrival (-inf: never)
        self.last_loss = -math.inf
        self.last_imu = -math.inf
        self.last_mag = -math.inf
        #: messages received per topic, and messages dropped because they could not be read
        self.n_imu = 0
        self.n_mag = 0
        #: magnetometer samples that reached the engine after the IMU sample with their stamp (or a later one) had
        #: been processed: replay (bag order) pairs them earlier
        self.n_mag_late = 0
        self.n_unreadable = 0

    def on_imu(self, t: float, now: float) -> None:
        """An IMU sample with stamp ``t`` (s) arrived at ``now``.

        The statistics of the window (:meth:`_refresh`): the nominal interval ``L`` between stamps (between reads, for
        a driver that stamps a FIFO read of ``m`` samples together) and ``m``. A hole is an interval longer than
        :data:`HOLE_FACTOR` ``L`` and than ``L`` plus :data:`HOLE_SIGMAS` robust deviations of the intervals, and
        counts ``(round(dt / L) - 1) m`` lost messages; jittered or bursty stamps are not holes.
        """
        self._arrivals.append(now)
        self.last_imu = now
        self.n_imu += 1
        dt = t - self._last_stamp
        if 0.0 < dt < 1.0:
            nominal = self._nominal_s
            if nominal and dt > self._hole_s:
                self.n_lost += (round(dt / nominal) - 1) * self._per_read
                self.last_loss = now
            # Holes stay in the window: a lasting slower rate becomes the normal one within a refresh or two.
            self._intervals.append(dt)
            self._n_since += 1
            if self._n_since >= INTERVAL_REFRESH or (not nominal and len(self._intervals) >= INTERVAL_MIN):
                self._refresh()
        if t > self._last_stamp:
            self._last_stamp = t

    def _refresh(self) -> None:
        """The nominal interval: the median of the window's intervals that are not the short ones inside a burst
        (below a third of the 95th percentile), robust to jitter, to bursts and to losses of up to half the
        messages; samples per read: the nominal interval over the mean of the intervals that are not holes."""
        s = sorted(self._intervals)
        p95 = s[int(0.95 * (len(s) - 1))]
        long = [x for x in s if x >= p95 / 3.0]
        nominal = long[len(long) // 2]
        # Jitter: a hole must also stand HOLE_SIGMAS robust deviations (1.4826 MAD) of the nominal intervals above
        # them, or a driver that stamps on arrival would report losses all the time.
        spread = 1.4826 * sorted(abs(x - nominal) for x in long)[len(long) // 2]
        self._hole_s = nominal + max((HOLE_FACTOR - 1.0) * nominal, HOLE_SIGMAS * spread)
        normal = [x for x in s if x <= self._hole_s]
        self._period_s = sum(normal) / len(normal)
        self._per_read = max(1, round(nominal / self._period_s))
        self._nominal_s = nominal
        self._n_since = 0

    def on_mag(self, now: float) -> None:
        """A magnetometer sample arrived at ``now``."""
        self.last_mag = now
        self.n_mag += 1

    def rate_hz(self, now: float, window_s: float = RATE_WINDOW_S) -> float:
        """IMU input rate over the arrivals of the last ``window_s`` s (0 with fewer than 3)."""
        arr = [a for a in self._arrivals if now - a <= window_s]
        return (len(arr) - 1) / (arr[-1] - arr[0]) if len(arr) > 2 and arr[-1] > arr[0] else 0.0

    @property
    def period_s(self) -> float:
        """Estimated nominal IMU period from the stamps (mean normal interval), s (0 before INTERVAL_MIN samples)."""
        return self._period_s


class Diagnostics(NamedTuple):
    """One diagnostics status: level (:data:`OK`, :data:`WARN`, :data:`ERROR`), message and key/value pairs."""

    level: int
    message: str
    values: dict[str, str]


def _yes(flag: bool) -> str:
    return 'true' if flag else 'false'


def diagnostics(
    now: float,
    stats: InputStats,
    engine: ImuEngine,
    hold: HoldStats,
    *,
    use_mag: bool,
    mag_timeout_s: float,
) -> Diagnostics:
    """The node's status from its input statistics, the engine (filter flags and counters) and the hold statistics.

    Rules, first match wins: ERROR no IMU input for more than :data:`NO_INPUT_S`, ERROR not initialised (no valid
    accelerometer yet); WARN more than :data:`STALE_WARN` of the latest answers held the orientation; WARN
    magnetometer in use but none for ``mag_timeout_s``, WARN magnetic disturbance, WARN
    non-finite filter state (re-initialised), WARN messages lost upstream in the last :data:`LOSS_WARN_S`; else OK.
    """
    filt = engine.filter
    flags = filt.flags
    mag_age = now - stats.last_mag
    bias = filt.gyro_bias
    bias_deg_s = math.degrees(math.sqrt(sum(b * b for b in bias)))
    n_nonfinite = engine.n_nonfinite_resets  # kept across resets (the filter's own counter starts over)
    level, message = OK, 'ok'
    if now - stats.last_imu > NO_INPUT_S:
        level, message = ERROR, f'no IMU input for more than {NO_INPUT_S:g} s'
    elif not flags.initialized:
        level, message = ERROR, 'waiting for a valid accelerometer sample'
    elif engine.stale_share > STALE_WARN:
        level, message = WARN, (
            f'{engine.stale_share:.0%} of the latest samples were answered with a held orientation (repeated, '
            'backward or zero stamps, or a bad gyro); set constant_dt if the driver does not stamp messages')
    elif use_mag and mag_age > mag_timeout_s:
        since = f'for {mag_age:.1f} s' if math.isfinite(mag_age) else 'sample yet'
        level, message = WARN, f'no magnetometer {since}: heading runs on the gyro'
    elif flags.mag_disturbed:
        level, message = WARN, 'magnetic disturbance: heading runs on the gyro'
    elif n_nonfinite:
        level, message = WARN, f'filter state became non-finite {n_nonfinite} times and was re-initialised'
    elif now - stats.last_loss <= LOSS_WARN_S:
        level, message = WARN, f'input messages lost upstream ({stats.n_lost} so far)'
    values = {
        'input rate (Hz)': f'{stats.rate_hz(now):.1f}',
        'samples in': str(engine.n_in),
        'magnetometer samples in': str(stats.n_mag),
        'magnetometer samples after their IMU sample': str(stats.n_mag_late),
        'samples answered': str(engine.answered()),
        'samples answered with the current orientation (could not advance the filter)': str(engine.n_answered_stale),
        'share of the latest answers with a held orientation': f'{engine.stale_share:.2f}',
        'messages lost upstream (estimated)': str(stats.n_lost),
        'unreadable messages dropped': str(stats.n_unreadable),
        'magnetometer age (s)': f'{mag_age:.2f}' if math.isfinite(mag_age) else 'never',
        'gyro bias norm (deg/s)': f'{bias_deg_s:.3f}',
        'gyro bias 1-sigma per axis (deg/s)': (
            f'{math.degrees(sigma):.3f}' if (sigma := getattr(engine.filter, 'gyro_bias_sigma_rad_s', None)) is not None
            else 'not estimated'),
        'resets after clock jumps': str(engine.n_resets_jump),
        'gyro-only samples (bad accelerometer)': str(engine.n_no_acc),
        'samples without heading (bad magnetometer)': str(engine.n_no_mag),
        'non-finite state resets': str(n_nonfinite),
        'gyro samples clipped (at gyro_range_rad_s)': str(engine.n_gyro_clipped),
        'initialized': _yes(flags.initialized),
        'at rest': _yes(flags.at_rest),
        'accelerometer used': _yes(flags.acc_used),
        'magnetometer used': _yes(flags.mag_used),
        'magnetic disturbance': _yes(flags.mag_disturbed),
        'heading absolute': _yes(flags.heading_absolute),
        'magnetometer in lock-step': _yes(hold.lockstep),
        'samples held for magnetometer': str(hold.n_held),
        'hold timeouts': str(hold.n_timeouts),
        'hold max (ms)': f'{hold.max_ms:.2f}',
        'hold mean (ms)': f'{hold.mean_ms:.3f}',
    }
    hi = engine.hard_iron_status()
    if hi is None:
        values['online hard iron'] = 'off'
    else:
        # The field in tesla (sensor_msgs/MagneticField): shown in uT.
        values['online hard iron'] = hi.status
        values['online hard-iron offset applied (uT)'] = ' '.join(f'{v * 1e6:.2f}' for v in hi.offset)
        values['online hard-iron estimate (uT)'] = ' '.join(f'{v * 1e6:.2f}' for v in hi.estimate)
        values['online hard-iron 1-sigma (uT)'] = ' '.join(f'{v * 1e6:.2f}' for v in hi.sigma)
        values['online hard-iron model residual (share of the field)'] = f'{hi.residual_rel:.3f}'
    values.update({f'skipped: {k}': str(v) for k, v in engine.skipped_by_reason().items()})
    return Diagnostics(level, message, values)
