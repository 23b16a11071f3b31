"""The bulk path's engine call (``ImuEngine.on_chunk``) against the message-by-message one (``on_imu``/``on_mag``):
same answers to the bit, same engine state after every chunk, on a stream with every stamp fault the engine handles
(clock jumps, a lone far-ahead stamp, a real gap, repeats, NaN), under the settings that change its per-sample steps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ccf_ros.engine import ImuEngine
from ccf_ros.offline.simulate import generate
from ccf_ros.settings import build


def _stream(mag_offset_t: tuple[float, float, float] | None = None, duration_s: float = 30.0,
            ) -> tuple[list[bool], list[float], np.ndarray, np.ndarray]:
    """Interleaved magnetometer and IMU messages (mag first, each with its IMU sample's stamp) of 30 s at 100 Hz,
    with faults: no usable accelerometer at the start, a repeated and a slightly backward stamp, a NaN gyro and a
    NaN stamp, a lone stamp 5 s ahead, a real 3 s gap, the clock jumping back 20 s (a restart) and a lone stamp 5 s
    ahead of the restarting one (skipped as after any other stamp: no second restart).
    ``mag_offset_t``: a magnetometer offset carried by the body, T (for the online hard iron to find)."""
    d = generate(duration_s, 100.0, seed=3)
    t = d.t_s.copy()
    gyr, acc, mag = d.gyr.copy(), d.acc.copy(), d.mag.copy()
    if mag_offset_t is not None:
        mag += np.asarray(mag_offset_t)
    acc[:5] = 0.0  # no orientation yet: no answers
    t[300] = t[299]  # repeated
    t[400] = t[399] - 0.002  # slightly backward
    gyr[500] = math.nan
    t[600] = math.nan
    t[700] = t[699] + 5.0  # a lone stamp far ahead: skipped (its magnetometer sample's too: dropped as a stray)
    t[1000:] += 3.0  # a gap: the filter re-initialises
    t[2000:] -= 20.0  # the clock jumps back: a restart after JUMP_BACK_SAMPLES (at 2002)
    t[2003] = t[2002] + 5.0  # a lone stamp far ahead right after the restart
    n = len(t)
    is_imu = [False, True] * n
    stamps = np.repeat(t, 2).tolist()
    v1 = np.empty((2 * n, 3))
    v2 = np.zeros((2 * n, 3))
    v1[0::2], v1[1::2], v2[1::2] = mag, gyr, acc
    return is_imu, stamps, v1, v2


def _state(e: ImuEngine) -> tuple:
    f = e.filter
    return (e.n_in, e.n_out, e.counts(), e.n_answered_stale, e.stale_share, e.n_resets_jump, e.clock_s, e.paired_mag,
            e.latest_stamp_s, e._t_ahead, e._n_far_back, f.quaternion, f.gyro_bias, f.orientation_variance, f.initialized,
            e.hard_iron_state(), e.pairer.n_pushed_out, e.pairer.n_stray_ahead)


@pytest.mark.parametrize('settings', [
    {},
    {'yaw_offset': 0.3, 'declination': 0.05},
    {'orientation_stddev': 0.02},
    {'mag_bias_x': 1e-6, 'mag_soft_iron': [1.01, 0, 0, 0, 0.99, 0, 0, 0, 1.0]},
    {'bias_corrected_rate': True, 'remove_gravity_vector': True},
    {'constant_dt': 0.01},
    {'use_mag': False},
    {'mag_online_calibration': False},
])
def test_on_chunk_answers_and_state_equal_message_by_message(settings):
    _compare(settings, True)


@pytest.mark.parametrize('answers', [True, False])
def test_on_chunk_with_an_offset_the_online_hard_iron_applies(answers):
    """The default online hard iron inside the bulk loop: a (30, -12, 8) µT offset carried by the body is found and
    subtracted mid-stream (its pairing, the applied offset's jump, the filter told), to the bit as message by
    message."""
    _compare({}, answers, _stream((30e-6, -12e-6, 8e-6), duration_s=60.0))


def test_on_chunk_counts_the_magnetometer_samples_pushed_out_as_message_by_message():
    """A magnetometer clock 50 s ahead of the IMU's: its samples wait in the pairer's queue, which pushes out its
    oldest once full (MagPairer.QUEUE_MAX), counted alike in both paths: 60 s at 100 Hz, 6000 samples, 1904 out."""
    d = generate(60.0, 100.0, seed=3)
    n = len(d.t_s)
    is_imu = [False, True] * n
    stamps = np.repeat(d.t_s, 2)
    stamps[0::2] += 50.0
    v1, v2 = np.empty((2 * n, 3)), np.zeros((2 * n, 3))
    v1[0::2], v1[1::2], v2[1::2] = d.mag, d.gyr, d.acc
    one, bulk = ImuEngine(*build({})), ImuEngine(*build({}))
    for imu, t, a, b in zip(is_imu, stamps.tolist(), v1.tolist(), v2.tolist(), strict=True):
        one.on_imu(t, tuple(a), tuple(b)) if imu else one.on_mag(t, tuple(a))
    for a, b in ((0, 5001), (5001, 9000), (9000, 2 * n)):
        bulk.on_chunk(is_imu[a:b], stamps[a:b].tolist(), tuple(v1[a:b].T.tolist()), tuple(v2[a:b].T.tolist()))
    assert repr(_state(bulk)) == repr(_state(one))
    assert one.pairer.n_pushed_out == n - one.pairer.QUEUE_MAX == 1904


@pytest.mark.parametrize('settings', [{}, {'mag_bias_x': 1e-6}, {'remove_gravity_vector': True}])
def test_on_chunk_without_answers_leaves_the_same_state(settings):
    """The health-only task's call (``answers=False``): no answers collected, the engine's state and the observed
    magnetometer samples as message by message."""
    _compare(settings, False)


def _compare(settings: dict, answers: bool, stream: tuple | None = None) -> None:
    is_imu, stamps, v1, v2 = stream if stream is not None else _stream()
    one, bulk = (ImuEngine(*build(settings)) for _ in range(2))
    rng = np.random.default_rng(0)
    cuts = np.unique(np.r_[0, rng.integers(1, len(stamps), 12), len(stamps)])
    n_answers = 0
    for a, b in zip(cuts[:-1].tolist(), cuts[1:].tolist(), strict=True):
        outs, mags, gated, answered = [], [], [], []
        for k in range(a, b):
            if is_imu[k]:
                o = one.on_imu(stamps[k], tuple(v1[k].tolist()), tuple(v2[k].tolist()))
                mags.append(one.paired_mag)
                gated.append(one.filter.mag_disturbed)
                if o is not None:
                    answered.append(len(mags) - 1)  # the chunk's IMU sample it answers (replay writes it there)
                    outs.append(o)
            else:
                one.on_mag(stamps[k], tuple(v1[k].tolist()))
        ans = bulk.on_chunk(is_imu[a:b], stamps[a:b], tuple(v1[a:b].T.tolist()), tuple(v2[a:b].T.tolist()),
                            observe=True, answers=answers)
        assert np.array(ans.paired_mag).tobytes() == np.array([m or (math.nan,) * 3 for m in mags]).tobytes()
        assert ans.mag_rejected == gated
        assert repr(_state(bulk)) == repr(_state(one))
        if not answers:
            assert not (ans.answered or ans.quaternion or ans.variance or ans.bias or ans.rate
                        or ans.linear_acceleration)
            n_answers += len(outs)
            continue
        m = len(outs)
        assert ans.answered == answered
        q = np.array(ans.quaternion).reshape(m, 4)
        want_q = np.array([o.orientation_xyzw for o in outs]).reshape(m, 4)
        assert q[:, [1, 2, 3, 0]].tobytes() == want_q.tobytes()
        want_cov = np.array([o.covariance for o in outs]).reshape(m, 9)
        assert np.array(ans.variance).reshape(m, 3).tobytes() == want_cov[:, [0, 4, 8]].tobytes()
        assert not want_cov[:, [1, 2, 3, 5, 6, 7]].any()
        assert np.array(ans.bias).tobytes() == np.array([o.bias for o in outs]).tobytes()
        for got, field in ((ans.rate, 'angular_velocity'), (ans.linear_acceleration, 'linear_acceleration')):
            want = [getattr(o, field) for o in outs]
            if got is None:
                assert all(w is None for w in want)
            else:
                assert np.array(got).tobytes() == np.array(want).tobytes()
        n_answers += m
    # The stream reached every rare path and the answers were many.
    assert one.n_resets_jump == 1 and n_answers > 2800
    if stream is not None:
        # The offset was found and applied (within 2 µT) before the end.
        assert np.allclose(one.hard_iron_status().offset, (30e-6, -12e-6, 8e-6), atol=2e-6), one.hard_iron_status()
    skipped = one.skipped_by_reason()
    assert skipped.get('skipped_bad_gyro', 0) == 1, skipped
    if 'constant_dt' not in settings:  # (its clock replaces the stamps the filter sees)
        assert skipped.get('skipped_stamp', 0) >= 3, skipped
