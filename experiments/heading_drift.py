"""Where a trial's 6-D heading drift builds up: at rest, in slow or in fast rotation, and what the gyro does there.

For each shared BROAD trial, the filter without magnetometer (defaults plus any ``NAME=VALUE``) is scored as the 6-D
column of ``broad_accuracy.py`` (total RMSE, one heading offset fitted). Its heading error after that offset is then
followed sample by sample and its changes summed by how fast the reference turns (1 s mean of its rate: rest below
5 °/s, slow up to 60 °/s, fast above). Beside them, the gyro error along world up (gyro minus the motion capture's
body rate, turned into the world by the reference: what drifts a heading) against the filter's bias estimate along
its own world up, averaged per class, and the integral of their difference over the same intervals (it matches the
heading change to within ~0.5°: the check that the drift is the gyro's). A class present for less than 1 s is NaN.
Last, ``k`` of the fit ``e = b + k w`` of the world-up error ``e`` against the world-up rate ``w`` while moving: a
rate-proportional error (scale factor, misalignment) that no bias estimate can follow.

Usage: python experiments/heading_drift.py [--shared ../shared/data/broad] [--trials 07,30,33] [NAME=VALUE ...]
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from _trials import map_trials, parser, trials_and_settings
from heading_offset import signed_heading
from motion_bias import RATE_HZ, gyro_minus_reference, moving_mean

from ccf_ros.core import run_batch
from ccf_ros.core.metrics import fit_heading_offset, fitted_total_rmse_deg
from ccf_ros.core.quaternion import quat_rotate
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build

#: Rate classes by the reference's 1 s mean rate, rad/s: rest below the first, fast above the second.
CLASSES = ('rest', 'slow', 'fast')
_LIMITS = np.radians([5.0, 60.0])


def world_up(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``(N,)`` world-up component of body vectors ``v`` (N, 3) turned by ``q`` (N, 4); NaN where either is NaN."""
    ok = np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(v), axis=1)
    out = np.full(len(v), np.nan)
    out[ok] = quat_rotate(q[ok], v[ok])[:, 2]
    return out


def run_trial(args: tuple[Path, dict[str, str]]) -> tuple[str, dict[str, Any]]:
    trial, settings = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    moving_t = read_bools(trial, '/ground_truth/moving')
    mask = mask_at(t_ref, *moving_t)
    f6, _ = build({**settings, 'use_mag': 'false'})
    r = run_batch(f6, imu.t_s, imu.gyr, imu.acc, None)
    q = align(imu.t_s[r.answered], r.quat[r.answered], t_ref, q_ref)
    score = fitted_total_rmse_deg(q, q_ref, mask)
    # The heading error after the fitted offset, at the reference's samples (in BROAD, also the IMU's stamps).
    both = np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(q_ref), axis=1)
    sel = mask & both
    psi = signed_heading(fit_heading_offset(q[sel], q_ref[sel])[:1], q_ref[sel][:1])[0]
    h = np.full(len(t_ref), np.nan)
    h[both] = (signed_heading(q[both], q_ref[both]) - psi + 180.0) % 360.0 - 180.0
    # The gyro's error and the reference rate at the IMU samples, and the reference orientation there.
    d, w = gyro_minus_reference(imu.t_s, imu.gyr, t_ref, q_ref)
    i_ref = np.clip(np.searchsorted(t_ref, imu.t_s - 0.25 / RATE_HZ), 0, len(t_ref) - 1)
    paired = np.abs(t_ref[i_ref] - imu.t_s) < 0.25 / RATE_HZ
    q_at = np.where(paired[:, None], q_ref[i_ref], np.nan)
    e_up = world_up(q_at, d)
    w_up = world_up(q_at, w)
    b_up = world_up(r.quat, r.bias)
    speed = np.linalg.norm(w, axis=1)
    rate = moving_mean(np.column_stack([speed, speed, speed]), int(RATE_HZ))[:, 0]
    rate[~np.isfinite(speed)] = np.nan
    cls = np.searchsorted(_LIMITS, rate)  # 0 rest, 1 slow, 2 fast (NaN rate: excluded below)
    h_imu = np.where(paired, h[i_ref], np.nan)
    dh = (np.diff(h_imu) + 180.0) % 360.0 - 180.0
    # One set of intervals per class for the heading change and the integral, each interval's own length.
    dt = np.diff(imu.t_s)
    usable = np.isfinite(dh) & np.isfinite(rate[1:]) & np.isfinite(e_up[1:]) & np.isfinite(b_up[1:])
    out: dict[str, Any] = {'score': score}
    for c, name in enumerate(CLASSES):
        m = usable & (cls[1:] == c)
        seconds = float(dt[m].sum())
        if seconds < 1.0:  # (a class hardly present: its means say nothing)
            out[name] = (np.nan, seconds, np.nan, np.nan, np.nan)
            continue
        e, b = e_up[1:][m], b_up[1:][m]
        out[name] = (float(dh[m].sum()), seconds, np.degrees(e.mean()), np.degrees(b.mean()),
                     float(np.degrees(np.sum((e - b) * dt[m]))))
    moving = mask_at(imu.t_s, *moving_t) & np.isfinite(e_up) & np.isfinite(w_up)
    k = np.linalg.lstsq(np.column_stack([np.ones(moving.sum()), w_up[moving]]), e_up[moving], rcond=None)[0][1]
    out['k'] = float(k)
    return trial.name, out


def main() -> None:
    args = parser(__doc__).parse_args()
    trials, settings = trials_and_settings(args)
    res = map_trials(run_trial, [(t, settings) for t in trials])
    print('6-D (offset fitted) total RMSE, deg; heading change after the fitted offset by reference rate class, deg '
          '(seconds);')
    print('world-up gyro error: motion capture / filter bias, deg/s, and the integral of their difference, deg; k: '
          'world-up error per world-up rate while moving, %')
    print(f'{"trial":44s} {"6-D":>5s} | ' + ' | '.join(f'{c:>22s}' for c in CLASSES) + ' | '
          + ' | '.join(f'{c + " gyro err / bias / int":>30s}' for c in CLASSES) + ' |      k')
    for name, o in res:
        change = ' | '.join(f'{o[c][0]:+8.2f} ({o[c][1]:6.0f} s)     ' for c in CLASSES)
        gyro = ' | '.join(f'{o[c][2]:+8.3f} / {o[c][3]:+7.3f} / {o[c][4]:+7.2f}  ' for c in CLASSES)
        print(f'{name:44s} {o["score"]:5.2f} | {change} | {gyro} | {100 * o["k"]:+6.3f}')


if __name__ == '__main__':
    main()
