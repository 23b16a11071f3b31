"""Pair each IMU sample with the latest magnetometer sample, identically in the node and in replay."""

from __future__ import annotations

import math
from collections import deque


class MagPairer:
    """Keeps the latest magnetometer sample (by stamp) and hands it to IMU samples that are not older than it.

    A magnetometer sample is used for an IMU sample at ``t`` if its stamp is ``<= t + tolerance_s`` and
    ``>= t - timeout_s``. Messages are processed in arrival order (bag order in replay, callback order in the node),
    which makes both paths pair identically.

    A stray stamp (a glitch of the magnetometer's clock) would wait at the front and hold back every sample behind it
    until the queue's length pushed it out. So a front sample stamped more than ``timeout_s`` ahead of the IMU stamp
    (or NaN) is dropped, counted in :attr:`n_stray_ahead`, while the newest queued sample is a current one (within
    ``timeout_s`` of the IMU stamp: the stream has gone on behind the stray) and the sample in use is not far ahead
    either (else the IMU's clock jumped back). A magnetometer clock that runs more than ``timeout_s`` ahead, or whose
    newest sample is far behind (its clock jumped back: a bag loop, which :meth:`restart` handles), is left as it is.

    Args:
        timeout_s: oldest magnetometer sample still used, s before the IMU stamp. Default 0.5 s.
        tolerance_s: a magnetometer stamp up to this much after the IMU stamp still counts (clock jitter), s.
    """

    #: Most samples queued, oldest pushed out first (counted: :attr:`n_pushed_out`): the samples ahead of the IMU
    #: stream wait here. The node takes a reader queue's backlog only while there is :attr:`room`, but its executor
    #: hands it every magnetometer sample as it comes: an IMU topic delivered this far behind the magnetometer's
    #: loses pairs. 4096 is 14 s of a 286 Hz magnetometer, 4 s at 1 kHz (256 before: 0.9 s at 286 Hz); ~1 MB at most.
    QUEUE_MAX = 4096

    def __init__(self, timeout_s: float = 0.5, tolerance_s: float = 1e-4) -> None:
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f'mag timeout_s must be a finite number > 0, got {timeout_s!r}')
        if not (math.isfinite(tolerance_s) and tolerance_s >= 0):
            raise ValueError(f'mag tolerance_s must be a finite number >= 0, got {tolerance_s!r}')
        self.timeout_s = timeout_s
        self.tolerance_s = tolerance_s
        #: stray magnetometer stamps dropped (far ahead of the IMU stamp, a current sample behind), over the pairer's life
        self.n_stray_ahead = 0
        #: samples pushed out of a full queue before an IMU stamp reached them, over the pairer's life
        self.n_pushed_out = 0
        self.reset()

    def reset(self) -> None:
        """Forget all magnetometer samples."""
        self._t_in_use = -math.inf
        self._field_in_use: tuple[float, float, float] | None = None
        self._pending: deque[tuple[float, tuple[float, float, float]]] = deque(maxlen=self.QUEUE_MAX)

    def restart(self, t_s: float, horizon_s: float) -> None:
        """The clock jumped back to ``t_s`` (bag loop, simulation reset): forget the sample in use and the pending
        ones of the old timeline, keep those of the new one (stamps from ``t_s - timeout_s`` to ``t_s + horizon_s``,
        s), so the restart initialises with the magnetometer and later samples still pair."""
        keep = [(tm, m) for tm, m in self._pending if t_s - self.timeout_s <= tm <= t_s + horizon_s]
        self._t_in_use = -math.inf
        self._field_in_use = None
        self._pending.clear()
        self._pending.extend(keep)

    def add(self, t_s: float, mag: tuple[float, float, float]) -> None:
        """Record a magnetometer sample at ``t_s`` (s)."""
        # A sample that arrives ahead of the IMU stream waits until an IMU stamp reaches it.
        pending = self._pending
        if len(pending) == pending.maxlen:
            self.n_pushed_out += 1
        pending.append((t_s, mag))

    def get(self, t_s: float) -> tuple[float, float, float] | None:
        """The magnetometer sample for an IMU sample at ``t_s``, or None if there is none recent enough."""
        pending = self._pending
        if pending:
            limit = t_s + self.tolerance_s
            # Arrival order is (nearly) stamp order: take samples from the front while they are due.
            while pending and pending[0][0] <= limit:
                tm, m = pending.popleft()
                if tm >= self._t_in_use:
                    self._t_in_use, self._field_in_use = tm, m
            if pending and not pending[0][0] - t_s <= self.timeout_s:
                # The front is far ahead of this IMU stamp (or NaN): perhaps a stray (rare).
                self.skip_strays_ahead(t_s, limit)
        if self._field_in_use is None or t_s - self._t_in_use > self.timeout_s:
            return None
        return self._field_in_use

    def skip_strays_ahead(self, t_s: float, limit: float) -> None:
        """The rare path of :meth:`get` for an IMU sample at ``t_s`` (s; ``limit``: ``t_s`` + tolerance) whose queue's
        front is more than ``timeout_s`` ahead of it: drop the front samples that far ahead (or NaN) if the newest
        one is within ``timeout_s`` of ``t_s`` and the one in use is not far ahead, then take the due ones."""
        pending = self._pending
        ahead = t_s + self.timeout_s
        if not (t_s - self.timeout_s <= pending[-1][0] <= ahead and self._t_in_use <= ahead):
            # The newest is not a current sample (the magnetometer's clock runs ahead, jumped back or sent a stamp
            # far behind), or the IMU's clock jumped back; or NaN: nothing is known to be a stray.
            return
        while not pending[0][0] <= ahead:  # (stops at the newest at the latest)
            pending.popleft()
            self.n_stray_ahead += 1
        while pending and pending[0][0] <= limit:
            tm, m = pending.popleft()
            if tm >= self._t_in_use:
                self._t_in_use, self._field_in_use = tm, m

    @property
    def room(self) -> int:
        """Samples that can be added before the queue pushes out its oldest."""
        pending = self._pending
        return (self.QUEUE_MAX if pending.maxlen is None else pending.maxlen) - len(pending)

    @property
    def stamp_in_use_s(self) -> float:
        """Stamp of the magnetometer sample in use, s (``-inf`` if none)."""
        return self._t_in_use
