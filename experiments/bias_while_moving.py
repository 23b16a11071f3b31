"""Gyro bias learnt while moving (issue 8): rest detection off, a constant bias of 1 °/s on every axis (random
signs), simulated hand-held motion from the first sample (no rest), 400 s at 200 Hz, six random motions, 9-D and
6-D. Prints per motion the largest per-axis bias error at 60/120/200/300/400 s and the time after which it stays
within 0.1 °/s.

Usage: python experiments/bias_while_moving.py [--seeds 1,2,3,4,5,6] [NAME=VALUE ...]
"""

from __future__ import annotations

import argparse

import numpy as np

from ccf_ros.core import make_filter, run_batch
from ccf_ros.offline.simulate import generate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--seeds', default='1,2,3,4,5,6')
    ap.add_argument('params', nargs='*', help='NAME=VALUE filter settings')
    args = ap.parse_args()
    extra = {k: float(v) for k, v in (p.split('=', 1) for p in args.params)}
    print('bias error (max over axes, deg/s) at 60 / 120 / 200 / 300 / 400 s; within 0.1 deg/s from')
    for use_mag in (True, False):
        settled = []
        for seed in (int(s) for s in args.seeds.split(',')):
            d = generate(400.0, 200.0, seed=seed, bias_init_rad_s=0.0, bias_walk_rad_s_sqrt_s=0.0, rest_s=0.0)
            b_true = np.radians(1.0) * np.random.default_rng(seed).choice([-1.0, 1.0], 3)
            f = make_filter({'rest_bias': False, 'use_mag': use_mag, **extra})
            r = run_batch(f, d.t_s, d.gyr + b_true, d.acc, d.mag)
            err = np.degrees(np.abs(r.bias - b_true)).max(axis=1)
            t = d.t_s - d.t_s[0]
            above = np.flatnonzero(err > 0.1)
            t_ok = float(t[above[-1]]) if len(above) else 0.0
            done = len(above) == 0 or above[-1] < len(t) - 1
            settled.append(t_ok if done else np.inf)
            at = ' '.join(f'{err[int(x * 200) - 1]:5.3f}' for x in (60, 120, 200, 300, 400))
            print(f'{"9-D" if use_mag else "6-D"} motion {seed}: {at}   '
                  + (f'{t_ok:5.0f} s' if done else 'not within 0.1 deg/s at 400 s'))
        ok = sorted(s for s in settled if np.isfinite(s))
        print(f'{"9-D" if use_mag else "6-D"}: {len(ok)}/{len(settled)} within 0.1 deg/s by 400 s'
              + (f' (from {", ".join(f"{s:.0f}" for s in ok)} s)' if ok else ''))


if __name__ == '__main__':
    main()
