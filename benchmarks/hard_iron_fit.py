"""How much of the heading error a magnetometer offset (hard iron) explains, per shared BROAD trial.

Fits, per trial, the constant body-frame offset ``h`` and the world field ``m_w`` of the model
``m_k = R_kᵀ m_w + h`` (``R_k``: the default filter's body->world orientation) by linear least squares over all
samples, on the whole trial and on each half (a real offset is the same in both), then runs the defaults again with
``h`` subtracted from the magnetometer. It is a batch fit with hindsight: it bounds what an online offset estimator
could give, and shows where the model does not hold (a translation through a non-uniform field, a magnet in the
room, soft iron), which is where such an estimator would have to refuse.

Usage: python benchmarks/hard_iron_fit.py [--shared ../shared/data/broad] [--trials 02,27]
"""

from __future__ import annotations

import numpy as np
from _trials import map_trials, parser, trials_and_settings

from ccf_ros.core import run_batch
from ccf_ros.core.metrics import summarize
from ccf_ros.offline.bagio import read_bools, read_imu_arrays, read_orientations
from ccf_ros.offline.evaluate import align, mask_at
from ccf_ros.settings import build


def rotation_matrices(q: np.ndarray) -> np.ndarray:
    """``(N, 3, 3)`` body->world rotation matrices of ``(N, 4)`` unit quaternions ``[w, x, y, z]``."""
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=1,
    )


def fit_offset(r: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares ``h`` (body) of ``m_k = R_kᵀ m_w + h`` over ``(N, 3, 3)`` rotations and ``(N, 3)`` fields (any
    unit; ``h`` in the same), and the condition number of the system (large: too little rotation to tell)."""
    n = len(m)
    s_r = r.sum(axis=0)
    s_m = m.sum(axis=0)
    s_rm = np.einsum('nij,nj->i', r, m)
    # Eliminating h (N h + s_rᵀ m_w = s_m) leaves a 3x3 system in m_w.
    a = n * np.eye(3) - s_r @ s_r.T / n
    m_w = np.linalg.solve(a, s_rm - s_r @ s_m / n)
    return (s_m - s_r.T @ m_w) / n, float(np.linalg.cond(a))


def run_trial(trial) -> tuple[str, tuple]:
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))

    def heading(mag: np.ndarray) -> tuple[float, np.ndarray]:
        filt, _ = build({})
        res = run_batch(filt, imu.t_s, imu.gyr, imu.acc, mag)
        q = align(imu.t_s[res.answered], res.quat[res.answered], t_ref, q_ref)
        return summarize(q, q_ref, mask).heading_rmse_deg, res.quat

    before, quat = heading(imu.mag)
    r = rotation_matrices(quat)
    m_ut = imu.mag * 1e6
    h, cond = fit_offset(r, m_ut)
    half = len(m_ut) // 2
    h1, _ = fit_offset(r[:half], m_ut[:half])
    h2, _ = fit_offset(r[half:], m_ut[half:])
    after, _ = heading(imu.mag - h * 1e-6)
    return trial.name, (h, h1, h2, cond, before, after)


def main() -> None:
    ap = parser(__doc__)
    ap.add_argument('--trials', default='', help='comma-separated trial numbers (default: all)')
    a = ap.parse_args()
    trials, _ = trials_and_settings(a)
    if a.trials:
        trials = [t for t in trials if t.name[:2] in a.trials.split(',')]
    results = map_trials(run_trial, trials)

    def v(x: np.ndarray) -> str:
        return ' '.join(f'{c:+6.2f}' for c in x)

    print(
        'hard-iron offset h (uT, body x y z) fitted per trial: whole trial, first and second half; heading RMSE (deg)'
    )
    print(
        f'{"trial":44s} {"h":>20s}  {"h, 1st half":>20s}  {"h, 2nd half":>20s}  {"cond":>5s}  heading -> with h removed'
    )
    for name, (h, h1, h2, cond, before, after) in results:
        print(f'{name:44s} {v(h)}  {v(h1)}  {v(h2)}  {cond:5.1f}  {before:5.2f} -> {after:5.2f}')
    m = np.mean([res[4:] for _, res in results], axis=0)
    print(f'{"mean":44s} {"":20s}  {"":20s}  {"":20s}  {"":5s}  {m[0]:5.2f} -> {m[1]:5.2f}')


if __name__ == '__main__':
    main()
