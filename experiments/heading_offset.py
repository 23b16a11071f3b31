"""Where the heading error on the shared BROAD trials comes from: a constant part, and the magnetometer's own north.

For each trial the signed heading error (rotation of ``q_est ⊗ q_ref⁻¹`` about the vertical, degrees) while moving is
split into its mean and the RMS about that mean, and the mean is compared with the one at rest (5-25 s). Beside it,
no filter involved: the direction of the measured field's horizontal part in the reference's world (the magnetometer
rotated by the reference orientation; 0 = the reference's north), its mean at rest and while moving. If the filter's
change of heading offset from rest to moving equals the field's change of direction, that offset is the recording's:
the magnetometer's north where the IMU moves is not its north where it rests.

Usage: python experiments/heading_offset.py [--shared ../shared/data/broad] [--trials 02,11] [NAME=VALUE ...]
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from _trials import map_trials, parser, trials_and_settings

from ccf_ros.core import run_batch
from ccf_ros.core.quaternion import quat_conj, quat_mul, quat_rotate
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build


def signed_heading(q_est: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """``(N,)`` heading error, degrees: the twist of ``q_est ⊗ q_ref⁻¹`` about the world vertical, in (-180, 180]."""
    e = quat_mul(q_est, quat_conj(q_ref))
    e = e * np.sign(e[:, :1] + 1e-300)
    return np.degrees(2.0 * np.arctan2(e[:, 3], e[:, 0]))


def field_direction(q_ref: np.ndarray, mag: np.ndarray) -> np.ndarray:
    """``(N,)`` direction of the horizontal field in the reference world, degrees from its north (+y) towards east
    (+x): the heading error (counter-clockwise about up) of a filter that turns this field onto north."""
    m = quat_rotate(q_ref, mag)
    return np.degrees(np.arctan2(m[:, 0], m[:, 1]))


def run_trial(args: tuple[Path, dict[str, str]]) -> tuple[str, tuple[float, ...]]:
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
    # The field at the reference's samples (the IMU sample with the same stamp).
    i = np.clip(np.searchsorted(imu.t_s, t_ref), 0, len(imu.t_s) - 1)
    same = np.abs(imu.t_s[i] - t_ref) < 1e-4
    fd = field_direction(np.where(ok[:, None], q_ref, [1.0, 0.0, 0.0, 0.0]), imu.mag[i])
    fine = ok & same & np.all(np.isfinite(imu.mag[i]), axis=1)
    f_rest = float(fd[fine & rest].mean())
    f_moving = float(fd[fine & moving].mean())
    return trial.name, (rms, mean, about, at_rest, mean - at_rest, f_rest, f_moving, f_moving - f_rest)


def main() -> None:
    ap = parser(__doc__)
    a = ap.parse_args()
    trials, settings = trials_and_settings(a)
    results = map_trials(run_trial, [(t, settings) for t in trials])
    print('heading error, degrees: RMSE while moving = its mean (signed) + the RMS about it; the mean at rest and the')
    print("change from rest to moving; the measured field's direction from the reference's north, at rest, moving, and")
    print('its change')
    print(
        f'{"trial":45s} {"RMSE":>6s} {"mean":>7s} {"about":>6s} {"at rest":>8s} {"moving - rest":>14s}'
        f' {"field: rest":>12s} {"moving":>7s} {"change":>7s}'
    )
    for trial, (rms, mean, about, at_rest, change, f_rest, f_moving, f_change) in results:
        print(
            f'{trial:45s} {rms:6.2f} {mean:7.2f} {about:6.2f} {at_rest:8.2f} {change:14.2f}'
            f' {f_rest:12.2f} {f_moving:7.2f} {f_change:7.2f}'
        )
    m = np.mean([res for _, res in results], axis=0)
    abs_mean = np.mean([abs(res[1]) for _, res in results])
    abs_change = np.mean([abs(res[4]) for _, res in results])
    print(f'{"mean (|mean|, |moving - rest|)":45s} {m[0]:6.2f} {abs_mean:7.2f} {m[2]:6.2f} {"":8s} {abs_change:14.2f}')


if __name__ == '__main__':
    main()
