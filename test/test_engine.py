"""The shared engine (node and replay path): calibration, output shaping, one answer per message, clock jumps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ccf_ros.core import make_filter
from ccf_ros.core.metrics import error_angles
from ccf_ros.core.pairing import MagPairer
from ccf_ros.core.quaternion import from_xyzw, quat_mul, quat_rotate
from ccf_ros.core.registry import FILTERS
from ccf_ros.engine import ImuEngine
from ccf_ros.node.diagnostics import diagnostics
from ccf_ros.node.stats import InputStats
from ccf_ros.node.sync import HoldStats
from ccf_ros.offline.simulate import generate
from ccf_ros.settings import adapter_settings, build


@pytest.fixture(scope='module')
def sim():
    return generate(60.0, 200.0, seed=8)


def run(engine: ImuEngine, t, gyr, acc, mag):
    """Feed arrays through the engine like replay does (magnetometer first); outputs per IMU sample (None if none)."""
    out = []
    for k in range(len(t)):
        if mag is not None:
            engine.on_mag(float(t[k]), tuple(mag[k]))
        out.append(engine.on_imu(float(t[k]), tuple(gyr[k]), tuple(acc[k])))
    return out


def quats(outs) -> np.ndarray:
    return np.array([from_xyzw(*o.orientation_xyzw) if o is not None else (np.nan,) * 4 for o in outs])


def test_hard_and_soft_iron_calibration_is_applied_before_everything_else(sim):
    """A magnetometer with a known offset and matrix, calibrated by the engine, gives the clean result."""
    offset = np.array([30e-6, -12e-6, 8e-6])
    w = np.array([[1.1, 0.05, 0.0], [0.05, 0.95, 0.02], [0.0, 0.02, 1.02]])
    distorted = sim.mag @ w.T + offset
    clean = quats(run(ImuEngine(make_filter()), sim.t_s, sim.gyr, sim.acc, sim.mag))
    s_cal = np.linalg.inv(w)
    settings = {'mag_bias_x': offset[0], 'mag_bias_y': offset[1], 'mag_bias_z': offset[2],
                'mag_soft_iron': s_cal.ravel().tolist()}
    filt, adapter = build(settings)
    cal = quats(run(ImuEngine(filt, adapter), sim.t_s, sim.gyr, sim.acc, distorted))
    raw = quats(run(ImuEngine(make_filter()), sim.t_s, sim.gyr, sim.acc, distorted))
    err_cal = np.degrees(error_angles(cal, clean)[0])
    err_raw = np.degrees(error_angles(raw, clean)[0])
    assert err_cal.max() < 1e-6
    assert np.sqrt(np.mean(err_raw**2)) > 5.0  # uncalibrated, the offset ruins the heading


def test_yaw_offset_minus_declination_turns_the_output_about_world_up(sim):
    base = run(ImuEngine(make_filter()), sim.t_s, sim.gyr, sim.acc, sim.mag)
    filt, adapter = build({'yaw_offset': 0.3, 'declination': 0.1})
    turned = run(ImuEngine(filt, adapter), sim.t_s, sim.gyr, sim.acc, sim.mag)
    rz = np.array([math.cos(0.1), 0.0, 0.0, math.sin(0.1)])  # 0.2 rad about z
    np.testing.assert_allclose(quats(turned), quat_mul(rz, quats(base)), atol=1e-12)
    # The covariance and everything else is unchanged.
    assert turned[100].covariance == base[100].covariance and turned[100].bias == base[100].bias


@pytest.mark.parametrize('frame', ['enu', 'ned', 'nwu'])
def test_remove_gravity_vector_leaves_only_linear_acceleration(sim, frame):
    filt, adapter = build({'remove_gravity_vector': True, 'world_frame': frame})
    outs = run(ImuEngine(filt, adapter), sim.t_s, sim.gyr, sim.acc, sim.mag)
    lin = np.array([o.linear_acceleration for o in outs[1:]])
    # The truth: the simulated linear acceleration in the body frame (acc minus gravity rotated into the body).
    true_lin = sim.acc[1:] - quat_rotate(sim.q_true[1:] * [1, -1, -1, -1], [0.0, 0.0, 9.80665])
    err = np.linalg.norm(lin - true_lin, axis=1)
    # At rest (3-4 s, bias learnt): ~0 instead of 9.8; measured 0.16 m/s² (tilt error ~1 deg from the initial bias).
    assert np.median(np.linalg.norm(lin[3 * 200:4 * 200], axis=1)) < 0.19
    assert np.median(err) < 0.033  # whole run, moving included: measured 0.027 m/s²


def test_bias_corrected_rate_and_stateless_orientation(sim):
    filt, adapter = build({'bias_corrected_rate': True})
    outs = run(ImuEngine(filt, adapter), sim.t_s, sim.gyr, sim.acc, sim.mag)
    k = len(outs) - 1
    np.testing.assert_allclose(outs[k].angular_velocity, sim.gyr[k] - np.array(outs[k].bias), atol=1e-15)
    filt, adapter = build({'stateless': True})
    st = quats(run(ImuEngine(filt, adapter), sim.t_s, sim.gyr, sim.acc, sim.mag))
    # Stateless: each orientation comes from that sample's accelerometer and magnetometer alone (noisy, unfiltered).
    up = quat_rotate(st * [1, -1, -1, -1], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(up, sim.acc / np.linalg.norm(sim.acc, axis=1, keepdims=True), atol=1e-9)


@pytest.mark.parametrize('use_mag', [True, False])
def test_stateless_reports_the_floors_and_keeps_the_filter_running(sim, use_mag):
    from ccf_ros.core import CcfParams

    filt, adapter = build({'stateless': True, 'use_mag': use_mag})
    eng = ImuEngine(filt, adapter)
    outs = run(eng, sim.t_s, sim.gyr, sim.acc, sim.mag)
    assert all(o is not None for o in outs) and eng.answered() == len(outs)
    var = np.array([o.covariance[::4] for o in outs])
    incl = CcfParams.incl_sigma_rad ** 2
    head = CcfParams.heading_sigma_rad ** 2 if use_mag else (math.pi / 2) ** 2
    np.testing.assert_allclose(var, np.tile([incl, incl, head], (len(outs), 1)), rtol=1e-12)
    # The filter behind it ran: its bias and flags are the filter's (the simulation's bias is learnt).
    assert filt.initialized and np.linalg.norm(outs[-1].bias) > 0.0
    np.testing.assert_allclose(outs[-1].bias, sim.bias[-1], atol=math.radians(0.014))  # measured 0.0069, 0.0117°/s


def test_replacing_the_filter_restarts_the_estimate_but_counts_on(sim):
    eng = ImuEngine(make_filter())
    run(eng, sim.t_s[:300], sim.gyr[:300], sim.acc[:300], sim.mag[:300])
    eng.on_imu(float(sim.t_s[299]), tuple(sim.gyr[299]), tuple(sim.acc[299]))  # a repeated stamp: skipped
    before = eng.counts()
    new = make_filter({'filter': 'madgwick'})
    eng.replace_filter(new)
    assert eng.filter is new and not new.initialized
    outs = run(eng, sim.t_s[300:400], sim.gyr[300:400], sim.acc[300:400], sim.mag[300:400])
    assert all(o is not None for o in outs) and new.initialized
    assert sum(eng.counts()) == sum(before) + 100 and eng.skipped_by_reason() == {'skipped_stamp': 1}
    assert eng.answered() == 401


def test_every_message_is_answered_even_a_repeated_or_backward_stamp(sim):
    eng = ImuEngine(make_filter())
    t, g, a, m = sim.t_s[:400], sim.gyr[:400], sim.acc[:400], sim.mag[:400]
    outs = run(eng, t, g, a, m)
    q_last = outs[-1].orientation_xyzw
    again = eng.on_imu(float(t[-1]), tuple(g[-1]), tuple(a[-1]))  # same stamp
    back = eng.on_imu(float(t[-1]) - 0.01, tuple(g[-1]), tuple(a[-1]))  # a little backward
    nan = eng.on_imu(float(t[-1]) + 0.005, (math.nan, 0.0, 0.0), tuple(a[-1]))
    for o in (again, back, nan):
        assert o is not None and o.orientation_xyzw == q_last and o.status >= 3
    assert eng.n_answered_stale == 3 and eng.answered() == 403 == eng.n_in
    assert eng.skipped_by_reason() == {'skipped_stamp': 2, 'skipped_bad_gyro': 1}



def test_a_lone_stamp_far_ahead_is_skipped_and_a_real_gap_reinitialises(sim):
    """One stamp 100 s ahead (a clock-sync step undone at once) is skipped, not a new timeline: it used to
    re-initialise the filter and then, with every later stamp "far behind", reset it (17.7 deg off). A real gap, the
    stream going on from the stamp ahead, re-initialises from its second sample."""
    clean = quats(run(ImuEngine(make_filter()), sim.t_s, sim.gyr, sim.acc, sim.mag))
    k = len(sim.t_s) // 2
    t = sim.t_s.copy()
    t[k] += 100.0
    eng = ImuEngine(make_filter())
    glitched = quats(run(eng, t, sim.gyr, sim.acc, sim.mag))
    assert eng.n_resets_jump == 0 and eng.skipped_by_reason() == {'skipped_stamp': 1}
    diff = np.degrees(error_angles(glitched, clean)[0])
    # The skipped sample answers with the held orientation (0.15 deg behind, measured); the interval it leaves out
    # offsets the next ones by 0.0024 deg, which the blends take out (0.0010 deg 10 s later), as after any skip. (Its
    # magnetometer stamp, 100 s ahead too, is dropped: it used to hold back the magnetometer samples behind it, 0.055
    # and 0.015 deg.)
    assert diff[:k].max() < 1e-9 and diff[k] < 0.18 and diff[k + 1:].max() < 0.0029 and diff[k + 2000] < 0.0012
    assert eng.pairer.n_stray_ahead == 1
    t = sim.t_s.copy()
    t[k:] += 5.0
    eng = ImuEngine(make_filter())
    outs = run(eng, t, sim.gyr, sim.acc, sim.mag)
    assert eng.n_resets_jump == 0 and eng.skipped_by_reason() == {'skipped_stamp': 1}
    assert outs[k].status == 4 and outs[k + 1].status == 2  # answered with the held orientation, then re-initialised
    assert outs[k].orientation_xyzw == outs[k - 1].orientation_xyzw


@pytest.mark.parametrize('lead', [0, 3])
@pytest.mark.parametrize('strays', [1, 2])
def test_a_stray_magnetometer_stamp_far_ahead_does_not_hold_back_the_samples_behind_it(sim, strays, lead):
    """One (or two in a row) magnetometer stamps 5 s ahead, the IMU's stamps unchanged, each magnetometer sample
    arriving with its IMU sample or ``lead`` IMU samples before it: the stray waited at the front of the pairer's
    queue until 256 later samples pushed it out, and the IMU samples after the sample in use timed out (0.5 s) got
    none (at 200 Hz 156 of them). Now it is dropped once a sample not far ahead is queued behind it, and every IMU
    sample is paired as without it."""
    k = len(sim.t_s) // 2
    n = len(sim.t_s)
    tm = sim.t_s.copy()
    tm[k:k + strays] += 5.0
    clean, eng = ImuEngine(make_filter()), ImuEngine(make_filter())
    unpaired = 0
    q_clean, q_stray = [], []
    for j in range(lead):
        clean.on_mag(float(sim.t_s[j]), tuple(sim.mag[j]))
        eng.on_mag(float(tm[j]), tuple(sim.mag[j]))
    for i in range(n):
        t, g, a = float(sim.t_s[i]), tuple(sim.gyr[i]), tuple(sim.acc[i])
        if (j := i + lead) < n:
            clean.on_mag(float(sim.t_s[j]), tuple(sim.mag[j]))
            eng.on_mag(float(tm[j]), tuple(sim.mag[j]))
        clean.on_imu(t, g, a)
        eng.on_imu(t, g, a)
        unpaired += eng.paired_mag is None
        q_clean.append(clean.filter.quaternion)
        q_stray.append(eng.filter.quaternion)
        if not k <= i < k + strays:  # (at the strays' own IMU samples the previous field is in use: 5 ms old)
            assert eng.paired_mag == clean.paired_mag, i
    assert unpaired == 0 and eng.pairer.n_stray_ahead == strays and clean.pairer.n_stray_ahead == 0
    # Only the strays' own IMU samples took the previous field (5 ms older): 0.0004 deg at most, measured (before:
    # 156 samples unpaired, 0.053 deg).
    diff = np.degrees(error_angles(np.array(q_stray), np.array(q_clean))[0])
    assert diff.max() < 0.0005, diff.max()
    eng.reset()  # (the count is the pairer's, kept across the engine's restarts as the other counters are)
    d = diagnostics(0.0, InputStats(), eng, HoldStats(0, 0, 0.0, 0.0, False), use_mag=True, mag_timeout_s=0.5)
    assert d.values['stray magnetometer stamps dropped (far ahead or NaN)'] == str(strays)


def _pairings(messages: list[tuple[str, float]]) -> list[float]:
    """The stamp of the magnetometer sample each IMU sample is paired with (nan: none), messages in the given order
    (('mag' or 'imu', stamp s)); the field carries the magnetometer stamp."""
    p = MagPairer()
    out = []
    for kind, t in messages:
        if kind == 'mag':
            p.add(t, (t, 0.0, 0.0))
        else:
            m = p.get(t)
            out.append(math.nan if m is None else m[0])
    return out


def test_a_magnetometer_sample_ahead_of_a_clock_jump_back_is_not_a_stray():
    """The IMU's clock jumped back first (bag loop): the old timeline's next magnetometer sample waits ahead of the
    new IMU stamps with the new timeline's samples queued behind it. The sample in use is the old timeline's too, so
    nothing is dropped (the new ones stay for the restart), also when the sample in use is older than the timeout
    (a magnetometer pause before the loop)."""
    for t_used in (10.00, 9.00):
        p = MagPairer()
        p.add(t_used, (1.0, 0.0, 0.0))
        assert p.get(10.00) == ((1.0, 0.0, 0.0) if t_used == 10.0 else None)
        p.add(10.01, (2.0, 0.0, 0.0))  # the old timeline's next sample ...
        p.add(0.00, (3.0, 0.0, 0.0))  # ... and the new one's first
        p.get(0.00)
        assert p.n_stray_ahead == 0 and [tm for tm, _ in p._pending] == [10.01, 0.00]
        p.restart(0.00, 1.0)
        assert p.get(0.00) == (3.0, 0.0, 0.0)
    # The magnetometer's clock jumps back first (its new timeline queued while the IMU is still on the old one,
    # after a magnetometer pause): the old timeline's next sample, 0.55 s ahead, is no stray either.
    p = MagPairer()
    p.add(7.00, (1.0, 0.0, 0.0))
    p.get(7.00)
    for t in (8.00, 0.00, 0.01, 0.02):
        p.add(t, (t, 0.0, 0.0))
    p.get(7.45)
    assert p.n_stray_ahead == 0 and [tm for tm, _ in p._pending] == [8.00, 0.00, 0.01, 0.02]
    p.restart(0.00, 1.0)
    assert p.get(0.02) == (0.02, 0.0, 0.0)
    # A magnetometer clock 1.5 s ahead (every queued sample far ahead), then one stamp far behind (an unset header):
    # nothing is a stray, the samples ahead pair when the IMU reaches them.
    p = MagPairer()
    for t in (101.5, 101.6, 101.7, 0.0):
        p.add(t, (t, 0.0, 0.0))
    assert p.get(100.0) is None and p.n_stray_ahead == 0 and len(p._pending) == 4
    assert p.get(101.5) == (101.5, 0.0, 0.0)
    # A stamp far ahead (or NaN) with a current sample behind it is dropped; a magnetometer clock that runs ahead
    # (every queued sample far ahead) is not.
    p = MagPairer()
    p.add(10.00, (1.0, 0.0, 0.0))
    p.add(20.0, (4.0, 0.0, 0.0))
    p.add(math.nan, (5.0, 0.0, 0.0))
    assert p.get(10.00) == (1.0, 0.0, 0.0) and p.n_stray_ahead == 0  # (nothing queued behind them yet)
    p.add(10.02, (6.0, 0.0, 0.0))
    assert p.get(10.01) == (1.0, 0.0, 0.0) and p.n_stray_ahead == 2 and [tm for tm, _ in p._pending] == [10.02]
    assert p.get(10.02) == (6.0, 0.0, 0.0)
    p.add(30.0, (7.0, 0.0, 0.0))
    p.add(30.01, (8.0, 0.0, 0.0))
    assert p.get(10.03) == (6.0, 0.0, 0.0) and p.n_stray_ahead == 2
    assert p.get(30.0) == (7.0, 0.0, 0.0)


def test_a_stray_is_paired_around_alike_in_bag_order_and_magnetometer_first():
    """The node takes queued magnetometer samples before an IMU sample (several under a backlog); replay takes them
    in bag order. With a stray stamp among them, every IMU sample still gets the same magnetometer sample."""
    stamps = [round(10.0 + 0.005 * i, 3) for i in range(40)]
    mag = [15.0 if i == 8 else t for i, t in enumerate(stamps)]
    bag = [m for i in range(40) for m in (('mag', mag[i]), ('imu', stamps[i]))]
    # magnetometer first: a backlog of 4 samples each time (a 20 ms stall of the node)
    backlog = [m for b in range(0, 40, 4) for m in [('mag', mag[i]) for i in range(b, b + 4)]
               + [('imu', stamps[i]) for i in range(b, b + 4)]]
    paired = _pairings(bag)
    assert paired == _pairings(backlog)
    assert paired[8] == stamps[7] and paired[9:] == stamps[9:]  # (none for the stray's own: the previous one)


def test_a_bag_loop_reinitialises_with_the_magnetometer_and_keeps_the_disturbance_gate(sim):
    """Loop back to the start, then meet a magnet: heading as good as without the loop (was 12.9 vs 0.8 deg)."""
    n = len(sim.t_s)
    magnet = sim.mag.copy()
    hit = slice(n // 2, n // 2 + 10 * 200)  # 10 s next to a magnet: field +40 % along body x
    magnet[hit] += np.array([20e-6, 0.0, 0.0])
    straight = quats(run(ImuEngine(make_filter()), sim.t_s, sim.gyr, sim.acc, magnet))
    eng = ImuEngine(make_filter())
    first = n // 3
    run(eng, sim.t_s[:first], sim.gyr[:first], sim.acc[:first], sim.mag[:first])  # a first pass, then the loop
    looped = quats(run(eng, sim.t_s, sim.gyr, sim.acc, magnet))
    assert eng.n_resets_jump == 1
    after = np.arange(n) >= 10  # from shortly after the jump (the two stray stamps before the reset)
    h_straight = np.degrees(np.sqrt(np.nanmean(error_angles(straight, sim.q_true)[1][after] ** 2)))
    h_looped = np.degrees(np.sqrt(np.nanmean(error_angles(looped, sim.q_true)[1][after] ** 2)))
    assert h_looped < 1.5 * h_straight, (h_looped, h_straight)


def test_adapter_settings_accept_integers_and_strings_and_name_bad_values():
    s = adapter_settings({'yaw_offset': 1, 'mag_bias_x': 0, 'mag_soft_iron': '[1,0,0, 0,1,0, 0,0,1]',
                          'remove_gravity_vector': 'true'})
    assert s.yaw_offset == 1.0 and s.mag_bias == (0.0, 0.0, 0.0) and s.remove_gravity_vector is True
    with pytest.raises(ValueError, match='mag_soft_iron'):
        adapter_settings({'mag_soft_iron': [1.0, 0.0]})
    with pytest.raises(ValueError, match='yaw_offset'):
        adapter_settings({'yaw_offset': 'north'})


#: Values a broken driver or a corrupted message can carry, beside plausible ones.
_GARBAGE = (0.0, -0.0, 5e-324, 1e-300, -1e-160, 1e155, -1e200, 1e300, math.inf, -math.inf, math.nan)


@pytest.mark.parametrize('stateless', [False, True])
@pytest.mark.parametrize('name', sorted({k for k, _ in FILTERS}))
def test_random_garbage_never_raises_nor_reaches_the_output(name, stateless):
    """Fuzz: 3000 samples, a third of their components garbage (NaN, Inf, 0, subnormal, 1e300), stamps repeated,
    backward, 1 ns apart or gapped, and the magnetometer as often as the IMU or not at all. Every answer is a unit
    quaternion with finite, positive variances and a finite bias; nothing raises."""
    rng = np.random.default_rng(7)
    filt, adapter = build({'filter': name, 'stateless': stateless})
    engine = ImuEngine(filt, adapter)

    def vec(scale: float, up: float) -> tuple[float, float, float]:
        v = [float(x) for x in rng.normal(0.0, 1.0, 3) * scale]
        v[2] += up
        for i in range(3):
            if rng.random() < 0.12:
                v[i] = float(rng.choice(_GARBAGE))
        return (v[0], v[1], v[2])

    t, n_out = 100.0, 0
    for _ in range(3000):
        t += float(rng.choice([0.0035, 0.0035, 0.0035, 0.0, -0.001, 1e-9, 0.6, 2.0, -3.0]))
        if rng.random() < 0.5:
            engine.on_mag(t, vec(20e-6, -40e-6))
        out = engine.on_imu(t, vec(0.5, 0.0), vec(1.0, 9.81))
        if out is None:
            continue
        n_out += 1
        q = np.array(out.orientation_xyzw)
        var = np.array(out.covariance)[[0, 4, 8]]
        assert np.isfinite(q).all() and abs(np.linalg.norm(q) - 1.0) < 1e-9, (n_out, q)
        assert np.isfinite(out.covariance).all() and (var > 0.0).all(), (n_out, out.covariance)
        assert np.isfinite(out.bias).all(), (n_out, out.bias)
    assert n_out > 2000  # most samples answered (measured 2587 with the default filter)
