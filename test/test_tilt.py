"""Inclination (tilt) of the cascade: the magnetometer must not make it worse than the filter's own 6-D tilt
(issue 23)."""

from __future__ import annotations

import numpy as np
import pytest

from ccf_ros.core import run_batch
from ccf_ros.core.ccf import CcfParams, QuaternionCcf
from ccf_ros.core.metrics import summarize
from ccf_ros.offline.simulate import generate

SEEDS = range(4)


def _inclinations(tau_mag_s: float) -> tuple[float, float]:
    """Mean inclination RMSE (deg) over SEEDS of 9-D and 6-D on hand-held motion started 0.5 s after switching on,
    40 Hz, 67 s (the arm-chain recordings' rate and length)."""
    i9, i6 = [], []
    for seed in SEEDS:
        d = generate(67.0, 40.0, seed, rest_s=0.5)
        q9 = run_batch(QuaternionCcf(CcfParams(tau_mag_s=tau_mag_s)), d.t_s, d.gyr, d.acc, d.mag).quat
        q6 = run_batch(QuaternionCcf(CcfParams(use_mag=False)), d.t_s, d.gyr, d.acc, None).quat
        i9.append(summarize(q9, d.q_true, d.moving).inclination_rmse_deg)
        i6.append(summarize(q6, d.q_true, d.moving).inclination_rmse_deg)
    return float(np.mean(i9)), float(np.mean(i6))


@pytest.mark.parametrize('tau_mag_s', [15.0, 60.0])
def test_started_while_moving_9d_tilt_is_no_worse_than_6d(tau_mag_s):
    # The bias learns from tilt once the tilt blends have handed over, whatever the heading blend's time constant:
    # before, 9-D learnt nothing for tau_mag_s (the heading start-up) and measured 1.31x (tau_mag_s 15) and 2.4x
    # (60) the 6-D inclination here; now 0.98x and 1.00x.
    i9, i6 = _inclinations(tau_mag_s)
    assert i9 <= 1.15 * i6, (i9, i6)


def test_the_bias_is_learnt_while_the_heading_blend_still_starts_up():
    # 12 s in (after the tilt blends' 2.5 s, within the heading blend's 15 s start-up) the 9-D bias estimate has
    # moved from zero towards the true bias as the 6-D one has (measured: error 0.65x the bias, 1.04x 6-D's; before:
    # not moved, 1.0x).
    d = generate(20.0, 40.0, 1, rest_s=0.5, bias_init_rad_s=np.radians(1.0))
    n = int(12.0 * 40)
    errs = []
    for use_mag in (True, False):
        f = QuaternionCcf(CcfParams(use_mag=use_mag))
        run_batch(f, d.t_s[:n], d.gyr[:n], d.acc[:n], d.mag[:n] if use_mag else None)
        errs.append(float(np.linalg.norm(np.subtract(f.gyro_bias, d.bias[n - 1]))))
    e9, e6 = errs
    b0 = float(np.linalg.norm(d.bias[n - 1]))
    assert e9 < 0.8 * b0 and e9 < 1.2 * e6 + np.radians(0.02), (e9, e6, b0)
