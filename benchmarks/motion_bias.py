"""The gyro bias while moving, measured with the motion capture, against the bias learnt at rest.

For each shared BROAD trial the body rate of the reference (from consecutive reference orientations) is subtracted
from the gyro sample of the same interval: what is left is the gyro bias plus the reference's noise, which averages
out. Its mean over the first rest is the rest bias; its mean over the moving samples is the bias the filter needs
while moving. The script prints both (°/s, body x y z), their difference, the default filter's estimate averaged
over the moving samples, and the mean body rate (a scale-factor or misalignment error would show in proportion to
it: where it is within ±MAX_MEAN_RATE_DEG_S the difference is a bias change; where the motion turns mostly one way,
as in the trials with a magnet, it is not, and those trials are left out of the summary).

It then runs an oracle: the gyro corrected by the measured gyro error (a 20 s moving mean of gyro minus reference
rate: the bias, and whatever else varies slowly, such as a scale-factor error times the mean rate), bias learning
off, the other defaults unchanged. Its inclination and 6-D (heading offset fitted) errors bound what a better
estimate of the gyro error while moving could give.

Usage: python benchmarks/motion_bias.py [--shared ../shared/data/broad] [--trials 02,11] [--window 20]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from _trials import map_trials, parser, trials_and_settings

from ccf_ros.core import run_batch
from ccf_ros.core.metrics import fit_heading_offset, summarize
from ccf_ros.core.quaternion import quat_conj, quat_mul, quat_to_rotvec
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build

RATE_HZ = 286.0
#: Largest mean body rate while moving (deg/s, per axis) at which moving - rest is read as a bias change: a 1 %
#: scale-factor error then adds at most 0.05 deg/s.
MAX_MEAN_RATE_DEG_S = 5.0


def gyro_minus_reference(t_s: np.ndarray, gyr: np.ndarray, t_ref: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """``(N, 3)`` gyro minus the reference body rate over the interval before each IMU sample, rad/s; NaN where
    the reference has no pair of samples there."""
    dq = quat_mul(quat_conj(q_ref[:-1]), q_ref[1:])
    dq = dq * np.sign(dq[:, :1] + 1e-300)
    w_ref = quat_to_rotvec(np.nan_to_num(dq, nan=1.0)) / np.diff(t_ref)[:, None]
    ok = np.all(np.isfinite(dq), axis=1)
    # A gyro sample is the mean rate over the interval before its stamp: pair it with the reference interval
    # that ends at the same stamp.
    i = np.clip(np.searchsorted(t_s, t_ref[1:]), 0, len(t_s) - 1)
    ok &= np.abs(t_s[i] - t_ref[1:]) < 0.25 / RATE_HZ
    out = np.full((len(t_s), 3), np.nan)
    out[i[ok]] = gyr[i[ok]] - w_ref[ok]
    return out


def moving_mean(x: np.ndarray, n: int) -> np.ndarray:
    """Centred mean of the finite values of ``x`` (N, 3) over ``n`` samples."""
    k = np.ones(n)
    ok = np.isfinite(x[:, 0])
    s = np.stack([np.convolve(np.where(ok, x[:, j], 0.0), k, 'same') for j in range(3)], axis=1)
    c = np.convolve(ok.astype(float), k, 'same')
    return s / np.maximum(c, 1.0)[:, None]


def scores(filt, t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag, t_ref, q_ref, mask) -> tuple[float, float]:
    """(inclination RMSE, total RMSE with one heading offset fitted), degrees."""
    r = run_batch(filt, t, gyr, acc, mag)
    q = align(t[r.answered], r.quat[r.answered], t_ref, q_ref)
    s = summarize(q, q_ref, mask)
    sel = mask & np.all(np.isfinite(q_ref), axis=1) & np.all(np.isfinite(q), axis=1)
    q_fit = q_ref.copy()
    q_fit[sel] = fit_heading_offset(q[sel], q_ref[sel])
    return s.inclination_rmse_deg, summarize(q, q_fit, mask).total_rmse_deg


def run_trial(args: tuple[Path, int]) -> tuple[str, dict[str, np.ndarray | tuple[float, ...]]]:
    trial, window = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    moving = read_bools(trial, '/ground_truth/moving')
    mask = mask_at(t_ref, *moving)
    mask_imu = mask_at(imu.t_s, *moving)
    d = gyro_minus_reference(imu.t_s, imu.gyr, t_ref, q_ref)
    first = int(np.argmax(mask_imu))
    rest = np.zeros(len(d), bool)
    rest[int(2 * RATE_HZ) : max(first - int(RATE_HZ), 0)] = True  # the first rest, 2 s in, 1 s before the motion
    out: dict[str, np.ndarray | tuple[float, ...]] = {
        'rest': np.degrees(np.nanmean(d[rest], axis=0)),
        'moving': np.degrees(np.nanmean(d[mask_imu], axis=0)),
        'rate': np.degrees(np.nanmean(imu.gyr[mask_imu], axis=0)),
    }
    filt, _ = build({})
    r = run_batch(filt, imu.t_s, imu.gyr, imu.acc, imu.mag)
    out['filter'] = np.degrees(np.mean(r.bias[mask_imu], axis=0))
    oracle = {'rest_bias': 'false', 'motion_bias': 'false'}
    gyr_corrected = imu.gyr - moving_mean(d, int(window * RATE_HZ))
    for key, gyr, settings in (('defaults', imu.gyr, {}), ('oracle', gyr_corrected, oracle)):
        f9, _ = build(settings)
        incl, _ = scores(f9, imu.t_s, gyr, imu.acc, imu.mag, t_ref, q_ref, mask)
        f6, _ = build({**settings, 'use_mag': 'false'})
        _, fit6 = scores(f6, imu.t_s, gyr, imu.acc, None, t_ref, q_ref, mask)
        out[key] = (incl, fit6)
    return trial.name, out


def main() -> None:
    ap: argparse.ArgumentParser = parser(__doc__)
    ap.add_argument('--trials', default='', help='comma-separated trial numbers (default: all)')
    ap.add_argument('--window', type=float, default=20.0, help='oracle: moving-mean window of the bias, s')
    args = ap.parse_args()
    trials, _ = trials_and_settings(args)
    if args.trials:
        keep = set(args.trials.split(','))
        trials = [t for t in trials if t.name[:2] in keep]
    res = map_trials(run_trial, [(t, args.window) for t in trials])

    def v(x: np.ndarray) -> str:
        return ' '.join(f'{c:+6.3f}' for c in x)

    print('gyro bias, deg/s, body x y z: at the first rest, while moving (motion capture), moving - rest, the default')
    print("filter's estimate while moving, and the mean body rate while moving")
    print(f'{"trial":44s} {"rest":>20s}  {"moving":>20s}  {"moving - rest":>20s}  {"filter":>20s}  {"mean rate":>20s}')
    diffs = []
    valid = set()
    for name, o in res:
        diff = o['moving'] - o['rest']
        ok = bool(np.all(np.abs(o['rate']) < MAX_MEAN_RATE_DEG_S))
        if ok:
            diffs.append(np.abs(diff))
            valid.add(name)
        note = '' if ok else '  (turns mostly one way: not a bias measurement)'
        print(f'{name:44s} {v(o["rest"])}  {v(o["moving"])}  {v(diff)}  {v(o["filter"])}  {v(o["rate"])}{note}')
    print(
        f'{"mean |moving - rest|, " + str(len(diffs)) + " trials":44s} {"":20s}  {"":20s}  {v(np.mean(diffs, axis=0))}'
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
    for label, sel in (
        ('mean', res),
        (f'mean of the {len(valid)} with a bias measurement', [x for x in res if x[0] in valid]),
    ):
        cols = (('defaults', 0), ('oracle', 0), ('defaults', 1), ('oracle', 1))
        m = [np.mean([o[k][i] for _, o in sel]) for k, i in cols]
        print(f'{label:44s} {m[0]:15.2f} {m[1]:13.2f} {m[2]:17.2f} {m[3]:15.2f}')


if __name__ == '__main__':
    main()
