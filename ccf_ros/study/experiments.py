"""The paper's experiments, each a function of one dataset (so that datasets run in parallel).

Both formulations are studied with the same gains:

* **euler** — the paper's per-axis filters: NCF (eqs 10-11) and CCF (eqs 12-15) with ``(Kp, Ki, alpha)`` as given.
* **quaternion** — the NCF's quaternion counterpart is Mahony's filter (a PI correction on the attitude error, gains
  ``Kp`` 1/s and ``Ki`` 1/s²); the ccf_ros CCF (an NCF -> LCF cascade on quaternions) takes the same gains through the
  per-axis equivalence of :func:`quaternion_ccf_settings`.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from ..core.ccf import CcfParams
from ..core.metrics import summarize
from ..core.quaternion import quat_from_acc_mag, quat_from_rotvec, quat_mul, quat_to_euler
from ..core.registry import make_filter
from .datasets import Dataset, run_filter, score
from .labels import (
    ACC_MAG_ONLY,
    CCF_EULER,
    CCF_QUATERNION,
    CKF,
    EKF,
    EULER,
    FORMULATIONS,
    GRID_CCF,
    GRID_NCF,
    GYRO_ONLY,
    LCF,
    MADGWICK,
    MAHONY,
    NCF,
    QUATERNION,
    REFERENCE,
)

#: The paper's gain grid (Tables 1-2) and defaults.
KP_GRID = (75.0, 25.0, 1.0, 0.1)
KI_GRID = (0.01, 0.1, 1.0)
ALPHA_GRID = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
PAPER_KP, PAPER_KI, PAPER_ALPHA = 25.0, 0.1, 0.7
#: Factors applied to the ccf_ros default time constants in :func:`default_sensitivity`.
SENSITIVITY_FACTORS = (1 / 3, 1.0, 3.0)


# Keys of the per-dataset results; the report reads them back with the same functions.
def grid_key(form: str, kind: str, kp: float, ki: float) -> str:
    """Key of :func:`gain_grid`: ``formulation/kind/kp/ki`` (kind: GRID_NCF or GRID_CCF)."""
    return f'{form}/{kind}/{kp:g}/{ki:g}'


def alpha_key(form: str, alpha: float) -> str:
    """Key of :func:`alpha_sweep`: ``formulation/alpha``."""
    return f'{form}/{alpha:g}'


def sensitivity_key(f_blend: float, f_ncf: float) -> str:
    """Key of :func:`default_sensitivity`: ``f_blend/f_ncf``."""
    return f'{f_blend:.3g}/{f_ncf:.3g}'


def quaternion_ccf_settings(kp: float, ki: float, alpha: float) -> dict[str, Any]:
    """ccf_ros CCF settings equivalent to the paper's gains.

    Per axis the paper's CCF integrates ``rate + Kp (x_a - x) + I`` with ``x = alpha x_g + (1 - alpha) x_a``, so the
    integrator sees the error ``alpha (x_a - x_g)``: proportional rate ``alpha Kp`` (1/s), integral gain ``alpha Ki``
    (1/s²). The ccf_ros cascade's NCF has the proportional gain ``1/tau_ncf_s`` and, in steady motion, the integral
    gain ``1/(tau_ncf_s tau_bias_s)`` (its Kalman steady state), so ``tau_ncf_s = 1/(alpha Kp)`` and
    ``tau_bias_s = Kp/Ki``; its LCF blends at the same rate (``tau_acc_s = tau_acc_lp_s = tau_ncf_s``), heading three
    times slower (``tau_mag_s = 3 tau_acc_s``).
    """
    tau = 1.0 / max(alpha * kp, 1e-9)
    return {
        'filter': 'ccf',
        'formulation': QUATERNION,
        'tau_ncf_s': tau,
        'tau_bias_s': kp / max(ki, 1e-12),
        'tau_acc_s': tau,
        'tau_acc_lp_s': tau,
        'tau_mag_s': 3.0 * tau,
    }


def euler_ccf_settings(kp: Any, ki: Any, alpha: Any) -> dict[str, Any]:
    """The paper's CCF; each gain a float or a ``(roll, pitch, yaw)`` triple."""
    return {'filter': 'ccf', 'formulation': EULER, 'kp': kp, 'ki': ki, 'alpha': alpha}


def ncf_settings(formulation: str, kp: float, ki: float) -> dict[str, Any]:
    """The NCF of a formulation at gains ``kp`` (1/s), ``ki`` (1/s²)."""
    if formulation == EULER:
        return {'filter': 'ncf', 'kp': kp, 'ki': ki}
    return {'filter': 'mahony', 'mahony_kp': kp, 'mahony_ki': ki}


def ccf_settings(formulation: str, kp: float, ki: float, alpha: float) -> dict[str, Any]:
    """The CCF of a formulation at the paper's gains."""
    if formulation == EULER:
        return euler_ccf_settings(kp, ki, alpha)
    return quaternion_ccf_settings(kp, ki, alpha)


#: Figs 10-11: every method with its Table 4 / default parameters (LSCF is added per dataset after its fit).
METHODS: dict[str, dict[str, Any]] = {
    LCF: {'filter': 'lcf'},
    NCF: {'filter': 'ncf'},
    CCF_EULER: {'filter': 'ccf', 'formulation': EULER},
    CCF_QUATERNION: {'filter': 'ccf'},
    MAHONY: {'filter': 'mahony'},
    MADGWICK: {'filter': 'madgwick'},
    EKF: {'filter': 'ekf'},
    CKF: {'filter': 'ckf'},
}


def gain_grid(ds: Dataset) -> dict[str, Any]:
    """Tables 1-2: NCF and CCF (alpha = 0.7) over Kp x Ki, both formulations. Keys: :func:`grid_key`."""
    out: dict[str, Any] = {}
    for form in FORMULATIONS:
        for kp in KP_GRID:
            for ki in KI_GRID:
                out[grid_key(form, GRID_NCF, kp, ki)] = score(ncf_settings(form, kp, ki), ds)
                out[grid_key(form, GRID_CCF, kp, ki)] = score(ccf_settings(form, kp, ki, PAPER_ALPHA), ds)
    return out


def default_sensitivity(ds: Dataset) -> dict[str, Any]:
    """The ccf_ros CCF with its time constants scaled around the defaults: the blends (``tau_acc_s``,
    ``tau_acc_lp_s``, ``tau_mag_s`` together) and the NCF (``tau_ncf_s``, ``tau_bias_s`` together) each by 1/3, 1,
    3. Keys: :func:`sensitivity_key`."""
    d = CcfParams()
    out = {}
    for fa in SENSITIVITY_FACTORS:
        for fb in SENSITIVITY_FACTORS:
            settings = {'filter': 'ccf', 'tau_acc_s': d.tau_acc_s * fa, 'tau_acc_lp_s': d.tau_acc_lp_s * fa,
                        'tau_mag_s': d.tau_mag_s * fa, 'tau_ncf_s': d.tau_ncf_s * fb, 'tau_bias_s': d.tau_bias_s * fb}
            out[sensitivity_key(fa, fb)] = score(settings, ds)
    return out


def alpha_sweep(ds: Dataset) -> dict[str, Any]:
    """Fig 9: CCF at the paper's Kp, Ki over alpha 0.1-0.9, both formulations. Keys: :func:`alpha_key`."""
    return {
        alpha_key(form, a): score(ccf_settings(form, PAPER_KP, PAPER_KI, a), ds) for form in FORMULATIONS for a in ALPHA_GRID
    }


def methods(ds: Dataset, names: tuple[str, ...] = tuple(METHODS)) -> dict[str, Any]:
    """Figs 10-11: the methods of :data:`METHODS` on one dataset."""
    return {name: score(METHODS[name], ds) for name in names}


def time_series(ds: Dataset, max_points: int = 4000) -> dict[str, Any]:
    """Figs 13-14: roll/pitch/yaw (rad) of the reference, the CCFs, gyro-only integration and the accelerometer/
    magnetometer attitude alone, at (at most ``max_points``) reference stamps."""
    step = max(1, len(ds.t_ref) // max_points)
    sel = np.arange(0, len(ds.t_ref), step)
    out: dict[str, Any] = {'t_s': (ds.t_ref[sel] - ds.t_ref[0]).tolist(), REFERENCE: quat_to_euler(ds.q_ref[sel])}
    for label in (CCF_QUATERNION, CCF_EULER):
        q, _, _ = run_filter(METHODS[label], ds)
        out[label] = quat_to_euler(q[sel])
    # Gyro only: integrate from the first reference orientation (exact rotation per sample).
    k0 = int(np.searchsorted(ds.t_s, ds.t_ref[0]))
    q_g = np.empty((len(ds.t_s), 4))
    q_g[:] = np.nan
    q0 = ds.q_ref[np.flatnonzero(np.isfinite(ds.q_ref[:, 0]))[0]]
    dt = np.diff(ds.t_s, prepend=ds.t_s[0])
    steps = quat_from_rotvec(ds.gyr * dt[:, None])
    q_cur = np.asarray(q0, dtype=float)
    for k in range(k0, len(ds.t_s)):
        q_cur = quat_mul(q_cur, steps[k])
        q_cur /= math.sqrt(float(q_cur @ q_cur))
        q_g[k] = q_cur
    idx = np.clip(np.searchsorted(ds.t_s, ds.t_ref[sel]), 0, len(ds.t_s) - 1)
    out[GYRO_ONLY] = quat_to_euler(q_g[idx])
    mag = ds.mag[idx]
    q_am = quat_from_acc_mag(ds.acc[idx], np.where(np.isfinite(mag), mag, 0.0))
    out[ACC_MAG_ONLY] = quat_to_euler(q_am)
    for key, val in list(out.items()):
        if isinstance(val, np.ndarray):
            out[key] = val.tolist()
    out['dataset'] = ds.name
    return out


#: Figs 15-16: filters of the long run.
LONG_RUN_FILTERS: dict[str, dict[str, Any]] = {
    k: METHODS[k] for k in (CCF_QUATERNION, CCF_EULER, NCF, EKF, CKF)
}


def long_run(ds: Dataset, label: str, window_s: float = 100.0) -> dict[str, Any]:
    """Figs 15-16: one filter over a long simulated run: RMSE per ``window_s`` window (total deg, per axis rad;
    scored as in :func:`ccf_ros.core.metrics.summarize`) and the bias estimate against the true bias (rad/s),
    decimated to one value per second."""
    q, bias, _ = run_filter(LONG_RUN_FILTERS[label], ds)
    win = np.floor((ds.t_ref - ds.t_ref[0]) / window_s).astype(int)
    rmse_deg: list[float] = []
    rmse_axis: list[list[float]] = []
    for w in range(int(win.max()) + 1):
        m = (win == w) & ds.mask
        if not m.any():
            continue  # a window of rest only
        s = summarize(q[m], ds.q_ref[m])
        rmse_deg.append(s.total_rmse_deg)
        rmse_axis.append(list(s.rmse_rad))
    per_s = max(1, int(round(ds.rate_hz)))
    out: dict[str, Any] = {
        'window_s': window_s,
        'rmse_total_deg': rmse_deg,
        'rmse_rad': rmse_axis,
        'bias_rad_s': bias[::per_s].tolist(),
    }
    if ds.bias is not None:
        out['true_bias_rad_s'] = ds.bias[::per_s].tolist()
    return out


def compute_time(ds: Dataset, repetitions: int = 20, n_samples: int = 2860) -> dict[str, Any]:
    """Fig 12: time per ``update()`` (µs) of CCF (both forms), EKF and CKF over the first ``n_samples`` samples,
    ``repetitions`` times, the filters interleaved within each repetition so that machine load hits all alike."""
    labels = {k: METHODS[k] for k in (CCF_EULER, CCF_QUATERNION, EKF, CKF)}
    n = min(n_samples, len(ds.t_s))
    t = ds.t_s[:n].tolist()
    g = ds.gyr[:n].tolist()
    a = ds.acc[:n].tolist()
    m = [v if all(math.isfinite(x) for x in v) else None for v in ds.mag[:n].tolist()]
    times: dict[str, list[float]] = {k: [] for k in labels}
    for _ in range(repetitions):
        for label, settings in labels.items():
            filt = make_filter(settings)
            update = filt.update
            t0 = time.perf_counter()
            for i in range(n):
                update(t[i], g[i], a[i], m[i])
            times[label].append((time.perf_counter() - t0) / n * 1e6)
    ratios = {k: [v / r for v, r in zip(vals, times[CCF_EULER], strict=True)] for k, vals in times.items()}
    return {
        'n_samples': n,
        'repetitions': repetitions,
        'us_per_sample': times,
        'median_us': {k: float(np.median(v)) for k, v in times.items()},
        'ratio_to_ccf_euler_median': {k: float(np.median(v)) for k, v in ratios.items()},
    }

