"""The bias Kalman's observation noise while rotating: the cross-axis share (``bias._CROSS_AXIS``) swept.

A gyro scale error's rate error lies along the rotation axis, its cross-axis sensitivity's across it; a bias
observation row (east, north, up in the body) is inflated by the rate along it, plus this share of the whole rate
(1 = the isotropic inflation by |w|² of before). Prints, per share, the 6-D figures (no magnetometer; one heading
offset fitted): the planar swing (a pendulum, ``experiments/simulated_accuracy.py --mag``'s) at 40/100/286 Hz, the
simulated hand-held scenarios, and the nine BROAD trials at 286 Hz (with ``--shared``; per trial).

Usage: python experiments/bias_cross_axis.py [--shared ../shared/data/broad] [--shares 0,0.33,0.67,1 (negative: the rate low-passed)]
       [--seeds 0,1,2] [--no-broad] [--no-sim] [NAME=VALUE ...]
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from _trials import map_trials, parser, trials_and_settings
from simulated_accuracy import MAG_RATES, SCENARIOS, _data, _heading_rmse, mag_env_data

from ccf_ros.core import run_batch
from ccf_ros.core.ccf import bias
from ccf_ros.core.metrics import fitted_total_rmse_deg
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build


def _share(share: float) -> None:
    """Set the cross-axis share in this (worker) process (negative: its magnitude, with the rate low-passed)."""
    bias._RATE_LP = share < 0.0
    share = abs(share)
    bias._CROSS_AXIS = share
    bias._CROSS_AXIS2 = share * share


def run_swing(args: tuple[float, float, int, dict[str, str]]) -> tuple[float, float, float]:
    """(share, rate, 6-D heading RMSE fitted) of one planar-swing run."""
    share, rate, seed, settings = args
    _share(share)
    d = mag_env_data('planar swing', rate, seed)
    f6, _ = build({**settings, 'use_mag': 'false'})
    q6 = run_batch(f6, d.t_s, d.gyr, d.acc, None).quat
    return share, rate, _heading_rmse(q6, d.q_true, d.moving, fitted=True)


def run_hand(args: tuple[float, str, int, dict[str, str]]) -> tuple[float, str, float]:
    """(share, scenario, 6-D fitted total) of one simulated scenario run."""
    share, name, seed, settings = args
    _share(share)
    d = _data(name, seed)
    f6, _ = build({**settings, 'use_mag': 'false'})
    q6 = run_batch(f6, d.t_s, d.gyr, d.acc, None).quat
    return share, name, fitted_total_rmse_deg(q6, d.q_true, d.moving)


def run_broad(args: tuple[float, Path, dict[str, str]]) -> tuple[float, str, float]:
    """(share, trial, 6-D fitted total) of one BROAD trial at 286 Hz."""
    share, trial, settings = args
    _share(share)
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    f6, _ = build({**settings, 'use_mag': 'false'})
    r = run_batch(f6, imu.t_s, imu.gyr, imu.acc, None)
    q = align(imu.t_s[r.answered], r.quat[r.answered], t_ref, q_ref)
    return share, trial.name, fitted_total_rmse_deg(q, q_ref, mask)


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument('--shares', default='0,0.33,0.67,1')
    ap.add_argument('--seeds', default='0,1,2')
    ap.add_argument('--no-broad', action='store_true')
    ap.add_argument('--no-sim', action='store_true')
    a = ap.parse_args()
    shares = [float(s) for s in a.shares.split(',')]
    seeds = [int(s) for s in a.seeds.split(',')]
    trials, settings = trials_and_settings(a) if not a.no_broad else ([], dict(p.split('=', 1) for p in a.params))
    jobs: list[tuple[Any, ...]] = []
    if not a.no_sim:
        sw = map_trials(run_swing, [(s, r, sd, settings) for s in shares for r in MAG_RATES for sd in seeds])
        hd = map_trials(run_hand, [(s, n, sd, settings) for s in shares for n in SCENARIOS for sd in seeds])
        print(f'6-D, degrees, mean over seeds {seeds}; settings {settings or "defaults"}')
        print(f'{"share":>6s} ' + ' '.join(f'{"swing " + str(int(r)):>10s}' for r in MAG_RATES)
              + ' ' + ' '.join(f'{n[:10]:>10s}' for n in SCENARIOS) + f' {"hand mean":>10s}')
        for s in shares:
            row = [np.mean([x for sh, r, x in sw if sh == s and r == rate]) for rate in MAG_RATES]
            hand = [np.mean([x for sh, n, x in hd if sh == s and n == name]) for name in SCENARIOS]
            print(f'{s:6.2f} ' + ' '.join(f'{x:10.2f}' for x in row + hand) + f' {np.mean(hand):10.2f}')
    if trials:
        jobs = [(s, t, settings) for s in shares for t in trials]
        br = map_trials(run_broad, jobs)
        names = sorted({n for _, n, _ in br})
        print('\nBROAD 286 Hz, 6-D fitted total, degrees')
        print(f'{"share":>6s} ' + ' '.join(f'{n[:2]:>5s}' for n in names) + f' {"mean":>6s}')
        for s in shares:
            row = [next(x for sh, n2, x in br if sh == s and n2 == n) for n in names]
            print(f'{s:6.2f} ' + ' '.join(f'{x:5.2f}' for x in row) + f' {np.mean(row):6.2f}')


if __name__ == '__main__':
    main()
