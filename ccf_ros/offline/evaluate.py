"""``ccf eval``: score an orientation topic against a reference orientation topic; and the engine run over arrays to
score (:func:`engine_orientations`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.metrics import ErrorSummary, summarize
from ..core.quaternion import from_xyzw, quat_slerp
from ..engine import ImuEngine
from ..errors import BagError
from .bagio import read_bools, read_orientations


@dataclass
class Aligned:
    """Estimate resampled at the reference stamps. t_s (N,), q_est (N,4; NaN = no estimate), q_ref (N,4), mask (N,)."""

    t_s: np.ndarray
    q_est: np.ndarray
    q_ref: np.ndarray
    mask: np.ndarray


def align(
    t_est: np.ndarray, q_est: np.ndarray, t_ref: np.ndarray, q_ref: np.ndarray, max_gap_s: float | None = None
) -> np.ndarray:
    """Estimate at each reference stamp: exact stamp match, else slerp between the neighbouring estimates.

    A reference stamp outside the estimate's span, or between estimates further apart than ``max_gap_s``
    (default: 2.5 median estimate periods), gets NaN (scored as missing).
    """
    out = np.full((len(t_ref), 4), np.nan)
    if len(t_est) == 0:
        return out
    order = np.argsort(t_est, kind='stable')
    t_est = t_est[order]
    q_est = q_est[order]
    if max_gap_s is None:
        max_gap_s = 2.5 * float(np.median(np.diff(t_est))) if len(t_est) > 1 else 0.0
    tol = 1e-6
    i = np.searchsorted(t_est, t_ref - tol)
    i = np.clip(i, 0, len(t_est) - 1)
    exact = np.abs(t_est[i] - t_ref) <= tol
    out[exact] = q_est[i[exact]]
    j = np.searchsorted(t_est, t_ref, side='right')
    inner = ~exact & (j > 0) & (j < len(t_est))
    lo = np.clip(j - 1, 0, len(t_est) - 1)
    hi = np.clip(j, 0, len(t_est) - 1)
    gap = t_est[hi] - t_est[lo]
    inner &= (gap > 0) & (gap <= max_gap_s)
    if inner.any():
        f = (t_ref[inner] - t_est[lo[inner]]) / gap[inner]
        out[inner] = quat_slerp(q_est[lo[inner]], q_est[hi[inner]], f)
    return out


def mask_at(t_ref: np.ndarray, t_mask: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``(M,)`` value of a Bool topic (``t_mask`` s, ``values``) in force at each reference stamp ``t_ref`` (s);
    False before its first message, all True if it has none."""
    if len(t_mask) == 0:
        return np.ones(len(t_ref), dtype=bool)
    k = np.searchsorted(t_mask, t_ref + 1e-6, side='right') - 1
    return np.where(k >= 0, values[np.clip(k, 0, None)], False)


def load_aligned(
    bag: str | Path,
    reference: str,
    *,
    reference_bag: str | Path | None = None,
    estimate_topic: str = '/imu/data',
    mask_topic: str | None = None,
    progress: bool = False,
) -> Aligned:
    """Read estimate, reference and optional mask and resample the estimate at the reference stamps (``progress``: a
    bar per topic read, on a terminal)."""
    t_est, q_est = read_orientations(bag, estimate_topic, progress=estimate_topic if progress else None)
    if len(t_est) == 0:
        raise BagError(f'{bag}: no messages on {estimate_topic}')
    t_ref, q_ref = read_orientations(reference_bag or bag, reference, progress=reference if progress else None)
    if len(t_ref) == 0:
        raise BagError(f'no messages on reference topic {reference}')
    mask = np.ones(len(t_ref), dtype=bool)
    if mask_topic:
        mask = mask_at(t_ref, *read_bools(reference_bag or bag, mask_topic))
    return Aligned(t_s=t_ref, q_est=align(t_est, q_est, t_ref, q_ref), q_ref=q_ref, mask=mask)


def evaluate(aligned: Aligned) -> ErrorSummary:
    """Paper and BROAD metrics over the masked samples with a finite reference."""
    return summarize(aligned.q_est, aligned.q_ref, aligned.mask)


def format_summary(s: ErrorSummary, label: str = 'estimate') -> str:
    """A short human-readable table."""
    r, p, y = s.rmse_rad
    return '\n'.join(
        [
            f'{label}: {s.n_scored} samples scored, {s.n_missing} without estimate (counted as 180 deg)',
            f'  BROAD  total {s.total_rmse_deg:7.3f} deg   heading {s.heading_rmse_deg:7.3f} deg   '
            f'inclination {s.inclination_rmse_deg:7.3f} deg',
            f'  paper  RMSE roll {r:.4f}  pitch {p:.4f}  yaw {y:.4f} rad   mean (eq 17) {s.mean_rmse_rad:.4f} rad',
        ]
    )


def engine_orientations(engine: ImuEngine, t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray,
                        after: Callable[[int, float], None] | None = None) -> np.ndarray:
    """The engine's orientations over arrays, fed as replay feeds it (each sample's magnetometer first, then the IMU):
    stamps ``t`` (N,) s, ``gyr`` (N,3) rad/s, ``acc`` (N,3) m/s², ``mag`` (N,3) (a row with a NaN: no magnetometer
    message). Returns (N,4) [w, x, y, z], NaN where the engine gave no answer; ``after(k, t_k)`` is called after each
    sample (to look at the engine's state on the way)."""
    q = np.full((len(t), 4), np.nan)
    tl, gl, al, ml = t.tolist(), gyr.tolist(), acc.tolist(), mag.tolist()
    has_mag = np.all(np.isfinite(mag), axis=1).tolist()
    for k in range(len(tl)):
        if has_mag[k]:
            engine.on_mag(tl[k], tuple(ml[k]))
        out = engine.on_imu(tl[k], tuple(gl[k]), tuple(al[k]))
        if out is not None:
            q[k] = from_xyzw(*out.orientation_xyzw)
        if after is not None:
            after(k, tl[k])
    return q
