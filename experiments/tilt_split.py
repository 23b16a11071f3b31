"""Where inclination is lost on the shared BROAD trials: 9-D against 6-D, at 286, 95 and 48 Hz.

Per trial and rate: the inclination RMSE while moving (9-D and 6-D), and the 9-D error split into its constant part
(the mean world-frame tilt vector while moving, minus the same at rest: the recording's IMU-to-marker misalignment is
in both) and the RMS about the mean. A 9-D figure above the 6-D one is tilt the magnetometer leaks in; a large
constant part at 48 Hz that is not there at 286 Hz is a sample-period effect.

Usage: python experiments/tilt_split.py [--shared ../shared/data/broad] [--rates 1,3,6] [NAME=VALUE ...]
"""

from __future__ import annotations

import numpy as np
from _trials import map_trials, parser, trials_and_settings
from inclination_offset import tilt_vectors

from ccf_ros.core import run_batch
from ccf_ros.core.metrics import summarize
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build


def run_trial(args: tuple) -> tuple[str, dict[str, tuple[float, ...]]]:
    trial, steps, settings = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    moving = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    rest = ~moving & (t_ref - t_ref[0] >= 5.0) & (t_ref - t_ref[0] < 25.0)
    out = {}
    for step in steps:
        sl = slice(None, None, step)
        t, gyr, acc, mag = imu.t_s[sl], imu.gyr[sl], imu.acc[sl], imu.mag[sl]
        for dims, use_mag in (('9', True), ('6', False)):
            filt, _ = build(settings if use_mag else {**settings, 'use_mag': 'false'})
            r = run_batch(filt, t, gyr, acc, mag if use_mag else None)
            q = align(t[r.answered], r.quat[r.answered], t_ref, q_ref)
            ok = np.isfinite(q).all(axis=1) & np.isfinite(q_ref).all(axis=1)
            inc = summarize(q, q_ref, moving).inclination_rmse_deg
            ev = tilt_vectors(q[ok & moving], q_ref[ok & moving])
            mean = ev.mean(axis=0) - tilt_vectors(q[ok & rest], q_ref[ok & rest]).mean(axis=0)
            about = float(np.sqrt(np.mean(np.sum((ev - ev.mean(axis=0)) ** 2, axis=1))))
            out[f'{step}/{dims}'] = (inc, float(np.linalg.norm(mean)), about)
    return trial.name, out


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument('--rates', default='1,3,6', help='decimation steps (1 = 286 Hz, 3 = 95 Hz, 6 = 48 Hz)')
    a = ap.parse_args()
    steps = [int(s) for s in a.rates.split(',')]
    trials, settings = trials_and_settings(a)
    res = map_trials(run_trial, [(t, steps, settings) for t in trials])
    print(f'settings {settings or "defaults"}: inclination RMSE while moving, deg: 9-D (its constant part beyond '
          'the rest\'s | RMS about the mean) and 6-D')
    for step in steps:
        print(f'\n== {286 / step:.0f} Hz')
        print(f'{"trial":40s} {"9-D":>6s} {"const":>6s} {"about":>6s} {"6-D":>6s} {"const":>6s} {"about":>6s}')
        for name, r in res:
            a9, a6 = r[f'{step}/9'], r[f'{step}/6']
            print(f'{name:40s} {a9[0]:6.3f} {a9[1]:6.3f} {a9[2]:6.3f} {a6[0]:6.3f} {a6[1]:6.3f} {a6[2]:6.3f}')
        m9 = np.mean([r[f'{step}/9'] for _, r in res], axis=0)
        m6 = np.mean([r[f'{step}/6'] for _, r in res], axis=0)
        print(f'{"mean":40s} {m9[0]:6.3f} {m9[1]:6.3f} {m9[2]:6.3f} {m6[0]:6.3f} {m6[1]:6.3f} {m6[2]:6.3f}')


if __name__ == '__main__':
    main()
