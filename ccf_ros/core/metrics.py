"""Orientation error metrics: the paper's (eqs 16-17) and BROAD's.

BROAD: error quaternion ``q_err = q_est ⊗ q_ref⁻¹`` (world frame); total error = its rotation angle; heading error =
its rotation about world up; inclination error = the remaining tilt. RMSE in degrees over the scored samples.
A missing (NaN) estimate counts as a 180° error.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from .quaternion import quat_conj, quat_mul, quat_to_euler, wrap_angle


@dataclass(frozen=True)
class ErrorSummary:
    """Errors over the scored samples.

    Attributes:
        total_rmse_deg, heading_rmse_deg, inclination_rmse_deg: BROAD metrics, degrees.
        rmse_rad: paper eq 16, per Euler axis ``(roll, pitch, yaw)``, rad. mean_rmse_rad: eq 17, rad.
        n_scored: samples scored. n_missing: of those, samples without an estimate.
    """

    total_rmse_deg: float
    heading_rmse_deg: float
    inclination_rmse_deg: float
    rmse_rad: tuple[float, float, float]
    mean_rmse_rad: float
    n_scored: int
    n_missing: int

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


def error_angles(q_est: ArrayLike, q_ref: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Total, heading and inclination error angles in rad, each ``(N,)``; NaN estimates give NaN."""
    q_err = quat_mul(q_est, quat_conj(q_ref))
    w = np.abs(q_err[..., 0])
    total = 2.0 * np.arctan2(np.linalg.norm(q_err[..., 1:], axis=-1), w)
    # Swing-twist about world z: twist = (w, 0, 0, z) normalised -> heading; the rest -> inclination.
    heading = 2.0 * np.arctan2(np.abs(q_err[..., 3]), w)
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(q_err[..., 0] ** 2 + q_err[..., 3] ** 2), 0.0, 1.0))
    return total, heading, inclination


def fill_missing(q: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Estimates ``(M, 4)`` with the rows lacking one (any non-finite value) set to the identity, and those rows
    ``(M,)`` bool, which the caller scores as a 180° error (BROAD's rule for a missing estimate)."""
    q = np.asarray(q, dtype=float)
    missing = ~np.isfinite(q).all(axis=-1)
    return np.where(missing[:, None], [1.0, 0.0, 0.0, 0.0], q), missing


def fit_heading_offset(q_est: ArrayLike, q_ref: ArrayLike) -> np.ndarray:
    """``q_ref`` (``(N, 4)``) turned about world up by the constant angle that minimises the RMS total error against
    ``q_est`` (both finite): how 6-D filters, which have no absolute heading, are scored (their heading *drift*)."""
    q_est = np.asarray(q_est, dtype=float)
    q_ref = np.asarray(q_ref, dtype=float)

    def turned(psi: float) -> np.ndarray:
        return quat_mul(np.array([np.cos(psi / 2), 0.0, 0.0, np.sin(psi / 2)]), q_ref)

    def cost(psi: float) -> float:
        return float(np.mean(error_angles(q_est, turned(psi))[0] ** 2))

    # A coarse grid finds the basin, a golden-section search the minimum (the cost is smooth around it).
    grid = np.linspace(-np.pi, np.pi, 73)
    best = float(grid[int(np.argmin([cost(p) for p in grid]))])
    lo, hi = best - 0.1, best + 0.1
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    for _ in range(40):
        m1, m2 = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
        if cost(m1) < cost(m2):
            hi = m2
        else:
            lo = m1
    return turned(0.5 * (lo + hi))


def fitted_total_rmse_deg(q_est: ArrayLike, q_ref: ArrayLike, mask: ArrayLike | None = None) -> float:
    """Total RMSE, degrees, over ``mask`` (default all) after :func:`fit_heading_offset` on the samples where both
    ``q_est`` and ``q_ref`` (``(N, 4)``) are finite: the 6-D score (heading drift, not north)."""
    q_est = np.asarray(q_est, dtype=float)
    q_ref = np.asarray(q_ref, dtype=float)
    sel = np.ones(len(q_ref), dtype=bool) if mask is None else np.asarray(mask, dtype=bool).copy()
    sel &= np.all(np.isfinite(q_ref), axis=-1) & np.all(np.isfinite(q_est), axis=-1)
    q_fit = q_ref.copy()
    q_fit[sel] = fit_heading_offset(q_est[sel], q_ref[sel])
    return summarize(q_est, q_fit, mask).total_rmse_deg


def summarize(q_est: ArrayLike, q_ref: ArrayLike, mask: ArrayLike | None = None) -> ErrorSummary:
    """Score ``q_est`` against ``q_ref`` (both ``(N, 4)``, same world frame) over ``mask`` (default all).

    Samples whose reference is NaN are not scored; samples whose estimate is NaN count as 180°.
    """
    q_est = np.asarray(q_est, dtype=float)
    q_ref = np.asarray(q_ref, dtype=float)
    sel = np.ones(len(q_ref), dtype=bool) if mask is None else np.asarray(mask, dtype=bool).copy()
    sel &= np.all(np.isfinite(q_ref), axis=-1)
    est = q_est[sel]
    ref = q_ref[sel]
    filled, missing = fill_missing(est)
    total, heading, incl = error_angles(filled, ref)
    total[missing] = heading[missing] = incl[missing] = np.pi
    e_est = quat_to_euler(filled)
    e_ref = quat_to_euler(ref)
    d = wrap_angle(e_est - e_ref)
    d[missing] = np.pi
    n = int(sel.sum())

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x * x))) if n else float('nan')

    axis_rmse = tuple(rms(d[:, i]) for i in range(3)) if n else (float('nan'),) * 3
    return ErrorSummary(
        total_rmse_deg=float(np.degrees(rms(total))),
        heading_rmse_deg=float(np.degrees(rms(heading))),
        inclination_rmse_deg=float(np.degrees(rms(incl))),
        rmse_rad=axis_rmse,  # type: ignore[arg-type]
        mean_rmse_rad=float(np.mean(axis_rmse)),
        n_scored=n,
        n_missing=int(missing.sum()),
    )
