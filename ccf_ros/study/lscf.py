"""LSCF: the CCF with gains fitted by least squares against the reference (paper Table 3). Needs scipy
(``pip install ccf_ros[study]``).

* **euler** — ``(Kp, Ki, alpha)`` per axis (9 values) minimising the per-axis attitude errors. The paper's eq 16
  residuals, Euler-angle differences, jump by 2 pi wherever the motion passes near ±90° pitch (gimbal lock; most
  BROAD trials do), which defeats a least-squares fit; the residuals are therefore the x, y, z components of the
  error rotation vector (world frame), equal to the roll, pitch, yaw errors near level. Each axis's error depends on
  its own gains almost only (the axes couple through the kinematics), so the Jacobian is estimated per gain *kind*
  with all three axes perturbed at once: 3 filter runs instead of 9.
* **quaternion** — ``tau_acc_s, tau_mag_s, tau_bias_s`` minimising the total error angle.

Gains are searched in log space (``alpha`` linearly), starting from the paper's / ccf_ros defaults, with a fixed
budget of filter runs: the fit is what a user would get in a few minutes, not a global optimum.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..core.quaternion import quat_conj, quat_mul, quat_to_rotvec
from ..errors import CcfError
from .datasets import Dataset, fill_missing, run_filter, total_error_rad
from .experiments import euler_ccf_settings
from .labels import EULER

_MAX_RESIDUALS = 4000


def _scored_rows(ds: Dataset) -> np.ndarray:
    """Indices of the scored samples with a reference, thinned to at most ``_MAX_RESIDUALS`` (fit time)."""
    idx = np.flatnonzero(ds.mask & np.isfinite(ds.q_ref).all(axis=1))
    step = max(1, len(idx) // _MAX_RESIDUALS)
    return idx[::step]


def _rotation_error(q: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """``(M, 3)`` rotation vectors (rad, world frame) of ``q ⊗ q_ref⁻¹``; a missing estimate counts as pi about x."""
    filled, bad = fill_missing(q)
    out = quat_to_rotvec(quat_mul(filled, quat_conj(q_ref)))
    out[bad] = (math.pi, 0.0, 0.0)
    return out


def _least_squares() -> Any:
    try:
        from scipy.optimize import least_squares
    except ImportError as err:  # pragma: no cover - depends on the install
        raise CcfError('the LSCF fit needs scipy: pip install "ccf_ros[study]" (or run ccf study --no-lscf)') from err
    return least_squares


def _rms(r: np.ndarray) -> float:
    return float(np.sqrt(np.mean(r**2)))


def _fit_result(gains: dict[str, Any], runs: int, r_start: np.ndarray, res: Any, settings: dict[str, Any]
                ) -> dict[str, Any]:
    """What both fits return: the fitted values, the filter runs spent, the residual RMS before/after (rad)."""
    return {
        **gains,
        'filter_runs': runs,
        'residual_rms_rad_start': _rms(r_start),
        'residual_rms_rad_end': _rms(res.fun),
        'settings': settings,
    }


def _quaternion_settings(tau_acc_s: float, tau_mag_s: float, tau_bias_s: float) -> dict[str, Any]:
    """The ccf_ros CCF with the three fitted time constants (s), the others at their defaults."""
    return {'filter': 'ccf', 'tau_acc_s': tau_acc_s, 'tau_mag_s': tau_mag_s, 'tau_bias_s': tau_bias_s}


def fit_euler(ds: Dataset, max_iterations: int = 8) -> dict[str, Any]:
    """Fit ``(Kp, Ki, alpha)`` per axis of the paper's CCF. Returns the gains, the number of filter runs and the
    residual RMS before/after (rad)."""
    least_squares = _least_squares()
    rows = _scored_rows(ds)
    q_ref = ds.q_ref[rows]
    runs = [0]
    cache: dict[bytes, np.ndarray] = {}

    def gains(x: np.ndarray) -> dict[str, Any]:
        return euler_ccf_settings(
            kp=tuple(float(10.0**v) for v in x[0:3]),
            ki=tuple(float(10.0**v) for v in x[3:6]),
            alpha=tuple(float(min(1.0, max(0.0, v))) for v in x[6:9]),
        )

    def residuals(x: np.ndarray) -> np.ndarray:
        key = np.asarray(x, dtype=float).tobytes()
        if key not in cache:
            runs[0] += 1
            q, _, _ = run_filter(gains(x), ds)
            d = _rotation_error(q[rows], q_ref)
            cache.clear()
            cache[key] = d.T.reshape(-1)  # roll block, pitch block, yaw block
        return cache[key]

    lo = np.array([-2.0] * 3 + [-4.0] * 3 + [0.0] * 3)
    hi = np.array([2.5] * 3 + [1.0] * 3 + [1.0] * 3)
    steps = np.array([0.1] * 6 + [0.05] * 3)

    def jacobian(x: np.ndarray) -> np.ndarray:
        r0 = residuals(x)
        n = len(r0) // 3
        jac = np.zeros((len(r0), 9))
        for kind in range(3):
            cols = [kind * 3 + axis for axis in range(3)]
            h = steps[cols].copy()
            h[x[cols] + h > hi[cols]] *= -1.0
            xp = x.copy()
            xp[cols] += h
            dr = residuals(xp) - r0
            for axis, col in enumerate(cols):
                jac[axis * n : (axis + 1) * n, col] = dr[axis * n : (axis + 1) * n] / h[axis]
        return jac

    x0 = np.array([math.log10(25.0)] * 3 + [math.log10(0.1)] * 3 + [0.7] * 3)
    r_start = residuals(x0)
    res = least_squares(residuals, x0, jac=jacobian, bounds=(lo, hi), max_nfev=max_iterations, x_scale='jac')
    g = gains(res.x)
    return _fit_result({k: list(g[k]) for k in ('kp', 'ki', 'alpha')}, runs[0], r_start, res, g)


def fit_quaternion(ds: Dataset, max_iterations: int = 8) -> dict[str, Any]:
    """Fit ``tau_acc_s, tau_mag_s, tau_bias_s`` of the ccf_ros CCF (log space) on the total error angle."""
    least_squares = _least_squares()
    rows = _scored_rows(ds)
    q_ref = ds.q_ref[rows]
    runs = [0]

    def settings(x: np.ndarray) -> dict[str, Any]:
        return _quaternion_settings(float(10.0 ** x[0]), float(10.0 ** x[1]), float(10.0 ** x[2]))

    def residuals(x: np.ndarray) -> np.ndarray:
        runs[0] += 1
        q, _, _ = run_filter(settings(x), ds)
        return total_error_rad(q[rows], q_ref)

    x0 = np.log10([3.0, 9.0, 60.0])
    r_start = residuals(x0)
    res = least_squares(
        residuals, x0, bounds=([-2.0, -2.0, 0.0], [2.5, 2.5, 3.5]), max_nfev=max_iterations, diff_step=0.05
    )
    s = settings(res.x)
    return _fit_result({k: s[k] for k in ('tau_acc_s', 'tau_mag_s', 'tau_bias_s')}, runs[0], r_start, res, s)


def pooled_settings(form: str, fits: list[dict[str, Any]]) -> dict[str, Any]:
    """Settings from the fits of *other* datasets (leave-one-out): geometric median of the gains and time constants,
    median of alpha. Scored on the held-out dataset, they show what LSE tuning buys on data it has not seen."""
    if not fits:
        raise ValueError('no fits to pool')

    def gmed(values: list[float]) -> float:
        return float(10.0 ** np.median(np.log10(values)))

    if form == EULER:
        return euler_ccf_settings(
            kp=tuple(gmed([f['kp'][i] for f in fits]) for i in range(3)),
            ki=tuple(gmed([f['ki'][i] for f in fits]) for i in range(3)),
            alpha=tuple(float(np.median([f['alpha'][i] for f in fits])) for i in range(3)),
        )
    return _quaternion_settings(*(gmed([f[k] for f in fits]) for k in ('tau_acc_s', 'tau_mag_s', 'tau_bias_s')))
