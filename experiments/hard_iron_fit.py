"""How much of the heading error a magnetometer offset (hard iron) explains, per shared BROAD trial.

Fits, per trial, the constant body-frame offset ``h`` and the world field ``m_w`` of the model
``m_k = R_kᵀ m_w + h`` by linear least squares over all samples, with ``R_k`` (body->world) the reference
orientation (so that the fit does not lean on the filter's own heading), on the whole trial and on each half (a real
offset is the same in both). It prints the rotation spread (the smallest eigenvalue of ``I - mean(R) mean(R)ᵀ``: 0
without rotation, where ``h`` cannot be told from the field), then runs the filter again with ``h`` subtracted from
the magnetometer. It is a batch fit with hindsight; where it makes heading worse, the model does not hold (a
translation through a non-uniform field, a magnet in the room, soft iron), which an online estimator would have to
detect.

Usage: python experiments/hard_iron_fit.py [--shared ../shared/data/broad] [--trials 02,27] [NAME=VALUE ...]
"""

from __future__ import annotations

from pathlib import Path

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
    unit; ``h`` in the same; rows with a non-finite value are left out), and the rotation spread (see above). ``h`` is
    NaN where the spread is below 1e-6 (no rotation: the system is singular)."""
    ok = np.all(np.isfinite(m), axis=1) & np.all(np.isfinite(r), axis=(1, 2))
    r, m = r[ok], m[ok]
    n = len(m)
    s_r = r.sum(axis=0)
    s_m = m.sum(axis=0)
    s_rm = np.einsum('nij,nj->i', r, m)
    mean_r = s_r / n
    spread = float(np.linalg.eigvalsh(np.eye(3) - mean_r @ mean_r.T)[0])
    if spread < 1e-6:
        return np.full(3, np.nan), spread
    # Eliminating h (N h + s_rᵀ m_w = s_m) leaves a 3x3 system in m_w.
    m_w = np.linalg.solve(n * np.eye(3) - s_r @ s_r.T / n, s_rm - s_r @ s_m / n)
    return (s_m - s_r.T @ m_w) / n, spread


def run_trial(args: tuple[Path, dict[str, str]]) -> tuple[str, tuple]:
    trial, settings = args
    imu = read_imu_arrays(trial)
    t_ref, q_ref = read_orientations(trial, '/ground_truth/pose')
    mask = mask_at(t_ref, *read_bools(trial, '/ground_truth/moving'))

    def heading(mag: np.ndarray) -> float:
        filt, _ = build(settings)
        res = run_batch(filt, imu.t_s, imu.gyr, imu.acc, mag)
        q = align(imu.t_s[res.answered], res.quat[res.answered], t_ref, q_ref)
        return summarize(q, q_ref, mask).heading_rmse_deg

    # The reference at the IMU samples with the same stamp (NaN where it has none).
    i = np.clip(np.searchsorted(t_ref, imu.t_s), 0, len(t_ref) - 1)
    q = np.where((np.abs(t_ref[i] - imu.t_s) < 1e-4)[:, None], q_ref[i], np.nan)
    r = rotation_matrices(q)
    m_ut = imu.mag * 1e6
    h, spread = fit_offset(r, m_ut)
    half = len(m_ut) // 2
    h1, _ = fit_offset(r[:half], m_ut[:half])
    h2, _ = fit_offset(r[half:], m_ut[half:])
    before = heading(imu.mag)
    after = heading(imu.mag - h * 1e-6) if np.all(np.isfinite(h)) else float('nan')
    return trial.name, (h, h1, h2, spread, before, after)


def main() -> None:
    ap = parser(__doc__)
    a = ap.parse_args()
    trials, settings = trials_and_settings(a)
    results = map_trials(run_trial, [(t, settings) for t in trials])

    def v(x: np.ndarray) -> str:
        return ' '.join(f'{c:+6.2f}' for c in x)

    print('hard-iron offset h (uT, body x y z) fitted per trial on the reference orientation: whole trial, first and')
    print('second half, their difference; the rotation spread; heading RMSE (deg) of the defaults, and with h removed')
    print(
        f'{"trial":44s} {"h":>20s}  {"h, 1st half":>20s}  {"h, 2nd half":>20s}  {"|h1-h2|":>7s}  {"spread":>6s}'
        '  heading -> with h removed'
    )
    for name, (h, h1, h2, spread, before, after) in results:
        print(
            f'{name:44s} {v(h)}  {v(h1)}  {v(h2)}  {np.linalg.norm(h1 - h2):7.2f}  {spread:6.3f}'
            f'  {before:5.2f} -> {after:5.2f}'
        )
    m = np.mean([res[4:] for _, res in results], axis=0)
    print(f'{"mean":44s} {"":20s}  {"":20s}  {"":20s}  {"":7s}  {"":6s}  {m[0]:5.2f} -> {m[1]:5.2f}')


if __name__ == '__main__':
    main()
