"""The bias Kalman's observation noise while rotating: a gyro scale error shows along the rotation axis, so a
rotation inflates the noise of the bias observation along its axis and (by the cross-axis share) much less of the
others'; the planar swing's 6-D heading, where that matters."""

from __future__ import annotations

import numpy as np

from ccf_ros.core import make_filter, run_batch
from ccf_ros.core.ccf import BIAS_UPDATE_PERIOD_S, CcfParams
from ccf_ros.core.ccf.bias import _CROSS_AXIS, BiasKalman
from ccf_ros.core.ccf.discretisation import _bin, _BlockCoefficients
from ccf_ros.core.metrics import error_angles, fit_heading_offset
from ccf_ros.offline.simulate import generate_swing

#: World east, north, up = body x, y, z.
LEVEL = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


def _variances_after(w: tuple[float, float, float], updates: int = 25) -> tuple[float, ...]:
    """The bias variances (x, y, z; (rad/s)²) after ``updates`` blocks at rate ``w`` (rad/s, body), level, no error."""
    p = CcfParams()
    c = _BlockCoefficients.of(p, _bin(BIAS_UPDATE_PERIOD_S))
    kf = BiasKalman(p.bias_sigma_init_rad_s**2)
    for _ in range(updates):
        kf.update(c, 10, 0.0, 0.0, 0.0, LEVEL, 0.0, 0.0, 0.0, None, w, True, False)
    return kf.p[0], kf.p[3], kf.p[5]


def test_a_rotation_inflates_the_observation_along_its_axis_more_than_across():
    """Level, turning at 60 °/s about body x (world east): the east row (body x) sees the scale error in full, the
    north row (body y) only the cross-axis share; so the y bias is learnt faster than the x bias (with the isotropic
    inflation of before, both alike). At rest rate, both alike."""
    px, py, _ = _variances_after((np.radians(60.0), 0.0, 0.0))
    assert py < 0.65 * px, (px, py)  # measured py/px 0.52 (cross-axis share 2/3; isotropic: 1)
    qx, qy, _ = _variances_after((0.0, np.radians(60.0), 0.0))
    assert qx == py and qy == px  # the same turned by 90°
    sx, sy, _ = _variances_after((0.0, 0.0, 0.0))
    assert sx == sy < py  # not turning: both learnt alike, and faster
    # A rotation about up (not a row of the tilt observations) inflates the tilt rows by the cross-axis share only.
    ux, uy, _ = _variances_after((0.0, 0.0, np.radians(60.0)))
    assert ux == uy == py
    assert 0.0 < _CROSS_AXIS < 1.0


def _swing_heading_deg(rate_hz: float, seed: int) -> float:
    """6-D heading RMSE (deg, one offset fitted) on the simulated planar swing."""
    d = generate_swing(200.0, rate_hz, seed)
    q = run_batch(make_filter({}), d.t_s, d.gyr, d.acc, None).quat
    mv = d.moving
    ref = fit_heading_offset(q[mv], d.q_true[mv])
    return float(np.degrees(np.sqrt(np.mean(error_angles(q[mv], ref)[1] ** 2))))
