"""Core behaviour: import isolation, parameters, reset, batch == per-sample, frames, transfer function."""

from __future__ import annotations

import ast
import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ccf_ros.core import CcfParams, EulerCcf, EulerCcfParams, QuaternionCcf, Status, make_filter, run_batch
from ccf_ros.core.ccf.discretisation import _bin, _Coefficients
from ccf_ros.core.ccf.mag_gate import MagGate
from ccf_ros.core.metrics import summarize
from ccf_ros.core.quaternion import WORLD_FRAMES, quat_mul, quat_rotate
from ccf_ros.offline.simulate import generate

CORE = Path(__file__).resolve().parents[1] / 'ccf_ros' / 'core'
#: The numpy-only packages: the filter and the magnetometer fit.
PURE = {'core': CORE, 'magcal': CORE.parent / 'magcal'}


@pytest.mark.parametrize('package', sorted(PURE))
def test_core_imports_only_numpy_and_stdlib(package):
    """A numpy-only package imports numpy and the stdlib (no argparse: commands live elsewhere); its relative imports
    leave it only for ccf_ros.errors, which itself imports only the stdlib. Importing it loads no ROS, bag or plot
    code."""
    allowed = (set(sys.stdlib_module_names) - {'argparse'}) | {'numpy'}
    files = sorted(PURE[package].rglob('*.py'))
    assert files
    for path in [*files, CORE.parent / 'errors.py']:
        depth = len(path.relative_to(PURE[package]).parts) if path.is_relative_to(PURE[package]) else 1
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or '']
            else:
                if isinstance(node, ast.ImportFrom) and node.level > depth:  # out of the package: errors only
                    assert node.level == depth + 1 and node.module == 'errors', f'{path.name} imports {node.module}'
                continue
            for name in names:
                assert name.split('.')[0] in allowed, f'{path.relative_to(CORE.parent)} imports {name}'
    code = (f'import sys, ccf_ros.{package}; sys.exit(1 if any(m.startswith(("rclpy", "rosbags", "matplotlib", "yaml"))'
            ' for m in sys.modules) else 0)')
    assert subprocess.run([sys.executable, '-c', code]).returncode == 0


@pytest.fixture(scope='module')
def sim():
    return generate(40.0, 200.0, seed=3)


@pytest.mark.parametrize('settings', [{}, {'formulation': 'euler'}, {'use_mag': False}, {'world_frame': 'ned'},
                                      {'filter': 'madgwick'}, {'filter': 'mahony'}])
def test_batch_equals_per_sample_updates(sim, settings):
    batch = run_batch(make_filter(settings), sim.t_s, sim.gyr, sim.acc, sim.mag)
    f = make_filter(settings)
    quats = []
    for i in range(len(sim.t_s)):
        status = f.update(float(sim.t_s[i]), tuple(sim.gyr[i].tolist()), tuple(sim.acc[i].tolist()),
                          tuple(sim.mag[i].tolist()))
        assert status == batch.status[i]
        quats.append(f.quaternion)
    assert np.array_equal(np.array(quats), batch.quat)


def test_reset_equals_fresh_instance(sim):
    f = QuaternionCcf()
    run_batch(f, sim.t_s, sim.gyr, sim.acc, sim.mag)
    assert f.gyro_bias != (0.0, 0.0, 0.0)
    f.reset()
    a = run_batch(f, sim.t_s, sim.gyr, sim.acc, sim.mag)
    b = run_batch(QuaternionCcf(), sim.t_s, sim.gyr, sim.acc, sim.mag)
    assert np.array_equal(a.quat, b.quat) and np.array_equal(a.bias, b.bias)
    # The magnetometer gate's state too (a stale timer or band would show only in a field that turns).
    f.reset()
    fresh = QuaternionCcf()
    for name in MagGate.__slots__:
        assert getattr(f, name) == getattr(fresh, name), name


@pytest.mark.parametrize(
    ('cls', 'name', 'value'),
    [
        (CcfParams, 'tau_acc_s', -1.0),
        (CcfParams, 'tau_mag_s', float('nan')),
        (CcfParams, 'max_dt_s', 0.0),
        (CcfParams, 'world_frame', 'xyz'),
        (CcfParams, 'mag_dip_tol_rad', 4.0),
        (EulerCcfParams, 'alpha', 1.5),
        (EulerCcfParams, 'kp', (1.0, 2.0)),
        (EulerCcfParams, 'ki', -0.1),
    ],
)
def test_invalid_parameters_raise_value_error_naming_the_value(cls, name, value):
    with pytest.raises(ValueError, match=name) as err:
        cls(**{name: value})
    assert repr(value)[:3] in str(err.value) or str(value) in str(err.value)


def test_params_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        CcfParams().tau_acc_s = 1.0  # type: ignore[misc]


def test_make_filter_rejects_unknown_and_inapplicable_names():
    with pytest.raises(ValueError, match='unknown parameter'):
        make_filter({'tau_acc': 3})
    with pytest.raises(ValueError, match='does not apply'):
        make_filter({'kp': 2.0})
    f = make_filter({'formulation': 'euler', 'kp': '[1, 2, 3]', 'alpha': '0.5'})
    assert isinstance(f, EulerCcf) and f.gains.kp == (1.0, 2.0, 3.0)


@pytest.mark.parametrize('frame', ['enu', 'ned', 'nwu'])
def test_world_frames_put_gravity_and_north_where_rep103_says(sim, frame):
    r = run_batch(make_filter({'world_frame': frame}), sim.t_s, sim.gyr, sim.acc, sim.mag)
    i = len(sim.t_s) // 2
    acc_world = quat_rotate(r.quat[i], sim.acc[i])
    up = {'enu': 2, 'ned': 2, 'nwu': 2}[frame]
    sign = -1.0 if frame == 'ned' else 1.0
    assert sign * acc_world[up] > 8.0
    mag_world = quat_rotate(r.quat[i], sim.mag[i])
    north = {'enu': 1, 'ned': 0, 'nwu': 0}[frame]
    assert mag_world[north] > 0.8 * np.linalg.norm(mag_world[:2])
    enu = run_batch(make_filter(), sim.t_s, sim.gyr, sim.acc, sim.mag)
    np.testing.assert_allclose(np.abs(np.sum(quat_mul(WORLD_FRAMES[frame], enu.quat[i]) * r.quat[i])), 1.0, atol=1e-9)


def test_no_singularity_at_90_deg_pitch():
    # Rotate about body y through +-90 deg pitch and beyond; gravity still consistent.
    rate = 200.0
    t = np.arange(int(20 * rate)) / rate
    pitch = np.radians(120.0) * np.sin(2 * np.pi * 0.1 * t)
    pitch_rate = np.gradient(pitch, t)
    gyr = np.stack((0 * t, pitch_rate, 0 * t), axis=1)
    acc = 9.81 * np.stack((-np.sin(pitch), 0 * t, np.cos(pitch)), axis=1)
    mag_w = np.array([0.0, 20.0, -40.0])
    mag = np.stack((mag_w[0] * np.cos(pitch) - mag_w[2] * np.sin(pitch), mag_w[1] + 0 * t,
                    mag_w[0] * np.sin(pitch) + mag_w[2] * np.cos(pitch)), axis=1)
    r = run_batch(QuaternionCcf(), t, gyr, acc, mag)
    up_est = quat_rotate(r.quat, acc) / 9.81
    assert np.all(np.isfinite(r.quat))
    assert np.degrees(np.arccos(np.clip(up_est[:, 2], -1, 1))).max() < 3.0


def _euler_response(kp: float, ki: float, alpha: float, f_hz: float, rate_hz: float = 1000.0):
    """Drive the Euler CCF's roll with x_a = A sin(wt) (accelerometer only, zero gyro); return gain, phase (deg)."""
    amp = np.radians(2.0)
    n_periods = 12
    t = np.arange(int(n_periods / f_hz * rate_hz)) / rate_hz
    roll = amp * np.sin(2 * np.pi * f_hz * t)
    acc = 9.81 * np.stack((0 * t, np.sin(roll), np.cos(roll)), axis=1)
    f = EulerCcf(EulerCcfParams(kp=kp, ki=ki, alpha=alpha, use_mag=False, max_dt_s=1.0))
    r = run_batch(f, t, np.zeros((len(t), 3)), acc)
    x = np.arctan2(2 * (r.quat[:, 0] * r.quat[:, 1] + r.quat[:, 2] * r.quat[:, 3]),
                   1 - 2 * (r.quat[:, 1] ** 2 + r.quat[:, 2] ** 2))
    keep = t >= t[-1] - 6 / f_hz  # steady state: last 6 periods
    basis = np.exp(-1j * 2 * np.pi * f_hz * t[keep])
    out = np.sum(x[keep] * basis)
    inp = np.sum(roll[keep] * basis)
    h = out / inp
    return abs(h), np.degrees(np.angle(h))


@pytest.mark.parametrize('f_hz', [0.05, 0.3, 1.0])
def test_euler_ccf_matches_transfer_function_eq15(f_hz):
    kp, ki, alpha = 2.0, 0.5, 0.7
    s = 2j * np.pi * f_hz
    h = ((1 - alpha) * s**2 + alpha * kp * s + alpha * ki) / (s**2 + alpha * kp * s + alpha * ki)
    gain, phase = _euler_response(kp, ki, alpha, f_hz)
    assert 20 * math.log10(gain) == pytest.approx(20 * math.log10(abs(h)), abs=0.3)
    assert phase == pytest.approx(np.degrees(np.angle(h)), abs=3.0)


def test_quaternion_ccf_estimates_a_constant_gyro_bias():
    d = generate(120.0, 200.0, seed=5, bias_init_rad_s=np.radians(1.0), bias_walk_rad_s_sqrt_s=0.0)
    r = run_batch(QuaternionCcf(), d.t_s, d.gyr, d.acc, d.mag)
    err = np.degrees(np.abs(r.bias[-1] - d.bias[-1]))
    assert np.all(err < 0.0063), err  # °/s, measured 0.0053
    assert np.all(r.status[1:] == Status.UPDATED)


def test_config_file_lists_every_parameter_with_its_default():
    from ccf_ros.offline.params_file import load_params_file
    from ccf_ros.settings import all_defaults

    cfg = load_params_file(Path(__file__).resolve().parents[1] / 'config' / 'ccf.yaml')
    defaults = all_defaults()
    assert set(cfg) == set(defaults)
    for name, value in defaults.items():
        if isinstance(value, tuple):
            assert tuple(cfg[name]) == pytest.approx(value, rel=1e-6), name
        else:
            assert cfg[name] == pytest.approx(value, rel=1e-6) if isinstance(value, float) else cfg[name] == value, name
    from ccf_ros.settings import config_yaml

    assert (Path(__file__).resolve().parents[1] / 'config' / 'ccf.yaml').read_text() == config_yaml()


def test_vehicle_profile_is_a_valid_override():
    """config/ccf_vehicle.yaml names only real parameters, in range, and changes what it says it changes."""
    from ccf_ros.offline.params_file import load_params_file
    from ccf_ros.settings import build

    cfg = load_params_file(Path(__file__).resolve().parents[1] / 'config' / 'ccf_vehicle.yaml')
    assert set(cfg) == {'tau_acc_lp_s', 'tau_acc_s', 'tau_bias_s'}
    f, _ = build(cfg)
    assert (f.params.tau_acc_lp_s, f.params.tau_acc_s, f.params.tau_bias_s) == (8.0, 2.0, 20.0)
    assert f.params.tau_ncf_s == CcfParams().tau_ncf_s  # the rest stays at the defaults


# --- the NCF -> LCF cascade (default) -------------------------------------------------------------------------------


def _cascade_response(p: CcfParams, f_hz: float, kind: str, rate_hz: float = 100.0) -> complex:
    """Measured complex gain of one tilt axis: from the accelerometer roll angle (``acc``) or from the roll rate
    (``rate``, rad per rad/s), gyro otherwise silent, no magnetometer."""
    from ccf_ros.core.ccf import GRAVITY_M_S2

    # Small signals (0.3°): the NCF's gate on its observations (3 sigma, ~0.5°/s) must not cut in.
    amp = 0.005 if kind == 'acc' else 0.005 * 2 * math.pi * f_hz
    # The NCF's bias covariance reaches its steady state in ~10 tau_bias_s; the low-passes settle in ~6 delays.
    settle = max(3.0 / f_hz, 10.0 * p.tau_bias_s, 6.0 * (p.tau_acc_s + p.tau_acc_lp_s + p.tau_ncf_s))
    fit = math.ceil(max(4.0 / f_hz, 10.0) * f_hz) / f_hz
    n = int(round((settle + fit) * rate_hz))
    t = np.arange(n) / rate_hz
    sig = amp * np.sin(2 * np.pi * f_hz * t)
    zero = np.zeros(n)
    if kind == 'acc':
        gyr = np.stack((zero, zero, zero), 1)
        acc = GRAVITY_M_S2 * np.stack((zero, np.sin(sig), np.cos(sig)), 1)
    else:
        gyr = np.stack((sig, zero, zero), 1)
        acc = np.tile([0.0, 0.0, GRAVITY_M_S2], (n, 1))
    q = run_batch(QuaternionCcf(p), t, gyr, acc).quat
    roll = np.arctan2(2 * (q[:, 0] * q[:, 1] + q[:, 2] * q[:, 3]), 1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2))
    sel = t >= t[-1] - fit
    ts = t[sel]
    basis = np.stack((np.sin(2 * np.pi * f_hz * ts), np.cos(2 * np.pi * f_hz * ts), np.ones_like(ts), ts - ts[0]), 1)
    coef, *_ = np.linalg.lstsq(basis, roll[sel], rcond=None)
    return complex(coef[0], coef[1]) / amp


@pytest.mark.parametrize('kind', ['acc', 'rate'])
@pytest.mark.parametrize('f_hz', [0.005, 0.05, 0.3, 1.0])
def test_cascade_matches_its_small_angle_transfer_function(kind, f_hz):
    """The default is a genuine NCF -> LCF cascade: its measured response is the derived one (ccf.tilt_transfer, the
    NCF's Kalman gain at its steady state), which differs from a single PI stage, below fs/100 within 0.5 dB / 5 deg."""
    from ccf_ros.core.ccf import tilt_transfer

    p = CcfParams(use_mag=False, rest_bias=False, max_dt_s=1.0)
    h = _cascade_response(p, f_hz, kind)
    h_a, h_w = tilt_transfer(p, f_hz)
    ref = h_a if kind == 'acc' else h_w
    # The rate path's estimate is half a sample ahead for point samples (360° f dt / 2 at the test's 100 Hz).
    lead = 180.0 * f_hz / 100.0 if kind == 'rate' else 0.0
    # Measured: within 0.018 dB (the discrete Kalman's steady state, updated every 40 ms) and 0.077° after the lead.
    assert 20 * math.log10(abs(h)) == pytest.approx(20 * math.log10(abs(ref)), abs=0.022)
    assert np.degrees(np.angle(h / ref)) - lead == pytest.approx(0.0, abs=0.093)
    # A single PI stage (the NCF alone, eq 11, as the previous default was) lets far more acceleration through.
    if kind == 'acc' and f_hz == 0.3:
        s = 2j * math.pi * f_hz
        kn, ki = 1 / p.tau_ncf_s, p.bias_gain_per_s / p.tau_ncf_s
        single = (kn * s + ki) / (s * s + kn * s + ki)
        assert 20 * math.log10(abs(single)) - 20 * math.log10(abs(h)) > 10.5  # measured 12.6 dB


def test_bias_is_learnt_while_moving_without_rest():
    """Rest detection off, a constant 1 deg/s bias on every axis, hand-held motion (9-D): the NCF learns it."""
    d = generate(300.0, 200.0, seed=2, bias_init_rad_s=0.0, bias_walk_rad_s_sqrt_s=0.0, rest_s=0.0)
    b_true = np.radians([1.0, -1.0, 1.0])
    r = run_batch(make_filter({'rest_bias': False}), d.t_s, d.gyr + b_true, d.acc, d.mag)
    err = np.degrees(np.abs(r.bias - b_true)).max(axis=1)
    t = d.t_s - d.t_s[0]
    assert np.all(err[t < 14.9] == 1.0)  # nothing is learnt during the 15 s start-up ...
    # ... and it is within 0.1 °/s from 60 s on, the figure the README states (measured: from 42 s; at most 0.042 °/s
    # after 60 s, 0.0086 °/s at the end).
    assert err[t >= 60].max() < 0.05, err[t >= 60].max()
    assert err[-1] < 0.0103, err[-1]


def test_bursts_of_stamps_do_not_stall_the_bias_update():
    """A driver that stamps on arrival reads in bursts (here 4 samples 10 µs apart every 20 ms): the NCF's update is
    due when its block spans 40 ms of stamps, not a number of samples sized from the latest step (a block sized from
    a 10 µs step waited minutes: the bias stayed 1.2 °/s off)."""
    d = generate(300.0, 200.0, seed=2, bias_init_rad_s=0.0, bias_walk_rad_s_sqrt_s=0.0, rest_s=0.0)
    b_true = np.radians([1.0, -1.0, 1.0])
    k = np.arange(len(d.t_s))
    t = d.t_s[0] + (k // 4) * 0.02 + (k % 4) * 1e-5
    r = run_batch(make_filter({'rest_bias': False}), t, d.gyr + b_true, d.acc, d.mag)
    err = np.degrees(np.abs(r.bias - b_true)).max(axis=1)
    assert err[t - t[0] >= 120].max() < 0.033  # °/s, measured 0.027
    assert err[-1] < 0.0115  # measured 0.0096 (regular stamps: 0.0086)


def test_jittered_stamps_reuse_the_gains_of_their_bin(monkeypatch):
    """Stamps jittered by 2 % of the period: the per-sample gains and the bias update's constants are computed once
    per 0.1 % bin of the span they visit and then reused, not once per sample or block (measured at 40 Hz: 171 and
    84 computations for 4800 samples and ~2400 blocks)."""
    import ccf_ros.core.ccf as ccf_module

    calls = {'sample': 0, 'block': 0}
    for kind, cls in (('sample', ccf_module._Coefficients), ('block', ccf_module._BlockCoefficients)):
        make = cls.of.__func__

        def counted(c, p, key, *more, kind=kind, make=make):
            calls[kind] += 1
            return make(c, p, key, *more)

        monkeypatch.setattr(cls, 'of', classmethod(counted))
    d = generate(120.0, 40.0, seed=1)
    t = np.sort(d.t_s + np.random.default_rng(0).normal(0.0, 0.02 / 40.0, len(d.t_s)))
    r = run_batch(QuaternionCcf(), t, d.gyr, d.acc, d.mag)
    assert np.all(r.status[1:] == Status.UPDATED)
    assert calls['sample'] < 210 and calls['block'] < 100, calls


def test_a_period_on_a_bin_edge_takes_its_gains_without_a_lookup_per_sample(monkeypatch):
    """400 Hz stamps near 1.7e9 s: the period (2.5 ms) sits on the edge of a 0.1 % bin, and the stamps' float
    rounding sends about every other sample to the neighbouring bin. The two bins' gains are swapped without the
    cache's lookup (measured: 2 lookups for 4000 samples; without the swap 1921), and each sample still gets its own
    bin's gains."""
    calls = []
    lookup = QuaternionCcf._coefficients

    def counted(self, dt):
        calls.append(dt)
        return lookup(self, dt)

    f = QuaternionCcf()
    monkeypatch.setattr(QuaternionCcf, '_coefficients', counted)
    t = 1_700_000_000.0 + np.arange(4000) * 0.0025
    dts = np.diff(t)
    assert 0.2 < np.mean([_bin(d) != _bin(0.0025) for d in dts.tolist()]) < 0.8  # the case: both bins visited
    for k, tk in enumerate(t.tolist()):
        f.update(tk, (0.01, -0.02, 0.005), (0.0, 0.3, 9.8), (2e-5, 0.0, -4e-5))
        if k:
            assert f._coef is lookup(f, float(dts[k - 1])), k  # this sample's bin (looked up uncounted)
    assert len(calls) <= 4, len(calls)


def test_a_period_on_a_bin_edge_takes_new_gains_after_a_change():
    """The swapped-in neighbouring bin (test_a_period_on_a_bin_edge_takes_its_gains_without_a_lookup_per_sample) is
    never a stale one: after set_params (new time constants, a gyro range) and after raw_clip_check toggles,
    mid-stream on bin-alternating 400 Hz stamps, every later sample runs with the gains the cache builds for its own
    period under the settings of the moment."""
    f = QuaternionCcf()
    lookup = QuaternionCcf._coefficients
    t = (1_700_000_000.0 + np.arange(1200) * 0.0025).tolist()
    changes = {
        300: lambda: f.set_params(dataclasses.replace(f.params, tau_acc_s=2.0 * f.params.tau_acc_s)),
        500: lambda: f.set_params(dataclasses.replace(f.params, gyro_range_rad_s=0.5)),
        700: lambda: setattr(f, 'raw_clip_check', True),
        900: lambda: setattr(f, 'raw_clip_check', False),
    }
    before = {}
    for k, tk in enumerate(t):
        if k in changes:
            before[k] = (f._coef.k_acc, f._coef.clip)
            changes[k]()
        f.update(tk, (0.01, -0.02, 0.005), (0.0, 0.3, 9.8), (2e-5, 0.0, -4e-5))
        if k:
            c = f._coef
            fresh = _Coefficients.of(f.params, _bin(t[k] - t[k - 1]), not f.raw_clip_check)
            assert c is lookup(f, t[k] - t[k - 1]), k
            assert (c.dt_lo, c.dt_hi, c.k_acc, c.clip) == (fresh.dt_lo, fresh.dt_hi, fresh.k_acc, fresh.clip), k
    # (The changes did change the gains: the test would see a stale bin.)
    assert before[300][0] != f._coef.k_acc and before[500][1] == math.inf
    assert math.isfinite(f._coef.clip)


@pytest.mark.parametrize('world_frame', ['enu', 'ned'])
def test_estimate_is_the_three_properties_for_every_filter(world_frame):
    """OrientationFilter.estimate() (the engine's per-sample read; the CCF writes it out) equals quaternion,
    orientation_variance and gyro_bias, through a start, a magnetometer's arrival and a turn, for every filter."""
    from ccf_ros.core.registry import FILTERS

    sim = generate(8.0, 100.0, seed=2)
    for kind, formulation in FILTERS:
        f = make_filter({'filter': kind, 'formulation': formulation, 'world_frame': world_frame})
        for k in range(len(sim.t_s)):
            f.update(float(sim.t_s[k]), tuple(sim.gyr[k]), tuple(sim.acc[k]), tuple(sim.mag[k]) if k > 300 else None)
            if k % 50 == 0 or k == len(sim.t_s) - 1:
                assert f.estimate() == (f.quaternion, f.orientation_variance, f.gyro_bias), (kind, formulation, k)


def test_a_drive_off_is_not_learnt_as_bias():
    """After a rest (the bias known), a robot drives off at 1 m/s² for 10 s while weaving (yaw ±30°/s): the
    accelerometer tilts by 5.8° while the gyro says no tilt. The NCF does not use observations beyond 3 sigma of what
    the bias uncertainty and the accelerometer's own error explain (measured 0.13 °/s of false bias; with the gate
    off 0.33)."""
    import ccf_ros.core.ccf.bias as ccf_module

    rate = 200.0
    t = np.arange(int(60 * rate)) / rate
    b_true = np.radians([0.3, -0.2, 0.1])
    gyr = np.tile(b_true, (len(t), 1))
    acc = np.tile([0.0, 0.0, 9.80665], (len(t), 1))
    drive = (t >= 20.0) & (t < 30.0)
    gyr[drive, 2] += np.radians(30.0) * np.sin(2 * np.pi * 0.5 * (t[drive] - 20.0))
    acc[drive, 0] = 1.0

    def false_bias() -> float:
        r = run_batch(QuaternionCcf(), t, gyr, acc)
        return float(np.degrees(np.abs(r.bias - b_true)).max(axis=1)[t >= 20.0].max())

    gated = false_bias()
    assert gated < 0.16, gated
    gate = ccf_module._GATE2
    try:
        ccf_module._GATE2 = math.inf
        assert false_bias() > 2 * gated  # the gate is what keeps it out
    finally:
        ccf_module._GATE2 = gate


def test_set_params_with_the_same_values_changes_nothing():
    """The node applies a parameter change through set_params (here, mid-motion, the same values): the estimate must
    go on as if nothing happened (rebuilding the NCF's observation model lost its memory: 0.0044° off)."""
    d = generate(60.0, 200.0, seed=9)
    plain = run_batch(QuaternionCcf(), d.t_s, d.gyr, d.acc, d.mag).quat
    f = QuaternionCcf()
    half = len(d.t_s) // 2
    first = run_batch(f, d.t_s[:half], d.gyr[:half], d.acc[:half], d.mag[:half]).quat
    f.set_params(dataclasses.replace(f.params))
    second = run_batch(f, d.t_s[half:], d.gyr[half:], d.acc[half:], d.mag[half:]).quat
    np.testing.assert_array_equal(np.vstack((first, second)), plain)


def test_extreme_bias_uncertainties_keep_the_covariance_valid():
    """A prior far wider than the walk (1000 rad/s against 1e-8 rad/s/√s) once left a variance a hair below zero, and
    the square root of the reported uncertainty raised in update()."""
    d = generate(40.0, 200.0, seed=10)
    f = QuaternionCcf(CcfParams(bias_sigma_init_rad_s=1e3, bias_walk_rad_s_sqrt_s=1e-8))
    r = run_batch(f, d.t_s, d.gyr, d.acc, np.where((np.arange(len(d.t_s)) % 7 == 0)[:, None], np.nan, d.mag))
    assert np.all(np.isfinite(r.quat)) and np.all(np.isfinite(r.variance))
    assert f.gyro_bias_sigma_rad_s >= 0.0


def test_a_malformed_accelerometer_raises_even_with_a_bad_gyro():
    """update() unpacks the gyro and the accelerometer before it looks at either (then goes on as _update_floats on
    the floats): an accelerometer of the wrong length is a caller's bug and raises whatever the gyro is, rather than
    hiding behind a skipped sample. A well-formed one with the same bad gyro is skipped and counted."""
    f = QuaternionCcf()
    with pytest.raises(ValueError):
        f.update(0.0, (math.nan, 0.0, 0.0), (1.0, 2.0))
    assert f.update(0.0, (math.nan, 0.0, 0.0), (0.0, 0.0, 9.81)) == Status.SKIPPED_BAD_GYRO
    assert f.counts[Status.SKIPPED_BAD_GYRO] == 1


def test_a_corrupted_accelerometer_sample_does_not_end_a_rest():
    """One unusable accelerometer sample in a hundred neither extends nor ends a rest: before, no rest lasted the
    1.5 s it needs, the bias went unlearnt and the error rose from 0.63° to 1.65°."""
    d = generate(120.0, 200.0, seed=3)
    acc = d.acc.copy()
    acc[::100] = np.nan
    out = {}
    for name, a in (('clean', d.acc), ('corrupted', acc)):
        f = QuaternionCcf()
        rest, q = [], []
        for k in range(len(d.t_s)):
            f.update(float(d.t_s[k]), tuple(d.gyr[k]), tuple(a[k]), tuple(d.mag[k]))
            rest.append(f.at_rest)
            q.append(f.quaternion)
        out[name] = (np.mean(rest), summarize(np.array(q), d.q_true, d.moving).total_rmse_deg)
    assert out['corrupted'][0] > 0.9 * out['clean'][0] > 0.0  # measured 0.0290 and 0.0292 of the samples
    assert out['corrupted'][1] < 1.05 * out['clean'][1]  # measured 0.555 and 0.547 deg


def test_bias_estimate_is_clamped_per_axis():
    d = generate(60.0, 200.0, seed=4, rest_s=5.0)
    big = np.radians([5.0, -5.0, 5.0])
    f = make_filter({'bias_max_rad_s': math.radians(2.0)})
    r = run_batch(f, d.t_s, d.gyr + big, d.acc, d.mag)
    assert np.all(np.abs(r.bias[r.answered]) <= math.radians(2.0) + 1e-15)
    assert np.max(np.abs(r.bias)) == pytest.approx(math.radians(2.0))


def test_magnetometer_along_gravity_at_start_gives_no_nan():
    f = QuaternionCcf()
    up = (0.0, 0.0, 9.81)
    assert f.update(0.0, (0.0, 0.0, 0.0), up, (0.0, 0.0, -45e-6)) == Status.INITIALIZED
    assert all(math.isfinite(v) for v in f.quaternion)
    for k in range(1, 500):
        f.update(0.01 * k, (0.0, 0.0, 0.01), up, (0.0, 20e-6, -40e-6))
    assert all(math.isfinite(v) for v in f.quaternion) and f.flags.heading_absolute


def test_magnetometer_reference_is_learnt_after_an_initialisation_without_magnetometer():
    """No magnetometer at initialisation, then a steady field, then a magnet: once the reference is learnt (the
    first mag_ref_learn_s of field), the disturbance is still caught."""
    f = QuaternionCcf()
    learn_s = f.params.mag_ref_learn_s
    g, up, field = (0.0, 0.0, 0.0), (0.0, 0.0, 9.81), (0.0, 20e-6, -40e-6)
    f.update(0.0, g, up, None)
    n = int(round(100 * (learn_s + 1.0)))
    for k in range(1, n):
        f.update(0.01 * k, g, up, field)
    assert f.flags.mag_used and not f.flags.mag_disturbed
    f.update(0.01 * n, g, up, (15e-6, 35e-6, -40e-6))  # a magnet nearby
    assert f.flags.mag_disturbed and not f.flags.mag_used


def test_6d_gap_relevels_the_tilt_but_keeps_the_heading():
    d = generate(40.0, 200.0, seed=6)
    f = make_filter({'use_mag': False})
    n = len(d.t_s) // 2
    a = run_batch(f, d.t_s[:n], d.gyr[:n], d.acc[:n])
    yaw_before = math.atan2(2 * (a.quat[-1, 0] * a.quat[-1, 3] + a.quat[-1, 1] * a.quat[-1, 2]),
                            1 - 2 * (a.quat[-1, 2] ** 2 + a.quat[-1, 3] ** 2))
    # 2 s later (a gap longer than max_dt_s), the IMU at the orientation it had just before the gap, tilted by 10 deg.
    tilt = 0.17
    acc = quat_rotate(np.array([math.cos(tilt / 2), math.sin(tilt / 2), 0.0, 0.0]), [0.0, 0.0, 9.81])
    assert f.update(d.t_s[n - 1] + 2.0, (0.0, 0.0, 0.0), tuple(acc), None) == Status.REINITIALIZED_AFTER_GAP
    q = f.quaternion
    yaw_after = math.atan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] ** 2 + q[3] ** 2))
    up_body = quat_rotate(np.array(q) * [1, -1, -1, -1], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(up_body, acc / np.linalg.norm(acc), atol=1e-9)  # tilt re-levelled exactly
    assert abs(math.remainder(yaw_after - yaw_before, 2 * math.pi)) < math.radians(12.0)  # heading kept (~tilt)


def test_nonfinite_state_reinitialises_and_is_counted(sim, monkeypatch):
    f = QuaternionCcf()
    r = run_batch(f, sim.t_s[:200], sim.gyr[:200], sim.acc[:200], sim.mag[:200])
    step = QuaternionCcf._step

    def broken(self, *args):
        step(self, *args)
        self._q = (float('nan'),) * 4

    monkeypatch.setattr(QuaternionCcf, '_step', broken)
    assert f.update(float(sim.t_s[200]), tuple(sim.gyr[200]), tuple(sim.acc[200]), tuple(sim.mag[200])) == 2
    monkeypatch.setattr(QuaternionCcf, '_step', step)
    assert f.n_nonfinite_resets == 1 and all(math.isfinite(v) for v in f.quaternion)
    assert r.answered.all()


def test_flags_are_one_read_only_structure_on_every_filter(sim):
    from ccf_ros.core.base import FilterFlags
    from ccf_ros.core.registry import FILTERS

    for kind, formulation in FILTERS:
        f = make_filter({'filter': kind, 'formulation': formulation})
        assert f.flags == FilterFlags(False, False, False, False, False, False)
        run_batch(f, sim.t_s[:400], sim.gyr[:400], sim.acc[:400], sim.mag[:400])
        flags = f.flags
        assert isinstance(flags, FilterFlags) and flags.initialized and flags.acc_used
        with pytest.raises(AttributeError):
            flags.at_rest = True  # type: ignore[misc]


def test_reported_covariance_is_rate_independent_and_grows_without_corrections():
    d = generate(40.0, 286.0, seed=9)
    full = run_batch(QuaternionCcf(), d.t_s, d.gyr, d.acc, d.mag)
    dec = run_batch(QuaternionCcf(), d.t_s[::6], d.gyr[::6], d.acc[::6], d.mag[::6])
    ratio = np.sqrt(dec.variance[-1]) / np.sqrt(full.variance[-1])
    np.testing.assert_allclose(ratio, 1.0, atol=0.05)  # 48 Hz vs 286 Hz (the old model: 2.4x)
    # The accelerometer unusable for 15 s: the inclination variance grows, then shrinks once it is back.
    acc = d.acc.copy()
    k0, k1 = 10 * 286, 25 * 286
    acc[k0:k1] = 0.0
    mag = d.mag.copy()
    mag[k0:k1] *= 1.5  # and a magnet: heading runs on the gyro too
    r = run_batch(QuaternionCcf(), d.t_s, d.gyr, acc, mag)
    vi, vh = r.variance[:, 0], r.variance[:, 2]
    # 15 s at ~0.02-0.05 deg/s of bias uncertainty: inclination variance x2.8 (floor 0.5 deg); heading x1.15 (its
    # 1.7 deg floor dominates a 0.3 deg drift).
    assert vi[k1 - 1] > 2.3 * vi[k0 - 1] and vh[k1 - 1] > 1.1 * vh[k0 - 1]
    assert vi[-1] < 1.1 * vi[k0 - 1]


def test_6d_yaw_variance_is_the_relative_drift_not_unknown_north():
    d = generate(60.0, 200.0, seed=10)
    r = run_batch(make_filter({'use_mag': False}), d.t_s, d.gyr, d.acc)
    sigma_yaw = np.degrees(np.sqrt(r.variance[:, 2]))
    assert sigma_yaw[10] < 0.5  # just initialised: the heading is the reference (relative)
    assert 0.5 < sigma_yaw[-1] < 6.0, sigma_yaw[-1]  # grows with the bias uncertainty; far below 90 deg
    assert np.all(np.diff(sigma_yaw[1:]) >= -1e-12)


def test_quaternion_conversions_agree_with_scipy():
    """Property test on random orientations: every Euler/quaternion conversion and rotation of core/quaternion.py
    against an independent implementation (scipy's Rotation, intrinsic Z-Y-X = 'ZYX', scalar-last)."""
    from scipy.spatial.transform import Rotation

    from ccf_ros.core.quaternion import euler_to_quat, quat_of_rpy, quat_to_euler, rpy_of

    rng = np.random.default_rng(12)
    for _ in range(20):
        q = rng.standard_normal((64, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        r = Rotation.from_quat(q[:, [1, 2, 3, 0]])
        ypr = r.as_euler('ZYX')
        np.testing.assert_allclose(quat_to_euler(q), ypr[:, ::-1], atol=1e-9)
        np.testing.assert_allclose([rpy_of(tuple(v)) for v in q], ypr[:, ::-1], atol=1e-9)
        back = np.array([quat_of_rpy(*v) for v in ypr[:, ::-1]])
        np.testing.assert_allclose(np.abs(np.sum(back * q, axis=1)), 1.0, atol=1e-12)  # same rotation, +-q
        np.testing.assert_allclose(euler_to_quat(*ypr[:, ::-1].T), back, atol=1e-12)
        v = rng.standard_normal((64, 3))
        np.testing.assert_allclose(quat_rotate(q, v), r.apply(v), atol=1e-12)
        p = rng.standard_normal((64, 4))
        p /= np.linalg.norm(p, axis=1, keepdims=True)
        prod = (Rotation.from_quat(p[:, [1, 2, 3, 0]]) * r).as_quat()[:, [3, 0, 1, 2]]
        np.testing.assert_allclose(np.abs(np.sum(quat_mul(p, q) * prod, axis=1)), 1.0, atol=1e-12)


@pytest.mark.parametrize('averaged', [True, False])
def test_sample_timing_constant_rotation_at_40_hz(averaged):
    """90 °/s about a horizontal axis, 40 Hz. A real sensor's samples are means over the interval before the stamp:
    then the estimate is the frame at the stamp. With instantaneous (point) samples it is, as documented, the frame
    half a step later (1.1° here)."""
    rate, w, g = 40.0, math.radians(90.0), 9.80665
    dt = 1.0 / rate
    t = np.arange(1, 2401) * dt
    th1, th0 = w * t, w * (t - dt)
    if averaged:
        acc = g * np.stack((0 * t, (np.cos(th0) - np.cos(th1)) / (w * dt), (np.sin(th1) - np.sin(th0)) / (w * dt)), 1)
    else:
        acc = g * np.stack((0 * t, np.sin(th1), np.cos(th1)), 1)
    gyr = np.tile([w, 0.0, 0.0], (len(t), 1))
    filt = QuaternionCcf(CcfParams(use_mag=False, rest_bias=False))
    q = run_batch(filt, t, gyr, acc).quat[-400:]  # the last 10 s
    lead = 0.0 if averaged else 0.5 * w * dt
    # The angle of the estimate's rotation about x (it stays a rotation about x), against the truth at stamp + lead.
    est = 2 * np.arctan2(q[:, 1], q[:, 0])
    err = np.degrees(np.angle(np.exp(1j * (est - (th1[-400:] + lead)))))
    assert np.abs(q[:, 2:]).max() < 1e-6
    assert np.abs(err).max() < 0.037, np.abs(err).max()  # measured 0.031 (first-order half-step rotation)
    assert np.degrees(np.abs(filt.gyro_bias).max()) < 0.0074  # °/s; measured 0.0061


def test_sample_timing_of_the_magnetometer_at_40_hz():
    """Yaw at 90 °/s, 40 Hz, the magnetometer's samples means over the interval before the stamp like the gyro's:
    the field is compared with the attitude at the step's start, so it is carried back half a step. The heading is
    then the frame at the stamp (measured 0.0016°; compared as it came, half a step late: 1.13°)."""
    rate, w = 40.0, math.radians(90.0)
    dt = 1.0 / rate
    t = np.arange(1, 4801) * dt
    # The field in ENU (0, 20, -40) µT seen from a body yawed by w t, averaged over each interval.
    psi = w * (t[:, None] - dt + dt * np.linspace(0.0, 1.0, 201)[None, :])
    mag = np.stack((20.0 * np.sin(psi).mean(1), 20.0 * np.cos(psi).mean(1), np.full(len(t), -40.0)), 1)
    gyr = np.tile([0.0, 0.0, w], (len(t), 1))
    acc = np.tile([0.0, 0.0, 9.80665], (len(t), 1))
    q = run_batch(QuaternionCcf(CcfParams(rest_bias=False)), t, gyr, acc, mag).quat[-800:]
    yaw = 2 * np.arctan2(q[:, 3], q[:, 0])
    assert np.degrees(np.abs(np.angle(np.exp(1j * (yaw - w * t[-800:]))))).max() < 0.002


# Half-step angles 0.0044 (the series) and 0.014 (sin/cos).
@pytest.mark.parametrize('rate_rad_s', [2.5, 8.0])
def test_gyro_integration_stays_unit_and_exact_over_100k_steps(rate_rad_s):
    """Yaw at a constant rate, gravity along the axis (no tilt correction), no magnetometer: the estimate is the
    gyro's integral alone. |q| must stay 1 to rounding (measured 4.4e-16; without the renormalisation 2.5e-12 and
    6.3e-13, with the series cut at x² 4e-10 — which 2 acos|q1·q2| reads as a 3e-3° rotation) and the angle exact
    (measured 9e-14 and 3e-13 rad; the series cut at x²: 1e-8)."""
    rate_hz, n = 286.0, 100_000
    t = 1.7e9 + np.arange(n) / rate_hz
    gyr = np.tile([0.0, 0.0, rate_rad_s], (n, 1))
    acc = np.tile([0.0, 0.0, 9.80665], (n, 1))
    q = run_batch(QuaternionCcf(CcfParams(use_mag=False)), t, gyr, acc).quat
    norm_err = np.abs(np.linalg.norm(q, axis=1) - 1.0).max()
    assert norm_err < 1e-14, norm_err
    yaw = 2.0 * np.arctan2(q[:, 3], q[:, 0])
    err = np.abs(np.angle(np.exp(1j * (yaw - rate_rad_s * (t - t[0]))))).max()
    assert err < 1e-11, err  # rad: rounding over 100k steps, with room for another libm's sin/cos


def _flags_per_sample(filt, d, mag):
    out = []
    for k in range(len(d.t_s)):
        filt.update(float(d.t_s[k]), tuple(d.gyr[k]), tuple(d.acc[k]), tuple(mag[k]))
        out.append((filt.flags.mag_used, filt.flags.mag_disturbed, filt.quaternion))
    used, disturbed, q = (np.array(v) for v in zip(*out, strict=True))
    return used, disturbed, q


def test_magnetic_disturbance_is_flagged_ignored_and_cleared_when_the_field_returns():
    d = generate(60.0, 200.0, seed=5)
    t = d.t_s - d.t_s[0]
    bad = (t >= 20.0) & (t < 30.0)
    mag = d.mag.copy()
    c, s = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    x, y = mag[bad, 0].copy(), mag[bad, 1].copy()
    mag[bad, 0], mag[bad, 1] = c * x - s * y, s * x + c * y
    mag[bad] *= 1.3  # 30 % stronger and turned 30° about body z: a magnet nearby
    used, disturbed, q = _flags_per_sample(QuaternionCcf(), d, mag)
    used_clean, disturbed_clean, q_clean = _flags_per_sample(QuaternionCcf(), d, d.mag)
    assert not disturbed[t < 20.0].any() and used[t < 20.0].all()
    assert disturbed[bad].all() and not used[bad].any()
    # The field came back, but its world direction jumped twice (30° and back) within seconds: the consistency check
    # holds it off until the jumps have left its band-pass (8 s), then the flags are those of the undisturbed run
    # (which rejects a few samples of its own: the dip is measured against an accelerometer that sees linear
    # acceleration). Measured: the last difference 8.8 s after the field returned.
    after = t >= 30.0 + 10.5
    np.testing.assert_array_equal(disturbed[after], disturbed_clean[after])
    np.testing.assert_array_equal(used[after], used_clean[after])
    assert used[after].mean() > 0.99
    # Meanwhile the heading went on with the gyro alone: close to the undisturbed run.
    from ccf_ros.core.metrics import error_angles

    assert np.degrees(np.abs(error_angles(q, q_clean)[1][bad])).max() < 0.67  # measured 0.554
    assert np.degrees(np.abs(error_angles(q, q_clean)[1][t >= 30.0])).max() < 0.87  # measured 0.721


def test_a_new_field_steady_for_mag_reaccept_s_becomes_the_reference():
    d = generate(120.0, 200.0, seed=6)
    t = d.t_s - d.t_s[0]
    mag = d.mag.copy()
    mag[t >= 20.0] *= 1.3  # e.g. the robot parked beside steel: a new normal
    p = CcfParams()
    used, disturbed, _ = _flags_per_sample(QuaternionCcf(p), d, mag)
    wait = (t >= 20.0) & (t < 20.0 + p.mag_reaccept_s)
    assert disturbed[wait].all() and not used[wait].any()
    after = t >= 20.0 + p.mag_reaccept_s + 0.01
    assert not disturbed[after].any() and used[after].all()


def test_the_reference_field_is_a_mean_not_the_first_sample():
    """A first magnetometer sample 4.5 % too strong (a MEMS sample scatters by ~1.5 %) must not bias the gate: with
    a one-sample reference 4 % of the normal field was rejected afterwards; learnt over mag_ref_learn_s, none is."""
    d = generate(60.0, 200.0, seed=21)
    t = d.t_s - d.t_s[0]
    mag = d.mag.copy()
    mag[0] *= 1.045
    used, _, _ = _flags_per_sample(QuaternionCcf(), d, mag)
    assert used[t < CcfParams().mag_ref_learn_s].all()  # learning: every sample is used
    assert used[t >= 10.0].mean() > 0.999  # measured 1.0 (a one-sample reference: 0.958)
    used0, _, _ = _flags_per_sample(QuaternionCcf(CcfParams(mag_ref_learn_s=0.0)), d, mag)
    assert used0[t >= 10.0].mean() < 0.99  # the lottery mag_ref_learn_s removes (measured 0.958)


@pytest.mark.parametrize(('seed', 'bound_deg'), [(22, 0.64), (23, 1.05)])
def test_started_while_moving_the_heading_converges(seed, bound_deg):
    """The filter started 30 s into strong hand-held motion (0.3 m translations: the first accelerometer samples
    tilt the start by tens of degrees): the reference field is learnt while the tilt converges, the bias integral
    waits for the start-up, and the heading is right from 30 s on. (A one-sample reference learnt on the wrong tilt
    rejected the true field: 45° RMS for seed 22, 3.4° for 23.)"""
    from ccf_ros.core.metrics import error_angles

    d = generate(150.0, 200.0, seed=seed, translation_m=0.3)
    k0 = 30 * 200
    r = run_batch(QuaternionCcf(), d.t_s[k0:], d.gyr[k0:], d.acc[k0:], d.mag[k0:])
    late = d.t_s[k0:] - d.t_s[k0] > 30.0
    head = np.degrees(np.abs(error_angles(r.quat, d.q_true[k0:])[1]))[late]
    assert np.sqrt(np.mean(head**2)) < bound_deg  # measured 0.53 (seed 22), 0.88 (seed 23)


def test_a_reference_learnt_through_the_start_ups_tilt_is_measured_again():
    """Started 30 s into strong hand-held motion (seed 19: the tilt ~30° off at first, 3° after the reference's 5 s
    of learning), the gate's dip is learnt -56.1° in the field of -60° (-54.6° in started_moving_heading.py's longer
    recording, where it then rejected the true field 76 % of the time). The LCF turned the tilt by 27° while it was
    learnt, more than mag_dip_tol_rad, so the dip is measured again once the start-up has ended (15-20 s), through
    the converged tilt; the norm agrees, so it is the same field. After a start at rest the tilt hardly moves (~1°):
    no second measurement, the reference stays as learnt."""
    true_dip = -60.0
    d = generate(60.0, 200.0, seed=19, translation_m=0.3)
    k0 = 30 * 200
    f = QuaternionCcf()
    run_batch(f, d.t_s[k0:], d.gyr[k0:], d.acc[k0:], d.mag[k0:])
    assert abs(math.degrees(math.asin(f._mag_ref[1])) - true_dip) < 1.5  # measured -59.41 (-56.15 learnt)
    d = generate(30.0, 100.0, seed=0)
    f = QuaternionCcf()
    run_batch(f, d.t_s[:600], d.gyr[:600], d.acc[:600], d.mag[:600])
    assert f._mag_recheck is None and f._mag_learn_s <= 0.0
    ref = f._mag_ref
    run_batch(f, d.t_s[600:], d.gyr[600:], d.acc[600:], d.mag[600:])
    assert f._mag_ref == ref


def test_started_mid_motion_without_magnetometer_the_tilt_is_not_learnt_as_bias():
    """6-D, started 30 s into strong hand-held motion (0.5 m translations at 100 Hz, linear accelerations to ~15 m/s²):
    the start-up leaves the tilt degrees off for seconds, and the bias learns only from a tilt error a bias could
    hold. (Learning from the tilt's hand-over on, its decay was read as drift: the bias went to 6-10 °/s and the
    inclination to 18-33° RMS.)"""
    incl, b_max = [], []
    for seed in range(4):
        d = generate(80.0, 100.0, seed, translation_m=0.5)
        k0 = 30 * 100
        r = run_batch(QuaternionCcf(CcfParams(use_mag=False)), d.t_s[k0:], d.gyr[k0:], d.acc[k0:])
        late = d.moving[k0:] & (d.t_s[k0:] - d.t_s[k0] > 10.0)
        incl.append(summarize(r.quat, d.q_true[k0:], late).inclination_rmse_deg)
        b_max.append(np.degrees(np.linalg.norm(r.bias, axis=1)).max())
    assert np.mean(incl) < 2.1, incl  # measured 1.74 (2.44, 1.72, 1.32, 1.49); before 25.8
    assert max(b_max) < 2.0, b_max  # measured 1.67 °/s at most; before 5.8-9.8


def test_started_gently_without_magnetometer_the_bias_learns_once_the_tilt_is_found():
    """6-D after a 0.5 s rest, the motion beginning gently (the simulator's 2 s ramp): the NCF's tilt error is one a
    bias could hold, so the bias learns from the tilt's hand-over (2.5 s) on, not only after the start-up (15 s)."""
    before, after = 0.0, 0.0
    for seed in range(4):
        d = generate(20.0, 40.0, seed, rest_s=0.5)
        r = run_batch(QuaternionCcf(CcfParams(use_mag=False)), d.t_s, d.gyr, d.acc)
        t = d.t_s - d.t_s[0]
        i_handover, i_10s = np.searchsorted(t, [2.4, 10.0])
        err = np.degrees(np.linalg.norm(r.bias - d.bias, axis=1))
        before += err[i_handover]
        after += err[i_10s]
    # Measured: 3.20 -> 1.35 °/s summed over the seeds (0.42); waiting for the start-up's end leaves it (1.01).
    assert after < 0.5 * before, (before, after)


def test_a_new_field_with_outliers_still_becomes_the_reference():
    """A new normal field (x1.3 from 20 s) with 10 % outlier samples (x1.5): single outliers do not restart the
    candidate; the leaky timer gains 0.9 - 3 x 0.1 = 0.6 s per second, so it takes ~mag_reaccept_s / 0.6."""
    d = generate(150.0, 200.0, seed=25)
    t = d.t_s - d.t_s[0]
    p = CcfParams()
    mag = d.mag.copy()
    mag[t >= 20.0] *= 1.3
    outlier = (t >= 20.0) & (np.random.default_rng(0).random(len(t)) < 0.1)
    mag[outlier] *= 1.5
    used, disturbed, _ = _flags_per_sample(QuaternionCcf(p), d, mag)
    first = t[np.flatnonzero((t >= 20.0) & used & ~outlier)[0]] - 20.0
    assert p.mag_reaccept_s < first < 1.2 * p.mag_reaccept_s / 0.6  # measured 33.8 s
    # The reference is then the candidate's mean without the outliers: every normal sample used from there on,
    # every outlier rejected (re-learning it with the gate open would average the outliers in).
    after = t > 20.0 + first
    assert used[after & ~outlier].all() and disturbed[after & outlier].all()


def test_a_large_heading_error_is_not_learnt_as_gyro_bias():
    """6-D start, then a magnetometer whose north is 90° from the start's heading: the NCF takes the whole error
    into its own heading, and its bias estimate none while the error, or the NCF's heading offset from the LCF's,
    exceeds 5°, so the (zero) bias stays small while the heading swings round. (Without the offset rule the decay of
    the NCF's error reads as 0.98°/s of bias; limiting only the error for both: 1.8°/s.)"""
    from ccf_ros.core.quaternion import quat_conj
    from ccf_ros.offline.simulate import MAG_WORLD

    d = generate(90.0, 200.0, seed=26, bias_init_rad_s=0.0, bias_walk_rad_s_sqrt_s=0.0)
    t = d.t_s - d.t_s[0]
    north_turned = np.array([MAG_WORLD[1], -MAG_WORLD[0], MAG_WORLD[2]])  # the field turned -90° about up
    mag = quat_rotate(quat_conj(d.q_true), np.broadcast_to(north_turned, (len(t), 3)))
    f = QuaternionCcf(CcfParams(rest_bias=False))
    bias = []
    for k in range(len(t)):
        f.update(float(d.t_s[k]), tuple(d.gyr[k]), tuple(d.acc[k]), tuple(mag[k]) if t[k] >= 10.0 else None)
        bias.append(f.gyro_bias)
    bias = np.degrees(np.abs(bias))
    assert bias[t > 10.0].max() < 0.042  # °/s; measured 0.035
    assert bias[-1].max() < 0.0062  # measured 0.0051


@pytest.mark.parametrize('motion_bias', [False, True])
def test_bias_uncertainty_schedule_rest_makes_it_small_motion_lets_it_grow(motion_bias):
    """The NCF's covariance: bias_sigma_rest after a rest; while moving it grows with the bias random walk alone
    without motion learning, and less with it, as the observations add what the walk takes away."""
    d = generate(65.0, 200.0, seed=7, rest_s=10.0, bias_walk_rad_s_sqrt_s=0.0)
    t = d.t_s - d.t_s[0]
    p = CcfParams(motion_bias=motion_bias)
    f = QuaternionCcf(p)
    assert f.gyro_bias_sigma_rad_s == p.bias_sigma_init_rad_s
    sigma = []
    for k in range(len(t)):
        f.update(float(d.t_s[k]), tuple(d.gyr[k]), tuple(d.acc[k]), tuple(d.mag[k]))
        sigma.append(f.gyro_bias_sigma_rad_s)
        if t[k] < 10.0:
            b_rest = f.gyro_bias
    sigma = np.degrees(sigma)
    end_rest = np.searchsorted(t, 10.0) - 1
    assert sigma[end_rest] < 0.024, sigma[end_rest]  # °/s: bias_sigma_rest_rad_s (0.02) reached (measured 0.0200)
    grow = np.degrees(p.bias_walk_rad_s_sqrt_s) ** 2 * (t[-1] - t[end_rest])
    err_rest = np.degrees(np.abs(np.subtract(b_rest, d.bias[-1]))).max()  # the rest estimate's noise, 0.014 °/s
    err_end = np.degrees(np.abs(f.gyro_bias - d.bias[-1])).max()
    if not motion_bias:
        # The variance grows by bias_walk² per second (random walk), and the rest estimate stays as it was.
        assert sigma[-1] ** 2 == pytest.approx(sigma[end_rest] ** 2 + grow, rel=0.05)
        assert np.all(np.diff(sigma[end_rest + 200:]) >= 0.0)
        assert err_end == err_rest
    else:
        # Learning while moving holds the uncertainty below the walk's (measured 0.045 against 0.077 °/s) and
        # improves on the rest estimate (error measured 0.0077 against 0.0141 °/s).
        assert sigma[end_rest:].max() ** 2 < 0.42 * (sigma[end_rest] ** 2 + grow)  # measured 0.35
        assert err_end < 0.0093 and err_rest > 1.5 * err_end, (err_end, err_rest)


def test_a_longer_rest_min_s_set_live_ends_the_rest_until_the_timer_reaches_it():
    """set_params with a longer rest_min_s while at rest: not at rest (the NCF integral and the bias random walk run
    again) until the rest has lasted the new minimum."""
    rate = 100.0
    f = QuaternionCcf(CcfParams(use_mag=False, rest_min_s=1.0))
    gyr, acc = (0.001, -0.002, 0.0015), (0.0, 0.0, 9.80665)
    k = 0
    for k in range(300):  # 3 s at rest
        f.update(k / rate, gyr, acc)
    assert f.at_rest
    f.set_params(dataclasses.replace(f.params, rest_min_s=10.0))
    assert not f.at_rest
    first = None
    for j in range(k + 1, k + 1 + 1000):  # 10 s more
        f.update(j / rate, gyr, acc)
        if first is None and f.at_rest:
            first = j / rate
    assert first is not None and 9.9 <= first <= 10.1, first  # the rest began at 0 s


def test_rotation_vectors_invert_quat_from_rotvec_either_sign():
    from ccf_ros.core.quaternion import quat_from_rotvec, quat_to_rotvec

    rng = np.random.default_rng(3)
    r = rng.standard_normal((200, 3))
    r *= (rng.uniform(0.0, 0.999 * np.pi, 200) / np.linalg.norm(r, axis=1))[:, None]
    r[0] = 0.0  # the identity: the limit, not 0/0
    q = quat_from_rotvec(r)
    np.testing.assert_allclose(quat_to_rotvec(q), r, atol=1e-12)
    np.testing.assert_allclose(quat_to_rotvec(-q), r, atol=1e-12)  # -q is the same rotation


def test_fitted_total_removes_a_constant_heading_offset_and_nothing_else():
    """The 6-D score: a constant turn about up is fitted away, a tilt error is not."""
    from ccf_ros.core.metrics import fitted_total_rmse_deg, summarize
    from ccf_ros.core.quaternion import euler_to_quat

    rng = np.random.default_rng(3)
    n = 500
    q_ref = euler_to_quat(rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), rng.uniform(-3, 3, n))
    turn = euler_to_quat(0.0, 0.0, np.radians(7.0))
    tilt = euler_to_quat(np.radians(0.5), 0.0, 0.0)
    q_est = quat_mul(turn, q_ref)
    assert summarize(q_est, q_ref).total_rmse_deg == pytest.approx(7.0, abs=1e-6)
    assert fitted_total_rmse_deg(q_est, q_ref) < 1e-3
    q_est = quat_mul(tilt, quat_mul(turn, q_ref))
    assert fitted_total_rmse_deg(q_est, q_ref) == pytest.approx(0.5, abs=1e-3)
    # Unscored samples and missing estimates stay out of the fit; a missing one counts 180° in the score.
    q_est[:10] = np.nan
    mask = np.ones(n, bool)
    mask[10:20] = False
    expected = np.sqrt((10 * 180.0**2 + (n - 20) * 0.5**2) / (n - 10))
    assert fitted_total_rmse_deg(q_est, q_ref, mask) == pytest.approx(expected, rel=1e-3)


def _steady_turn(rate_deg_s: float, bias_deg_s: tuple[float, float, float], seed: int = 0):
    """10 s at rest, then 60 s turning about the vertical at ``rate_deg_s`` (a tracked robot turning in place, so
    steady that the accelerometer cannot tell), then 20 s at rest; 100 Hz, a gyro offset ``bias_deg_s``."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 90.0, 0.01)
    w = np.where((t >= 10.0) & (t < 70.0), math.radians(rate_deg_s), 0.0)
    gyr = np.zeros((len(t), 3))
    gyr[:, 2] = w
    gyr += np.radians(bias_deg_s) + rng.normal(0.0, 0.005, gyr.shape)
    acc = np.tile([0.0, 0.0, 9.81], (len(t), 1)) + rng.normal(0.0, 0.05, gyr.shape)
    return t + 1.7e9, gyr, acc


def test_a_slow_steady_turn_after_a_rest_is_not_learnt_as_bias():
    """6-D, no hint: the bias seen at the first rest does not jump to a 1 °/s turn that the accelerometer cannot see
    (imu_tools #87); the rest after it is a rest again."""
    t, gyr, acc = _steady_turn(1.0, (0.3, -0.2, 0.4))
    r = run_batch(make_filter({'use_mag': False}), t, gyr, acc, None)
    rel = t - t[0]
    err_z = np.degrees(np.abs(r.bias[:, 2] - math.radians(0.4)))
    assert err_z[(rel > 8.0) & (rel < 10.0)].max() < 0.05  # learnt at the first rest
    # Measured 0.086 °/s (what the rest low-pass took in before the turn stood out; without the rule: learnt as
    # bias, 1.06 °/s off).
    assert err_z[(rel >= 10.0) & (rel < 70.0)].max() < 0.105, err_z[(rel >= 10.0) & (rel < 70.0)].max()


@pytest.mark.parametrize('offset_deg_s', [5.0, 10.0])
def test_a_consumer_mems_offset_of_several_deg_per_s_is_learnt_at_the_first_rest(offset_deg_s):
    """The bias clamp is 15 °/s and the accelerometer's stillness is judged in the body, not against the gravity the
    (still uncorrected) gyro carries: a 5 or 10 °/s offset is learnt at the start-up rest."""
    t, gyr, acc = _steady_turn(0.0, (offset_deg_s, -offset_deg_s, offset_deg_s))
    r = run_batch(make_filter({'use_mag': False}), t, gyr, acc, None)
    rel = t - t[0]
    err = np.degrees(np.abs(r.bias - np.radians([offset_deg_s, -offset_deg_s, offset_deg_s]))).max(axis=1)
    assert err[rel > 8.0].max() < 0.077, err[rel > 8.0].max()  # measured 0.064 °/s for both


def _flip(rate_hz: float = 200.0, seed: int = 0, t_hit_s: float = 20.0, dur_s: float = 0.3, axis=(1.0, 0.0, 0.0)):
    """30 s of slow sway with a 360° flip about ``axis`` (unit, body frame; default roll) in ``dur_s`` at ``t_hit_s``
    (peak 2400 °/s); exact attitude, no linear acceleration. Returns t (s), gyro, acc, mag, q_true."""
    from ccf_ros.core.quaternion import quat_conj, quat_from_rotvec, quat_mul, quat_rotate

    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    t = np.arange(0.0, 30.0, dt)
    w = np.zeros((len(t), 3))
    w[:, 2] = math.radians(20.0) * np.sin(2 * np.pi * 0.1 * t)
    w[:, 1] = math.radians(10.0) * np.sin(2 * np.pi * 0.13 * t)
    hit = (t >= t_hit_s) & (t < t_hit_s + dur_s)
    w[hit] += np.outer((4 * np.pi / dur_s) * np.sin(np.pi * (t[hit] - t_hit_s) / dur_s) ** 2, axis)
    q = np.zeros((len(t), 4))
    q[0] = [1.0, 0.0, 0.0, 0.0]
    for i in range(1, len(t)):
        q[i] = quat_mul(q[i - 1], quat_from_rotvec(0.5 * (w[i - 1] + w[i]) * dt))
        q[i] /= np.linalg.norm(q[i])
    qc = quat_conj(q)
    acc = quat_rotate(qc, np.tile([0.0, 0.0, 9.81], (len(t), 1))) + rng.normal(0.0, 0.05, w.shape)
    mag = quat_rotate(qc, np.tile([0.0, 20e-6, -40e-6], (len(t), 1))) + rng.normal(0.0, 0.5e-6, w.shape)
    return t + 1.7e9, w + rng.normal(0.0, 0.005, w.shape), acc, mag, q


def test_a_gyro_clipped_at_its_range_is_counted_and_the_attitude_recovers_within_2_s():
    """x-io Fusion's gyroscopeRange case: a 2400 °/s flip on a 2000 °/s gyro. Integrated as if true, it leaves the
    attitude 18° off for many seconds; with gyro_range_rad_s the blends restart and it is back within 2 s."""
    from ccf_ros.core.metrics import error_angles

    t, gyr, acc, mag, q = _flip()
    rel = t - t[0]
    full = math.radians(2000.0)
    clipped = np.clip(gyr, -full, full)
    at = np.searchsorted(rel, 22.3)  # 2 s after the flip
    clean = run_batch(make_filter({}), t, gyr, acc, mag)
    f = make_filter({'gyro_range_rad_s': full})
    hit = run_batch(f, t, clipped, acc, mag)
    blind = run_batch(make_filter({}), t, clipped, acc, mag)
    err = {k: np.degrees(error_angles(r.quat, q)[0]) for k, r in (('clean', clean), ('hit', hit), ('blind', blind))}
    assert f.n_gyro_clipped == int((np.abs(clipped) >= 0.998 * full).any(axis=1).sum()) > 0
    # Measured 9-D: 0.19° 2 s after (clean run 0.33°; without the range 18.3°).
    assert err['hit'][at] <= 2.0 * err['clean'][at], (err['hit'][at], err['clean'][at])
    assert err['blind'][at] > 10.0
    # 6-D: the heading the flip missed is lost for good, the inclination is not (measured 0.04°, without 14°).
    f6 = make_filter({'gyro_range_rad_s': full, 'use_mag': False})
    inc6 = np.degrees(error_angles(run_batch(f6, t, clipped, acc, None).quat, q)[2])
    assert inc6[at] < 0.1, inc6[at]


def _engine_run(settings, t, gyr, acc, mag, chunk=False):
    """Through ImuEngine: on_mag/on_imu per sample, or one on_chunk. Returns (engine, quaternions [w, x, y, z])."""
    from ccf_ros.engine import ImuEngine
    from ccf_ros.settings import build

    eng = ImuEngine(*build(settings))
    if chunk:
        n = len(t)
        is_imu = [False, True] * n
        ts = np.repeat(t, 2).tolist()
        v1 = np.empty((2 * n, 3))
        v1[0::2], v1[1::2] = mag, gyr
        v2 = np.zeros((2 * n, 3))
        v2[1::2] = acc
        ans = eng.on_chunk(is_imu, ts, tuple(v1.T.tolist()), tuple(v2.T.tolist()))
        assert ans.answered == list(range(n))
        return eng, np.array(ans.quaternion).reshape(-1, 4)
    quats = []
    for k in range(len(t)):
        eng.on_mag(float(t[k]), tuple(mag[k]))
        x, y, z, w = eng.on_imu(float(t[k]), tuple(gyr[k]), tuple(acc[k])).orientation_xyzw
        quats.append((w, x, y, z))
    return eng, np.array(quats)


def test_a_gyro_clipped_at_its_range_is_seen_on_the_raw_readings_with_a_mount_rotation_and_an_offset():
    """gyro_range_rad_s is the sensor's, per axis of its raw readings: with mount_rotation [0, 0, π/4] a flip about
    the IMU's x clipped at 2000 °/s is ~1414 °/s on the output frame's axes (never flagged before: 0 counted). The
    engine checks the raw reading, in on_imu and in on_chunk (its general path), and the attitude recovers as
    without a mount."""
    from ccf_ros.core.metrics import error_angles
    from ccf_ros.frames import rotation_matrix

    mount = [0.0, 0.0, math.pi / 4]
    rot = np.array(rotation_matrix('mount_rotation', mount)).reshape(3, 3)  # IMU -> output frame
    off = np.array([0.01, -0.02, 0.015])
    t, gyr, acc, mag, q = _flip(axis=tuple(rot[:, 0]))  # (the output frame's motion: about the IMU's x)
    raw_gyr = gyr @ rot + off  # v_imu = R^T v_out (+ the offset the engine subtracts)
    raw_acc, raw_mag = acc @ rot, mag @ rot
    full = math.radians(2000.0)
    clipped = np.clip(raw_gyr, -full, full)
    n_clip = int((np.abs(clipped) >= 0.998 * full).any(axis=1).sum())
    settings = {'gyro_range_rad_s': full, 'mount_rotation': mount, 'gyro_offset_rad_s': off.tolist()}
    rel = t - t[0]
    at = np.searchsorted(rel, 22.3)  # 2 s after the flip
    _, clean = _engine_run({**settings, 'gyro_range_rad_s': 0.0}, t, raw_gyr, raw_acc, raw_mag)
    eng, hit = _engine_run(settings, t, clipped, raw_acc, raw_mag)
    eng_c, hit_c = _engine_run(settings, t, clipped, raw_acc, raw_mag, chunk=True)
    assert eng.n_gyro_clipped == eng_c.n_gyro_clipped == n_clip > 0, (eng.n_gyro_clipped, eng_c.n_gyro_clipped, n_clip)
    np.testing.assert_array_equal(hit_c, hit)
    e_clean, e_hit = (np.degrees(error_angles(r, q)[0]) for r in (clean, hit))
    # Measured 0.32° 2 s after (clean 0.33°; the old code, which counted none: 16.8°).
    assert e_hit[at] <= 2.0 * e_clean[at], (e_hit[at], e_clean[at])


def test_a_field_that_varies_with_position_steers_neither_heading_nor_tilt():
    """Issue 23's arm-chain case: hand-guided motion through a field a dipole 1.2 m away turns by tens of degrees over
    the workspace. The magnetometer must not make heading worse than the filter's own 6-D, and never touch tilt."""
    from ccf_ros.core.metrics import fitted_total_rmse_deg, summarize
    from ccf_ros.offline.simulate import generate_near_dipole

    d = generate_near_dipole(286.0, 1)
    q9 = run_batch(make_filter({}), d.t_s, d.gyr, d.acc, d.mag).quat
    q6 = run_batch(make_filter({'use_mag': False}), d.t_s, d.gyr, d.acc, None).quat
    s9, s6 = summarize(q9, d.q_true, d.moving), summarize(q6, d.q_true, d.moving)
    # Measured: inclination 0.298 vs 0.285 deg (1.047x); total with one heading offset fitted 0.63 vs 0.45 deg, and
    # 3.21 deg with the check off (the norm and dip gate alone let the turned field in).
    assert s9.inclination_rmse_deg < 1.1 * s6.inclination_rmse_deg, (s9.inclination_rmse_deg, s6.inclination_rmse_deg)
    h9, h6 = fitted_total_rmse_deg(q9, d.q_true, d.moving), fitted_total_rmse_deg(q6, d.q_true, d.moving)
    assert h9 < h6 + 0.5, (h9, h6)
    off = run_batch(make_filter({'mag_consistency_rad': 0.0}), d.t_s, d.gyr, d.acc, d.mag).quat
    assert fitted_total_rmse_deg(off, d.q_true, d.moving) > 2.0 * h9, (fitted_total_rmse_deg(off, d.q_true, d.moving), h9)


def _level_imu(t: np.ndarray, yaw: np.ndarray, yaw_rate: np.ndarray, bias_up: float = 0.0):
    """A level IMU turning about up (yaw rad, its rate rad/s, each ``(N,)``) in a homogeneous field, 100 Hz-grade noise
    (seed 0): (q_true, gyr, acc, mag), the gyro with ``bias_up`` rad/s about its z."""
    from ccf_ros.core.quaternion import quat_conj, quat_from_rotvec
    from ccf_ros.offline.simulate import MAG_WORLD

    q = quat_from_rotvec(np.outer(yaw, [0.0, 0.0, 1.0]))
    rng = np.random.default_rng(0)
    gyr = np.outer(yaw_rate, [0.0, 0.0, 1.0]) + [0.0, 0.0, bias_up] + rng.normal(0.0, 0.002, (len(t), 3))
    acc = quat_rotate(quat_conj(q), np.array([0.0, 0.0, 9.81])) + rng.normal(0.0, 0.02, (len(t), 3))
    mag = quat_rotate(quat_conj(q), MAG_WORLD) + rng.normal(0.0, 0.2e-6, (len(t), 3))
    return q, gyr, acc, mag


@pytest.mark.parametrize('yaw_deg', [30.0, 120.0, 179.0])
def test_a_magnetometer_that_arrives_late_is_acquired_without_looking_like_a_turning_field(yaw_deg):
    """The magnetometer's first sample 3 s after the IMU's (a node whose magnetometer topic comes later), the sensor
    lying still at a heading of `yaw_deg`: heading is re-acquired with a step of that size within one bias-update
    block. Its samples, summed through the attitude before and after the step, once seeded the consistency band with
    a direction between the two, which the band then read as the field's motion: the field was weighted down (to
    0.27 / 0.07 / 0.05) for ~20 s, at 120° and 179° rejected outright."""
    t = np.arange(0.0, 30.0, 0.01)
    _, gyr, acc, mag = _level_imu(t, np.full(len(t), math.radians(yaw_deg)), np.zeros(len(t)))
    f = QuaternionCcf()
    weights, yaw_err = [], []
    for i in range(len(t)):
        f.update(1.7e9 + t[i], tuple(gyr[i]), tuple(acc[i]), tuple(mag[i]) if t[i] >= 3.0 else None)
        weights.append(f._mag_weight if f._mag_consistent else 0.0)
        yaw_err.append(math.degrees(math.remainder(2.0 * math.atan2(f.quaternion[3], f.quaternion[0])
                                                   - math.radians(yaw_deg), 2.0 * math.pi)))
    late = np.abs(np.array(yaw_err))[t >= 10.0]
    band_rms_deg = math.degrees(math.sqrt(f._mag_band[6]))
    # Measured: the weight 1.0 throughout; heading within 0.03 / 0.06 / 0.11° from 10 s on (before: 0.05 / 1.43 /
    # 2.89°, the field rejected or weighted down for the rest of the run); the band's RMS at the end 0.025 / 0.028 /
    # 0.029° (before 0.56 / 2.2 / 3.2°): the check runs, and sees a field that stays put.
    assert min(weights) == 1.0, min(weights)
    assert late.max() < 0.13, late.max()
    assert band_rms_deg < 0.036, band_rms_deg


def test_a_heading_set_in_9d_turns_the_gate_s_world_frame_filters_with_the_attitude():
    """Level turns back and forth in a homogeneous field; at 20 s the heading is set 31° off (the core's
    set_heading, 9-D): the field seen through the attitude turns with it, and so do the consistency check's filters,
    so that the field keeps steering heading and the blend brings it back to north over tau_mag_s (before, the band
    read the turn as the field's motion and weighted it down to 0.46)."""
    from ccf_ros.core.quaternion import rpy_of

    t = np.arange(0.0, 40.0, 0.01)
    yaw = 1.0 - np.cos(0.5 * t)
    _, gyr, acc, mag = _level_imu(t, yaw, 0.5 * np.sin(0.5 * t))
    f = QuaternionCcf()
    weights, err, band_rms = [], [], []
    for i in range(len(t)):
        if i == 2000:
            f.set_heading(1.3)
        f.update(1.7e9 + t[i], tuple(gyr[i]), tuple(acc[i]), tuple(mag[i]))
        if i >= 2000:
            weights.append(f._mag_weight if f._mag_consistent else 0.0)
            err.append(math.degrees(math.remainder(rpy_of(f.quaternion)[2] - yaw[i], 2.0 * math.pi)))
            band_rms.append(math.degrees(math.sqrt(f._mag_band[6])))
    # The blend alone (heading known: no re-acquisition) takes the set error back as exp(-t / tau_mag_s).
    expected = abs(err[0]) * math.exp(-(len(err) - 1) * 0.01 / CcfParams().tau_mag_s)
    # Measured: weight 1.0; -31.0° at the set, -8.0° 20 s later against 8.2° expected (before: 12.5°); the band's RMS
    # at most 0.050° (0.161° with the block's field sum left unturned by the set).
    assert min(weights) == 1.0, min(weights)
    assert 29.0 < abs(err[0]) < 33.0, err[0]
    assert 0.8 * expected < abs(err[-1]) < 1.2 * expected, (err[0], err[-1], expected)
    assert max(band_rms) < 0.06, max(band_rms)


def test_a_bias_along_up_beyond_the_heading_rows_5_degrees_is_learnt_from_its_steady_lag():
    """Level turns back and forth in a homogeneous field, no rest, a gyro bias of 1.4 °/s about up (2.8 sigma of the
    prior): the blend lags the field by b tau_mag_s and the NCF by b tau_ncf_s, so the stages' headings differ by a
    steady 17°, beyond the ±5° of the heading rows. Held that long, it is taken for a bias's lag and learnt. (With
    the ±5° alone the bias stayed unlearnt, a level body shows it to no tilt row, and heading lagged by 24°.)"""
    from ccf_ros.core.quaternion import rpy_of

    t = np.arange(0.0, 150.0, 0.01)
    yaw = 1.0 - np.cos(0.5 * t)
    _, gyr, acc, mag = _level_imu(t, yaw, 0.5 * np.sin(0.5 * t), bias_up=math.radians(1.4))
    f = QuaternionCcf()
    err = []
    for i in range(len(t)):
        f.update(1.7e9 + t[i], tuple(gyr[i]), tuple(acc[i]), tuple(mag[i]))
        err.append(math.degrees(math.remainder(rpy_of(f.quaternion)[2] - yaw[i], 2.0 * math.pi)))
    late = t >= 120.0
    # Measured: heading 0.15° RMS over 120-150 s, the bias 1.396 °/s (before: 24.3°, 0.000 °/s).
    assert np.sqrt(np.mean(np.square(err)[late])) < 0.2
    assert abs(math.degrees(f.gyro_bias[2]) - 1.4) < 0.01


def test_started_moving_in_a_slowly_turning_field_its_turn_is_not_taken_for_a_bias_s_lag():
    """Started while moving through a dipole's field that turns slowly (a crossing of the workspace every ~20 s):
    the stages' heading difference the turn opens passes through steady moments, at its peaks, which the rule for
    a bias's steady lag must not take (it holds for tau_mag_s). '300/1.2 across slow' of `experiments/field_sweep.py
    --rest 0.5 --bias-deg 0.15`, 12 seeds."""
    m9, m6 = _started_moving_in_a_dipole(300.0, 1.2, 0.15, range(12), band_hz=(0.022, 0.028))
    # Measured (9-D, 6-D): (3.83, 2.32); taking the steady moments without the hold: 9-D 5.40.
    assert m9 < 4.5, (m9, m6)


def test_a_heading_set_while_a_new_field_is_timed_does_not_delay_its_acceptance():
    """Level turns back and forth; from 10 s a new homogeneous field (turned 40° about up, 1.2x: another building)
    is rejected and timed as the candidate for mag_reaccept_s. A heading set meanwhile (set_heading, 9-D) turns the
    candidate's world-frame band with the attitude, so the set is not read as the candidate moving: it is accepted
    when it is without the set (measured: at 30.01 s with or without; the candidate's band left unturned: 35.7,
    32.2, 42.9 s for sets at 15, 20, 25 s)."""
    from ccf_ros.core.quaternion import quat_conj, quat_from_rotvec
    from ccf_ros.offline.simulate import MAG_WORLD

    t = np.arange(0.0, 45.0, 0.01)
    yaw = 1.0 - np.cos(0.5 * t)
    q, gyr, acc, mag = _level_imu(t, yaw, 0.5 * np.sin(0.5 * t))
    new = 1.2 * quat_rotate(quat_from_rotvec(np.array([0.0, 0.0, 0.7])), np.asarray(MAG_WORLD, float))
    moved = t >= 10.0
    mag[moved] = quat_rotate(quat_conj(q[moved]), new) + np.random.default_rng(1).normal(0.0, 0.2e-6, (moved.sum(), 3))

    def accepted_at(set_at: float | None) -> float:
        f = QuaternionCcf()
        for i in range(len(t)):
            if set_at is not None and i == round(set_at * 100):
                f.set_heading(1.3)
            f.update(1.7e9 + t[i], tuple(gyr[i]), tuple(acc[i]), tuple(mag[i]))
            if t[i] > 10.5 and not f.mag_disturbed:
                return float(t[i])
        return math.inf

    clean = accepted_at(None)
    assert 10.0 + CcfParams().mag_reaccept_s < clean < 10.0 + 1.2 * CcfParams().mag_reaccept_s, clean
    for set_at in (15.0, 20.0, 25.0):
        assert abs(accepted_at(set_at) - clean) < 0.5, set_at


@pytest.mark.parametrize('band_hz', [(0.02, 0.08), (0.022, 0.028)])
def test_a_field_that_turns_during_the_start_up_does_not_drag_heading(band_hz):
    """A stronger dipole (600 A m², 1.2 m) turns the field at the start by ~100°, and the hand carries the sensor
    through it within the 15 s start-up, whose heading blend is a running mean: the consistency check runs once the
    tilt is found, not only after the start-up. 40 Hz, 67 s after a 5 s rest, as `experiments/field_sweep.py`
    (seed 5 of '600/1.2 across' and '600/1.2 across slow')."""
    from ccf_ros.core.metrics import fitted_total_rmse_deg, summarize
    from ccf_ros.offline.simulate import dipole_beside, wander_path

    rng = np.random.default_rng(1005)
    d = generate(67.0, 40.0, 5, translation_m=0.1, field=dipole_beside(rng, 600.0, 1.2),
                 path_m=wander_path(0.35, rng, band_hz=band_hz))
    q9 = run_batch(make_filter({}), d.t_s, d.gyr, d.acc, d.mag).quat
    q6 = run_batch(make_filter({'use_mag': False}), d.t_s, d.gyr, d.acc, None).quat
    h9, h6 = fitted_total_rmse_deg(q9, d.q_true, d.moving), fitted_total_rmse_deg(q6, d.q_true, d.moving)
    # Measured 9-D minus 6-D: +0.07 and +0.02, inclination 1.02x the 6-D's (with the check only after the start-up,
    # before 2026-12-07: +8.6 and +9.3).
    assert h9 < h6 + 0.5, (h9, h6)
    s9, s6 = summarize(q9, d.q_true, d.moving), summarize(q6, d.q_true, d.moving)
    assert s9.inclination_rmse_deg < 1.1 * s6.inclination_rmse_deg, (s9.inclination_rmse_deg, s6.inclination_rmse_deg)


def _slower_magnetometer(mag: np.ndarray, every: int, mode: str) -> np.ndarray:
    """``mag`` (N, 3) as a magnetometer at 1/``every`` of the IMU's rate delivers it: each sample held until the next
    (``'held'``, as the engine pairs them) or NaN rows between them (``'missing'``: no sample)."""
    if every == 1:
        return mag
    if mode == 'held':
        return mag[np.arange(len(mag)) // every * every]
    out = np.full_like(mag, np.nan)
    out[::every] = mag[::every]
    return out


def _started_moving_in_a_dipole(moment: float, dist_m: float, bias_deg_s: float, seeds: range | list[int],
                                mag_every: int = 1, mode: str = 'held', *, orient: str = 'across',
                                band_hz: tuple[float, float] = (0.02, 0.08), rest_s: float = 0.5,
                                amplitude_m: float = 0.35, settings: dict | None = None) -> tuple[float, float]:
    """Mean over ``seeds`` of the (9-D, 6-D) heading RMSE (one offset fitted each), degrees: 67 s at 40 Hz after a
    ``rest_s`` rest, the hand wandering by ``amplitude_m`` through a dipole's field as `experiments/field_sweep.py
    --rest R --bias-deg B` runs it (a bias drawn with σ ``bias_deg_s`` °/s per axis); the magnetometer at
    1/``mag_every`` of the rate; the 9-D filter with ``settings``."""
    from ccf_ros.core.metrics import fitted_total_rmse_deg
    from ccf_ros.offline.simulate import dipole_beside, wander_path

    h = []
    for seed in seeds:
        rng = np.random.default_rng(1000 + seed)
        d = generate(67.0, 40.0, seed, rest_s=rest_s, translation_m=0.1, field=dipole_beside(rng, moment, dist_m, orient),
                     path_m=wander_path(amplitude_m, rng, rest_s, band_hz=band_hz),
                     bias_init_rad_s=math.radians(bias_deg_s))
        mag = _slower_magnetometer(d.mag, mag_every, mode)
        q9 = run_batch(make_filter(settings or {}), d.t_s, d.gyr, d.acc, mag).quat
        q6 = run_batch(make_filter({'use_mag': False}), d.t_s, d.gyr, d.acc, None).quat
        h.append((fitted_total_rmse_deg(q9, d.q_true, d.moving), fitted_total_rmse_deg(q6, d.q_true, d.moving)))
    m9, m6 = np.mean(h, axis=0)
    return float(m9), float(m6)


@pytest.mark.parametrize(('moment', 'dist_m', 'seed', 'measured'), [(600.0, 1.2, 8, (5.78, 14.98)),
                                                                     (3000.0, 1.5, 7, (2.63, 10.11))])
def test_started_moving_in_a_turning_field_a_heading_re_acquired_weighs_it_as_the_blend(moment, dist_m, seed, measured):
    """Started while moving with a bias of σ 0.5 °/s per axis (the 6-D heading drifts) through a field that turns:
    the magnetometer still helps, because a heading re-acquired after the field was weighted down takes it with the
    blend's weight (without, before the band's curvature was judged: 9-D 8.72 and 7.30). '600/1.2 across' seed 8 and '3000/1.5 across' seed 7 of
    `experiments/field_sweep.py --rest 0.5`."""
    m9, m6 = _started_moving_in_a_dipole(moment, dist_m, 0.5, [seed])
    # Measured (9-D, 6-D): `measured`.
    assert m9 < 0.5 * m6, (m9, m6, measured)


@pytest.mark.parametrize(('moment', 'dist_m', 'bias_deg_s', 'mag', 'measured', 'before'), [
    (300.0, 1.2, 0.15, (1, ''), (2.95, 2.65), (5.11, 2.65)),
    (300.0, 1.2, 0.15, (4, 'missing'), (2.39, 2.65), (4.39, 2.65)),
    (300.0, 1.2, 0.15, (4, 'held'), (2.91, 2.65), (5.07, 2.65)),
    (3000.0, 1.5, 0.5, (1, ''), (2.82, 4.97), (3.97, 4.97)),
    (600.0, 1.2, 0.5, (1, ''), (2.90, 4.97), (5.02, 4.97)),
])
def test_started_moving_in_a_turning_field_the_bias_does_not_learn_its_turn(moment, dist_m, bias_deg_s, mag, measured,
                                                                             before):
    """Started while moving through a field that turns (seeds 0-5 of the sweep's layout): a field that returns after
    a rejection neither teaches the bias (its heading rows) nor re-acquires heading whole until it has steered
    heading steadily for MAG_BAND_S[1]. Before that rule (`before`: 9-D, 6-D) it passed the check for a few seconds
    while turning slowly, the bias learnt its turn (0.4-0.5 °/s along world up with a bias of σ 0.15 °/s), and
    nothing corrected it while the field was rejected again. With a small bias the 9-D heading stays near the 6-D's;
    with a large one (the 6-D heading drifts) the magnetometer helps. `mag`: the magnetometer at 1/n of the IMU's 40
    Hz, its samples missing in between or held."""
    m9, m6 = _started_moving_in_a_dipole(moment, dist_m, bias_deg_s, range(6), *mag)
    # Measured (9-D, 6-D): `measured`.
    if bias_deg_s < 0.3:
        assert m9 < m6 + 0.7, (m9, m6, measured)
    else:
        assert m9 < 0.7 * m6, (m9, m6, measured)


def test_after_a_rest_a_slowly_turning_field_is_allowed_only_the_drift_the_bias_could_have_given():
    """A weak dipole crossed slowly (300 A m², 1.2 m, ±0.2 m at ~0.025 Hz: the field turns by 5-8° RMS) after a 5 s
    rest (`experiments/field_sweep.py --rest 5 --bias-deg 0.15`, '300/1.2 across A0.2 slow', seeds 1, 3, 5, 10). The
    consistency check starts 2.5 s in, while the rest is still teaching the bias (its relative variance 0.14). The
    allowance for an unknown bias's drift is that drift as the band shows it, a ramp at the bias's 2σ band-passed
    like the field, which stays below 0.9° since the bias was learnt a second later. When it held the bias's
    uncertainty at the check's start for the band's memory (before 2026-12-07), its drift term was 3.0° of band RMS at
    the start, 1.5° at 15 s, 1.2° at 20 s, the field passed and dragged heading: 9-D 1.61 / 1.60 / 4.17 / 1.41 (mean
    2.20) against 6-D 0.70 / 1.05 / 0.79 / 0.80."""
    m9, m6 = _started_moving_in_a_dipole(300.0, 1.2, 0.15, [1, 3, 5, 10], band_hz=(0.022, 0.028), rest_s=5.0,
                                         amplitude_m=0.2)
    # Measured: 9-D 0.92 (0.89 / 1.19 / 0.79 / 0.80), 6-D 0.84.
    assert m9 < 1.2 * 0.92, (m9, m6)
    assert m9 < m6 + 0.2, (m9, m6)


@pytest.mark.parametrize(('moment', 'measured', 'before'), [(600.0, (2.87, 2.65), (3.29, 2.65)),
                                                            (1000.0, (2.97, 2.65), (3.24, 2.65))])
def test_started_moving_in_a_wandering_field_its_curvature_rejects_it_while_the_bias_is_unknown(moment, measured,
                                                                                                 before):
    """Started while moving with a bias of σ 0.15 °/s (seeds 0-5 of `experiments/field_sweep.py --rest 0.5`'s
    '600/1.2 across' and '1000/1.2 across': the field's direction spreads 20-25° RMS as the hand wanders through it).
    Until the bias is learnt, the consistency band allows for the drift it may give the attitude (~8° RMS over the
    band), and the field passed while it turned by tens of degrees. The band's curvature does not see a drift at a
    steady rate, so it is held to the homogeneous field's wander alone (and the change of rate while the bias is
    learnt): the field is weighted down from the start. Before (`before`: 9-D, 6-D) the 9-D heading was 0.6° worse
    than the 6-D's."""
    m9, m6 = _started_moving_in_a_dipole(moment, 1.2, 0.15, range(6))
    # Measured (9-D, 6-D): `measured`.
    assert m9 < m6 + 0.5, (m9, m6, measured)


def test_without_bias_from_mag_the_magnetometer_holds_heading_but_never_teaches_the_bias():
    """Level turns back and forth (yaw rate 0.5 sin(0.5 t) rad/s, 100 Hz, 180 s, never at rest) with a gyro bias of
    0.3 °/s along world up, which gravity cannot see: by default the magnetometer's heading errors teach it; with
    bias_from_mag false (or motion_bias false: nothing learnt while moving, as the drop-ins' do_bias_estimation
    false) the bias stays unlearnt and the heading blend alone holds heading, lagging by bias x tau_mag_s, and the
    reported yaw variance says so."""
    from ccf_ros.core.metrics import error_angles

    t = np.arange(0.0, 180.0, 0.01)
    # (yaw = the rate's integral)
    q, gyr, acc, mag = _level_imu(t, 1.0 - np.cos(0.5 * t), 0.5 * np.sin(0.5 * t), math.radians(0.3))
    late = t > 60.0
    lag = 0.3 * CcfParams().tau_mag_s
    for settings in ({}, {'bias_from_mag': False}, {'motion_bias': False}):
        f = make_filter(settings)
        r = run_batch(f, t + 1.7e9, gyr, acc, mag)
        heading = np.degrees(np.abs(error_angles(r.quat, q)[1]))[late]
        rms = np.sqrt(np.mean(heading**2))
        sigma = np.degrees(np.sqrt(np.mean(r.variance[late, 2])))
        assert f.estimate()[1] == f.orientation_variance  # the engine's read and the property agree
        bz = math.degrees(f.gyro_bias[2])
        if not settings:
            # Measured: bias 0.304 °/s, heading error at most 0.25°.
            assert abs(bz - 0.3) < 0.03 and heading.max() < 0.3, (bz, heading.max())
            continue
        # Measured: bias 0.000 °/s; heading RMS 4.49° against 0.3 °/s x 15 s = 4.5°. The reported yaw σ covers the
        # lag: the bias's σ along world up (0.5 °/s, the prior: gravity sees only the horizontal) x tau_mag_s, 7.69°
        # (σ/RMS 1.71; 1.70° = 0.38 without the lag's share).
        assert abs(bz) < 0.01, (settings, bz)
        assert 0.8 * lag < rms < 1.2 * lag, (settings, rms)
        assert 1.0 < sigma / rms < 2.0, (settings, sigma, rms)


@pytest.mark.parametrize(('orient', 'measured'), [('across', (3.90, 1.95, 2.00)), ('vertical', (3.22, 2.14, 2.00))])
def test_started_moving_in_a_slowly_turning_field_bias_from_mag_false_keeps_9d_near_6d(orient, measured):
    """A weak dipole (100 A m², 1.2 m: the field's direction spreads ~3-5° RMS) crossed slowly (~20 s a crossing),
    started while moving with a bias of σ 0.15 °/s (seeds 0-5 of `experiments/field_sweep.py --rest 0.5`'s '100/1.2
    across slow' and '100/1.2 vertical slow'): the field turns slower than the consistency band sees, and with the
    bias unknown it passes as homogeneous; by default its turns teach the bias (9-D 2° worse than 6-D), with
    bias_from_mag false they cannot."""
    slow = (0.022, 0.028)
    m9, m6 = _started_moving_in_a_dipole(100.0, 1.2, 0.15, range(6), orient=orient, band_hz=slow)
    off9, _ = _started_moving_in_a_dipole(100.0, 1.2, 0.15, range(6), orient=orient, band_hz=slow,
                                          settings={'bias_from_mag': False})
    # Measured (9-D by default, 9-D with bias_from_mag false, 6-D): `measured`.
    assert m9 > m6 + 1.0, (m9, m6, measured)  # the case: the field's turns taught the bias
    assert off9 < m6 + 0.5, (off9, m6, measured)


@pytest.mark.parametrize(('every', 'mode'), [(1, ''), (5, 'missing'), (5, 'held'), (10, 'held')])
def test_a_noisy_magnetometer_s_single_outliers_do_not_stop_the_field_counting_as_steady(every, mode):
    """A phone-grade magnetometer (3x the noise: 10-18 % of its samples outside the norm and dip bounds, one at a time)
    in a homogeneous field: only runs of rejected samples count against the steadiness timer, so the field keeps
    teaching the bias and re-acquiring heading. Measured share of moving samples with the field steady (seeds 0, 1):
    0.95 and 0.92 with 12 and 16 % rejected; a magnetometer at 1/5 of the rate 0.94 and 0.94 (samples missing in
    between), 0.92 and 0.88 (held, as the engine pairs them); at 1/10 held 0.90 and 0.80. Counting every rejected
    sample: 0.68 and 0.49 (`experiments/simulated_accuracy.py`'s phone-grade 9-D total 2.55 against 2.63 then,
    seeds 0-9); counting each held copy: 0.60 and 0.46 at 1/5."""
    from ccf_ros.core.base import ANSWERED_BELOW
    from ccf_ros.core.ccf import MAG_BAND_S

    for seed in (0, 1):
        d = generate(120.0, 100.0, seed, gyro_noise_rad_s=0.02, acc_noise_m_s2=0.15, mag_noise_t=1.5e-6,
                     bias_init_rad_s=math.radians(0.7), bias_walk_rad_s_sqrt_s=5e-4)
        f = make_filter({})
        steady, rejected = [], []
        mag = _slower_magnetometer(d.mag, every, mode)
        for t, g, a, m, mv in zip(d.t_s.tolist(), d.gyr.tolist(), d.acc.tolist(), mag.tolist(), d.moving.tolist(),
                                  strict=True):
            assert f.update(t, tuple(g), tuple(a), None if math.isnan(m[0]) else tuple(m)) < ANSWERED_BELOW
            if mv:
                steady.append(f._mag_steady_s >= MAG_BAND_S[1])
                rejected.append(f.mag_disturbed)
        assert np.mean(rejected) > 0.05, np.mean(rejected)  # the case: a noisy magnetometer
        assert np.mean(steady) > 0.65, (seed, np.mean(steady))


def test_the_engine_counts_clipped_gyro_samples_across_resets_and_diagnostics_show_them():
    import time

    from ccf_ros.engine import ImuEngine
    from ccf_ros.node.diagnostics import diagnostics
    from ccf_ros.node.stats import InputStats
    from ccf_ros.node.sync import HoldStats
    from ccf_ros.settings import build

    t, gyr, acc, mag, _ = _flip()
    full = math.radians(2000.0)
    clipped = np.clip(gyr, -full, full)
    n_clip = int((np.abs(clipped) >= 0.998 * full).any(axis=1).sum())
    eng = ImuEngine(*build({'gyro_range_rad_s': full}))
    for k in range(len(t)):
        eng.on_mag(float(t[k]), tuple(mag[k]))
        eng.on_imu(float(t[k]), tuple(clipped[k]), tuple(acc[k]))
    assert eng.n_gyro_clipped == n_clip > 0
    eng.reset()  # the filter's own counter starts again; the engine's total keeps them
    assert eng.n_gyro_clipped == n_clip
    d = diagnostics(time.monotonic(), InputStats(), eng, HoldStats(0, 0, 0.0, 0.0, False), use_mag=True,
                    mag_timeout_s=0.5)
    assert d.values['gyro samples clipped (at gyro_range_rad_s)'] == str(n_clip)


def test_a_short_first_rest_does_not_lock_a_half_learnt_offset_in():
    """A 10 °/s offset, a first rest too short for the estimate to converge (1.8 s), 3 s of vibration, then rest:
    the later rest learns the offset (a rest that ended before the estimate agreed with it was no "seen" bias)."""
    rng = np.random.default_rng(2)
    t = np.arange(0.0, 30.0, 0.01)
    off = math.radians(10.0)
    gyr = np.zeros((len(t), 3)) + [0.0, 0.0, off] + rng.normal(0.0, 0.005, (len(t), 3))
    acc = np.tile([0.0, 0.0, 9.81], (len(t), 1)) + rng.normal(0.0, 0.05, (len(t), 3))
    shake = (t >= 1.8) & (t < 4.8)
    acc[shake] += rng.normal(0.0, 3.0, (int(shake.sum()), 3))
    r = run_batch(make_filter({'use_mag': False}), t + 1.7e9, gyr, acc, None)
    err = np.degrees(np.abs(r.bias[:, 2] - off))
    # Measured 0.052 °/s (with the rest that ended marking the bias as seen: stuck 4.5 °/s off for 120 s).
    assert err[t >= 15.0].max() < 0.065, err[t >= 15.0].max()
