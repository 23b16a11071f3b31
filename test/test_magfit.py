"""Planar magnetometer calibration (issue 24 item 3): a ground robot spinning in place, the motion check, the
calibrate-mag command's planar path and ``ccf simulate --motion spin``. All data simulated."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ccf_ros.cli import main as ccf
from ccf_ros.core.metrics import summarize
from ccf_ros.engine import ImuEngine
from ccf_ros.offline.evaluate import engine_orientations
from ccf_ros.offline.magcal import CalibrationError, read_mag
from ccf_ros.offline.magfit import fit_planar, rotation_axes, turn_coverage
from ccf_ros.offline.params_file import load_params_file
from ccf_ros.offline.simulate import (
    MAG_WORLD,
    SimData,
    generate,
    generate_spin,
    generate_vehicle,
    with_mag_distortion,
    write_bag,
)
from ccf_ros.settings import build

OFFSET_T = np.array([30.0, -12.0, 8.0]) * 1e-6
SOFT_IRON = np.array([[1.05, 0.03, 0.0], [0.03, 0.96, 0.0], [0.0, 0.0, 1.0]])
FIELD_T = float(np.linalg.norm(MAG_WORLD))


def heading_deg(data: SimData, params: dict | None = None) -> float:
    q = engine_orientations(ImuEngine(*build(params or {})), data.t_s, data.gyr, data.acc, data.mag)
    return summarize(q, data.q_true, data.moving).heading_rmse_deg


@pytest.fixture(scope='module')
def spin() -> SimData:
    return generate_spin(60.0, 100.0, 1)


@pytest.fixture(scope='module')
def spin_bag(spin, tmp_path_factory):
    path = tmp_path_factory.mktemp('magfit') / 'spin'
    write_bag(with_mag_distortion(spin, OFFSET_T, SOFT_IRON), path)
    return path


def test_the_gyro_tells_a_spin_from_a_calibration_dance(spin):
    ax = rotation_axes(spin.gyr, np.gradient(spin.t_s), spin.acc)
    assert ax.planar and ax.off_axis < 0.006  # measured 0.0048 (1 deg of rocking)
    assert ax.axis[2] > 0.9999  # up: the accelerometer signs it
    assert 25.0 < ax.angle_rad < 36.0  # measured 30.1 rad
    flipped = rotation_axes(spin.gyr, np.gradient(spin.t_s), -spin.acc)
    assert flipped.axis[2] < -0.9999
    hand = generate(60.0, 100.0, 1, rot_scale=3.0)
    ax = rotation_axes(hand.gyr, np.gradient(hand.t_s), hand.acc)
    assert not ax.planar and ax.off_axis > 0.25  # measured 0.31
    with pytest.raises(CalibrationError, match='no rotation'):
        rotation_axes(np.zeros((100, 3)), 0.01)


@pytest.mark.parametrize(('norm', 'dip', 'axial_err_ut'), [
    (FIELD_T, math.radians(60.0), 0.05),  # measured 0.008 uT
    (None, math.radians(60.0), 0.4),  # dip only: measured 0.31 (the radius at det S = 1, det W = 1.007)
    (FIELD_T, None, 0.2),  # norm only: measured 0.16
])
def test_planar_fit_recovers_the_offset_and_the_heading(spin, norm, dip, axial_err_ut):
    raw = with_mag_distortion(spin, OFFSET_T, SOFT_IRON)
    pc = fit_planar(raw.mag, (0.0, 0.0, 1.0), field_norm_t=norm, field_dip_rad=dip)
    err = (pc.cal.offset - OFFSET_T) * 1e6
    assert math.hypot(err[0], err[1]) < 0.035  # measured 0.026 uT
    assert abs(err[2]) < axial_err_ut
    assert pc.model == 'ellipse' and pc.turn_coverage == 1.0
    assert 0.55e-6 < pc.residual_t < 0.85e-6  # measured 0.71 uT: the noise and 1 deg of rocking
    # S undoes the soft iron in the plane (to its scale).
    s = pc.cal.matrix[:2, :2] @ SOFT_IRON[:2, :2]
    np.testing.assert_allclose(s / s[0, 0], np.eye(2), atol=0.01)


def test_planar_fit_without_the_field_leaves_the_axial_offset_and_says_so(spin):
    raw = with_mag_distortion(spin, OFFSET_T, SOFT_IRON)
    pc = fit_planar(raw.mag, (0.0, 0.0, 1.0))
    assert pc.axial_source == 'none' and pc.axial_offset_t == 0.0
    assert abs(pc.cal.offset_t[2]) < 0.1e-6  # measured 0.045 uT: the plane's tilt, not an estimate
    assert np.linalg.det(pc.cal.matrix) == pytest.approx(1.0, abs=1e-9)


def test_a_half_turn_is_refused_unless_forced(spin):
    raw = with_mag_distortion(spin, OFFSET_T, SOFT_IRON).mag
    p = raw[:, :2] - OFFSET_T[:2]
    half = raw[(np.arctan2(p[:, 1], p[:, 0]) > 0)]
    with pytest.raises(CalibrationError, match=r'turns through 5\d% of a full turn'):
        fit_planar(half, (0.0, 0.0, 1.0))
    assert fit_planar(half, (0.0, 0.0, 1.0), force=True).turn_coverage < 0.6
    assert turn_coverage(np.array([[1.0, 0.0]] * 10)) == 1 / 36


def test_calibrate_mag_chooses_planar_and_the_replay_heading_matches_clean(spin, spin_bag, tmp_path, capsys):
    out = tmp_path / 'cal.yaml'
    assert ccf(['calibrate-mag', str(spin_bag), '-o', str(out), '--field-norm-ut', '50', '--field-dip-deg', '60']) == 0
    text = capsys.readouterr().out
    assert 'motion: planar (auto' in text and 'turn coverage 100%' in text and 'from the field norm+dip' in text
    params = load_params_file(out)
    b = np.array([params[f'mag_bias_{c}'] for c in 'xyz'])
    assert np.linalg.norm(b - OFFSET_T) < 0.04e-6  # measured 0.027 uT
    assert len(params['mag_soft_iron']) == 9
    # Heading afterwards: on the spin itself and on a drive with the same sensor.
    raw = with_mag_distortion(spin, OFFSET_T, SOFT_IRON)
    clean, calibrated = heading_deg(spin), heading_deg(raw, params)
    assert calibrated < 1.2 * clean  # measured 0.37 vs 0.38 deg
    assert heading_deg(raw) > 50 * clean  # uncalibrated: measured 56 deg
    drive = generate_vehicle(120.0, 100.0, 2)
    assert heading_deg(with_mag_distortion(drive, OFFSET_T, SOFT_IRON), params) < 1.2 * heading_deg(drive)
    # Without the field the axial offset is left at 0 and the command says so.
    assert ccf(['calibrate-mag', str(spin_bag), '-o', str(out), '--overwrite']) == 0
    assert 'not determined by turning about it, left at 0' in capsys.readouterr().out
    # Forced 3-D: the old refusal (the samples are flat).
    assert ccf(['calibrate-mag', str(spin_bag), '-o', str(out), '--overwrite', '--motion', '3d']) == 2
    assert 'lie in a plane' in capsys.readouterr().err


def test_calibrate_mag_motion_auto_keeps_3d_for_a_dance_and_bad_dip_is_refused(tmp_path, capsys):
    bag = tmp_path / 'dance'
    write_bag(with_mag_distortion(generate(60.0, 50.0, 1, rot_scale=3.0), OFFSET_T), bag)
    assert ccf(['calibrate-mag', str(bag), '-o', str(tmp_path / 'c.yaml')]) == 0
    assert 'motion: 3d (auto: more than 10%' in capsys.readouterr().out
    assert ccf(['calibrate-mag', str(bag), '-o', str(tmp_path / 'd.yaml'), '--field-dip-deg', '95']) == 2
    assert '--field-dip-deg must be a number within (-90, 90) deg, got 95.0' in capsys.readouterr().err


def test_simulate_spin_with_an_offset(tmp_path, capsys):
    bag = tmp_path / 'spin'
    assert ccf(['simulate', '-o', str(bag), '--motion', 'spin', '--duration', '30', '--rate', '50',
                '--mag-offset-ut', '30', '-12', '8']) == 0
    assert 'spin motion' in capsys.readouterr().out
    m = read_mag(bag)
    # Spinning about z: x and y swing about the offset, z stays at the vertical field plus the offset.
    assert abs(np.median(m[:, 2]) - (MAG_WORLD[2] + 8e-6)) < 1e-6
    assert abs(0.5 * (m[:, 0].max() + m[:, 0].min()) - 30e-6) < 2e-6


def test_ccf_replay_with_the_planar_yaml_restores_the_heading(spin, spin_bag, tmp_path, capsys):
    """The real path: calibrate-mag on the bag, ccf replay with --params-file, ccf eval's scorer; plus the plot."""
    from ccf_ros.offline.evaluate import evaluate, load_aligned

    cal, png = tmp_path / 'cal.yaml', tmp_path / 'cal.png'
    assert ccf(['calibrate-mag', str(spin_bag), '-o', str(cal), '--field-dip-deg', '60', '--plot', str(png)]) == 0
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    clean_bag = tmp_path / 'clean'
    write_bag(spin, clean_bag)

    def heading(bag, *extra: str) -> float:
        out = tmp_path / f'out{len(list(tmp_path.iterdir()))}'
        assert ccf(['replay', str(bag), '-o', str(out), *extra]) == 0
        return evaluate(load_aligned(out, '/ground_truth/pose', reference_bag=bag,
                                     mask_topic='/ground_truth/moving')).heading_rmse_deg

    clean = heading(clean_bag)
    assert heading(spin_bag, f'--params-file={cal}') < 1.2 * clean  # measured 0.37 vs 0.38 deg (engine loop)
    assert heading(spin_bag) > 50 * clean
