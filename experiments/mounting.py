"""Mounting on a shared BROAD trial: the trial turned into the frame of an IMU mounted on a 90° bracket, upside down
and at an arbitrary angle (gyro, accelerometer and magnetometer), replayed through the engine with
``mount_rotation``; and the magnetometer alone turned, with ``mag_rotation``. Each should score as the unrotated
trial (total RMSE within 1 %; in fact to rounding).

Usage: python experiments/mounting.py [--shared ../shared/data/broad] [--trials 02] [NAME=VALUE ...]
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from _trials import parser, trials_and_settings

from ccf_ros.core.metrics import summarize
from ccf_ros.engine import ImuEngine
from ccf_ros.frames import rotation_matrix
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build

MOUNTS: dict[str, list[float]] = {
    'bracket 90 deg (yaw)': [0.0, 0.0, math.pi / 2],
    'bracket 90 deg (pitch)': [0.0, math.pi / 2, 0.0],
    'upside down': [math.pi, 0.0, 0.0],
    'arbitrary': [0.3, -1.1, 2.5],
}


def in_imu_frame(rotation: list[float], v: np.ndarray) -> np.ndarray:
    """What an IMU mounted with ``rotation`` (IMU -> output frame) measures of output-frame vectors ``v`` (N, 3)."""
    return v @ np.array(rotation_matrix('rotation', rotation)).reshape(3, 3)


def run_engine(settings: dict[str, Any], t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray,
               engine: ImuEngine | None = None) -> tuple[np.ndarray, np.ndarray, ImuEngine]:
    """The engine over arrays as replay feeds it (magnetometer first): answered stamps and quaternions [w,x,y,z]."""
    eng = engine or ImuEngine(*build(settings))
    if eng.wants_sensor_frame:
        eng.set_sensor_frame('imu_link')
    ts, qs = [], []
    on_mag, on_imu = eng.on_mag, eng.on_imu
    for k, (tk, g, a, m) in enumerate(zip(t.tolist(), gyr.tolist(), acc.tolist(), mag.tolist(), strict=True)):
        if m[0] == m[0]:  # not NaN: a paired magnetometer sample
            on_mag(tk, m)
        out = on_imu(tk, g, a)
        if out is not None:
            x, y, z, w = out.orientation_xyzw
            ts.append(t[k])
            qs.append((w, x, y, z))
    return np.array(ts), np.array(qs), eng


def score(trial: Path, t: np.ndarray, q: np.ndarray, window: tuple[float, float] | None = None) -> float:
    """Total RMSE (deg) over the trial's moving samples (within ``window`` [t0, t1) s if given)."""
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    if window is not None:
        mask = mask & (t_ref >= window[0]) & (t_ref < window[1])
    return summarize(align(t, q, t_ref, q_ref), q_ref, mask).total_rmse_deg


def main() -> None:
    ap = parser(__doc__, trials='02')
    a = ap.parse_args()
    trials, settings = trials_and_settings(a)
    for trial in trials:
        imu = read_imu_arrays(trial)
        t0, q0, _ = run_engine(settings, imu.t_s, imu.gyr, imu.acc, imu.mag)
        clean = score(trial, t0, q0)
        print(f'\n== {trial.name}  settings {settings or "defaults"}')
        print(f'{"case":42s} {"total RMSE":>10s} {"ratio":>8s} {"max |dq| vs unrotated":>22s}')
        print(f'{"unrotated":42s} {clean:10.4f} {1.0:8.4f} {0.0:22.1e}')
        for name, rot in MOUNTS.items():
            text = '[' + ', '.join(repr(v) for v in rot) + ']'
            for what in ('mount_rotation', 'mag_rotation'):
                if what == 'mount_rotation':
                    gyr, acc, mag = (in_imu_frame(rot, v) for v in (imu.gyr, imu.acc, imu.mag))
                else:
                    gyr, acc, mag = imu.gyr, imu.acc, in_imu_frame(rot, imu.mag)
                t1, q1, _ = run_engine({**settings, what: text}, imu.t_s, gyr, acc, mag)
                total = score(trial, t1, q1)
                dq = float(np.max(np.abs(q1 - q0))) if q1.shape == q0.shape else float('nan')
                print(f'{what + ": " + name:42s} {total:10.4f} {total / clean:8.4f} {dq:22.1e}')


if __name__ == '__main__':
    main()
