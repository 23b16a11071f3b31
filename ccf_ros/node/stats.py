"""What arrives at the node, as plain code (no ROS import): IMU arrival times -> input rate, holes in the stamp
sequence -> messages lost upstream, magnetometer arrival time. Stamps in s, ``now`` from a monotonic clock in s,
passed in by the caller."""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections import deque

#: Input rate over the arrivals of this window (s).
RATE_WINDOW_S = 2.0
#: Stamp intervals of this many latest IMU samples make the statistics of the normal interval ...
INTERVAL_WINDOW = 256
#: ... taken again every this many samples (and first after INTERVAL_MIN): sorting each time would cost per message.
INTERVAL_REFRESH = 32
INTERVAL_MIN = 16
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
        # (Slices of the sorted window where a filter would do: the same values, without a Python loop.)
        s = sorted(self._intervals)
        p95 = s[int(0.95 * (len(s) - 1))]
        long = s[bisect_left(s, p95 / 3.0):]
        nominal = long[len(long) // 2]
        # Jitter: a hole must also stand HOLE_SIGMAS robust deviations (1.4826 MAD) of the nominal intervals above
        # them, or a driver that stamps on arrival would report losses all the time.
        spread = 1.4826 * sorted([abs(x - nominal) for x in long])[len(long) // 2]
        self._hole_s = nominal + max((HOLE_FACTOR - 1.0) * nominal, HOLE_SIGMAS * spread)
        normal = s[:bisect_right(s, self._hole_s)]
        self._period_s = sum(normal) / len(normal)
        self._per_read = max(1, round(nominal / self._period_s))
        self._nominal_s = nominal
        self._n_since = 0

    def on_mag(self, now: float) -> None:
        """A magnetometer sample arrived at ``now``. (Written out in ``CcfNode._mag``: the two change together.)"""
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
