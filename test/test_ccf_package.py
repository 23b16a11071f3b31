"""The cascade as a package (ccf_ros/core/ccf/): the old module's imports keep working, and the named per-sample
state holds what its fields say."""

from __future__ import annotations

import math

import numpy as np
import pytest

import ccf_ros.core.ccf as ccf
from ccf_ros.core.ccf import BIAS_UPDATE_PERIOD_S, GRAVITY_M_S2, CcfState, QuaternionCcf
from ccf_ros.core.quaternion import quat_conj, quat_rotate
from ccf_ros.offline.simulate import generate


def test_the_package_exports_what_the_single_module_did():
    # Every name imported from ccf_ros.core.ccf in the repository before the split (engine, study, tests, benchmarks).
    for name in ('CcfParams', 'QuaternionCcf', 'tilt_transfer', 'butterworth_step', 'GRAVITY_M_S2',
                 'BIAS_UPDATE_PERIOD_S', 'MAG_BAND_S', 'MAG_SCORE_S', 'MAG_REJECT_SIGMAS', 'NEW_FIELD_TURN_RAD',
                 'REST_BIAS_TOL_RAD_S', 'REST_RELEARN_S', '_Coefficients', '_BlockCoefficients'):
        assert name in ccf.__all__ and hasattr(ccf, name), name
    assert all(hasattr(ccf, name) for name in ccf.__all__)
    assert ccf.QuaternionCcf is ccf.filter.QuaternionCcf and ccf.CcfParams is ccf.params.CcfParams


@pytest.fixture(scope='module')
def run():
    """A filter after 60 s of hand-held motion at 100 Hz with a 1°/s bias, and the recording."""
    d = generate(60.0, 100.0, seed=5, bias_init_rad_s=math.radians(1.0))
    f = QuaternionCcf()
    for i in range(len(d.t_s)):
        f.update(float(d.t_s[i]), d.gyr[i].tolist(), d.acc[i].tolist(), d.mag[i].tolist())
    return f, d


def test_the_named_state_holds_what_its_fields_say(run):
    f, d = run
    s = f.state
    assert len(s) == len(CcfState._fields) == len(f._x)
    # The bias: the filter's estimate, and near the truth (a 1.6°/s bias; measured 0.068°/s off).
    assert (s.bias_x, s.bias_y, s.bias_z) == f.gyro_bias
    assert np.degrees(np.abs(np.array([s.bias_x, s.bias_y, s.bias_z]) - d.bias[-1])).max() < 0.082
    # The gravity low-pass: the specific force in the body frame, along the attitude's up (measured 0.09°, 0.25 %),
    # and its rate (measured 0.12 m/s³).
    g = np.array([s.g_lp_x, s.g_lp_y, s.g_lp_z])
    up = quat_rotate(quat_conj(f.quaternion), [0.0, 0.0, 1.0])
    assert abs(np.linalg.norm(g) / GRAVITY_M_S2 - 1.0) < 0.003
    assert np.degrees(np.arccos(np.dot(g, up) / np.linalg.norm(g))) < 0.11
    assert np.linalg.norm([s.g_rate_x, s.g_rate_y, s.g_rate_z]) < 0.15
    # The NCF's offset from the LCF: small once converged (measured 0.50°).
    assert np.degrees(np.linalg.norm([s.dn_e, s.dn_n, s.dn_u])) < 0.6
    # The current block: fewer than a block's samples, spanning less than a block; its magnetometer samples among
    # them, its heading errors among those.
    assert isinstance(s.block_n, int) and isinstance(s.field_count, int) and isinstance(s.head_err_n, int)
    assert 0 <= s.block_n < BIAS_UPDATE_PERIOD_S * 100 + 1 and 0.0 <= s.block_s < BIAS_UPDATE_PERIOD_S
    assert s.block_s == pytest.approx(s.block_n * 0.01, abs=1e-6)  # (float stamps near 1.7e9 s)
    assert s.head_err_n <= s.field_count == s.block_n
    assert np.degrees(np.linalg.norm([s.corr_x, s.corr_y, s.corr_z])) < 0.0042  # 3 samples' LCF steps, measured 0.0034°


def test_reset_init_and_setters_write_the_state_by_name(run):
    f, _ = run
    before = f.state
    f.set_gyro_bias((0.01, -0.02, 0.005), 0.003)
    after = f.state
    assert (after.bias_x, after.bias_y, after.bias_z) == (0.01, -0.02, 0.005)
    assert after._replace(bias_x=0.0, bias_y=0.0, bias_z=0.0) == before._replace(bias_x=0.0, bias_y=0.0, bias_z=0.0)
    f.set_heading(0.5)  # turns the NCF offset with the orientation about up: its length is kept
    turned = f.state
    assert math.hypot(turned.dn_e, turned.dn_n) == pytest.approx(math.hypot(after.dn_e, after.dn_n), rel=1e-12)
    assert turned.dn_u == after.dn_u and turned.g_lp_x == after.g_lp_x
    f.reset()
    assert f.state == CcfState() and f.state.g_lp_z == GRAVITY_M_S2
    f.set_gyro_bias((0.01, -0.02, 0.005), 0.003)
    f.update(0.0, (0.0, 0.0, 0.0), (0.1, 0.2, 9.7), None)  # initialises: g_lp starts at the sample, bias kept
    assert f.state == CcfState(g_lp_x=0.1, g_lp_y=0.2, g_lp_z=9.7, bias_x=0.01, bias_y=-0.02, bias_z=0.005)
