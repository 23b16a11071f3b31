"""Per trial, the defaults beside VQF online and VQF offline (non-causal), scored as recorded and with the estimates'
stamps moved by ``--shift-ms`` (default -2.5 ms: the IMU-to-reference lag found in doc/history/2026-12-03-tilt3.md).

Where is the offline filter ahead, and is it the timing offset or something a causal filter could also do? All three
filters see the same samples (the magnetometer paired as ``ccf replay`` pairs it; VQF gets a zero field where none is
paired, which BROAD's lock-step magnetometer never needs). The shift is a diagnostic, not a setting: it is fitted to
these nine trials. Needs ``pip install vqf``.

Usage: python experiments/vqf_offline.py [--shared ../shared/data/broad] [--trials 02,11] [--shift-ms -2.5]
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from _trials import map_trials, parser, run_9d, trials_and_settings

from ccf_ros.core.metrics import summarize
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build

FILTERS = ('ccf_ros', 'VQF online', 'VQF offline')


def run_trial(args: tuple[Path, dict[str, str], float]) -> tuple[str, dict[tuple[str, float], tuple[float, float]]]:
    """(trial, {(filter, shift s): (total, inclination RMSE °)})."""
    from vqf import VQF, offlineVQF

    trial, settings, shift = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))
    ts = float(np.median(np.diff(imu.t_s)))
    gyr, acc = np.ascontiguousarray(imu.gyr), np.ascontiguousarray(imu.acc)
    mag_ut = np.ascontiguousarray(np.where(np.isfinite(imu.mag), imu.mag, 0.0) * 1e6)
    filt, adapter = build(settings)
    quat, answered = run_9d(filt, adapter, imu.t_s, imu.gyr, imu.acc, imu.mag)
    est: dict[str, tuple[np.ndarray, np.ndarray]] = {
        'ccf_ros': (imu.t_s[answered], quat[answered]),
        'VQF online': (imu.t_s, VQF(ts).updateBatch(gyr, acc, mag_ut)['quat9D']),
        'VQF offline': (imu.t_s, offlineVQF(gyr, acc, mag_ut, ts)['quat9D']),
    }
    out = {}
    for name, (t, q) in est.items():
        for s in (0.0, shift):
            r = summarize(align(t + s, q, t_ref, q_ref), q_ref, mask)
            out[(name, s)] = (r.total_rmse_deg, r.inclination_rmse_deg)
    return trial.name, out


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument('--shift-ms', type=float, default=-2.5, help='the estimates moved by this, ms (a diagnostic)')
    a = ap.parse_args()
    try:
        import vqf  # noqa: F401
    except ImportError:
        raise SystemExit('needs the vqf package: pip install vqf') from None
    trials, settings = trials_and_settings(a)
    shift = a.shift_ms / 1e3
    res: list[Any] = map_trials(run_trial, [(t, settings, shift) for t in trials])
    cols = [(f, s) for f in FILTERS for s in (0.0, shift)]
    print(f'total / inclination RMSE, degrees; settings {settings or "defaults"}; each filter as recorded and '
          f'moved by {a.shift_ms:+.1f} ms')
    print(f'{"trial":44s} ' + ' '.join(f'{f"{f} {s * 1e3:+.1f}":>15s}' for f, s in cols))
    for name, o in res:
        print(f'{name:44s} ' + ' '.join(f'{o[c][0]:7.2f}/{o[c][1]:5.2f}' for c in cols))
    means = [np.mean([o[c] for _, o in res], axis=0) for c in cols]
    print(f'{"mean":44s} ' + ' '.join(f'{m[0]:7.2f}/{m[1]:5.2f}' for m in means))


if __name__ == '__main__':
    main()
