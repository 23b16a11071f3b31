"""The node's bookkeeping as plain code: input statistics and the diagnostics it publishes. No ROS import.

:class:`InputStats` counts what arrives (IMU arrival times -> input rate, holes in the stamp sequence -> messages
lost upstream, magnetometer arrival time); :func:`diagnostics` turns those, the engine and the IMU/magnetometer
sync into the values and the OK / WARN / ERROR level of the node's ``/diagnostics`` status. Times are plain floats:
stamps in s, ``now`` from a monotonic clock in s, passed in by the caller.
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

from .engine import ImuEngine
from .sync import HoldStats

#: Levels as in diagnostic_msgs/DiagnosticStatus.
OK, WARN, ERROR = 0, 1, 2
#: No IMU sample for this long (s) is an error.
NO_INPUT_S = 1.0
#: Input rate over the arrivals of this window (s).
RATE_WINDOW_S = 2.0
#: Messages lost upstream within this long (s) warn.
LOSS_WARN_S = 10.0


class InputStats:
    """What arrives at the node: IMU arrival times, the nominal period and holes in the stamp sequence."""

    def __init__(self) -> None:
        self._arrivals: deque[float] = deque(maxlen=4096)
        self._last_stamp = -math.inf
        self._period_s = 0.0
        #: messages lost upstream (DDS drops under overload), estimated from holes in the IMU stamp sequence
        self.n_lost = 0
        #: ``now`` of the latest detected loss, of the latest IMU and magnetometer arrival (-inf: never)
        self.last_loss = -math.inf
        self.last_imu = -math.inf
        self.last_mag = -math.inf
        #: messages received per topic, and messages dropped because they could not be read
        self.n_imu = 0
        self.n_mag = 0
        self.n_unreadable = 0

    def on_imu(self, t: float, now: float) -> None:
        """An IMU sample with stamp ``t`` (s) arrived at ``now``."""
        self._arrivals.append(now)
        self.last_imu = now
        self.n_imu += 1
        dt = t - self._last_stamp
        if 0.0 < dt < 1.0:
            # Running estimate of the nominal period (follows a faster rate at once, a slower one slowly);
            # a hole of k periods means k - 1 lost messages.
            p = self._period_s
            p = dt if p == 0.0 else min(p * 1.001, 0.99 * p + 0.01 * dt)
            self._period_s = p
            if dt > 1.5 * p:
                self.n_lost += round(dt / p) - 1
                self.last_loss = now
        if t > self._last_stamp:
            self._last_stamp = t

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
        """Estimated nominal IMU period from the stamps, s (0 before two samples)."""
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
    accelerometer yet); WARN magnetometer in use but none for ``mag_timeout_s``, WARN magnetic disturbance, WARN
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
        'samples answered': str(engine.answered()),
        'messages lost upstream (estimated)': str(stats.n_lost),
        'unreadable messages dropped': str(stats.n_unreadable),
        'magnetometer age (s)': f'{mag_age:.2f}' if math.isfinite(mag_age) else 'never',
        'gyro bias norm (deg/s)': f'{bias_deg_s:.3f}',
        'resets after clock jumps': str(engine.n_resets_jump),
        'gyro-only samples (bad accelerometer)': str(engine.n_no_acc),
        'samples without heading (bad magnetometer)': str(engine.n_no_mag),
        'non-finite state resets': str(n_nonfinite),
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
    values.update({f'skipped: {k}': str(v) for k, v in engine.skipped_by_reason().items()})
    return Diagnostics(level, message, values)
