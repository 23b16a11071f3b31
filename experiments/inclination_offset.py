"""Where the inclination error on the shared BROAD trials comes from: a constant part and the rest.

For each trial the inclination error during motion is split into its mean (a world-frame tilt vector, degrees east /
north) and the RMS about that mean. At rest (the first 5-25 s) the mean is the IMU-to-marker misalignment of the
recording, the same for every filter. While moving, a gyro-bias error b adds a tilt offset of about b times the
tilt path's ramp lag (tau_acc_lp_s + tau_acc_s, 3.5 s at the defaults): the script runs the defaults, the tilt time
constants scaled by 0.6 and 1.6 (lag 2.1 and 5.6 s), and with motion_bias off, to show what learning the bias while
moving takes off the offset.

Usage: python experiments/inclination_offset.py [--shared ../shared/data/broad] [--trials 02,11,16] [NAME=VALUE ...]
"""

from __future__ import annotations

import numpy as np
from _trials import map_trials, parser, trials_and_settings

from ccf_ros.core import run_batch
from ccf_ros.core.quaternion import quat_conj, quat_mul, quat_to_rotvec
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build

VARIANTS = {
    'defaults': {},
    'tilt lag x0.6 (tau_acc_lp 1.5 s, tau_acc 0.6 s)': {'tau_acc_s': '0.6', 'tau_acc_lp_s': '1.5'},
    'tilt lag x1.6 (tau_acc_lp 4 s, tau_acc 1.6 s)': {'tau_acc_s': '1.6', 'tau_acc_lp_s': '4'},
    'no motion bias learning': {'motion_bias': 'false'},
}


def tilt_vectors(q_est: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """``(N, 2)`` world-frame tilt error (east, north components of the swing of ``q_est ⊗ q_ref⁻¹``), degrees."""
    e = quat_mul(q_est, quat_conj(q_ref))
    e = e * np.sign(e[:, :1] + 1e-300)
    twist = e[:, [0, 3]] / np.linalg.norm(e[:, [0, 3]], axis=1, keepdims=True)
    t = np.zeros_like(e)
    t[:, 0], t[:, 3] = twist[:, 0], twist[:, 1]
    return np.degrees(quat_to_rotvec(quat_mul(e, quat_conj(t)))[:, :2])


def run_trial(args: tuple) -> tuple[str, dict[str, tuple[float, ...]]]:
    trial, settings = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    moving = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    rest = ~moving & (t_ref - t_ref[0] >= 5.0) & (t_ref - t_ref[0] < 25.0)
    out = {}
    for name, variant in VARIANTS.items():
        filt, _ = build({**settings, **variant})
        r = run_batch(filt, imu.t_s, imu.gyr, imu.acc, imu.mag)
        q = align(imu.t_s[r.answered], r.quat[r.answered], t_ref, q_ref)
        ok = np.isfinite(q).all(axis=1) & np.isfinite(q_ref).all(axis=1)
        ev = tilt_vectors(q[ok & moving], q_ref[ok & moving])
        mean = ev.mean(axis=0)
        rest_mean = tilt_vectors(q[ok & rest], q_ref[ok & rest]).mean(axis=0)
        rms = float(np.sqrt(np.mean(np.sum(ev**2, axis=1))))
        about = float(np.sqrt(np.mean(np.sum((ev - mean) ** 2, axis=1))))
        out[name] = (rms, *mean, about, float(np.linalg.norm(rest_mean)))
    return trial.name, out


def main() -> None:
    ap = parser(__doc__)
    a = ap.parse_args()
    trials, settings = trials_and_settings(a)
    results = map_trials(run_trial, [(t, settings) for t in trials])
    for name in VARIANTS:
        print(f'\n== {name}: inclination RMSE while moving = its mean (world tilt, deg east / north) + RMS about it')
        print(f'{"trial":45s} {"incl":>6s} {"east":>7s} {"north":>7s} {"about":>6s}   |mean| at rest')
        for trial, res in results:
            rms, east, north, about, at_rest = res[name]
            print(f'{trial:45s} {rms:6.3f} {east:7.3f} {north:7.3f} {about:6.3f}   {at_rest:.3f}')
        m = np.mean([res[name] for _, res in results], axis=0)
        print(f'{"mean":45s} {m[0]:6.3f} {"":15s} {m[3]:6.3f}')


if __name__ == '__main__':
    main()
