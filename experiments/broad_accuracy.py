"""Accuracy of the default filter on the shared BROAD trials, through ``ccf replay``'s engine, at 286/95/48 Hz.

Usage: python experiments/broad_accuracy.py [--shared ../shared/data/broad] [--rates 1,3,6] [--no-6d] [NAME=VALUE ...]
Prints per-trial total/heading/inclination RMSE (deg) and the mean, beside the VQF columns of
shared/data/broad/README.md; and the 6-D run (no magnetometer) at each rate, scored with one heading offset fitted per trial.
Lower rates are made two ways: every n-th sample (point samples, the usual benchmark) and the mean of each n samples
(what a sensor running at the lower output rate reports: its decimation filter averages); the means are printed as a
last line per rate.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from _trials import map_trials, parser, run_9d, trials_and_settings

from ccf_ros.core.metrics import fitted_total_rmse_deg, summarize
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build

#: VQF's figures on these trials (shared/data/broad/README.md): online total, inclination, heading; 6-D fitted total.
VQF = {
    '02': (1.38, 0.43, 1.31, 0.63), '05': (0.99, 0.35, 0.92, 0.67), '07': (1.75, 1.02, 1.43, 1.55),
    '11': (0.90, 0.42, 0.80, 0.68), '16': (0.74, 0.54, 0.51, 0.66), '25': (1.62, 0.38, 1.57, 1.74),
    '27': (6.73, 0.37, 6.72, 1.70), '30': (2.57, 1.25, 2.25, 5.22), '33': (3.75, 0.60, 3.70, 2.31),
}


def _decimated(imu, step: int, *, mean: bool) -> tuple[np.ndarray, ...]:
    """(t_s, gyr, acc, mag) at 1/step of the rate: every step-th sample, or (mean) the mean of each step samples
    stamped at the last of them."""
    if not mean:
        sl = slice(None, None, step)
        return imu.t_s[sl], imu.gyr[sl], imu.acc[sl], imu.mag[sl]
    n = len(imu.t_s) // step * step

    def box(x: np.ndarray) -> np.ndarray:
        return x[:n].reshape(-1, step, 3).mean(axis=1)

    return imu.t_s[step - 1:n:step], box(imu.gyr), box(imu.acc), box(imu.mag)


def run_trial(args: tuple[Path, list[int], dict[str, str], bool]) -> tuple[str, dict[str, tuple[float, ...]]]:
    trial, steps, settings, six_d = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    out: dict[str, tuple[float, ...]] = {}
    runs = [(str(step), step, True) for step in steps] + [(f'{step}m', step, True) for step in steps if step > 1]
    runs += [(f'6d{step}', step, False) for step in steps] if six_d else []
    for key, step, use_mag in runs:
        t, gyr, acc, mag = _decimated(imu, step, mean=key.endswith('m'))
        filt, adapter = build({**settings, 'use_mag': use_mag} if not use_mag else settings)
        quat, answered = run_9d(filt, adapter, t, gyr, acc, mag if use_mag else None)
        # Scored at every reference sample, estimate interpolated (decimated runs) as `ccf eval` does.
        q = align(t[answered], quat[answered], t_ref, q_ref)
        s = summarize(q, q_ref, mask)
        nan_out = int((~np.isfinite(quat).all(axis=1)).sum())
        fitted = float('nan') if use_mag else fitted_total_rmse_deg(q, q_ref, mask)
        out[key] = (s.total_rmse_deg, s.heading_rmse_deg, s.inclination_rmse_deg, nan_out, fitted)
    return trial.name, out


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument('--rates', default='1,3,6', help='decimation steps (1 = 286 Hz, 3 = 95 Hz, 6 = 48 Hz)')
    ap.add_argument('--no-6d', action='store_true', help='skip the run without magnetometer')
    a = ap.parse_args()
    steps = [int(s) for s in a.rates.split(',')]
    trials, settings = trials_and_settings(a)
    t0 = time.time()
    results = dict(map_trials(run_trial, [(t, steps, settings, not a.no_6d) for t in trials]))
    for step in steps:
        key = str(step)
        print(f'\n== {286 / step:.0f} Hz  settings {settings or "defaults"}   (VQF online: total / inclination / heading)')
        print(f'{"trial":45s} {"total":>7s} {"head":>7s} {"incl":>7s}   {"VQF":>17s}  NaN out')
        for name, res in results.items():
            tot, head, inc, nan_out, _ = res[key]
            v = VQF.get(name[:2])
            ref = f'{v[0]:5.2f} {v[1]:5.2f} {v[2]:5.2f}' if v and step == 1 else ''
            print(f'{name:45s} {tot:7.2f} {head:7.2f} {inc:7.2f}   {ref:>17s}  {nan_out}')
        means = np.mean([res[key][:3] for res in results.values()], axis=0)
        vq = np.mean([VQF[n[:2]] for n in results if n[:2] in VQF], axis=0) if step == 1 else None
        ref = f'{vq[0]:5.2f} {vq[1]:5.2f} {vq[2]:5.2f}' if vq is not None else ''
        print(f'{"mean":45s} {means[0]:7.2f} {means[1]:7.2f} {means[2]:7.2f}   {ref:>17s}')
        if step > 1:
            mm = np.mean([res[f'{step}m'][:3] for res in results.values()], axis=0)
            print(f'{"mean, averaged samples":45s} {mm[0]:7.2f} {mm[1]:7.2f} {mm[2]:7.2f}')
    if 1 in steps:
        base = np.mean([r['1'][0] for r in results.values()])
        for step in steps[1:]:
            m = np.mean([r[str(step)][0] for r in results.values()])
            mm = np.mean([r[f'{step}m'][0] for r in results.values()])
            print(f'rate ratio {286 / step:.0f} Hz / 286 Hz: {m / base:.3f} (averaged samples {mm / base:.3f})')
    for step in steps if not a.no_6d else []:
        key = f'6d{step}'
        print(f'\n== 6-D (no magnetometer), {286 / step:.0f} Hz: total with one heading offset fitted per trial, '
              'inclination')
        for name, res in results.items():
            v = VQF.get(name[:2])
            ref = f'VQF 6D {v[3] if v else float("nan"):5.2f}' if step == 1 else ''
            print(f'{name:45s} {res[key][4]:7.2f} {res[key][2]:7.2f}   {ref}')
        m6 = np.mean([r[key][4] for r in results.values()])
        i6 = np.mean([r[key][2] for r in results.values()])
        ref = f'VQF 6D {np.mean([v[3] for v in VQF.values()]):5.2f}' if step == 1 else ''
        print(f'{"mean":45s} {m6:7.2f} {i6:7.2f}   {ref}')
    print(f'({time.time() - t0:.0f} s)')


if __name__ == '__main__':
    main()
