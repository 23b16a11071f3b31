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
from ccf_ros.core.quaternion import WORLD_FRAMES, quat_mul, quat_rotate
from ccf_ros.offline.simulate import generate

CORE = Path(__file__).resolve().parents[1] / 'ccf_ros' / 'core'


def test_core_imports_only_numpy_and_stdlib():
    allowed = set(sys.stdlib_module_names) | {'numpy'}
    for path in CORE.glob('*.py'):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or '']
            else:
                continue
            for name in names:
                assert name.split('.')[0] in allowed, f'{path.name} imports {name}'
    code = 'import sys, ccf_ros.core; sys.exit(1 if any(m.startswith(("rclpy", "rosbags")) for m in sys.modules) else 0)'
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
    assert isinstance(f, EulerCcf) and f.params._kp3 == (1.0, 2.0, 3.0)


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
    assert np.all(err < 0.15), err
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
