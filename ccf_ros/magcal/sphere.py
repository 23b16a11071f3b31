"""The sphere: direction coverage of calibrated samples, and the offset-only (sphere) fit (numpy only).

Coverage: the calibrated directions are binned to the nearest of :data:`~.model.COVERAGE_BINS` Fibonacci-lattice
directions (bins of ~4 pi / 100 sr, ~23 deg across); coverage is the fraction of bins with at least
:data:`~.model.COVERAGE_MIN_PER_BIN` samples. A full calibration dance gives 0.5-0.9; a sensor turned about one axis
0.1-0.25, and there the fit is unreliable even though its residual looks fine.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .model import COVERAGE_BINS, COVERAGE_MIN_PER_BIN


def fibonacci_directions(n: int = COVERAGE_BINS) -> np.ndarray:
    """``n`` nearly uniform unit vectors (n, 3) on the sphere (Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack((r * np.cos(phi), r * np.sin(phi), z), axis=1)


def coverage(m_cal: ArrayLike) -> float:
    """Fraction of the :data:`COVERAGE_BINS` Fibonacci direction bins holding >= :data:`COVERAGE_MIN_PER_BIN`
    of the directions of ``m_cal`` (N, 3); each sample falls in the bin of its nearest direction."""
    m = np.asarray(m_cal, dtype=float).reshape(-1, 3)
    norm = np.linalg.norm(m, axis=1)
    m = m[norm > 0] / norm[norm > 0, None]
    dirs = fibonacci_directions()
    counts = np.zeros(len(dirs), dtype=int)
    for k in range(0, len(m), 20000):  # blocks: (N, 100) dot products of a long bag are hundreds of MB
        counts += np.bincount(np.argmax(m[k:k + 20000] @ dirs.T, axis=1), minlength=len(dirs))
    return float(np.mean(counts >= COVERAGE_MIN_PER_BIN))


def fit_sphere(x: np.ndarray, iterations: int = 20) -> tuple[np.ndarray, float]:
    """Centre (3,) and radius of the sphere through points ``x`` (N, 3) (of order 1): the linear least-squares
    fit of ``|x|^2 = 2 c.x + d``, then Gauss-Newton on the geometric residual ``|x - c| - r``."""
    A = np.column_stack((2.0 * x, np.ones(len(x))))
    sol = np.linalg.lstsq(A, np.sum(x * x, axis=1), rcond=None)[0]
    c, r = sol[:3], float(np.sqrt(max(sol[3] + sol[:3] @ sol[:3], 1e-12)))
    for _ in range(iterations):
        u = x - c
        n = np.linalg.norm(u, axis=1)
        J = np.column_stack((-u / n[:, None], -np.ones(len(x))))
        step = np.linalg.lstsq(J, r - n, rcond=None)[0]
        c, r = c + step[:3], r + float(step[3])
        if float(np.max(np.abs(step))) < 1e-12:
            break
    return c, r

