"""Is the reported orientation covariance calibrated? Reported 1-sigma vs measured RMSE on the shared BROAD trials.

Per trial, over the moving samples: inclination -- sqrt(mean(var_roll + var_pitch)) vs the inclination RMSE; heading
-- sqrt(mean(var_yaw)) vs the heading RMSE (9-D), and in 6-D (``--no-mag`` like) the yaw variance, documented as
relative, vs the heading RMSE after fitting one heading offset per trial (the drift). Ratios near 1 mean a
downstream EKF can trust the IMU's covariance. Also the 48 Hz / 286 Hz ratio of the reported sigma (rate independence).

Usage: python experiments/covariance.py [--shared ../shared/data/broad] [NAME=VALUE ...]
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from _trials import map_trials, parser, trials_and_settings

from ccf_ros.core import run_batch
from ccf_ros.core.metrics import error_angles, fit_heading_offset
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build


def run_trial(args: tuple[Path, dict[str, str]]) -> tuple[str, dict[str, float]]:
    trial, settings = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    out: dict[str, float] = {}
    for label, step, use_mag in (('9d', 1, True), ('9d48', 6, True), ('6d', 1, False)):
        sl = slice(None, None, step)
        filt, _ = build({**settings, 'use_mag': use_mag})
        r = run_batch(filt, imu.t_s[sl], imu.gyr[sl], imu.acc[sl], imu.mag[sl] if use_mag else None)
        q = align(imu.t_s[sl][r.answered], r.quat[r.answered], t_ref, q_ref)
        var = np.full((len(t_ref), 3), np.nan)
        idx = np.searchsorted(imu.t_s[sl][r.answered], t_ref)
        ok = idx < r.answered.sum()
        var[ok] = r.variance[r.answered][idx[ok]]
        sel = mask & np.all(np.isfinite(q_ref), axis=1) & np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(var), 1)
        ref = fit_heading_offset(q[sel], q_ref[sel]) if not use_mag else q_ref[sel]
        _, head, incl = error_angles(q[sel], ref)
        out[f'{label}_incl_rmse'] = float(np.degrees(np.sqrt(np.mean(incl**2))))
        out[f'{label}_head_rmse'] = float(np.degrees(np.sqrt(np.mean(head**2))))
        out[f'{label}_incl_sigma'] = float(np.degrees(np.sqrt(np.mean(var[sel, 0] + var[sel, 1]))))
        out[f'{label}_head_sigma'] = float(np.degrees(np.sqrt(np.mean(var[sel, 2]))))
    return trial.name, out


def main() -> None:
    trials, settings = trials_and_settings(parser(__doc__).parse_args())
    res = dict(map_trials(run_trial, [(t, settings) for t in trials]))

    print(f'{"trial":36s} | {"inclination sigma / RMSE, deg":30s} | {"heading 9-D sigma / RMSE":26s} | '
          f'{"heading 6-D (relative) sigma / RMSE":34s}')
    ratios: dict[str, list[float]] = {'incl': [], 'head': [], 'head6': [], 'rate': []}
    for name, r in res.items():
        ri = r['9d_incl_sigma'] / r['9d_incl_rmse']
        rh = r['9d_head_sigma'] / r['9d_head_rmse']
        r6 = r['6d_head_sigma'] / r['6d_head_rmse']
        ratios['incl'].append(ri)
        ratios['head'].append(rh)
        ratios['head6'].append(r6)
        ratios['rate'].append(np.hypot(r['9d48_incl_sigma'], r['9d48_head_sigma'])
                              / np.hypot(r['9d_incl_sigma'], r['9d_head_sigma']))
        print(f'{name[:36]:36s} | {r["9d_incl_sigma"]:5.2f} / {r["9d_incl_rmse"]:5.2f} = {ri:4.2f}x{"":12s} | '
              f'{r["9d_head_sigma"]:5.2f} / {r["9d_head_rmse"]:5.2f} = {rh:4.2f}x{"":4s} | '
              f'{r["6d_head_sigma"]:5.2f} / {r["6d_head_rmse"]:5.2f} = {r6:4.2f}x')
    for key, label in (('incl', 'inclination'), ('head', 'heading 9-D'), ('head6', 'heading 6-D (relative)')):
        v = np.array(ratios[key])
        print(f'{label:24s}: reported/measured geometric mean {np.exp(np.mean(np.log(v))):.2f}, '
              f'range {v.min():.2f}-{v.max():.2f}')
    v = np.array(ratios['rate'])
    print(f'reported sigma 48 Hz / 286 Hz: {v.min():.3f}-{v.max():.3f} (mean {v.mean():.3f})')


if __name__ == '__main__':
    main()
