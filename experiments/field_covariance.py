"""Is the reported heading variance calibrated in a field that varies with position? Reported yaw 1-sigma against the
absolute heading RMSE over the moving samples, per layout of `field_sweep.py` (the same recordings: 40 Hz, 67 s,
hand-guided through one dipole's field), the defaults beside the given settings.

The ratio is sqrt(mean(var_yaw)) / RMSE per run, its geometric mean over the seeds; near 1 a downstream EKF can
trust the yaw covariance. Without the bias's heading rows (``bias_from_mag=false`` or ``motion_bias=false``) the
variance includes the heading blend's lag behind the world-up bias (doc/algorithm.md, "Reported covariance"). What
a variance cannot know is the field's own direction error at the sensor: in a strong dipole it dominates.

Usage: python experiments/field_covariance.py [--rest 0.5] [--bias-deg 0.15] [--seeds 0,...,5]
       [--only NAME,...] [NAME=VALUE ...]   (default settings compared: bias_from_mag=false)
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import field_sweep
import numpy as np
from _trials import map_trials
from simulated_accuracy import _heading_rmse

from ccf_ros.core import run_batch
from ccf_ros.settings import build

LAYOUTS = ['uniform (control)', '100/1.2 across', 'ref 300/1.2 across', '600/1.2 across']


def run_one(args: tuple[str, int, float, float, dict[str, str]]) -> tuple[str, int, list[tuple[float, float]]]:
    """(layout, seed, [(heading RMSE °, reported yaw σ °) for the defaults, then for ``settings``])."""
    name, seed, rest_s, bias_rad_s, settings = args
    field_sweep.BIAS[0] = bias_rad_s
    d, _ = field_sweep.make_data(name, 40.0, seed, rest_s)
    out = []
    for s in ({}, settings):
        filt, _ = build(s)
        r = run_batch(filt, d.t_s, d.gyr, d.acc, d.mag)
        sel = d.moving & r.answered
        out.append((_heading_rmse(r.quat, d.q_true, sel, fitted=False),
                    float(np.degrees(np.sqrt(np.mean(r.variance[sel, 2]))))))
    return name, seed, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--rest', type=float, default=0.5, help='rest before the motion, s (default 0.5: started moving)')
    ap.add_argument('--bias-deg', type=float, default=0.15, help="gyro's initial bias, °/s per axis (default 0.15)")
    ap.add_argument('--seeds', default='0,1,2,3,4,5')
    ap.add_argument('--only', default='', help='comma-separated layouts of field_sweep.py (default: four)')
    ap.add_argument('params', nargs='*', help='NAME=VALUE filter settings (default: bias_from_mag=false)')
    a = ap.parse_args()
    settings: dict[str, Any] = dict(p.split('=', 1) for p in a.params) or {'bias_from_mag': 'false'}
    seeds = [int(s) for s in a.seeds.split(',')]
    names = a.only.split(',') if a.only else LAYOUTS
    unknown = [n for n in names if n not in field_sweep.CONFIGS]
    if unknown:
        raise SystemExit(f'unknown layout(s) {unknown}; known: {", ".join(field_sweep.CONFIGS)}')
    t0 = time.time()
    res = map_trials(run_one, [(n, s, a.rest, np.radians(a.bias_deg), settings) for n in names for s in seeds])
    print(f'40 Hz, {field_sweep.DURATION_S:g} s, rest {a.rest:g} s, bias {a.bias_deg:g} °/s, seeds {seeds}; '
          f'heading RMSE / reported σ (deg, means over seeds) and σ/RMSE (geometric mean)')
    label = ' '.join(f'{k}={v}' for k, v in settings.items())
    print(f'{"layout":22s} | {"defaults":^26s} | {label:^26s}')
    for n in names:
        runs = [out for nn, _, out in res if nn == n]
        cols = []
        for k in range(2):
            e = np.array([o[k][0] for o in runs])
            s = np.array([o[k][1] for o in runs])
            cols.append(f'{e.mean():6.2f} {s.mean():6.2f} {np.exp(np.mean(np.log(s / e))):6.2f}x')
        print(f'{n:22s} | {cols[0]:>26s} | {cols[1]:>26s}')
    print(f'{time.time() - t0:.0f} s')


if __name__ == '__main__':
    main()
