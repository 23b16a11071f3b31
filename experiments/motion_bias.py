"""The gyro bias while moving, measured with the motion capture, against the bias learnt at rest.

For each shared BROAD trial the body rate of the reference (from consecutive reference orientations) is subtracted
from the gyro sample of the same interval. What is left is the gyro error plus the reference's noise, which averages
out. Its mean over the first rest is the rest bias. While moving it is estimated two ways: its mean, and ``b`` of the
fit ``b + K w`` (``w``: the reference rate, ``K``: scale-factor and misalignment errors, 3x3), which keeps a motion
turning mostly one way from passing for a bias but is poorly determined where the rates are small. The script
prints the rest bias, both differences from it (°/s, body x y z), the default filter's estimate averaged over the
moving samples minus the rest bias, ``|K|`` and the share of samples paired.

It then runs an oracle: the gyro corrected by the measured gyro error (a 20 s moving mean of gyro minus reference
rate: the bias and whatever else varies slowly, such as ``K w``), bias learning off, the other settings unchanged.
Its inclination and 6-D (heading offset fitted) errors show what knowing the gyro error while moving is worth; it is
non-causal and carries the reference's own errors.

Usage: python experiments/motion_bias.py [--shared ../shared/data/broad] [--trials 02,11] [--window 20] [NAME=VALUE ...]
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
from _trials import map_trials, parser, trials_and_settings

from ccf_ros.core import run_batch
from ccf_ros.core.metrics import fitted_total_rmse_deg, summarize
from ccf_ros.core.quaternion import quat_conj, quat_mul, quat_to_rotvec
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build

#: BROAD's IMU rate, Hz.
RATE_HZ = 286.0
#: Stamps within this of each other (s) are the same sample.
_TOL_S = 0.25 / RATE_HZ


def gyro_minus_reference(
    t_s: np.ndarray, gyr: np.ndarray, t_ref: np.ndarray, q_ref: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(N, 3)`` gyro minus the reference body rate over the interval before each IMU sample, and that reference
    rate, rad/s; NaN where the reference has no pair of samples bounding the same interval."""
    dq = quat_mul(quat_conj(q_ref[:-1]), q_ref[1:])
    ok = np.all(np.isfinite(dq), axis=1) & (np.diff(t_ref) > 0.0)
    # The rows that are not ok get a placeholder, unused: quat_to_rotvec needs finite input.
    w_ref = quat_to_rotvec(np.where(ok[:, None], dq, [1.0, 0.0, 0.0, 0.0])) / np.where(ok, np.diff(t_ref), 1.0)[:, None]
    # A gyro sample is the mean rate over the interval before its stamp: pair it with the reference interval that
    # ends at the same stamp and begins at the previous sample's.
    i = np.clip(np.searchsorted(t_s, t_ref[1:] - _TOL_S), 1, len(t_s) - 1)
    ok &= (np.abs(t_s[i] - t_ref[1:]) < _TOL_S) & (np.abs(t_s[i - 1] - t_ref[:-1]) < _TOL_S)
    d = np.full((len(t_s), 3), np.nan)
    w = np.full((len(t_s), 3), np.nan)
    d[i[ok]] = gyr[i[ok]] - w_ref[ok]
    w[i[ok]] = w_ref[ok]
    return d, w


def bias_and_scale(d: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares ``d = b + K w`` over the rows where both are finite: ``b`` (3,) and ``K`` (3, 3), same units."""
    ok = np.all(np.isfinite(d), axis=1) & np.all(np.isfinite(w), axis=1)
    x = np.column_stack([np.ones(ok.sum()), w[ok]])
    beta, *_ = np.linalg.lstsq(x, d[ok], rcond=None)
    return beta[0], beta[1:].T


def moving_mean(x: np.ndarray, n: int) -> np.ndarray:
    """Centred mean over ``n`` samples of the rows of ``x`` (N, 3) that are finite (judged by the first column: the
    rows are NaN or finite as a whole)."""
    k = np.ones(n)
    ok = np.isfinite(x[:, 0])
    s = np.stack([np.convolve(np.where(ok, x[:, j], 0.0), k, 'same') for j in range(3)], axis=1)
    c = np.convolve(ok.astype(float), k, 'same')
    return s / np.maximum(c, 1.0)[:, None]


def scores(filt, t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag, t_ref, q_ref, mask) -> tuple[float, float, Any]:
    """(inclination RMSE, total RMSE with one heading offset fitted), degrees, and the batch result."""
    r = run_batch(filt, t, gyr, acc, mag)
    q = align(t[r.answered], r.quat[r.answered], t_ref, q_ref)
    return summarize(q, q_ref, mask).inclination_rmse_deg, fitted_total_rmse_deg(q, q_ref, mask), r


def run_trial(args: tuple[Path, float, dict[str, str]]) -> tuple[str, dict[str, Any]]:
    trial, window, settings = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    moving = read_bools(trial, '/ground_truth/moving')
    mask = mask_at(t_ref, *moving)
    mask_imu = mask_at(imu.t_s, *moving)
    d, w = gyro_minus_reference(imu.t_s, imu.gyr, t_ref, q_ref)
    first = int(np.argmax(mask_imu))
    rest = np.zeros(len(d), bool)
    rest[int(2 * RATE_HZ) : max(first - int(RATE_HZ), 0)] = True  # the first rest, 2 s in, 1 s before the motion
    b_moving, k = bias_and_scale(d[mask_imu], w[mask_imu])
    out: dict[str, Any] = {
        'rest': np.degrees(np.nanmean(d[rest], axis=0)),
        'mean': np.degrees(np.nanmean(d[mask_imu], axis=0)),
        'fit': np.degrees(b_moving),
        'k': float(np.linalg.norm(k)),
        'paired': float(np.mean(np.isfinite(d[:, 0]))),
    }
    oracle = {**settings, 'rest_bias': 'false', 'motion_bias': 'false'}
    gyr_corrected = imu.gyr - moving_mean(d, int(window * RATE_HZ))
    for key, gyr, cfg in (('defaults', imu.gyr, settings), ('oracle', gyr_corrected, oracle)):
        f9, _ = build(cfg)
        incl, _, r = scores(f9, imu.t_s, gyr, imu.acc, imu.mag, t_ref, q_ref, mask)
        if key == 'defaults':
            out['filter'] = np.degrees(np.nanmean(r.bias[mask_imu], axis=0))
        f6, _ = build({**cfg, 'use_mag': 'false'})
        _, fit6, _ = scores(f6, imu.t_s, gyr, imu.acc, None, t_ref, q_ref, mask)
        out[key] = (incl, fit6)
    return trial.name, out


def main() -> None:
    ap: argparse.ArgumentParser = parser(__doc__)
    ap.add_argument('--window', type=float, default=20.0, help='oracle: moving-mean window of the gyro error, s')
    args = ap.parse_args()
    trials, settings = trials_and_settings(args)
    res = map_trials(run_trial, [(t, args.window, settings) for t in trials])

    def v(x: np.ndarray) -> str:
        return ' '.join(f'{c:+6.3f}' for c in x)

    print('gyro bias, deg/s, body x y z: at the first rest; while moving minus that, as the mean and as b of b + K w')
    print("(motion capture); the filter's estimate averaged while moving minus the rest bias; |K| (%); share paired")
    print(
        f'{"trial":44s} {"rest":>20s}  {"mean - rest":>20s}  {"b - rest":>20s}  {"filter - rest":>20s}  {"|K| %":>5s}'
        ' paired'
    )
    d_mean, d_fit = [], []
    for name, o in res:
        d_mean.append(o['mean'] - o['rest'])
        d_fit.append(o['fit'] - o['rest'])
        print(
            f'{name:44s} {v(o["rest"])}  {v(d_mean[-1])}  {v(d_fit[-1])}  {v(o["filter"] - o["rest"])}  '
            f'{100 * o["k"]:5.2f} {o["paired"]:6.3f}'
        )
    print(
        f'{"mean |difference|":44s} {"":20s}  {v(np.mean(np.abs(d_mean), axis=0))}  {v(np.mean(np.abs(d_fit), axis=0))}'
    )
    print()
    print(f'oracle (gyro corrected by the measured gyro error, {args.window:g} s mean, bias learning off), degrees:')
    print(
        f'{"trial":44s} {"incl. defaults":>15s} {"incl. oracle":>13s} {"6-D fit defaults":>17s} {"6-D fit oracle":>15s}'
    )
    for name, o in res:
        print(
            f'{name:44s} {o["defaults"][0]:15.2f} {o["oracle"][0]:13.2f} {o["defaults"][1]:17.2f} {o["oracle"][1]:15.2f}'
        )
    m = [
        np.mean([o[k][i] for _, o in res]) for k, i in (('defaults', 0), ('oracle', 0), ('defaults', 1), ('oracle', 1))
    ]
    print(f'{"mean":44s} {m[0]:15.2f} {m[1]:13.2f} {m[2]:17.2f} {m[3]:15.2f}')


if __name__ == '__main__':
    main()
