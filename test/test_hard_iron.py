"""Online hard-iron estimation (issue 24 item 4): a body-fixed offset is found and applied, a world-fixed field is
not followed, an offset that goes away is dropped, the state survives a restart, the parameters are checked.
Simulated data, through the engine (the node's and replay's path); BROAD trials 30 and 33 when ../shared exists."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from conftest import SHARED, need_shared

from ccf_ros.core import run_batch
from ccf_ros.core.base import OrientationFilter
from ccf_ros.core.hard_iron import HardIronEstimator
from ccf_ros.core.metrics import error_angles, fit_heading_offset, summarize
from ccf_ros.engine import ImuEngine
from ccf_ros.errors import ParameterError
from ccf_ros.offline.evaluate import engine_orientations
from ccf_ros.offline.simulate import SimData, dipole_field, generate, generate_near_dipole, with_mag_distortion
from ccf_ros.settings import build

OFFSET_T = np.array([30.0, -12.0, 8.0]) * 1e-6
ON = {'mag_online_calibration': True}
OFF = {'mag_online_calibration': False}


def run(settings: dict, t, gyr, acc, mag, probe_s: float | None = None, engine: ImuEngine | None = None):
    """Orientations (N, 4) of an engine (new, from ``settings``, or ``engine``) fed the arrays (NaN mag rows: no
    message), the engine, and its hard-iron status at ``t[0] + probe_s``."""
    if engine is None:
        engine = ImuEngine(*build(settings))
    probe: list[object] = []

    def look(_k: int, t_k: float) -> None:
        if probe_s is not None and not probe and t_k - float(t[0]) >= probe_s:
            probe.append(engine.hard_iron_status())

    return engine_orientations(engine, t, gyr, acc, mag, look), engine, probe[0] if probe else None


@pytest.fixture(scope='module')
def hand() -> SimData:
    return generate(120.0, 100.0, 3)


def heading(q, data: SimData, mask) -> float:
    return summarize(q, data.q_true, mask).heading_rmse_deg


def test_a_body_fixed_offset_is_found_applied_and_the_heading_recovers(hand, monkeypatch):
    calls = []
    filt, adapter = build(ON)
    react = type(filt).magnetometer_changed

    def spy(self: OrientationFilter, change_rel: float | None = None) -> None:
        calls.append(change_rel)
        react(self, change_rel)

    monkeypatch.setattr(type(filt), 'magnetometer_changed', spy)
    dist = with_mag_distortion(hand, OFFSET_T)
    q_on, eng, probe = run({}, dist.t_s, dist.gyr, dist.acc, dist.mag, probe_s=65.0, engine=ImuEngine(filt, adapter))
    # After 60 s of motion (the first 5 s are rest).
    assert probe.status == 'applied'
    assert np.linalg.norm(np.array(probe.offset) - OFFSET_T) < 0.33e-6  # measured 0.228 uT (0.27 with a decision every 5 pairs)
    assert max(probe.sigma) < 0.17e-6  # measured 0.136 uT
    assert probe.residual_rel < 0.017  # measured 1.42 % of the field: the noise
    assert calls  # the filter was told each time the applied offset moved
    after = hand.moving & (hand.t_s - hand.t_s[0] >= 65.0)
    q_clean, _, _ = run(OFF, hand.t_s, hand.gyr, hand.acc, hand.mag)
    assert heading(q_on, hand, after) < 1.12 * heading(q_clean, hand, after)  # measured 0.501 vs 0.506 deg
    q_off, _, _ = run(OFF, dist.t_s, dist.gyr, dist.acc, dist.mag)
    assert heading(q_off, hand, after) > 40.0  # measured 52 deg without it
    # The engine reports it; the sample given to the filter has the offset subtracted.
    s = eng.hard_iron_status()
    np.testing.assert_allclose(eng.paired_mag, dist.mag[-1] - np.array(s.offset), rtol=0, atol=1e-15)


def test_a_world_fixed_dipole_is_not_followed(hand):
    d = generate(120.0, 100.0, 3, field=dipole_field([0.25, 0.0, 0.0], [0.0, 0.0, 1.0]))
    q_on, eng, _ = run(ON, d.t_s, d.gyr, d.acc, d.mag)
    s = eng.hard_iron_status()
    assert s.offset == (0.0, 0.0, 0.0) and s.status == 'tracking'
    assert s.residual_rel > 0.05  # measured 6.85 %: the body-fixed model does not hold
    q_off, _, _ = run(OFF, d.t_s, d.gyr, d.acc, d.mag)
    np.testing.assert_array_equal(q_on, q_off)


def test_an_offset_that_goes_away_is_dropped():
    """A magnet attached for the first 90 s then taken off (BROAD 33's case): the short memory fits the new state,
    the long one restarts from it, and the applied offset goes back to ~0."""
    d = generate(200.0, 100.0, 4)
    mag = d.mag + np.where((d.t_s - d.t_s[0] < 90.0)[:, None], OFFSET_T, 0.0)
    _, eng, probe = run(ON, d.t_s, d.gyr, d.acc, mag, probe_s=89.0)
    assert np.linalg.norm(np.array(probe.offset) - OFFSET_T) < 1e-6
    s = eng.hard_iron_status()
    assert s.status == 'applied' and np.linalg.norm(s.offset) < 1e-6, s


def test_on_by_default_and_the_state_survives_a_restart(hand):
    eng = ImuEngine(*build({}))
    assert eng.hard_iron is not None and eng.hard_iron_status().status == 'not_determined'
    eng = ImuEngine(*build(OFF))
    assert eng.hard_iron is None and eng.hard_iron_status() is None and eng.hard_iron_state() is None
    dist = with_mag_distortion(hand, OFFSET_T)
    _, first, _ = run(ON, dist.t_s, dist.gyr, dist.acc, dist.mag)
    state = first.hard_iron_state()
    fresh = ImuEngine(*build(ON))
    fresh.restore_hard_iron(state)
    s0, s1 = first.hard_iron_status(), fresh.hard_iron_status()
    assert s1.status == 'applied' and s1.offset == s0.offset
    # (the saved estimate includes the pairs since the latest decision; the live one is unchanged by saving)
    np.testing.assert_allclose(s1.estimate, state['estimate'], rtol=1e-9)
    # The restored offset is subtracted from the first sample on.
    fresh.on_mag(float(dist.t_s[0]), tuple(dist.mag[0]))
    fresh.on_imu(float(dist.t_s[0]), tuple(dist.gyr[0]), tuple(dist.acc[0]))
    np.testing.assert_allclose(fresh.paired_mag, dist.mag[0] - np.array(s0.offset), rtol=0, atol=1e-15)
    bad = dict(state, information=[1.0, 2.0])
    with pytest.raises(ValueError, match='hard_iron state is malformed'):
        fresh.restore_hard_iron(bad)
    with pytest.raises(ValueError, match="unknown status 'sure'"):
        fresh.restore_hard_iron(dict(state, status='sure'))
    assert fresh.hard_iron_status().offset == s0.offset  # unchanged by the bad states
    # Turning it off drops it; on again starts from nothing.
    fresh.set_settings(build(OFF)[1])
    assert fresh.hard_iron is None
    fresh.set_settings(build(ON)[1])
    assert fresh.hard_iron_status().status == 'not_determined'


def test_saving_the_state_does_not_change_what_comes_next(hand):
    """A node saves its bias_file (hard_iron section included) every few seconds of wall time; replay saves at the
    end. Reading the state must not fold or solve the live estimator, or node and replay answer differently."""
    dist = with_mag_distortion(hand, OFFSET_T)
    plain = ImuEngine(*build(ON))
    q_plain = engine_orientations(plain, dist.t_s, dist.gyr, dist.acc, dist.mag)
    saving = ImuEngine(*build(ON))
    states = []

    def save(k: int, _t: float) -> None:
        if k % 337 == 0:  # (not a multiple of the pair batch: pairs are pending at many of the saves)
            states.append(saving.hard_iron_state())

    q_saving = engine_orientations(saving, dist.t_s, dist.gyr, dist.acc, dist.mag, save)
    assert len(states) > 30 and plain.hard_iron_status().status == 'applied'
    assert q_saving.tobytes() == q_plain.tobytes()
    assert saving.hard_iron_state() == plain.hard_iron_state()


@pytest.mark.parametrize(('values', 'match'), [
    ({'mag_online_memory_rad': 0.0}, r'mag_online_memory_rad must be within \[1, 1e6\] rad, got 0.0'),
    ({'mag_online_memory_rad': 'long'}, "mag_online_memory_rad must be a number, got 'long'"),
    ({'mag_online_calibration': 'maybe'}, "mag_online_calibration must be true or false, got 'maybe'"),
])
def test_bad_parameters_are_named(values, match):
    with pytest.raises(ParameterError, match=match):
        build(values)
    with pytest.raises(ValueError, match='mag_online_memory_rad must be a finite number > 0'):
        HardIronEstimator(-1.0)


def test_broad_30_is_not_worse_and_33_is_better():
    """BROAD trial 30 (a magnet standing in the room) and 33 (a magnet attached 2 cm from the sensor for part of
    the trial), defaults vs mag_online_calibration, heading RMSE over the moving samples."""
    from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
    from ccf_ros.offline.evaluate import align, mask_at

    def headings(trial, step=1, cases=(OFF, ON)):
        imu = read_imu_arrays(trial)
        t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
        mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
        out = []
        t, gyr, acc, mag = imu.t_s[::step], imu.gyr[::step], imu.acc[::step], imu.mag[::step]
        for settings in cases:
            q, eng, _ = run(settings, t, gyr, acc, mag)
            ok = np.all(np.isfinite(q), axis=1)
            out.append(summarize(align(t[ok], q[ok], t_ref, q_ref), q_ref, mask).heading_rmse_deg)
        return out, eng.hard_iron_status()

    (off30, on30), s30 = headings(need_shared(SHARED / '30_disturbed_stationary_magnet_C'))
    assert on30 <= off30 * 1.001 and s30.offset == (0.0, 0.0, 0.0)  # measured 1.139 both: never applied
    trial33 = need_shared(SHARED / '33_disturbed_attached_magnet_2cm')
    (off33, on33), _ = headings(trial33)
    assert on33 < 0.65 * off33  # measured 1.554 vs 2.918 deg (0.53x)
    # At 48 Hz (every 6th sample): a refinement of the magnet's offset while the corrected field still wanders by ~4°
    # must not keep that field out (the calibration change's size is the offset's, not only the jump's: 4.07 deg).
    (on33_48,), _ = headings(trial33, 6, (ON,))
    assert on33_48 < 3.65  # measured 3.05 deg


def test_the_node_diagnostics_show_the_hard_iron_status(hand):
    import time

    from ccf_ros.node.diagnostics import diagnostics
    from ccf_ros.node.stats import InputStats
    from ccf_ros.node.sync import HoldStats

    hold = HoldStats(0, 0, 0.0, 0.0, False)
    off = diagnostics(time.monotonic(), InputStats(), ImuEngine(*build(OFF)), hold, use_mag=True, mag_timeout_s=0.5)
    assert off.values['online hard iron'] == 'off'
    dist = with_mag_distortion(hand, OFFSET_T)
    _, eng, _ = run(ON, dist.t_s[:9000], dist.gyr[:9000], dist.acc[:9000], dist.mag[:9000])
    d = diagnostics(time.monotonic(), InputStats(), eng, hold, use_mag=True, mag_timeout_s=0.5)
    assert d.values['online hard iron'] == 'applied'
    x, y, z = (float(v) for v in d.values['online hard-iron offset applied (uT)'].split())
    assert abs(x - 30.0) < 0.5 and abs(y + 12.0) < 0.5 and abs(z - 8.0) < 0.5
    assert float(d.values['online hard-iron model residual (share of the field)']) < 0.018


def test_ccf_replay_runs_the_online_estimate(tmp_path, capsys):
    """The real path: ccf simulate with an offset, ccf replay with --param mag_online_calibration=true, scored."""
    from ccf_ros.cli import main as ccf
    from ccf_ros.offline.evaluate import load_aligned

    bag, clean = tmp_path / 'sim', tmp_path / 'clean'
    common = ['--duration', '150', '--rate', '50', '--seed', '3']
    assert ccf(['simulate', '-o', str(bag), *common, '--mag-offset-ut', '30', '-12', '8']) == 0
    assert ccf(['simulate', '-o', str(clean), *common]) == 0

    def heading(src, *extra: str) -> float:
        out = tmp_path / f'out{len(list(tmp_path.iterdir()))}'
        assert ccf(['replay', str(src), '-o', str(out), *extra]) == 0
        s = load_aligned(out, '/ground_truth/pose', reference_bag=src, mask_topic='/ground_truth/moving')
        late = s.t_s - s.t_s[0] >= 100.0  # the heading has converged after the offset was applied
        return summarize(s.q_est[late], s.q_ref[late], s.mask[late]).heading_rmse_deg

    ref, on = heading(clean), heading(bag)  # (on by default)
    off = heading(bag, '--param', 'mag_online_calibration=false')
    assert off > 40.0 and on < 1.3 * ref, (ref, off, on)  # measured 0.507, 53.4, 0.553 deg (1.09x)


@pytest.mark.parametrize('bad', [1e200, 5e3, float('inf'), float('nan')])
def test_a_corrupted_gyro_sample_does_not_break_the_online_estimator(hand, bad):
    """A finite but huge rate once overflowed the estimator's quaternion norm (ZeroDivisionError on the next sample,
    ending ccf replay): such samples, which the filter skips as corrupted, are not integrated."""
    gyr = hand.gyr.copy()
    gyr[len(gyr) // 2] = (bad, 0.0, 0.0)
    q, _, _ = run(ON, hand.t_s, gyr, hand.acc, hand.mag)
    assert np.all(np.isfinite(q[1:]))
    q_clean, _, _ = run(ON, hand.t_s, hand.gyr, hand.acc, hand.mag)
    # The bad sample is skipped by the filter and not integrated by the estimator: the rest is answered as without it.
    err = np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(q[1:] * q_clean[1:], axis=1)), 0, 1)))
    assert err.max() < 1.0, err.max()


def _max_applied(settings: dict, d: SimData) -> tuple[float, ImuEngine]:
    """The largest applied offset's norm over a run (checked every 20 samples), T, and the engine."""
    worst = [0.0]
    eng = ImuEngine(*build(settings))

    def look(k: int, _t: float) -> None:
        if k % 20 == 0:
            worst[0] = max(worst[0], float(np.linalg.norm(eng.hard_iron_status().offset)))

    engine_orientations(eng, d.t_s, d.gyr, d.acc, d.mag, look)
    return worst[0], eng


def test_a_magnet_passed_closely_is_never_applied():
    """Carried to and fro over 2 m past a magnet 0.15 m beside the path (no offset): the field changes by tens of uT
    with position, not with the turns (the residual test; an estimator that paired every 0.5 s of turning once
    applied 3.3-4.4 uT here)."""
    def passing(t):
        x = -np.cos(2 * np.pi * np.clip(t - 5.0, 0.0, None) / 40.0)
        return np.stack((x, 0 * x, 0 * x), axis=1)

    d = generate(180.0, 100.0, 2, field=dipole_field([0.0, 0.15, 0.0], [3.0, 0.0, 0.0]), path_m=passing)
    worst, eng = _max_applied(ON, d)
    assert worst == 0.0 and eng.hard_iron_status().status != 'applied'


def test_steel_near_the_workspace_is_never_applied():
    """simulated_accuracy.py's dipole scenario (300 A m² 1.2 m away, hand-guided over ±0.35 m, no offset; seed 1):
    without the level test (the field's norm and vertical component with the offset subtracted must stay within 5 %)
    and the explained-share rule it applies 10 uT."""
    worst, _ = _max_applied(ON, generate_near_dipole(100.0, 1))
    assert worst == 0.0


def test_an_offset_that_appears_mid_run_is_applied():
    d = generate(180.0, 100.0, 0)
    mag = d.mag + np.where((d.t_s - d.t_s[0] >= 60.0)[:, None], OFFSET_T, 0.0)
    _, eng, probe = run(ON, d.t_s, d.gyr, d.acc, mag, probe_s=59.0)
    assert probe.offset == (0.0, 0.0, 0.0)
    s = eng.hard_iron_status()
    assert s.status == 'applied' and np.linalg.norm(np.array(s.offset) - OFFSET_T) < 0.6e-6, s  # measured 0.3 uT


def test_pairs_come_from_the_filter_orientation_every_tenth_of_a_second(hand, monkeypatch):
    """No second gyro integration: a pair is formed every 0.1 s from the filter's orientation at the kept sample's
    stamp (the message after it, before the filter's update); a filter restart starts a new epoch."""
    calls = []
    original = HardIronEstimator.pair

    def spy(self, q, epoch=None, count=0):
        calls.append((self.pending[0], q, epoch, count))
        original(self, q, epoch, count)

    monkeypatch.setattr(HardIronEstimator, 'pair', spy)
    eng = ImuEngine(*build(ON))
    seen = {}

    def look(k: int, t_k: float) -> None:
        seen[t_k] = eng.filter.quaternion

    engine_orientations(eng, hand.t_s, hand.gyr, hand.acc, hand.mag, look)
    duration = float(hand.t_s[-1] - hand.t_s[0])
    assert abs(len(calls) - duration / 0.1) <= 2
    # The orientation paired with each sample is the filter's right after that sample.
    assert all(q == seen[t] for t, q, _, _ in calls[1:])
    assert len({e for _, _, e, _ in calls[1:]}) == 1
    eng.reset()
    eng.on_mag(float(hand.t_s[-1]) + 0.01, tuple(hand.mag[0]))
    eng.on_imu(float(hand.t_s[-1]) + 0.01, tuple(hand.gyr[0]), tuple(hand.acc[0]))
    eng.on_imu(float(hand.t_s[-1]) + 0.02, tuple(hand.gyr[0]), tuple(hand.acc[0]))
    assert calls[-1][3] < calls[-2][3]  # the reset's count starts again: stored samples are forgotten
    assert not eng.hard_iron._history or len(eng.hard_iron._history) == 1


@pytest.mark.parametrize(('explained', 'pairs', 'applied'), [(0.2, 60.0, False), (0.6, 60.0, True), (0.2, 200.0, True)])
def test_a_first_offset_must_explain_the_pairs_or_have_many_behind_it(monkeypatch, explained, pairs, applied):
    """A spurious estimate (a field varying with position, correlated with the turns for a while) explains little of
    the pairs' variation: a first offset needs half of it explained, or FIRST_MIN_PAIRS (150) pairs behind it."""
    from ccf_ros.core import hard_iron

    monkeypatch.setattr(hard_iron._Fit, 'solve', lambda self: None)
    est = HardIronEstimator()
    for f in (est._long, est._short):
        f.estimate, f.norm, f.sigma = np.array([5e-6, 0.0, 0.0]), 50e-6, np.full(3, 0.2e-6)
        f.determined, f.residual_rel, f.level_spread = True, 0.02, 0.02
        f.explained, f.n = explained, pairs
    est._decide()
    assert (est.status().status == 'applied') == applied
    assert (est.offset is not None) == applied


def _fitted_heading(q, d: SimData) -> float:
    ref = fit_heading_offset(q[d.moving], d.q_true[d.moving])
    return float(np.degrees(np.sqrt(np.mean(error_angles(q[d.moving], ref)[1] ** 2))))


@pytest.mark.parametrize(('seed', 'rate', 'measured'), [(7, 100.0, 1.55), (12, 40.0, 1.08), (7, 286.0, 0.29)])
def test_a_spurious_first_offset_does_not_let_a_field_that_varies_with_position_steer(seed, rate, measured):
    """simulated_accuracy.py's dipole on the two of 60 seeds whose first offset is the field's, not the sensor's (19
    and 9 % of the norm after 5 s of turning, explaining ~60 % of the pairs): each jump of the applied offset used to
    reset the consistency check, and the field, accepted again, steered heading (3.06 against 6-D 1.76; 3.48 against
    1.27; 5.51 against 0.32). The part of the wander that the change can explain is taken off the check's scores,
    and the rest stands: 9-D within 0.5 deg of 6-D and within 20 % of ``measured`` (deg; 0.77 at 286 Hz if
    0.75 e² were taken off, 1.78 with e²)."""
    d = generate_near_dipole(rate, seed)
    worst, _ = _max_applied(ON, d)
    assert worst > 3e-6  # the scenario: a spurious offset is applied (measured 10.3, 5.7 and 10.0 uT)
    q9, _, _ = run(ON, d.t_s, d.gyr, d.acc, d.mag)
    q6 = run_batch(build({'use_mag': False})[0], d.t_s, d.gyr, d.acc, None).quat
    h9 = _fitted_heading(q9, d)
    assert h9 < _fitted_heading(q6, d) + 0.5 and h9 < 1.2 * measured


def test_a_calibration_change_keeps_the_wander_it_cannot_explain():
    """The consistency check's verdict after magnetometer_changed(e): the field of the dipole (seed 7, 100 Hz) has
    wandered by ~10 deg RMS when the spurious offset comes (10.5 s); a change of e (share of the norm) explains at most
    e/sqrt(2) rad of it. 0.6 (BROAD 33's magnet) explains it all: accepted again; 0.05 does not: still rejected;
    unknown (None): everything forgotten, as before."""
    d = generate_near_dipole(100.0, 7)
    filt, _ = build(OFF)
    n = int(np.searchsorted(d.t_s, d.t_s[0] + 10.4))
    run_batch(filt, d.t_s[:n], d.gyr[:n], d.acc[:n], d.mag[:n])
    assert not filt._mag_consistent and np.degrees(np.sqrt(filt._mag_band[6])) > 5.0
    verdicts = {}
    for change in (0.6, 0.05, None):
        f = copy.deepcopy(filt)
        f.magnetometer_changed(change)
        verdicts[change] = f._mag_consistent
    assert verdicts == {0.6: True, 0.05: False, None: True}
