"""Figs 2/4/8: frequency responses of LCF, NCF and CCF from the accelerometer angle to the estimate, from the
paper's transfer functions (eqs 9, 11, 15) and measured on the implementations.

Measurement: the roll angle seen by the accelerometer is a sinusoid ``A sin(2 pi f t)`` (gyro silent, no
magnetometer); the filter's roll output is fitted with ``sin, cos, 1, t`` over whole periods after the transient,
giving the complex gain at ``f``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..core.ccf import GRAVITY_M_S2, CcfParams, tilt_transfer
from ..core.quaternion import rpy_of
from ..core.registry import make_filter
from .experiments import PAPER_ALPHA, euler_ccf_settings, ncf_settings
from .labels import EULER


def tf_lcf(f_hz: np.ndarray, alpha: float, rate_hz: float) -> np.ndarray:
    """Eq 9: ``1 / (tau s + 1)`` with ``tau = alpha T / (1 - alpha)`` (per-sample alpha at period ``T``)."""
    s = 2j * np.pi * np.asarray(f_hz)
    tau = alpha / (1.0 - alpha) / rate_hz
    return 1.0 / (tau * s + 1.0)


def tf_ncf(f_hz: np.ndarray, kp: float, ki: float) -> np.ndarray:
    """Eq 11: ``(Kp s + Ki) / (s² + Kp s + Ki)``."""
    s = 2j * np.pi * np.asarray(f_hz)
    return (kp * s + ki) / (s * s + kp * s + ki)


def tf_ccf(f_hz: np.ndarray, kp: float, ki: float, alpha: float) -> np.ndarray:
    """Eq 15: ``((1 - a) s² + a Kp s + a Ki) / (s² + a Kp s + a Ki)``."""
    s = 2j * np.pi * np.asarray(f_hz)
    a = alpha
    return ((1 - a) * s * s + a * kp * s + a * ki) / (s * s + a * kp * s + a * ki)


def measure(
    settings: dict[str, Any], f_hz: float, rate_hz: float, slowest_pole: float = 1.0, amplitude_rad: float = 0.2
) -> complex:
    """Complex gain from the accelerometer roll angle to the filter's roll output at ``f_hz``.

    The transient is let die for 6 time constants of ``slowest_pole`` (rad/s; at most 300 s, at least 3 periods);
    slower remains (a pole nearly cancelled by a zero) are absorbed by the fit's linear term."""
    periods_settle = 3
    periods_fit = 4
    settle_s = max(periods_settle / f_hz, 20.0, min(300.0, 6.0 / slowest_pole))
    fit_s = max(periods_fit / f_hz, 10.0)
    fit_s = math.ceil(fit_s * f_hz) / f_hz
    n = int(round((settle_s + fit_s) * rate_hz))
    t = np.arange(n) / rate_hz
    roll = amplitude_rad * np.sin(2 * np.pi * f_hz * t)
    acc = np.stack((np.zeros(n), GRAVITY_M_S2 * np.sin(roll), GRAVITY_M_S2 * np.cos(roll)), axis=1)
    filt = make_filter({**settings, 'use_mag': False})
    out = np.full(n, np.nan)
    zero = (0.0, 0.0, 0.0)
    acc_l = acc.tolist()
    update = filt.update
    for k in range(n):
        update(float(t[k]), zero, acc_l[k], None)
        out[k] = rpy_of(filt.quaternion)[0]
    sel = t >= t[-1] - fit_s
    ts = t[sel]
    basis = np.stack((np.sin(2 * np.pi * f_hz * ts), np.cos(2 * np.pi * f_hz * ts), np.ones_like(ts), ts - ts[0]), 1)
    coef, *_ = np.linalg.lstsq(basis, out[sel], rcond=None)
    # out = A |H| sin(wt + phase) = A |H| (cos(phase) sin + sin(phase) cos)
    return complex(coef[0], coef[1]) / amplitude_rad


def db(h: np.ndarray | complex) -> np.ndarray:
    return 20.0 * np.log10(np.abs(h))


def phase_deg(h: np.ndarray | complex) -> np.ndarray:
    return np.degrees(np.angle(h))


def _slowest(*coefficients: float) -> float:
    """Smallest |real part| of the roots of the polynomial ``s^n + c1 s^(n-1) + ... + cn`` (``coefficients``: c1..cn),
    rad/s: the slowest pole of a transfer function with that denominator."""
    return float(min(abs(r.real) for r in np.roots([1.0, *coefficients])))


def cases(rate_hz: float) -> list[tuple[str, str, dict[str, Any], Any, float, float]]:
    """Filters whose response is measured: (figure, label, settings, transfer function of f, slowest pole, amplitude
    of the accelerometer angle, rad)."""
    out: list[tuple[str, str, dict[str, Any], Any, float, float]] = []
    for a in (0.7, 0.98):
        out.append(('fig02_lcf', f'LCF alpha={a:g}', {'filter': 'lcf', 'lcf_alpha': a},
                    lambda f, a=a: tf_lcf(f, a, rate_hz), (1.0 - a) * rate_hz / a, 0.2))
    for kp, ki in ((25.0, 0.1), (1.0, 0.01), (0.1, 1.0)):
        out.append(('fig04_ncf', f'NCF Kp={kp:g} Ki={ki:g}', ncf_settings(EULER, kp, ki),
                    lambda f, kp=kp, ki=ki: tf_ncf(f, kp, ki), _slowest(kp, ki), 0.2))
    alpha = PAPER_ALPHA
    for kp, ki in ((25.0, 0.1), (1.0, 0.01), (0.1, 1.0)):
        out.append(('fig08_ccf', f'CCF Kp={kp:g} Ki={ki:g} alpha={alpha:g}', euler_ccf_settings(kp, ki, alpha),
                    lambda f, kp=kp, ki=ki: tf_ccf(f, kp, ki, alpha), _slowest(alpha * kp, alpha * ki), 0.2))
    p = CcfParams(use_mag=False, rest_bias=False)
    # Poles: the Butterworth pair's real part 1/tau_acc_lp_s, the NCF's and the LCF's, and the bias gain.
    slowest = min(1.0 / p.tau_acc_lp_s, 1.0 / p.tau_ncf_s, 1.0 / p.tau_acc_s, p.bias_gain_per_s)
    out.append(('fig08_ccf', 'ccf_ros cascade (default, from the accelerometer angle)',
                {'filter': 'ccf', 'rest_bias': False},
                lambda f: np.array([tilt_transfer(p, float(x))[0] for x in np.atleast_1d(f)]), slowest,
                # Small (0.3°): the NCF uses no observation beyond 3 sigma of what it expects, a nonlinearity that a
                # large slow swing (0.2 rad at 0.02 Hz reads as 1.4°/s of drift) would meet.
                0.005))
    return out


def bode_study(rate_hz: float = 286.0, n_freq: int = 7) -> dict[str, Any]:
    """Theory and measurement at ``n_freq`` log-spaced frequencies from 0.02 Hz to ``rate_hz / 100``; the largest
    magnitude (dB) and phase (deg) deviations per case."""
    f_meas = np.geomspace(0.02, rate_hz / 100.0, n_freq)
    f_theory = np.geomspace(0.005, rate_hz / 2.0, 200)
    out: dict[str, Any] = {'rate_hz': rate_hz, 'f_measured_hz': f_meas.tolist(), 'f_theory_hz': f_theory.tolist(),
                           'cases': []}
    for fig, label, settings, tf, slowest, amplitude in cases(rate_hz):
        h_meas = np.array([measure(settings, float(f), rate_hz, slowest, amplitude) for f in f_meas])
        h_th = tf(f_meas)
        dmag = np.abs(db(h_meas) - db(h_th))
        dph = np.abs((phase_deg(h_meas) - phase_deg(h_th) + 180.0) % 360.0 - 180.0)
        curve = tf(f_theory)
        out['cases'].append({
            'figure': fig, 'label': label, 'settings': settings,
            'theory_db': db(curve).tolist(), 'theory_phase_deg': phase_deg(curve).tolist(),
            'measured_db': db(h_meas).tolist(), 'measured_phase_deg': phase_deg(h_meas).tolist(),
            'max_abs_db_error': float(dmag.max()), 'max_abs_phase_error_deg': float(dph.max()),
        })
    return out
