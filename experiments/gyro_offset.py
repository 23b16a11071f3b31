"""Large constant gyro offsets on a shared BROAD trial (5 and 10 deg/s added to every gyro axis).

For each offset, total RMSE (deg) over the moving samples:
- ``defaults``: the filter must learn the offset itself (at the first rest: bias_max_rad_s 15 deg/s, rest judged by
  steadiness, not by the rate's size);
- ``gyro_offset_rad_s``: the true offset given (subtracted first): should equal the clean trial;
- ``bias_file``: a first run over the whole trial writes the bias file; a second run, started at the first moving
  sample (a robot restarted while moving: no rest to learn from), loads it; scored over its first 60 s of motion,
  beside the same start without the file and the clean trial's same window.

Usage: python experiments/gyro_offset.py [--shared ../shared/data/broad] [--trials 02] [--offsets 5,10] [NAME=VALUE ...]
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
from _trials import parser, trials_and_settings
from mounting import run_engine, score

from ccf_ros.offline.bagio import read_bools, read_imu_arrays

WINDOW_S = 60.0


def main() -> None:
    ap = parser(__doc__, trials='02')
    ap.add_argument('--offsets', default='5,10', help='offsets to add, deg/s (every axis)')
    a = ap.parse_args()
    trials, settings = trials_and_settings(a)
    for trial in trials:
        imu = read_imu_arrays(trial)
        t_mv, mv = read_bools(trial, '/ground_truth/moving')
        t_start = float(t_mv[np.argmax(mv)])
        window = (t_start, t_start + WINDOW_S)
        k0 = int(np.searchsorted(imu.t_s, t_start))
        late = slice(k0, None)
        t, q, _ = run_engine(settings, imu.t_s, imu.gyr, imu.acc, imu.mag)
        clean = score(trial, t, q)
        t, q, _ = run_engine(settings, imu.t_s[late], imu.gyr[late], imu.acc[late], imu.mag[late])
        clean_late = score(trial, t, q, window)
        print(f'\n== {trial.name}  settings {settings or "defaults"}; motion starts at {t_start - imu.t_s[0]:.1f} s')
        print(f'clean: total RMSE {clean:.3f} deg; started at the motion, first {WINDOW_S:.0f} s of motion: '
              f'{clean_late:.3f} deg')
        print(f'{"offset":>8s} {"case":52s} {"RMSE deg":>9s} {"x clean":>8s} {"bias learnt deg/s (x, y, z)":>30s}')
        for off_deg in (float(v) for v in a.offsets.split(',')):
            off = math.radians(off_deg)
            gyr = imu.gyr + off
            rows = []
            t, q, eng = run_engine(settings, imu.t_s, gyr, imu.acc, imu.mag)
            rows.append(('defaults (whole trial)', score(trial, t, q), clean, eng.filter.gyro_bias))
            t, q, eng = run_engine({**settings, 'gyro_offset_rad_s': f'[{off!r}, {off!r}, {off!r}]'}, imu.t_s, gyr,
                                   imu.acc, imu.mag)
            rows.append(('gyro_offset_rad_s = the offset (whole trial)', score(trial, t, q), clean, eng.filter.gyro_bias))
            with tempfile.TemporaryDirectory() as tmp:
                path = str(Path(tmp) / 'bias.json')
                run_engine({**settings, 'bias_file': path}, imu.t_s, gyr, imu.acc, imu.mag)[2].save_state(path)
                t, q, eng = run_engine({**settings, 'bias_file': path}, imu.t_s[late], gyr[late], imu.acc[late],
                                       imu.mag[late])
                rows.append((f'bias_file from run 1, started moving, first {WINDOW_S:.0f} s', score(trial, t, q, window),
                             clean_late, eng.filter.gyro_bias))
            t, q, eng = run_engine(settings, imu.t_s[late], gyr[late], imu.acc[late], imu.mag[late])
            rows.append((f'no bias_file, started moving, first {WINDOW_S:.0f} s', score(trial, t, q, window), clean_late,
                         eng.filter.gyro_bias))
            for name, rmse, ref, b in rows:
                bias = ', '.join(f'{math.degrees(v):.2f}' for v in b)
                print(f'{off_deg:8.1f} {name:52s} {rmse:9.3f} {rmse / ref:8.2f} {bias:>30s}')


if __name__ == '__main__':
    main()
