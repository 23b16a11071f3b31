"""The filter started in the middle of a BROAD trial, while the sensor moves (a node started on a moving robot, a
bag that begins mid-motion): heading RMSE over the moving samples from 10 s after the start to the end of the trial,
for starts at 30, 40 and 55 % of each of the nine shared trials. Defaults unless NAME=VALUE settings are given.

Usage: python experiments/broad_started_moving.py [--shared ../shared/data/broad] [NAME=VALUE ...]
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


def run_trial(args: tuple[Path, dict[str, str]]) -> tuple[str, list[float]]:
    trial, settings = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    out = []
    for frac in STARTS:
        k = int(frac * len(imu.t_s))
        filt, _ = build(settings)
        r = run_batch(filt, imu.t_s[k:], imu.gyr[k:], imu.acc[k:], imu.mag[k:])
        q = align(imu.t_s[k:][r.answered], r.quat[r.answered], t_ref, q_ref)
        out.append(summarize(q, q_ref, mask & (t_ref > imu.t_s[k] + 10.0)).heading_rmse_deg)
    return trial.name, out


def main() -> None:
    trials, settings = trials_and_settings(parser(__doc__).parse_args())
    rows = map_trials(run_trial, [(t, settings) for t in trials])
    print(f'heading RMSE (deg) after a start at {" / ".join(f"{100 * s:.0f} %" for s in STARTS)} of the trial')
    for name, r in rows:
        print(f'{name:44s} ' + ' '.join(f'{x:7.2f}' for x in r))
    means = [float(np.mean([r[i] for _, r in rows])) for i in range(len(STARTS))]
    print(f'{"mean":44s} ' + ' '.join(f'{m:7.2f}' for m in means))


if __name__ == '__main__':
    main()
