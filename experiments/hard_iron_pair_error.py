"""How far the filter's own relative rotation between two samples <= 1 s apart is from the gyro's (issue 23).

The online hard-iron estimator (``ccf_ros/core/hard_iron.py``) pairs magnetometer samples through ``M = R_k^T R_j``
taken from the filter's orientation: ``M`` then contains the filter's corrections over the pair (tilt towards the
accelerometer, tau_acc_s; heading towards the magnetometer, tau_mag_s; a re-acquisition). This script runs the
engine (``mag_online_calibration`` on: the filter sees the corrected field, as it will) and compares, for every
pair the estimator would form (every 0.1 s, with the sample 1 s earlier), the filter's relative rotation with the
gyro's (bias-corrected by the filter's estimate, integrated per sample): the angle between the two, deg. An angle
``a`` (rad) makes an error of at most ``a`` x the field norm in ``M m_j``: compare with the estimator's residual
threshold (RESIDUAL_MAX_REL, 4 % of the field = 2.3 deg) and floor (1 % = 0.57 deg).

Usage: python experiments/hard_iron_pair_error.py [--shared DIR] [--trials 27,33] [--skip-sim] [NAME=VALUE ...]
"""

from __future__ import annotations

import numpy as np
from _trials import map_trials, parser, trials_and_settings

from ccf_ros.core.quaternion import quat_angle, quat_conj, quat_from_rotvec, quat_mul
from ccf_ros.engine import ImuEngine
from ccf_ros.offline.bagio import read_imu_arrays
from ccf_ros.offline.evaluate import engine_orientations
from ccf_ros.offline.simulate import dipole_field, generate, with_mag_distortion
from ccf_ros.settings import build

LAG_S = 1.0
PERIOD_S = 0.1


def pair_errors(settings: dict, t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray) -> np.ndarray:
    """Angles (deg) between the filter's and the gyro's rotation over every 0.1 s pair spanning 1 s."""
    eng = ImuEngine(*build({'mag_online_calibration': True, **settings}))
    qf = np.full((len(t), 4), np.nan)
    bias = np.zeros((len(t), 3))

    def look(k: int, _t: float) -> None:
        f = eng.filter
        if f.initialized:
            qf[k] = f.quaternion
        bias[k] = f.gyro_bias

    engine_orientations(eng, t, gyr, acc, mag, look)
    # The gyro's own integration, with the bias the filter had before each step (as the filter integrates).
    dt = np.diff(t)
    rv = (gyr[1:] - bias[:-1]) * dt[:, None]
    steps = quat_from_rotvec(rv)
    qg = np.empty((len(t), 4))
    qg[0] = (1.0, 0.0, 0.0, 0.0)
    cur = np.array([1.0, 0.0, 0.0, 0.0])
    for k in range(1, len(t)):
        cur = quat_mul(cur, steps[k - 1])
        cur /= np.linalg.norm(cur)
        qg[k] = cur
    k_idx = np.searchsorted(t, np.arange(t[0] + LAG_S + 1.0, t[-1], PERIOD_S))
    j_idx = np.searchsorted(t, t[k_idx] - LAG_S)
    ok = np.all(np.isfinite(qf[k_idx]), axis=1) & np.all(np.isfinite(qf[j_idx]), axis=1)
    k_idx, j_idx = k_idx[ok], j_idx[ok]
    rel_f = quat_mul(quat_conj(qf[k_idx]), qf[j_idx])
    rel_g = quat_mul(quat_conj(qg[k_idx]), qg[j_idx])
    return np.degrees(quat_angle(quat_mul(quat_conj(rel_f), rel_g)))


def line(name: str, e: np.ndarray) -> str:
    return (f'{name:32s} {np.median(e):7.3f} {np.percentile(e, 95):7.3f} {np.percentile(e, 99):7.3f} '
            f'{e.max():7.3f}  {np.mean(e > 0.57):6.2%} {np.mean(e > 2.3):6.2%}')


HEADER = f'{"recording":32s} {"median":>7s} {"p95":>7s} {"p99":>7s} {"max":>7s}  {">0.57":>6s} {">2.3":>6s}   (deg)'


def simulated() -> None:
    d = generate(120.0, 100.0, 3)
    cases = {
        'sim hand, clean': d,
        'sim hand, offset 30/-12/8 uT': with_mag_distortion(d, np.array([30.0, -12.0, 8.0]) * 1e-6),
        'sim hand, dipole at 0.25 m': generate(120.0, 100.0, 3, field=dipole_field([0.25, 0.0, 0.0],
                                                                                  [0.0, 0.0, 1.0])),
    }
    print(HEADER)
    for name, s in cases.items():
        print(line(name, pair_errors({}, s.t_s, s.gyr, s.acc, s.mag)))


def run_trial(args: tuple) -> tuple[str, np.ndarray]:
    trial, settings = args
    imu = read_imu_arrays(trial)
    return trial.name, pair_errors(settings, imu.t_s, imu.gyr, imu.acc, imu.mag)


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument('--skip-sim', action='store_true')
    a = ap.parse_args()
    if not a.skip_sim:
        simulated()
    trials, settings = trials_and_settings(a)
    if trials:
        print(HEADER)
        allv = []
        for name, e in map_trials(run_trial, [(t, settings) for t in trials]):
            print(line(name[:32], e))
            allv.append(e)
        print(line('all trials', np.concatenate(allv)))


if __name__ == '__main__':
    main()
