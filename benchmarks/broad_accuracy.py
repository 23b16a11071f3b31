"""Accuracy of the default filter on the shared BROAD trials, through ``ccf replay``'s engine, at 286/95/48 Hz.

Usage: python benchmarks/broad_accuracy.py [--shared ../shared/data/broad] [--rates 1,3,6] [-- NAME=VALUE ...]
Prints per-trial total/heading/inclination RMSE (deg) and the mean, as in shared/data/broad/README.md.
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from ccf_ros.core import run_batch
from ccf_ros.core.metrics import summarize
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build

DEFAULT_SHARED = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'broad'


def run_trial(args: tuple[Path, list[int], dict[str, str]]) -> tuple[str, dict[int, tuple[float, float, float, int]]]:
    trial, steps, settings = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    out = {}
    for step in steps:
        sl = slice(None, None, step)
        filt, _ = build(settings)
        r = run_batch(filt, imu.t_s[sl], imu.gyr[sl], imu.acc[sl], imu.mag[sl])
        # Scored at every reference sample, estimate interpolated (decimated runs) as `ccf eval` does.
        s = summarize(align(imu.t_s[sl][r.answered], r.quat[r.answered], t_ref, q_ref), q_ref, mask)
        nan_out = int((~np.isfinite(r.quat).all(axis=1)).sum())
        out[step] = (s.total_rmse_deg, s.heading_rmse_deg, s.inclination_rmse_deg, nan_out)
    return trial.name, out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--shared', type=Path, default=DEFAULT_SHARED)
    ap.add_argument('--rates', default='1,3,6', help='decimation steps (1 = 286 Hz, 3 = 95 Hz, 6 = 48 Hz)')
    ap.add_argument('params', nargs='*', help='NAME=VALUE filter settings')
    a = ap.parse_args()
    steps = [int(s) for s in a.rates.split(',')]
    settings = dict(p.split('=', 1) for p in a.params)
    trials = sorted(p for p in a.shared.iterdir() if p.is_dir() and p.name[:2].isdigit())
    t0 = time.time()
    with ProcessPoolExecutor(2) as ex:
        results = dict(ex.map(run_trial, [(t, steps, settings) for t in trials]))
    for step in steps:
        print(f'\n== {286 / step:.0f} Hz  settings {settings or "defaults"}')
        print(f'{"trial":45s} {"total":>7s} {"head":>7s} {"incl":>7s}  unanswered')
        for name, res in results.items():
            tot, head, inc, nan_out = res[step]
            print(f'{name:45s} {tot:7.2f} {head:7.2f} {inc:7.2f}  {nan_out}')
        means = np.mean([res[step][:3] for res in results.values()], axis=0)
        print(f'{"mean":45s} {means[0]:7.2f} {means[1]:7.2f} {means[2]:7.2f}')
    if 1 in steps:
        base = np.mean([r[1][0] for r in results.values()])
        for step in steps[1:]:
            m = np.mean([r[step][0] for r in results.values()])
            print(f'rate ratio {286 / step:.0f} Hz / 286 Hz: {m / base:.3f}')
    print(f'({time.time() - t0:.0f} s)')


if __name__ == '__main__':
    main()
