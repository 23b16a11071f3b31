"""The node's plain-Python parts without ROS, on deterministic stamps and clocks: the IMU/magnetometer sync
(ccf_ros.node.sync), input statistics and diagnostics (ccf_ros.node.stats, ccf_ros.node.diagnostics)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ccf_ros.core import make_filter
from ccf_ros.engine import ImuEngine
from ccf_ros.node.diagnostics import ERROR, LOSS_WARN_S, OK, WARN, diagnostics
from ccf_ros.node.stats import InputStats
from ccf_ros.node.sync import HOLD_S, HoldStats, ImuMagSync

P = 0.001  # IMU period, s (1 kHz)
T0 = 1_700_000_000.0


def stamp(k: int) -> float:
    """Stamp of sample k, computed as the node does (sec + nanosec * 1e-9): the same k gives the same float."""
    ns = 1_700_000_000 * 10**9 + k * 1_000_000
    return ns // 10**9 + (ns % 10**9) * 1e-9


class Run:
    """Drives a sync like the node does and records the processing order."""

    def __init__(self, **kw) -> None:
        self.sync: ImuMagSync[int] = ImuMagSync(**kw)
        self.done: list[int] = []
        self.now = 0.0
        self.held_on_arrival: list[int] = []

    def imu(self, k: int) -> None:
        if self.sync.on_imu(stamp(k), k, self.now):
            self.done.append(k)
        else:
            self.held_on_arrival.append(k)

    def mag(self, k: int) -> None:
        self.done.extend(self.sync.on_mag(stamp(k), self.now))

    def tick(self, dt: float = P) -> None:
        self.now += dt
        if self.sync.deadline is not None and self.now >= self.sync.deadline:
            self.done.extend(self.sync.expire(self.now))


def test_mag_first_lockstep_never_holds():
    r = Run()
    for k in range(200):
        r.mag(k)
        r.imu(k)
        r.tick()
    assert r.done == list(range(200)) and not r.held_on_arrival
    st = r.sync.stats()
    assert st.n_held == 0 and st.lockstep and st.max_ms == 0.0


def test_lockstep_with_reversed_delivery_holds_and_releases_in_order():
    r = Run()
    # Lock-step learnt from magnetometer-first pairs ...
    for k in range(5):
        r.mag(k)
        r.imu(k)
        r.tick()
    assert r.sync.lockstep and not r.held_on_arrival
    # ... then the IMU overtakes its magnetometer sample, sometimes by two samples.
    order = []
    for k in range(5, 205, 4):
        order += [('imu', k), ('mag', k), ('imu', k + 1), ('imu', k + 2), ('mag', k + 1), ('mag', k + 2),
                  ('mag', k + 3), ('imu', k + 3)]
    for topic, k in order:
        n_done = len(r.done)
        if topic == 'imu':
            r.imu(k)
        else:
            waiting = [i for i in r.held_on_arrival if i not in r.done]
            r.mag(k)
            # A magnetometer sample releases exactly the held samples up to its stamp, in order, nothing later.
            assert r.done[n_done:] == [i for i in waiting if i <= k]
        r.now += P / 4
    assert r.done == list(range(205))
    # Every IMU sample that overtook its magnetometer sample waited for it; the magnetometer-first ones did not.
    assert r.held_on_arrival == [k for k in range(5, 205) if (k - 5) % 4 in (0, 1, 2)]
    st = r.sync.stats()
    assert st.n_held == len(r.held_on_arrival) and st.n_timeouts == 0 and st.lockstep
    # Held until its magnetometer sample came: 1, 2 and 2 quarter-periods in each group of four.
    assert st.max_ms == pytest.approx(2 * P / 4 * 1e3)
    assert st.mean_ms == pytest.approx(5 / 3 * P / 4 * 1e3)


def test_held_sample_is_released_by_its_own_magnetometer_sample():
    r = Run()
    for k in range(3):
        r.mag(k)
        r.imu(k)
    r.imu(3)
    r.imu(4)
    assert r.held_on_arrival == [3, 4] and r.done == [0, 1, 2]
    r.mag(3)
    assert r.done == [0, 1, 2, 3]  # 4 still waits for its own sample
    r.mag(4)
    assert r.done == [0, 1, 2, 3, 4] and not r.sync.holding


@pytest.mark.parametrize('imu_first', [False, True])
def test_mag_at_quarter_rate_on_the_same_clock_never_holds_after_start_up(imu_first):
    r = Run()
    r.mag(0)
    r.imu(0)
    for k in range(1, 400):
        if k % 4 == 0 and not imu_first:
            r.mag(k)
        r.imu(k)
        if k % 4 == 0 and imu_first:
            r.mag(k)
        r.tick()
    assert r.done == list(range(400)) and not r.sync.lockstep
    # One match so far could be lock-step: at start-up the next samples wait for the first verdict, once, less than
    # the magnetometer's period (4 IMU periods); never again.
    assert r.held_on_arrival == ([1, 2, 3, 4] if imu_first else [1, 2, 3])
    st = r.sync.stats()
    assert st.n_held == len(r.held_on_arrival) and st.max_ms == pytest.approx(3 * P * 1e3) and st.n_timeouts == 0


@pytest.mark.parametrize('mag_rate', [1000.0, 100.0, 1100.0])
@pytest.mark.parametrize('offset_s', [0.0004, -0.0007])
def test_mag_on_its_own_clock_never_holds_after_start_up(mag_rate, offset_s):
    r = Run()
    next_mag = T0 - 0.0003
    r.sync.on_mag(next_mag, r.now)
    for k in range(500):
        # Its own clock (phase 0.3 ms, another rate), delivered up to offset_s ahead of / behind the IMU stream.
        while next_mag + 1 / mag_rate <= stamp(k) + offset_s:
            next_mag += 1 / mag_rate
            r.done.extend(r.sync.on_mag(next_mag, r.now))
        r.imu(k)
        r.tick()
    assert r.done == list(range(500)) and not r.sync.lockstep
    # At start-up the first samples wait for the first verdict: less than one magnetometer period, once.
    # (Its stamps delivered late by offset_s wait that much longer, plus the IMU period of this simulation.)
    longest_ms = 1e3 / mag_rate + max(0.0, -offset_s) * 1e3 + P * 1e3
    assert all(k * P * 1e3 < longest_ms for k in r.held_on_arrival)
    st = r.sync.stats()
    assert st.n_held == len(r.held_on_arrival) and st.max_ms <= longest_ms and st.n_timeouts == 0


def test_mag_on_its_own_clock_ahead_of_the_first_imu_sample_is_never_waited_for():
    r = Run()
    r.done.extend(r.sync.on_mag(stamp(0) + 0.0004, r.now))  # already past the first IMU stamp
    for k in range(100):
        r.imu(k)
        r.done.extend(r.sync.on_mag(stamp(k + 1) + 0.0004, r.now))
        r.tick()
    assert r.done == list(range(100)) and not r.held_on_arrival


def test_lost_mag_sample_releases_after_the_timeout():
    r = Run()
    for k in range(5):
        r.mag(k)
        r.imu(k)
        r.tick()
    # The magnetometer stops: the next IMU sample waits, the following ones queue behind it (order kept) ...
    r.imu(5)
    assert r.held_on_arrival == [5]
    while r.now < 0.005 + HOLD_S - 1.5 * P:
        r.tick()
        assert r.done == list(range(5))
    r.imu(6)
    r.imu(7)
    assert r.held_on_arrival == [5, 6, 7]
    # ... all are released when the first one has waited HOLD_S, and nothing is held any more.
    r.tick(2 * P)
    assert r.done == list(range(8)) and not r.sync.holding and not r.sync.lockstep
    st = r.sync.stats()
    assert st.n_held == 3 and st.n_timeouts == 1 and HOLD_S * 1e3 <= st.max_ms <= (HOLD_S + 2 * P) * 1e3
    for k in range(8, 50):
        r.imu(k)
        r.tick()
    assert r.done == list(range(50)) and r.held_on_arrival == [5, 6, 7]


def test_single_lost_mag_sample_is_released_by_the_next_one():
    r = Run()
    for k in range(5):
        r.mag(k)
        r.imu(k)
        r.tick()
    r.imu(5)  # its magnetometer sample is lost
    r.tick()
    r.mag(6)
    r.imu(6)
    assert r.done == list(range(7)) and r.sync.stats().n_timeouts == 0
    assert r.sync.stats().max_ms == pytest.approx(P * 1e3)


def test_lockstep_behind_the_imu_from_the_start_pairs_every_sample():
    r = Run()
    r.imu(0)  # overtook its magnetometer sample: waits for it
    assert r.held_on_arrival == [0]
    r.tick()
    r.mag(0)
    assert r.done == [0]
    # One match: lock-step or a slower magnetometer on the same clock? Still start-up: the next sample waits too.
    r.imu(1)
    r.tick()
    r.mag(1)
    assert r.done == [0, 1] and r.sync.lockstep
    for k in range(2, 50):
        r.imu(k)
        r.tick()
        r.mag(k)
    assert r.done == list(range(50)) and r.held_on_arrival == list(range(50))
    assert r.sync.stats().max_ms == pytest.approx(P * 1e3) and r.sync.stats().n_timeouts == 0


def test_slower_magnetometer_behind_the_imu_at_start_up_delays_the_first_samples_once():
    r = Run()
    r.imu(0)
    r.tick()
    r.mag(0)
    for k in range(1, 4):
        r.imu(k)
        r.tick()
    assert r.done == [0] and r.held_on_arrival == [0, 1, 2, 3]
    r.mag(4)  # stamps 1-3 have no magnetometer sample: not lock-step, nothing waits any more
    assert r.done == [0, 1, 2, 3] and not r.sync.holding
    assert r.sync.stats().max_ms == pytest.approx(3 * P * 1e3)  # less than the magnetometer's period
    for k in range(4, 400):
        if k % 4 == 0 and k > 4:
            r.mag(k)
        r.imu(k)
        r.tick()
    assert r.done == list(range(400)) and r.held_on_arrival == [0, 1, 2, 3]


def test_magnetometer_on_its_own_clock_behind_the_imu_at_start_up_releases_at_its_first_later_sample():
    r = Run()
    r.imu(0)
    r.tick()
    r.done.extend(r.sync.on_mag(stamp(0) - 0.0004, r.now))  # older than the IMU sample: no verdict yet
    r.imu(1)
    assert r.done == [] and r.held_on_arrival == [0, 1]
    r.tick()
    r.done.extend(r.sync.on_mag(stamp(1) - 0.0004, r.now))  # past stamp 0 without its sample: not lock-step
    assert r.done == [0, 1] and not r.sync.holding
    for k in range(2, 100):
        r.done.extend(r.sync.on_mag(stamp(k) - 0.0004, r.now))
        r.imu(k)
        r.tick()
    assert r.done == list(range(100)) and r.held_on_arrival == [0, 1]


def test_magnetometer_back_after_it_stopped_in_lockstep_pairs_from_its_first_sample():
    r = Run()
    for k in range(5):
        r.mag(k)
        r.imu(k)
        r.tick()
    for k in range(5, 40):  # it stops: one timeout, then nothing waits
        r.imu(k)
        r.tick()
    assert r.done == list(range(40)) and r.sync.stats().n_timeouts == 1 and r.held_on_arrival == list(range(5, 25))
    # Back, first sample before its IMU sample, the next ones after theirs: each of those waits for its own.
    r.mag(40)
    r.imu(40)
    for k in range(41, 60):
        r.imu(k)
        r.tick()
        r.mag(k)
    assert r.done == list(range(60)) and r.held_on_arrival[20:] == list(range(41, 60)) and r.sync.lockstep


def test_single_lost_mag_sample_in_lockstep_keeps_pairing_behind_the_imu():
    r = Run()
    for k in range(5):
        r.imu(k)
        r.mag(k)
    r.imu(5)  # its magnetometer sample is lost
    r.imu(6)
    r.mag(6)
    assert r.done == list(range(7))
    r.imu(7)  # one match since the loss: still waits (undecided), not processed with sample 6's field
    assert r.held_on_arrival[-1] == 7
    r.mag(7)
    r.imu(8)
    r.mag(8)
    assert r.done == list(range(9)) and r.held_on_arrival == list(range(9)) and r.sync.lockstep


def test_first_imu_sample_waits_for_the_first_magnetometer_sample():
    r = Run()
    r.imu(0)  # overtook its magnetometer sample
    assert r.held_on_arrival == [0]
    r.tick()
    r.mag(0)
    assert r.done == [0]
    # Without any magnetometer the first sample waits once, at most HOLD_S.
    r2 = Run()
    for k in range(40):
        r2.imu(k)
        r2.tick()
    assert r2.done == list(range(40)) and r2.sync.stats().n_timeouts == 1
    assert max(r2.held_on_arrival) < HOLD_S / P + 2


@pytest.mark.parametrize('imu_first_after_jump', [False, True])
def test_a_clock_jump_back_starts_the_sync_over_and_pairs_the_new_timeline(imu_first_after_jump):
    """A bag loop: lock-step, then the stamps start again from the beginning; IMU samples that overtake their
    magnetometer sample on the new timeline are still held for it (was: processed at once, lock-step lost)."""
    r = Run()
    for k in range(3000):  # 3 s in lock-step, magnetometer first
        r.mag(k)
        r.imu(k)
        r.tick()
    assert r.sync.lockstep
    n_before = len(r.done)
    first = [('imu', 0), ('mag', 0)] if imu_first_after_jump else [('mag', 0), ('imu', 0)]
    order = first + [item for k in range(1, 40) for item in (('imu', k), ('mag', k))]
    for topic, k in order:
        r.imu(k) if topic == 'imu' else r.mag(k)
        r.now += P / 4
    assert r.done[n_before:] == list(range(40))  # in order, each after its magnetometer sample
    after = [k for k in r.held_on_arrival if k < 40]
    assert after == list(range(1 if not imu_first_after_jump else 0, 40))  # the new timeline's IMU-first samples
    assert r.sync.lockstep and r.sync.stats().n_timeouts == 0


def test_disabled_never_holds():
    r = Run(enabled=False)
    for k in range(10):
        r.imu(k)
        r.mag(k)
    assert r.done == list(range(10)) and not r.held_on_arrival


def test_reset_forgets_lockstep_and_flush_releases_in_order():
    r = Run()
    for k in range(5):
        r.mag(k)
        r.imu(k)
    r.imu(5)
    r.imu(6)
    assert r.sync.holding and r.sync.lockstep and len(r.sync) == 2
    r.done.extend(r.sync.flush(r.now))
    assert r.done == list(range(7))
    r.sync.reset()
    assert not r.sync.lockstep and not r.sync.holding and r.sync.stats().n_held == 2
    # After a reset the first sample waits for a magnetometer sample again; lock-step is learnt again.
    r.imu(7)
    assert r.held_on_arrival[-1] == 7
    r.mag(7)
    r.mag(8)
    r.imu(8)
    r.imu(9)  # two matches in a row: lock-step, so 9 waits for its sample
    assert r.done == list(range(9)) and r.held_on_arrival[-1] == 9
    r.sync.reset_stats()
    assert r.sync.stats().n_held == 0


def test_invalid_arguments():
    with pytest.raises(ValueError, match='hold_s'):
        ImuMagSync(hold_s=0.0)
    with pytest.raises(ValueError, match='lockstep_after'):
        ImuMagSync(lockstep_after=0)


# --- stats, diagnostics --------------------------------------------------------------------------------------------


def test_input_stats_rate_and_messages_lost_from_stamp_holes():
    st = InputStats()
    now = 100.0
    k = 0
    for _ in range(1000):
        st.on_imu(stamp(k), now)
        k += 1
        if k == 500:
            k += 3  # three messages lost upstream
        now += P
    assert st.n_lost == 3 and st.n_imu == 1000 and st.last_loss == pytest.approx(100.0 + 500 * P)
    assert st.period_s == pytest.approx(P, rel=1e-3)
    assert st.rate_hz(now) == pytest.approx(1000.0, rel=1e-3)
    assert st.rate_hz(now + 5.0) == 0.0
    # A backward stamp and a repeated one are not holes; a jump of more than 1 s is not counted as losses.
    st.on_imu(stamp(k - 10), now)
    st.on_imu(stamp(k - 10), now)
    st.on_imu(stamp(k + 5000), now)
    assert st.n_lost == 3



def test_input_stats_read_at_any_sample_as_at_the_end():
    """The node hands samples over in batches (one list append per message): the statistics read after every
    sample, after some, or only at the end are the same, losses and their times included."""
    rng = np.random.default_rng(4)
    t = np.cumsum(np.where(rng.random(3000) < 0.01, 0.0025 * rng.integers(2, 9, 3000),
                           0.0025 * (1.0 + rng.normal(0.0, 0.05, 3000))))
    now = 50.0 + np.cumsum(0.0025 * (1.0 + rng.normal(0.0, 0.2, 3000)))
    every, some, end = InputStats(), InputStats(), InputStats()
    seen = []
    for i, (x, a) in enumerate(zip(t.tolist(), now.tolist(), strict=True)):
        for st in (every, some, end):
            st.on_imu(x, a)
        seen.append((every.n_imu, every.last_imu, every.n_lost, every.last_loss))
        if i % 97 == 0:
            assert (some.n_lost, some.last_loss, some.period_s) == (every.n_lost, every.last_loss, every.period_s)
    assert seen[-1] == (3000, now[-1], end.n_lost, end.last_loss) and end.n_imu == 3000
    assert end.n_lost == every.n_lost > 20 and end.period_s == every.period_s == some.period_s
    assert end.rate_hz(now[-1]) == every.rate_hz(now[-1]) == pytest.approx(400.0, rel=0.05)
    # A count and the time of the latest arrival are exact at every sample, before the batch is taken in.
    assert [s[0] for s in seen] == list(range(1, 3001)) and [s[1] for s in seen] == now.tolist()


def test_input_stats_read_mid_batch_are_the_arrivals_so_far():
    """Read between two batches (no catch_up by the caller), each figure is that of the samples so far: a hole is
    counted, with its arrival time, by the sample right after it; the rate is that of the arrivals of the last 2 s.
    (One InputStats per figure: a read of one figure must not be what brings another up to date.)"""
    lost, loss_at, rate, period = InputStats(), InputStats(), InputStats(), InputStats()
    stamps = [1_000.0 + k * 0.0025 for k in range(2000) if not 1200 <= k < 1205]  # 400 Hz, 5 samples lost once

    def arrival(i: int) -> float:
        return 7.0 + i * 0.003 + 1e-6 * i * i  # slowing down: the rate depends on which arrivals are counted

    for i, x in enumerate(stamps):
        now = arrival(i)
        for st in (lost, loss_at, rate, period):
            st.on_imu(x, now)
        if i % 37 == 5:
            window = [arrival(j) for j in range(i + 1) if now - arrival(j) <= 2.0]
            assert rate.rate_hz(now) == pytest.approx((len(window) - 1) / (window[-1] - window[0]), rel=1e-12), i
        if i in (1199, 1210, 1500):  # (1210: the hole at 1200 is among the pending samples, not yet taken in)
            assert lost.n_lost == (5 if i >= 1200 else 0), i
            assert loss_at.last_loss == (arrival(1200) if i >= 1200 else -math.inf), i
        if i == 20:  # (the first batch of 32 not taken in yet; the period is known from 16 intervals on)
            assert period.period_s == pytest.approx(0.0025, rel=1e-9)


def test_input_stats_take_jitter_bursts_and_a_slower_rate_for_no_losses():
    """Stamps with jitter (a driver that stamps on arrival) or in bursts (a FIFO read) are not holes; real holes
    still are, one by one and under a lasting loss; a switch to a slower rate costs a few false counts, not one per
    sample for a thousand samples."""
    rng = np.random.default_rng(0)

    def lost(t) -> InputStats:
        st = InputStats()
        for x in t:
            st.on_imu(float(x), float(x))
        return st

    jitter = np.sort(np.arange(12000) / 200.0 + rng.normal(0.0, 0.001, 12000))  # 200 Hz, 1 ms jitter
    st = lost(jitter)
    assert st.n_lost <= 1 and st.period_s == pytest.approx(0.005, rel=0.01)  # measured 1 (was 1927)
    keep = rng.random(6000) > 0.1  # 100 Hz, 10 % of the messages dropped, at random
    keep[:50] = True
    st = lost(np.arange(6000)[keep] / 100.0)
    assert st.n_lost == (~keep).sum() and st.period_s == pytest.approx(0.01, rel=1e-9)
    reads = np.repeat(np.arange(3750) * 4 / 250.0, 4) + np.tile([0.0, 1e-5, 2e-5, 3e-5], 3750)  # 250 Hz, 4 per read
    assert lost(reads).n_lost == 0  # was 5.8 million
    keep = np.ones(15000, dtype=bool)
    keep[4000:4004] = keep[8000:8004] = False  # two reads lost
    assert lost(reads[keep]).n_lost == 8
    st = InputStats()
    x = 0.0
    for i in range(8000):
        x += 1 / 400.0 if i < 4000 else 1 / 100.0
        if i != 2000:  # one message lost
            st.on_imu(x, x)
        if i == 2001:
            assert st.n_lost == 1
    assert st.n_lost <= 66  # 1 + 54 while the slower rate becomes the normal one (was ~1000)
    assert st.period_s == pytest.approx(0.01, rel=1e-6)


def test_input_stats_count_heavy_losses():
    """Under overload DDS drops a fifth or a quarter of the messages: the holes are then a large part of the window
    and must not inflate the jitter spread that a hole must stand above (an interquartile spread, whose upper
    quartile is then a hole itself, counted 71 of 3990)."""
    for every in (5, 4):  # 200 Hz, every 5th (4th) message lost
        k = np.arange(20000)
        t = k[k % every != 0] / 200.0
        st = InputStats()
        for x in t:
            st.on_imu(float(x), float(x))
        lost = 20000 // every - 1  # (the first one is before the first stamp)
        # measured: all but 4 and 5, the holes among the first INTERVAL_MIN samples (before the statistics exist)
        assert lost - 8 <= st.n_lost <= lost

def _engine(samples=400, mag=True, acc=9.81):
    eng = ImuEngine(make_filter())
    for k in range(samples):
        t = stamp(k)
        if mag:
            eng.on_mag(t, (0.0, 2e-5, -4e-5))
        eng.on_imu(t, (0.0, 0.0, 0.0), (0.0, 0.0, acc))
    return eng


NO_HOLDS = HoldStats(0, 0, 0.0, 0.0, False)


def _diag(stats, eng, now, hold=NO_HOLDS, use_mag=True):
    return diagnostics(now, stats, eng, hold, use_mag=use_mag, mag_timeout_s=0.5)


def test_diagnostics_levels_in_order_of_severity():
    st = InputStats()
    eng = _engine()
    d = _diag(st, eng, 10.0)
    assert d.level == ERROR and 'no IMU input' in d.message
    assert d.values['magnetometer age (s)'] == 'never' and d.values['input rate (Hz)'] == '0.0'
    st.on_imu(stamp(0), 10.0)
    d = _diag(st, _engine(acc=0.0), 10.1)
    assert d.level == ERROR and 'accelerometer' in d.message and d.values['initialized'] == 'false'
    d = _diag(st, eng, 10.1)
    assert d.level == WARN and d.message == 'no magnetometer sample yet: heading runs on the gyro'
    assert _diag(st, eng, 10.1, use_mag=False).level == OK
    st.on_mag(10.0)
    d = _diag(st, eng, 10.1)
    assert (d.level, d.message) == (OK, 'ok')
    assert d.values['magnetometer age (s)'] == '0.10'
    d = _diag(st, eng, 10.7)
    assert d.level == WARN and 'no magnetometer for 0.7 s' in d.message
    st.on_mag(10.7)
    eng.filter.mag_disturbed = True
    d = _diag(st, eng, 10.75)
    assert d.level == WARN and 'magnetic disturbance' in d.message and d.values['magnetic disturbance'] == 'true'
    eng.filter.mag_disturbed = False
    eng.filter.n_nonfinite_resets = 2
    d = _diag(st, eng, 10.75)
    assert d.level == WARN and 'non-finite 2 times' in d.message and d.values['non-finite state resets'] == '2'
    eng.filter.n_nonfinite_resets = 0
    for k in range(1, 41):  # enough samples to know the normal interval
        st.on_imu(stamp(k), 10.75)
    st.on_imu(stamp(43), 10.76)  # two lost
    d = _diag(st, eng, 10.76)
    assert d.level == WARN and '(2 so far)' in d.message and d.values['messages lost upstream (estimated)'] == '2'
    # Losses warn for LOSS_WARN_S, the count stays.
    st.on_imu(stamp(44), 10.76 + LOSS_WARN_S + 0.5)
    st.on_mag(10.76 + LOSS_WARN_S + 0.5)
    d = _diag(st, eng, 10.76 + LOSS_WARN_S + 0.6)
    assert d.level == OK and d.values['messages lost upstream (estimated)'] == '2'


def test_diagnostics_values_show_filter_flags_counters_and_hold_statistics():
    st = InputStats()
    eng = _engine()
    eng.on_imu(stamp(100), (math.nan, 0.0, 0.0), (0.0, 0.0, 9.81))  # cannot advance the filter
    st.on_imu(stamp(400), 20.0)
    st.on_mag(20.0)
    flags = eng.filter.flags
    d = _diag(st, eng, 20.0, hold=HoldStats(12, 1, 20.4, 1.25, True))
    v = d.values
    assert (v['initialized'], v['at rest'], v['accelerometer used'], v['magnetometer used'], v['magnetic disturbance'],
            v['heading absolute']) == tuple('true' if f else 'false' for f in flags)
    assert flags.initialized and flags.mag_used and flags.heading_absolute
    assert v['samples in'] == '401' and v['samples answered'] == '401' and v['skipped: skipped_bad_gyro'] == '1'
    assert (v['samples held for magnetometer'], v['hold timeouts'], v['hold max (ms)'], v['hold mean (ms)'],
            v['magnetometer in lock-step']) == ('12', '1', '20.40', '1.250', 'true')
    assert v['magnetometer samples in'] == '1' and v['non-finite state resets'] == '0'
    bias_norm = math.degrees(math.hypot(*eng.filter.gyro_bias))
    assert float(v['gyro bias norm (deg/s)']) == pytest.approx(bias_norm, abs=1e-3)
    assert float(v['gyro bias 1-sigma per axis (deg/s)']) == pytest.approx(
        math.degrees(eng.filter.gyro_bias_sigma_rad_s), abs=1e-3)


def test_diagnostics_warn_while_most_samples_cannot_advance_the_filter():
    """Zeroed or repeated stamps freeze the output (every sample answered with the held orientation): that is a
    WARN naming constant_dt, not OK; it clears once the samples advance the filter again."""
    st = InputStats()
    eng = _engine()
    st.on_imu(stamp(400), 20.0)
    st.on_mag(20.0)
    assert _diag(st, eng, 20.0).level == OK and eng.stale_share == 0.0
    for _ in range(100):  # a driver that stopped stamping: the same stamp again and again
        eng.on_mag(stamp(399), (0.0, 2e-5, -4e-5))
        eng.on_imu(stamp(399), (0.0, 0.0, 0.2), (0.0, 0.0, 9.81))
    d = _diag(st, eng, 20.0)
    assert d.level == WARN and 'held orientation' in d.message and 'constant_dt' in d.message
    assert float(d.values['share of the latest answers with a held orientation']) == pytest.approx(
        1 - 0.99 ** 100, abs=0.005)
    for k in range(400, 600):
        eng.on_mag(stamp(k), (0.0, 2e-5, -4e-5))
        eng.on_imu(stamp(k), (0.0, 0.0, 0.0), (0.0, 0.0, 9.81))
    assert _diag(st, eng, 20.0).level == OK


def test_stateless_answers_and_samples_before_the_start_are_not_held_outputs():
    """With stateless, a sample the filter skips (repeated stamp) still gets its own orientation: no held-output
    WARN; nor do the samples before the first valid accelerometer count (there is no output to hold yet)."""
    from ccf_ros.settings import build

    eng = ImuEngine(*build({'stateless': True}))
    for k in range(100):
        eng.on_mag(stamp(0), (0.0, 2e-5, -4e-5))
        eng.on_imu(stamp(0), (0.0, 0.0, 0.0), (0.0, 0.1 * k, 9.81))  # zeroed stamps, the sensor tilting
    assert eng.stale_share == 0.0 and eng.n_answered_stale == 0
    eng = _engine(samples=200, acc=0.0)  # no valid accelerometer yet
    assert eng.stale_share == 0.0
