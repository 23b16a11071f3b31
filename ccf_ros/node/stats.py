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
#: IMU samples kept as (stamp, arrival) before they are taken into the statistics together (a loop over them costs
#: less than a call with these steps per message).
PENDING_MAX = 32
#: An interval longer than this many times the nominal one is a hole (messages lost) ...
HOLE_FACTOR = 1.5
#: ... and longer than the nominal one by this many robust standard deviations of the nominal intervals (jitter).
HOLE_SIGMAS = 4.0


class InputStats:
    """What arrives at the node: IMU arrival times, the nominal period and holes in the stamp sequence."""

    def __init__(self) -> None:
        self._arrivals: deque[float] = deque(maxlen=4096)
        #: (stamp, now) of the IMU samples not yet taken into the statistics: taken PENDING_MAX at a time, and before
        #: any of them is read (one list append per message; CcfNode._imu writes :meth:`on_imu` out)
        self.pending: list[tuple[float, float]] = []
        self._last_stamp = -math.inf
        #: the stamp intervals of the latest IMU samples, s, and how many came since the statistics were taken
        self._intervals: deque[float] = deque(maxlen=INTERVAL_WINDOW)
        self._n_since = 0
        self._period_s = 0.0
        self._nominal_s = 0.0
        self._hole_s = 0.0
        self._per_read = 1
        self._n_lost = 0
        self._last_loss = -math.inf
        self._n_imu = 0
        self._last_imu = -math.inf
        #: ``now`` of the latest magnetometer arrival (-inf: never)
        self.last_mag = -math.inf
        #: magnetometer messages received, and messages dropped because they could not be read
        self.n_mag = 0
        #: magnetometer samples that reached the engine after the IMU sample with their stamp (or a later one) had
        #: been processed: replay (bag order) pairs them earlier
        self.n_mag_late = 0
        self.n_unreadable = 0

    def on_imu(self, t: float, now: float) -> None:
        """An IMU sample with stamp ``t`` (s) arrived at ``now`` (taken into the statistics by :meth:`catch_up`).
        (Written out in ``CcfNode._imu``: the two change together.)"""
        pending = self.pending
        pending.append((t, now))
        if len(pending) >= PENDING_MAX:
            self.catch_up()

    def catch_up(self) -> None:
        """Take the pending samples into the statistics, in their order.

        The statistics of the window (:meth:`_refresh`): the nominal interval ``L`` between stamps (between reads, for
        a driver that stamps a FIFO read of ``m`` samples together) and ``m``. A hole is an interval longer than
        :data:`HOLE_FACTOR` ``L`` and than ``L`` plus :data:`HOLE_SIGMAS` robust deviations of the intervals, and
        counts ``(round(dt / L) - 1) m`` lost messages; jittered or bursty stamps are not holes.
        """
        pending = self.pending
        if not pending:
            return
        intervals = self._intervals
        last_stamp = self._last_stamp
        for t, now in pending:
            dt = t - last_stamp
            if 0.0 < dt < 1.0:
                nominal = self._nominal_s
                if nominal and dt > self._hole_s:
                    self._n_lost += (round(dt / nominal) - 1) * self._per_read
                    self._last_loss = now
                # Holes stay in the window: a lasting slower rate becomes the normal one within a refresh or two.
                intervals.append(dt)
                self._n_since += 1
                if self._n_since >= INTERVAL_REFRESH or (not nominal and len(intervals) >= INTERVAL_MIN):
                    self._refresh()
            if t > last_stamp:
                last_stamp = t
        self._last_stamp = last_stamp
        self._arrivals.extend([now for _, now in pending])
        self._n_imu += len(pending)
        self._last_imu = pending[-1][1]
        pending.clear()

    @property
    def n_imu(self) -> int:
        """IMU messages received."""
        return self._n_imu + len(self.pending)

    @property
    def last_imu(self) -> float:
        """``now`` of the latest IMU arrival (-inf: never)."""
        return self.pending[-1][1] if self.pending else self._last_imu

    @property
    def n_lost(self) -> int:
        """Messages lost upstream (DDS drops under overload), estimated from holes in the IMU stamp sequence."""
        self.catch_up()
        return self._n_lost

    @property
    def last_loss(self) -> float:
        """``now`` of the latest detected loss (-inf: never)."""
        self.catch_up()
        return self._last_loss

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
        self.catch_up()
        arr = [a for a in self._arrivals if now - a <= window_s]
        return (len(arr) - 1) / (arr[-1] - arr[0]) if len(arr) > 2 and arr[-1] > arr[0] else 0.0

    @property
    def period_s(self) -> float:
        """Estimated nominal IMU period from the stamps (mean normal interval), s (0 before INTERVAL_MIN samples)."""
        self.catch_up()
        return self._period_s
