"""The 3-D calibration: hard and soft iron from a sensor turned through all orientations (numpy only).

Fit: Li & Griffiths' (2004) ellipsoid-specific least-squares quadric fit on centred and scaled data (raw values
are ~5e-5 T), then Levenberg-Marquardt on the geometric residual ``|S (m - b)| - r`` divided by its gradient
norm (Sampson's distance, in raw units). The model and its scale: :mod:`.model`.

Model (``model='auto'``, the default): the soft-iron matrix is kept only where the data show one. An ellipsoid
has 6 more unknowns than a sphere and always fits a little better; what it fits in a recording with no soft iron is
the field's own non-uniformity as the sensor moves through a room (steel in floors and benches), and that
"calibration" turns the heading. Measured on BROAD's calibrated trials: the ellipsoid lowers the RMS radial residual
by 2-4 % (ratio 0.96-0.98) and costs 0.4 deg of heading (1.36 -> 1.75 deg RMSE on trial 02); a soft-iron matrix
of a few percent lowers it by 20-50 % (ratio 0.50-0.80). So ``auto`` keeps the ellipsoid where its RMS scatter
(relative residual x radius: a huge sphere through a flat patch has a small relative one) is below
:data:`~.model.SOFT_IRON_MIN_GAIN` x the offset-only (sphere) fit's, else it writes the offset with ``S`` a
multiple of the identity. ``'ellipsoid'`` or ``'offset'`` force one model. Data that no believable ellipsoid fits (indefinite,
elongated) is refused in ``auto`` too, even where a sphere would fit it: it says the recording misleads.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from .model import (
    HINT,
    MAX_AXIS_RATIO,
    MIN_SAMPLES,
    MIN_SPAN_SNR,
    MIN_SPREAD_RATIO,
    MODELS,
    SOFT_IRON_MIN_GAIN,
    CalibrationError,
    MagCalibration,
)
from .sphere import coverage, fit_sphere


def _li_griffiths(x: np.ndarray) -> np.ndarray:
    """Ellipsoid ``(x - c)^T M (x - c) = 1`` through points ``x`` (N, 3) (of order 1): ``(c, M)`` packed as
    (12,); the quadric with ``4J - I^2 > 0`` (always an ellipsoid) minimising the algebraic residual."""
    X, Y, Z = x.T
    D = np.stack((X * X, Y * Y, Z * Z, 2 * Y * Z, 2 * X * Z, 2 * X * Y, 2 * X, 2 * Y, 2 * Z, np.ones_like(X)), axis=1)
    Sd = D.T @ D
    S11, S12, S22 = Sd[:6, :6], Sd[:6, 6:], Sd[6:, 6:]
    k = 4.0
    C1 = np.zeros((6, 6))
    C1[:3, :3] = k / 2 - 1
    np.fill_diagonal(C1[:3, :3], -1.0)
    # kJ - I^2 with J = ab + bc + ca - f^2 - g^2 - h^2 (f, g, h: half the cross-term coefficients, as in D).
    C1[3:, 3:] = -k * np.eye(3)
    try:
        S22_inv_S21 = np.linalg.solve(S22, S12.T)
        w, V = np.linalg.eig(np.linalg.solve(C1, S11 - S12 @ S22_inv_S21))
    except np.linalg.LinAlgError as err:
        raise CalibrationError(f'magnetometer samples are degenerate (no ellipsoid through them): {HINT}') from err
    # The constrained minimum is the eigenvector of the one positive eigenvalue.
    real = np.abs(w.imag) < 1e-9 * max(1.0, float(np.max(np.abs(w))))
    pos = np.flatnonzero(real & (w.real > 0))
    if len(pos) == 0:
        raise CalibrationError(f'magnetometer samples do not lie on an ellipsoid: {HINT}')
    v1 = V[:, pos[np.argmax(w.real[pos])]].real
    v2 = -S22_inv_S21 @ v1
    a, b, c, f, g, h = v1
    A = np.array([[a, h, g], [h, b, f], [g, f, c]])
    try:
        centre = -np.linalg.solve(A, v2[:3])
    except np.linalg.LinAlgError as err:
        raise CalibrationError(f'magnetometer samples do not lie on an ellipsoid: {HINT}') from err
    scale = centre @ A @ centre - v2[3]
    M = A / scale
    if not np.all(np.isfinite(M)) or np.min(np.linalg.eigvalsh(M)) <= 0:
        raise CalibrationError(f'magnetometer samples do not lie on an ellipsoid: {HINT}')
    return np.concatenate((centre, M.ravel()))


def _sym_sqrt(M: np.ndarray) -> np.ndarray:
    """Symmetric square root (3, 3) of a symmetric positive-definite ``M``."""
    w, V = np.linalg.eigh(M)
    root: np.ndarray = (V * np.sqrt(w)) @ V.T
    return root


_SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def _unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    S = np.empty((3, 3))
    for k, (i, j) in enumerate(_SYM):
        S[i, j] = S[j, i] = p[3 + k]
    return p[:3], S


def _refine(x: np.ndarray, c0: np.ndarray, S0: np.ndarray, iterations: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt over centre ``c`` (3,) and symmetric ``S`` (3, 3) (6 unknowns) of ``|S (x - c)| = 1``.

    The residual is ``(|S u| - 1) / |grad|`` with ``u = x - c``: the geometric residual divided by its gradient
    norm in ``x``, i.e. Sampson's first-order distance in raw units. Isotropic raw noise becomes anisotropic
    through ``S``; unweighted, the fit leans on the directions where it is stretched (offset errors 2-5x larger
    with half the sphere covered).
    """
    p = np.concatenate((c0, [S0[i, j] for i, j in _SYM]))

    def residual(p: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        S = _unpack(p)[1]
        u = x - p[:3]
        y = u @ S  # S symmetric: rows are (S u_i)^T
        n = np.linalg.norm(y, axis=1)
        yh = y / n[:, None]
        z = yh @ S  # gradient of |S u| in x
        g = np.linalg.norm(z, axis=1)
        return (n - 1.0) / g, {'S': S, 'u': u, 'n': n, 'yh': yh, 'z': z, 'g': g}

    def jacobian(w: dict[str, np.ndarray]) -> np.ndarray:
        S, u, n, yh, g = w['S'], w['u'], w['n'], w['yh'], w['g']
        zh = w['z'] / g[:, None]
        q = zh @ S
        v = (q - np.sum(q * yh, axis=1)[:, None] * yh) / n[:, None]  # d|S yh| / dy
        beta = (n - 1.0) / (g * g)
        a = yh / g[:, None] - beta[:, None] * v  # de / dy
        J = np.empty((len(u), 9))
        J[:, :3] = -a @ S  # dy / dc = -S
        for k, (i, j) in enumerate(_SYM):
            if i == j:
                J[:, 3 + k] = a[:, i] * u[:, i] - beta * zh[:, i] * yh[:, i]
            else:
                J[:, 3 + k] = (a[:, i] * u[:, j] + a[:, j] * u[:, i]
                               - beta * (zh[:, i] * yh[:, j] + zh[:, j] * yh[:, i]))
        return J

    e, work = residual(p)
    cost = float(e @ e)
    lam = 1e-3
    for _ in range(iterations):
        J = jacobian(work)
        JtJ, Jte = J.T @ J, J.T @ e
        improved = done = False
        while lam < 1e8:
            step = np.linalg.solve(JtJ + lam * np.diag(np.diag(JtJ)), -Jte)
            e2, work2 = residual(p + step)
            cost2 = float(e2 @ e2)
            if cost2 < cost:  # NaN (a step through a degenerate S) compares False: rejected
                done = cost - cost2 < 1e-12 * cost or float(np.max(np.abs(step))) < 1e-12
                p, e, work, cost, lam, improved = p + step, e2, work2, cost2, max(lam / 10, 1e-12), True
                break
            lam *= 10
        if not improved or done:
            break
    return _unpack(p)


def fit(mag: ArrayLike, *, field_norm_t: float | None = None, model: str = 'auto') -> MagCalibration:
    """Hard- and soft-iron calibration from raw magnetometer samples ``mag`` (N, 3), T.

    ``field_norm_t`` (T): the local field norm, which becomes the radius of the calibrated sphere; if None,
    ``det S = 1`` instead. ``model``: one of :data:`~.model.MODELS` (see the module docstring). Non-finite and all-zero
    samples are dropped. Raises :class:`CalibrationError` on fewer than :data:`~.model.MIN_SAMPLES` samples, flat or
    degenerate data, or a fit that is no believable ellipsoid.
    """
    if model not in MODELS:
        raise ValueError(f'model must be one of {", ".join(MODELS)}, got {model!r}')
    m = np.asarray(mag, dtype=float)
    if m.ndim != 2 or m.shape[1] != 3:
        raise ValueError(f'expected (N, 3) magnetometer samples, got shape {m.shape}')
    if field_norm_t is not None and not (math.isfinite(field_norm_t) and field_norm_t > 0):
        raise ValueError(f'field norm must be a positive number, got {field_norm_t!r}')
    m = m[np.all(np.isfinite(m), axis=1) & np.any(m != 0, axis=1)]
    if len(m) < MIN_SAMPLES:
        raise CalibrationError(f'{len(m)} usable magnetometer samples; need at least {MIN_SAMPLES}')
    # Centre and scale to order 1: the quadric's design matrix holds squares of ~5e-5 T values otherwise.
    mean = m.mean(axis=0)
    spread = np.linalg.svd(m - mean, compute_uv=False) / math.sqrt(len(m))
    if spread[0] <= 0 or spread[2] < MIN_SPREAD_RATIO * spread[0]:
        raise CalibrationError(f'magnetometer samples lie in a plane or on a line: {HINT}')
    scale = float(np.sqrt(np.sum(spread**2)))
    x = (m - mean) / scale
    c_sph, r_sph = fit_sphere(x)
    res_sph = float(np.sqrt(np.mean((np.linalg.norm(x - c_sph, axis=1) / r_sph - 1.0) ** 2)))
    chosen, axis_ratio = 'offset', 1.0
    c, S, r_fit, res = c_sph, np.eye(3) / r_sph, r_sph, res_sph
    if model != 'offset':
        packed = _li_griffiths(x)
        c_ell, S_ell = _refine(x, packed[:3], _sym_sqrt(packed[3:].reshape(3, 3)))
        w = np.linalg.eigvalsh(S_ell)
        if not np.all(np.isfinite(S_ell)) or w[0] <= 0:
            raise CalibrationError(f'magnetometer samples do not lie on an ellipsoid: {HINT}')
        axis_ratio = float(w[-1] / w[0])
        rel = np.linalg.norm((x - c_ell) @ S_ell, axis=1) - 1.0
        res_ell = float(np.sqrt(np.mean(rel * rel)))
        # Normalised units: the fitted ellipsoid's geometric-mean radius is det(S)^(-1/3). The two fits are
        # compared by their absolute scatter (relative residual x radius): a huge sphere through a flat patch of
        # samples has a small relative one.
        r_ell = float(np.prod(w)) ** (-1.0 / 3.0)
        if model == 'ellipsoid' or res_ell * r_ell < SOFT_IRON_MIN_GAIN * res_sph * r_sph:
            chosen, c, S, res, r_fit = 'ellipsoid', c_ell, S_ell, res_ell, r_ell
    if spread[0] / scale < MIN_SPAN_SNR * res * r_fit:
        # Some ellipsoid fits any cloud (at rest: the noise; disturbed: a mix of fields). It means something only
        # if the samples vary well beyond their scatter about it.
        raise CalibrationError(
            'magnetometer samples scatter about the fit nearly as much as they vary (sensor hardly turned, or field '
            'disturbed): ' + HINT
        )
    if model != 'offset' and axis_ratio > MAX_AXIS_RATIO:  # even where auto keeps the sphere: the data mislead
        raise CalibrationError(f'fitted ellipsoid is implausibly elongated (axis ratio {axis_ratio:.1f}): {HINT}')
    # Back to tesla: |S_unit (m - offset)| = 1 on the fitted ellipsoid.
    offset = mean + scale * c
    S_unit = S / scale
    if chosen == 'offset':  # S exactly a multiple of the identity (the identity for det S = 1)
        r_t = r_sph * scale
        radius = float(field_norm_t) if field_norm_t is not None else r_t
        S_t = np.eye(3) * (radius / r_t)
    else:
        radius = float(field_norm_t) if field_norm_t is not None else float(np.linalg.det(S_unit)) ** (-1.0 / 3.0)
        S_t = radius * S_unit
    m_cal = (m - offset) @ S_t.T
    rel = np.linalg.norm(m_cal, axis=1) / radius - 1.0
    return MagCalibration(
        offset_t=tuple(float(v) for v in offset),
        soft_iron=tuple(float(v) for v in S_t.ravel()),
        radius_t=radius,
        residual_rel=float(np.sqrt(np.mean(rel * rel))),
        coverage=coverage(m_cal),
        n_samples=len(m),
        model=chosen,
        offset_only_residual_rel=res_sph,
    )
