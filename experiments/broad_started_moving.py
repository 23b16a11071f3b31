"""The filter started in the middle of a BROAD trial, while the sensor moves (a node started on a moving robot, a
bag that begins mid-motion): heading RMSE over the moving samples from 10 s after the start to the end of the trial,
for starts at 30, 40 and 55 % of each of the nine shared trials. Defaults unless NAME=VALUE settings are given.
With ``--incl`` also the inclination RMSE over the same samples, 9-D beside 6-D (the magnetometer must not make
tilt worse: issue 23).

Usage: python experiments/broad_started_moving.py [--shared ../shared/data/broad] [--incl] [NAME=VALUE ...]
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from _trials import map_trials, parser, trials_and_settings

from ccf_ros.core import run_batch
from ccf_ros.core.metrics import summarize
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build

STARTS = (0.3, 0.4, 0.55)


def run_trial(args: tuple[Path, dict[str, str], bool]) -> tuple[str, list[float], list[tuple[float, float]]]:
    trial, settings, incl = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    out = []
    inc = []
    for frac in STARTS:
        k = int(frac * len(imu.t_s))
        filt, _ = build(settings)
        r = run_batch(filt, imu.t_s[k:], imu.gyr[k:], imu.acc[k:], imu.mag[k:])
        q = align(imu.t_s[k:][r.answered], r.quat[r.answered], t_ref, q_ref)
        sel = mask & (t_ref > imu.t_s[k] + 10.0)
        s9 = summarize(q, q_ref, sel)
        out.append(s9.heading_rmse_deg)
        if incl:
            f6, _ = build({**settings, 'use_mag': 'false'})
            r6 = run_batch(f6, imu.t_s[k:], imu.gyr[k:], imu.acc[k:], None)
            q6 = align(imu.t_s[k:][r6.answered], r6.quat[r6.answered], t_ref, q_ref)
            inc.append((s9.inclination_rmse_deg, summarize(q6, q_ref, sel).inclination_rmse_deg))
    return trial.name, out, inc


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument('--incl', action='store_true', help='also inclination, 9-D and 6-D')
    a = ap.parse_args()
    trials, settings = trials_and_settings(a)
    rows = map_trials(run_trial, [(t, settings, a.incl) for t in trials])
    print(f'heading RMSE (deg) after a start at {" / ".join(f"{100 * s:.0f} %" for s in STARTS)} of the trial')
    for name, r, _ in rows:
        print(f'{name:44s} ' + ' '.join(f'{x:7.2f}' for x in r))
    means = [float(np.mean([r[i] for _, r, _ in rows])) for i in range(len(STARTS))]
    print(f'{"mean":44s} ' + ' '.join(f'{m:7.2f}' for m in means))
    if a.incl:
        print('\ninclination RMSE (deg) over the same samples, 9-D / 6-D')
        for name, _, inc in rows:
            print(f'{name:44s} ' + ' '.join(f'{i9:5.2f} /{i6:5.2f}' for i9, i6 in inc))
        m = np.mean([inc for _, _, inc in rows], axis=0)
        print(f'{"mean":44s} ' + ' '.join(f'{i9:5.2f} /{i6:5.2f}' for i9, i6 in m))


if __name__ == '__main__':
    main()
