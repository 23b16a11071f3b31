"""Where the heading error on the shared BROAD trials comes from: a constant part and the rest.

For each trial the signed heading error (rotation of ``q_est ⊗ q_ref⁻¹`` about the vertical, degrees) while moving is
split into its mean and the RMS about that mean, and the mean is compared with the one at rest (5-25 s). On every
trial, the translation trials included (whose orientation barely changes), the mean while moving is 0.6-2.1° below
the mean at rest (VQF's output, scored the same way in a scratch environment: 0.7-2.4°): the north the magnetometer
gives where the IMU moves is not the north it gives where it rests, against the same reference. A filter cannot
know which is right, so that part of the heading error belongs to the recording.

Usage: python benchmarks/heading_offset.py [--shared ../shared/data/broad] [--trials 02,11] [NAME=VALUE ...]
"""

from __future__ import annotations

import numpy as np
from _trials import map_trials, parser, trials_and_settings

from ccf_ros.core import run_batch
from ccf_ros.core.quaternion import quat_conj, quat_mul
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build


def signed_heading(q_est: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """``(N,)`` heading error, degrees: the twist of ``q_est ⊗ q_ref⁻¹`` about the world vertical, in (-180, 180]."""
    e = quat_mul(q_est, quat_conj(q_ref))
    e = e * np.sign(e[:, :1] + 1e-300)
    return np.degrees(2.0 * np.arctan2(e[:, 3], e[:, 0]))


def run_trial(args: tuple) -> tuple[str, tuple[float, ...]]:
    trial, settings = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    moving = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    rest = ~moving & (t_ref - t_ref[0] >= 5.0) & (t_ref - t_ref[0] < 25.0)
    filt, _ = build(settings)
    r = run_batch(filt, imu.t_s, imu.gyr, imu.acc, imu.mag)
    q = align(imu.t_s[r.answered], r.quat[r.answered], t_ref, q_ref)
    ok = np.isfinite(q).all(axis=1) & np.isfinite(q_ref).all(axis=1)
    h = signed_heading(q[ok & moving], q_ref[ok & moving])
    mean = float(h.mean())
    at_rest = float(signed_heading(q[ok & rest], q_ref[ok & rest]).mean())
    rms = float(np.sqrt(np.mean(h**2)))
    about = float(h.std())
    return trial.name, (rms, mean, about, at_rest, mean - at_rest)


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument('--trials', default='', help='comma-separated trial numbers (default: all)')
    a = ap.parse_args()
    trials, settings = trials_and_settings(a)
    if a.trials:
        trials = [t for t in trials if t.name[:2] in a.trials.split(',')]
    results = map_trials(run_trial, [(t, settings) for t in trials])
    print('heading error, degrees: RMSE while moving = its mean (signed) + the RMS about it; the mean at rest and')
    print('the change from rest to moving')
    print(f'{"trial":45s} {"RMSE":>6s} {"mean":>7s} {"about":>6s} {"at rest":>8s} {"moving - rest":>14s}')
    for trial, (rms, mean, about, at_rest, change) in results:
        print(f'{trial:45s} {rms:6.2f} {mean:7.2f} {about:6.2f} {at_rest:8.2f} {change:14.2f}')
    m = np.mean([res for _, res in results], axis=0)
    abs_mean = np.mean([abs(res[1]) for _, res in results])
    abs_change = np.mean([abs(res[4]) for _, res in results])
    print(f'{"mean (|mean|, |moving - rest|)":45s} {m[0]:6.2f} {abs_mean:7.2f} {m[2]:6.2f} {"":8s} {abs_change:14.2f}')


if __name__ == '__main__':
    main()
