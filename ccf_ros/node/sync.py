"""IMU/magnetometer delivery order for the node: when to hold an IMU sample for its magnetometer sample. No ROS import.

DDS does not order delivery across topics. When the magnetometer carries the IMU's stamps (lock-step: a 9-axis
driver publishing both from one reading), an IMU sample can arrive before the magnetometer sample with the same
stamp; processed at once it would pair with the previous magnetometer sample, not as ``ccf replay`` pairs it (bag
order, magnetometer first). :class:`ImuMagSync` holds such a sample, in order, until its magnetometer sample arrives
or ``hold_s`` (20 ms) pass.

Every IMU stamp gets a verdict: *matched* (a magnetometer sample with the same stamp arrived, before or after it)
or *skipped* (a magnetometer sample with a later stamp arrived first, or the IMU sample came after a later one).
The magnetometer is in lock-step when the last ``lockstep_after`` (2) IMU stamps were matched: two in a row means a
magnetometer sample for every IMU sample, which a magnetometer slower than the IMU on the same clock (e.g. at every
4th IMU stamp: one match in a row at most) or on its own clock (none) never reaches. IMU samples wait only

* in lock-step, when their magnetometer sample has not arrived yet;
* while *undecided*: at start-up (and after :meth:`~ImuMagSync.reset`), after a lost magnetometer sample in
  lock-step, and when the magnetometer comes back after it stopped in lock-step. Undecided ends with lock-step, with
  a skipped stamp outside lock-step (a slower magnetometer or one on its own clock), or with the timeout.

So a lock-step magnetometer pairs as in replay from the first sample on, whatever the delivery order, and after
losses; a slower one or one on its own clock is never waited for after start-up, where the first samples may wait
once, less than one magnetometer period (at most ``hold_s``), for the first verdict.

Times are plain floats: stamps (s) as the node computes them (``sec + nanosec * 1e-9``, identical for identical
stamps), and a monotonic clock ``now`` (s) passed in by the caller, which makes the class deterministic to test.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import Generic, NamedTuple, TypeVar

from ..engine import JUMP_BACK_RESET_S

#: Longest time (s) an IMU sample waits for its magnetometer sample.
HOLD_S = 0.02
#: Lock-step: this many IMU stamps in a row had a magnetometer sample with the same stamp.
LOCKSTEP_AFTER = 2

T = TypeVar('T')
_NOTHING: tuple[()] = ()


class HoldStats(NamedTuple):
    """Hold statistics since the start (or :meth:`ImuMagSync.reset_stats`).

    Attributes:
        n_held: IMU samples that waited for a magnetometer sample.
        n_timeouts: times the held samples were released by the timeout (the magnetometer stopped, or none at
            start-up).
        max_ms: longest wait, ms (0 if none).
        mean_ms: mean wait of the held samples, ms (0 if none).
        lockstep: the magnetometer currently runs in lock-step with the IMU.
    """

    n_held: int
    n_timeouts: int
    max_ms: float
    mean_ms: float
    lockstep: bool


class ImuMagSync(Generic[T]):
    """Decides, per IMU sample, whether it is processed now or waits for its same-stamp magnetometer sample.

    Use: :meth:`on_imu` for every IMU sample (True: process it now; False: it is held), :meth:`on_mag` for every
    magnetometer sample *after* handing it to the pairer (returns the held samples it releases, in order, to be
    processed now), and :meth:`expire` when :attr:`deadline` has passed (returns the samples released by the
    timeout). Held samples keep their order; a sample arriving while others are held waits behind them.

    Args:
        hold_s: longest wait of a held sample, s.
        lockstep_after: matched stamps in a row that make the magnetometer count as lock-step.
        enabled: False never holds (no magnetometer in use).
    """

    #: recent stamps remembered per topic (a magnetometer may run ahead of, or behind, the IMU: a node that takes
    #: queued messages magnetometer first may see a few dozen ahead)
    WINDOW = 64

    def __init__(self, hold_s: float = HOLD_S, lockstep_after: int = LOCKSTEP_AFTER, enabled: bool = True) -> None:
        if not (math.isfinite(hold_s) and hold_s > 0):
            raise ValueError(f'hold_s must be a finite number > 0, got {hold_s!r}')
        if not lockstep_after >= 1:
            raise ValueError(f'lockstep_after must be >= 1, got {lockstep_after!r}')
        self.hold_s = hold_s
        self.lockstep_after = lockstep_after
        self.enabled = enabled
        self._held: deque[tuple[float, T, float]] = deque()
        self.reset_stats()
        self.reset()

    def reset(self) -> None:
        """Forget the stamps seen: start-up again (undecided, lock-step learnt again).

        Held samples are dropped: call :meth:`flush` first to process them.
        """
        self._held.clear()
        self._mag_t = -math.inf
        self._mag_recent: deque[float] = deque(maxlen=self.WINDOW)
        #: IMU stamps without a verdict yet, in arrival order
        self._unresolved: deque[float] = deque(maxlen=self.WINDOW)
        self._streak = 0
        self._undecided = True
        #: the magnetometer stopped while in lock-step: undecided again when it comes back
        self._resume = False

    def reset_stats(self) -> None:
        """Zero the hold statistics."""
        self._n_held = 0
        self._n_timeouts = 0
        self._hold_sum = 0.0
        self._hold_max = 0.0

    # --- verdicts ---------------------------------------------------------------------------------------------
    # (_matched is written out on the common path of on_imu and on_mag, where a call per message costs as much as its
    # body: those copies change together with it.)
    def _matched(self) -> None:
        self._streak += 1
        if self._streak >= self.lockstep_after:
            self._undecided = False

    def _skipped(self) -> None:
        # In lock-step: a lost magnetometer sample, wait and see. Otherwise: a slower magnetometer or its own clock.
        self._undecided = self._streak >= self.lockstep_after
        self._streak = 0

    # --- per sample -----------------------------------------------------------------------------------------
    def _new_timeline(self) -> None:
        """Forget the stamps of the old timeline (held samples stay, in order, until released or expired)."""
        held = self._held
        self._held = deque()
        self.reset()
        self._held = held

    def on_imu(self, t: float, item: T, now: float) -> bool:
        """An IMU sample with stamp ``t`` arrived at ``now``. True: process ``item`` now; False: it is held."""
        if not self.enabled:
            return True
        mag_t = self._mag_t
        if t < mag_t - JUMP_BACK_RESET_S:  # the clock jumped back (bag loop, simulation reset)
            self._new_timeline()
            mag_t = self._mag_t
        if t == mag_t or t in self._mag_recent:
            # Its magnetometer sample came first: _matched.
            self._streak += 1
            if self._streak >= self.lockstep_after:
                self._undecided = False
        elif t < mag_t:
            self._skipped()  # the magnetometer is already past this stamp: no sample of its own
        else:
            # Its magnetometer sample may be in flight (a full window of stamps without any drops the oldest).
            self._unresolved.append(t)
            if self._held or self._undecided or self._streak >= self.lockstep_after:
                self._held.append((t, item, now))
                return False
            return True
        if self._held:
            # Its magnetometer sample is here, but earlier samples still wait: keep the order.
            self._held.append((t, item, now))
            return False
        return True

    def on_mag(self, t: float, now: float) -> Sequence[T]:
        """A magnetometer sample with stamp ``t`` arrived at ``now``: the held samples it releases, in order."""
        released: list[T] | None = None
        if t < self._mag_t - JUMP_BACK_RESET_S:  # the clock jumped back (bag loop, simulation reset)
            # The old timeline's held samples will not get theirs: process them now, then start over.
            released = self.flush(now)
            self.reset()
        self._mag_recent.append(t)
        if t > self._mag_t:
            self._mag_t = t
        u = self._unresolved
        while u and u[0] <= t:
            if u.popleft() == t:
                self._matched()
            else:
                self._skipped()
        if self._resume:
            # Back after it stopped in lock-step (the stamps of the silence were skipped): wait and see again.
            self._resume = False
            self._undecided = self._streak < self.lockstep_after
        held = self._held
        if not held:
            return released or _NOTHING
        out = released or []
        if not self._undecided and self._streak < self.lockstep_after:
            return out + self.flush(now)  # not (or no longer) in lock-step: nothing to wait for
        while held and held[0][0] <= t:
            out.append(self._release(now))
        return out

    def expire(self, now: float) -> Sequence[T]:
        """Release everything held if the oldest held sample has waited ``hold_s``: the magnetometer stopped (or
        there is none, at start-up). Returns the released samples, in order."""
        held = self._held
        if not held or now - held[0][2] < self.hold_s:
            return _NOTHING
        self._n_timeouts += 1
        self._resume = self._streak >= self.lockstep_after
        self._streak = 0
        self._undecided = False
        self._unresolved.clear()
        return self.flush(now)

    def flush(self, now: float) -> list[T]:
        """Release every held sample now (reset, magnetometer switched off), in order."""
        out = []
        while self._held:
            out.append(self._release(now))
        return out

    def _release(self, now: float) -> T:
        _, item, since = self._held.popleft()
        wait = now - since
        self._n_held += 1
        self._hold_sum += wait
        if wait > self._hold_max:
            self._hold_max = wait
        return item

    # --- state ------------------------------------------------------------------------------------------------
    def __len__(self) -> int:
        """Number of samples held."""
        return len(self._held)

    @property
    def holding(self) -> bool:
        """Some samples are held."""
        return bool(self._held)

    @property
    def deadline(self) -> float | None:
        """``now`` at which :meth:`expire` releases the held samples, or None if nothing is held."""
        return self._held[0][2] + self.hold_s if self._held else None

    @property
    def lockstep(self) -> bool:
        """The magnetometer currently counts as lock-step with the IMU (IMU samples ahead of it are held)."""
        return self.enabled and self._streak >= self.lockstep_after

    def stats(self) -> HoldStats:
        """Hold statistics (see :class:`HoldStats`)."""
        n = self._n_held
        return HoldStats(n, self._n_timeouts, self._hold_max * 1e3, self._hold_sum / n * 1e3 if n else 0.0,
                         self.lockstep)
