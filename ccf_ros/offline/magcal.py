"""``ccf calibrate-mag``: magnetometer hard-/soft-iron calibration from a bag.

Model: a raw reading is ``m_raw = W m_true + b`` (tesla, as in sensor_msgs/MagneticField) with soft-iron matrix
``W`` (3x3) and hard-iron offset ``b`` (3,). The calibration gives ``b`` and a symmetric positive-definite ``S`` with
``m_cal = S (m_raw - b)`` on a sphere. ``S`` equals ``W^-1`` up to a rotation and a scale; of the rotations we
take the one that makes ``S`` symmetric, and the scale is fixed by:

* a given field norm ``field_norm_t``: the sphere radius is that norm (``S = W^-1`` if ``|m_true|`` is it);
* otherwise ``det S = 1``: ``S`` preserves volume and the radius is the geometric mean of the raw ellipsoid's
  semi-axes (``S = W^-1`` if ``det W = 1``).

Fit: Li & Griffiths' (2004) ellipsoid-specific least-squares quadric fit on centred and scaled data (raw values
are ~5e-5 T), then Levenberg-Marquardt on the geometric residual ``|S (m - b)| - r`` divided by its gradient
norm (Sampson's distance, in raw units). Numpy only.

Model (``model='auto'``, the default): the soft-iron matrix is kept only where the data show one. An ellipsoid
has 6 more unknowns than a sphere and always fits a little better; what it fits in a recording with no soft iron is
the field's own non-uniformity as the sensor moves through a room (steel in floors and benches), and that
"calibration" turns the heading. Measured on BROAD's calibrated trials: the ellipsoid lowers the RMS radial residual
by 2-4 % (ratio 0.96-0.98) and costs 0.4 deg of heading (1.36 -> 1.75 deg RMSE on trial 02); a soft-iron matrix
of a few percent lowers it by 20-50 % (ratio 0.50-0.80). So ``auto`` keeps the ellipsoid where its RMS scatter
(relative residual x radius: a huge sphere through a flat patch has a small relative one) is below
:data:`SOFT_IRON_MIN_GAIN` x the offset-only (sphere) fit's, else it writes the offset with ``S`` a multiple of the
identity. ``'ellipsoid'`` or ``'offset'`` force one model. Data that no believable ellipsoid fits (indefinite,
elongated) is refused in ``auto`` too, even where a sphere would fit it: it says the recording misleads.

Coverage: the calibrated directions are binned to the nearest of :data:`COVERAGE_BINS` Fibonacci-lattice
directions (bins of ~4 pi / 100 sr, ~23 deg across); coverage is the fraction of bins with at least
:data:`COVERAGE_MIN_PER_BIN` samples. A full calibration dance gives 0.5-0.9; a sensor turned about one axis
0.1-0.25, and there the fit is unreliable even though its residual looks fine.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import CcfError, ParameterError
from .bagio import read_topic, refuse_existing, staged
from .plot import save_figure

#: Fewest usable samples :func:`fit` accepts.
MIN_SAMPLES = 50
#: Coverage bins: this many Fibonacci-sphere directions; a sample falls in the bin of its nearest direction.
COVERAGE_BINS = 100
#: A bin counts as covered when it holds at least this many samples.
COVERAGE_MIN_PER_BIN = 3
#: Below this coverage the command warns.
COVERAGE_WARN = 0.3
#: Smallest over largest spread (principal standard deviation) of the data below which it counts as flat.
MIN_SPREAD_RATIO = 0.05
#: Smallest ratio of the samples' largest principal spread to their RMS radial residual (sensor turned enough).
MIN_SPAN_SNR = 5.0
#: Largest believable ratio of the fitted ellipsoid's longest to shortest axis.
MAX_AXIS_RATIO = 3.0
#: ``model='auto'`` keeps the soft-iron matrix only when the ellipsoid's RMS radial scatter is below this fraction
#: of the sphere's (offset-only) fit: the soft iron must explain a tenth of what the offset leaves, see above.
SOFT_IRON_MIN_GAIN = 0.9
#: Calibration models :func:`fit` accepts.
MODELS = ('auto', 'ellipsoid', 'offset')


_HINT = 'rotate the sensor through more orientations, away from magnetic disturbances'


class CalibrationError(CcfError, ValueError):
    """The samples cannot give a calibration; the message is meant for the user, one line.

    A :class:`~ccf_ros.errors.CcfError` (the ``ccf`` command shows it as one line, exit code 2) and, for callers of
    :func:`fit`, a ``ValueError`` (the samples are an unusable value).
    """


@dataclass(frozen=True)
class MagCalibration:
    """Result of :func:`fit`: ``m_cal = S (m_raw - offset)``.

    offset_t (3,) T; soft_iron (9,) ``S`` row-major, symmetric positive definite; radius_t sphere radius of
    ``m_cal``, T; residual_rel RMS of ``(|m_cal| - radius) / radius``; coverage fraction in [0, 1] of direction
    bins holding samples (see :func:`coverage`); n_samples samples used; model ``'ellipsoid'`` (offset and soft
    iron) or ``'offset'`` (``S`` a multiple of the identity); offset_only_residual_rel the offset-only fit's
    residual, as residual_rel (the yardstick of ``model='auto'``).
    """

    offset_t: tuple[float, ...]
    soft_iron: tuple[float, ...]
    radius_t: float
    residual_rel: float
    coverage: float
    n_samples: int
    model: str = 'ellipsoid'
    offset_only_residual_rel: float = float('nan')

    def __post_init__(self) -> None:
        if len(self.offset_t) != 3 or len(self.soft_iron) != 9:
            raise ValueError(f'expected 3 offsets and 9 soft-iron entries, got {len(self.offset_t)}, '
                             f'{len(self.soft_iron)}')

    @property
    def matrix(self) -> np.ndarray:
        """``S`` as a (3, 3) array."""
        return np.array(self.soft_iron, dtype=float).reshape(3, 3)

    @property
    def offset(self) -> np.ndarray:
        """Offset as a (3,) array, T."""
        return np.array(self.offset_t, dtype=float)

    def apply(self, m: ArrayLike) -> np.ndarray:
        """Calibrated field ``S (m - offset)`` of raw readings ``m`` (N, 3) or (3,), T; same shape."""
        m = np.asarray(m, dtype=float)
        if m.shape[-1:] != (3,) or m.ndim > 2:
            raise ValueError(f'expected (N, 3) or (3,) magnetometer readings, got shape {m.shape}')
        return (m - self.offset) @ self.matrix.T


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
        raise CalibrationError(f'magnetometer samples are degenerate (no ellipsoid through them): {_HINT}') from err
    # The constrained minimum is the eigenvector of the one positive eigenvalue.
    real = np.abs(w.imag) < 1e-9 * max(1.0, float(np.max(np.abs(w))))
    pos = np.flatnonzero(real & (w.real > 0))
    if len(pos) == 0:
        raise CalibrationError(f'magnetometer samples do not lie on an ellipsoid: {_HINT}')
    v1 = V[:, pos[np.argmax(w.real[pos])]].real
    v2 = -S22_inv_S21 @ v1
    a, b, c, f, g, h = v1
    A = np.array([[a, h, g], [h, b, f], [g, f, c]])
    try:
        centre = -np.linalg.solve(A, v2[:3])
    except np.linalg.LinAlgError as err:
        raise CalibrationError(f'magnetometer samples do not lie on an ellipsoid: {_HINT}') from err
    scale = centre @ A @ centre - v2[3]
    M = A / scale
    if not np.all(np.isfinite(M)) or np.min(np.linalg.eigvalsh(M)) <= 0:
        raise CalibrationError(f'magnetometer samples do not lie on an ellipsoid: {_HINT}')
    return np.concatenate((centre, M.ravel()))


def _sym_sqrt(M: np.ndarray) -> np.ndarray:
    """Symmetric square root (3, 3) of a symmetric positive-definite ``M``."""
    w, V = np.linalg.eigh(M)
    return (V * np.sqrt(w)) @ V.T


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


def _sphere(x: np.ndarray, iterations: int = 20) -> tuple[np.ndarray, float]:
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


def fit(mag: ArrayLike, *, field_norm_t: float | None = None, model: str = 'auto') -> MagCalibration:
    """Hard- and soft-iron calibration from raw magnetometer samples ``mag`` (N, 3), T.

    ``field_norm_t`` (T): the local field norm, which becomes the radius of the calibrated sphere; if None,
    ``det S = 1`` instead. ``model``: one of :data:`MODELS` (see the module docstring). Non-finite and all-zero
    samples are dropped. Raises :class:`CalibrationError` on fewer than :data:`MIN_SAMPLES` samples, flat or
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
        raise CalibrationError(f'magnetometer samples lie in a plane or on a line: {_HINT}')
    scale = float(np.sqrt(np.sum(spread**2)))
    x = (m - mean) / scale
    c_sph, r_sph = _sphere(x)
    res_sph = float(np.sqrt(np.mean((np.linalg.norm(x - c_sph, axis=1) / r_sph - 1.0) ** 2)))
    chosen, axis_ratio = 'offset', 1.0
    c, S, r_fit, res = c_sph, np.eye(3) / r_sph, r_sph, res_sph
    if model != 'offset':
        packed = _li_griffiths(x)
        c_ell, S_ell = _refine(x, packed[:3], _sym_sqrt(packed[3:].reshape(3, 3)))
        w = np.linalg.eigvalsh(S_ell)
        if not np.all(np.isfinite(S_ell)) or w[0] <= 0:
            raise CalibrationError(f'magnetometer samples do not lie on an ellipsoid: {_HINT}')
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
            'disturbed): ' + _HINT
        )
    if model != 'offset' and axis_ratio > MAX_AXIS_RATIO:  # even where auto keeps the sphere: the data mislead
        raise CalibrationError(f'fitted ellipsoid is implausibly elongated (axis ratio {axis_ratio:.1f}): {_HINT}')
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


def read_mag(bag: str | Path, topic: str = '/imu/mag') -> np.ndarray:
    """All magnetic_field vectors (N, 3), T, of a sensor_msgs/MagneticField topic; :class:`BagError` if absent."""
    out = [(m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z)
           for _, _, m in read_topic(bag, topic, 'sensor_msgs/msg/MagneticField')]
    return np.array(out, dtype=float).reshape(-1, 3)


def _num(v: float) -> str:
    # Always a mantissa dot and a signed exponent: YAML 1.1 (PyYAML) reads '5e-05' as a string.
    return f'{v:.10e}'


def params_yaml(cal: MagCalibration) -> str:
    """A ROS 2 parameters file (``/**: ros__parameters:``) with mag_bias_x/y/z (T) and mag_soft_iron (9, row-major)."""
    b = cal.offset_t
    lines = [
        '# Magnetometer calibration by ccf calibrate-mag: m_cal = S (m_raw - b), b = mag_bias_* (T),',
        '# S = mag_soft_iron (row-major).',
        f'# model {cal.model}, residual {cal.residual_rel:.3%} RMS of |m_cal|, coverage {cal.coverage:.0%} of '
        f'directions, radius {cal.radius_t * 1e6:.3f} uT, n_samples {cal.n_samples}',
        '/**:',
        '  ros__parameters:',
        f'    mag_bias_x: {_num(b[0])}',
        f'    mag_bias_y: {_num(b[1])}',
        f'    mag_bias_z: {_num(b[2])}',
        f'    mag_soft_iron: [{", ".join(_num(v) for v in cal.soft_iron)}]',
    ]
    return '\n'.join(lines) + '\n'


def plot(path: str | Path, raw: ArrayLike, cal: MagCalibration) -> None:
    """PNG of the xy, yz and zx projections of raw and calibrated samples (µT) with the fitted radius circle."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    m = np.asarray(raw, dtype=float).reshape(-1, 3)
    m = m[np.all(np.isfinite(m), axis=1) & np.any(m != 0, axis=1)]
    if len(m) > 5000:  # a scatter of every sample of a long bag is slow and no clearer
        m = m[np.linspace(0, len(m) - 1, 5000).astype(int)]
    raw_ut, cal_ut = m * 1e6, cal.apply(m) * 1e6
    r = cal.radius_t * 1e6
    t = np.linspace(0, 2 * np.pi, 361)
    fig, axes = plt.subplots(1, 3, figsize=(15, 5.4))
    for ax, (i, j), name in zip(axes, ((0, 1), (1, 2), (2, 0)), ('xy', 'yz', 'zx'), strict=True):
        ax.plot(raw_ut[:, i], raw_ut[:, j], '.', ms=1.5, alpha=0.4, color='tab:red', label='raw')
        ax.plot(cal_ut[:, i], cal_ut[:, j], '.', ms=1.5, alpha=0.4, color='tab:blue', label='calibrated')
        ax.plot(r * np.cos(t), r * np.sin(t), 'k-', lw=1.0, label=f'radius {r:.1f} µT')
        ax.set_xlabel(f'{name[0]} [µT]')
        ax.set_ylabel(f'{name[1]} [µT]')
        ax.set_title(f'{name} plane')
        ax.set_aspect('equal', adjustable='datalim')
        ax.grid(alpha=0.3)
    axes[0].legend(loc='upper right', fontsize=8, markerscale=6)
    fig.suptitle(f'magnetometer calibration: residual {cal.residual_rel:.2%} RMS, coverage {cal.coverage:.0%}, '
                 f'{cal.n_samples} samples')
    save_figure(fig, path)


#: ``--motion`` choices: tell from the gyro, or force the 3-D (ellipsoid) or planar (ellipse) fit.
MOTIONS = ('auto', '3d', 'planar')


def _motion_axes(args: argparse.Namespace, raw: np.ndarray) -> tuple[str, Any]:
    """The fit to run (``'3d'`` or ``'planar'``) and the rotation axes (a :class:`~.magfit.RotationAxes`, or None
    without a gyro), printing which was chosen and why."""
    from .bagio import read_imu_arrays
    from .magfit import PLANAR_MAX_OFF_AXIS, RotationAxes, rotation_axes

    axes: RotationAxes | None = None
    try:
        imu = read_imu_arrays(args.bag, args.imu_topic, mag_topic=None)
    except CcfError as err:
        if args.motion == 'planar':
            raise CalibrationError(f'--motion planar needs the gyro ({args.imu_topic}): {err}') from err
        if args.motion == 'auto':
            print(f'no gyro ({err}): motion from the magnetometer alone')
    else:
        dt = np.diff(imu.t_s, prepend=imu.t_s[:1])
        axes = rotation_axes(imu.gyr, dt, imu.acc)
        print(f'rotation: {axes.angle_rad:.1f} rad in all, {axes.off_axis:.1%} of it off the principal axis '
              f'[{axes.axis[0]:+.3f} {axes.axis[1]:+.3f} {axes.axis[2]:+.3f}] (body)')
    if args.motion != 'auto':
        print(f'motion: {args.motion} (forced by --motion)')
        return args.motion, axes
    if axes is not None:
        chosen = 'planar' if axes.planar else '3d'
        rel = 'at most' if axes.planar else 'more than'
        print(f'motion: {chosen} (auto: {rel} {PLANAR_MAX_OFF_AXIS:.0%} of the rotation off one axis)')
        return chosen, axes
    m = raw[np.all(np.isfinite(raw), axis=1) & np.any(raw != 0, axis=1)]
    spread = np.linalg.svd(m - m.mean(axis=0), compute_uv=False) if len(m) >= 3 else np.ones(3)
    chosen = 'planar' if spread[2] < 2 * MIN_SPREAD_RATIO * spread[0] else '3d'
    print(f'motion: {chosen} (auto: the magnetometer samples are {"" if chosen == "planar" else "not "}flat)')
    return chosen, None


def _planar(args: argparse.Namespace, raw: np.ndarray, axes: Any) -> MagCalibration:
    """The planar fit of ``cmd_calibrate_mag``, reported; returns the 3-D calibration to write."""
    from .magfit import TURN_COVERAGE_MIN, fit_planar

    if axes is None:
        m = raw[np.all(np.isfinite(raw), axis=1) & np.any(raw != 0, axis=1)]
        axis = np.linalg.svd(m - m.mean(axis=0))[2][2]
        print('axis: the normal of the magnetometer samples\' plane (no gyro: which way is up is unknown)')
    else:
        axis = np.array(axes.axis)
    norm = None if args.field_norm_ut is None else args.field_norm_ut * 1e-6
    dip = None if args.field_dip_deg is None else math.radians(args.field_dip_deg)
    if axes is None and (norm is not None or dip is not None):
        print('warning: without the accelerometer the axis has no sign: --field-norm-ut/--field-dip-deg ignored')
        norm = dip = None
    pc = fit_planar(raw, axis, field_norm_t=norm, field_dip_rad=dip, model=args.model, force=args.force)
    cal = pc.cal
    b = cal.offset * 1e6
    print(f'{cal.n_samples} samples from {args.mag_topic}')
    print(f'planar fit ({pc.model}) about the axis [{pc.axis[0]:+.3f} {pc.axis[1]:+.3f} {pc.axis[2]:+.3f}]: '
          f'residual {pc.residual_t * 1e6:.3f} uT RMS in the plane, turn coverage {pc.turn_coverage:.0%}, '
          f'horizontal radius {pc.radius_t * 1e6:.3f} uT')
    print(f'offset b [uT]: {b[0]:.3f} {b[1]:.3f} {b[2]:.3f}')
    if pc.axial_source == 'none':
        print('offset along the axis: not determined by turning about it, left at 0 (give --field-norm-ut and/or '
              '--field-dip-deg to fit it)')
    else:
        print(f'offset along the axis: {pc.axial_offset_t * 1e6:.3f} uT (from the field {pc.axial_source})')
        if pc.axial_source == 'norm':
            # The norm gives the vertical component's size, not its sign.
            print('  (the field taken to point down, as north of the magnetic equator: south of it give '
                  '--field-dip-deg, negative there)')
    print('soft iron S (m_cal = S (m_raw - b)), in the plane only:')
    for row in cal.matrix:
        print('  ' + ' '.join(f'{v:9.5f}' for v in row))
    if pc.turn_coverage < TURN_COVERAGE_MIN:
        print(f'warning: turn coverage {pc.turn_coverage:.0%} is low: turn full circles and record again')
    return cal


def cmd_calibrate_mag(args: argparse.Namespace) -> int:
    """Read, fit (3-D or planar, see ``--motion``), report, write the parameters YAML (atomically), optionally plot."""
    out = Path(args.output)
    refuse_existing(out, args.overwrite, bag=False)  # before the slow part, not after
    if args.field_norm_ut is not None and not (math.isfinite(args.field_norm_ut) and args.field_norm_ut > 0):
        raise ParameterError(f'--field-norm-ut must be a positive number of uT, got {args.field_norm_ut!r}')
    if args.field_dip_deg is not None and not (math.isfinite(args.field_dip_deg) and abs(args.field_dip_deg) < 89.9):
        raise ParameterError(f'--field-dip-deg must be a number within (-90, 90) deg, got {args.field_dip_deg!r}')
    raw = read_mag(args.bag, args.mag_topic)
    motion, axes = ('3d', None) if args.motion == '3d' else _motion_axes(args, raw)
    cal = _planar(args, raw, axes) if motion == 'planar' else _fit_3d(args, raw)
    # Staged and renamed: a reader (or a crash) never sees half a file.
    with staged(out, bag=False) as tmp:
        try:
            tmp.write_text(params_yaml(cal))
        except OSError as err:
            raise CcfError(f'cannot write {out}: {err.strerror}') from err
    print(f'wrote {out}')
    if args.plot:
        plot(args.plot, raw, cal)
        print(f'plot: {args.plot}')
    return 0


def _fit_3d(args: argparse.Namespace, raw: np.ndarray) -> MagCalibration:
    """The 3-D (ellipsoid) fit of ``cmd_calibrate_mag``, reported; refuses low coverage unless ``--force``."""
    field_norm_t = None if args.field_norm_ut is None else args.field_norm_ut * 1e-6
    cal = fit(raw, field_norm_t=field_norm_t, model=args.model)
    b = cal.offset * 1e6
    dropped = len(raw) - cal.n_samples
    note = f' ({dropped} non-finite or zero dropped)' if dropped else ''
    print(f'{cal.n_samples} samples from {args.mag_topic}{note}')
    print(f'offset b [uT]: {b[0]:.3f} {b[1]:.3f} {b[2]:.3f}')
    print('soft iron S (m_cal = S (m_raw - b)):')
    for row in cal.matrix:
        print('  ' + ' '.join(f'{v:9.5f}' for v in row))
    scale = 'given field norm' if field_norm_t is not None else 'det S = 1'
    print(f'radius {cal.radius_t * 1e6:.3f} uT ({scale}), residual {cal.residual_rel:.2%} RMS, '
          f'coverage {cal.coverage:.0%} of directions')
    if cal.model == 'ellipsoid':
        why = 'forced by --model' if args.model == 'ellipsoid' else (
            f'it lowers the scatter below {SOFT_IRON_MIN_GAIN:g} x the offset-only fit\'s '
            f'({cal.offset_only_residual_rel:.2%} RMS)')
        print(f'model: offset and soft iron ({why})')
    else:
        why = 'forced by --model' if args.model == 'offset' else (
            f'a soft-iron matrix lowers the scatter by less than {1 - SOFT_IRON_MIN_GAIN:.0%}: what is left is '
            'the field\'s non-uniformity, not the sensor\'s')
        print(f'model: offset only, S a multiple of the identity ({why})')
    if cal.coverage < COVERAGE_WARN:
        advice = 'rotate the sensor through more orientations (all sides up, full turns) and record again'
        if not args.force:
            # An offset along directions the recording never turned through is a guess: on BROAD trial 16 (12 %)
            # the file written would have raised the heading error from 0.48 to 3.35 deg.
            raise CalibrationError(f'coverage {cal.coverage:.0%} of directions is below {COVERAGE_WARN:.0%}: the '
                                   f'offset is not determined; {advice} (or --force to write it anyway; a robot '
                                   'that can only turn about one axis: --motion planar)')
        print(f'warning: coverage {cal.coverage:.0%} is low: {advice}')
    return cal


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``calibrate-mag`` on an ``add_subparsers()`` object; returns the new parser."""
    p: argparse.ArgumentParser = subparsers.add_parser(
        'calibrate-mag',
        help='fit magnetometer hard-/soft-iron calibration from a bag (3-D, or planar for a robot turning about one '
        'axis), write a parameters YAML',
        description='Fit m_cal = S (m_raw - b) to the magnetometer samples of a bag: b hard-iron offset, '
        'S symmetric soft-iron matrix (kept only where the data show one, see --model); radius = --field-norm-ut '
        'if given, else det S = 1.',
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument('bag', help='input: rosbag2 directory (mcap or sqlite3) or ROS 1 .bag')
    p.add_argument('--mag-topic', default='/imu/mag', help='sensor_msgs/MagneticField topic')
    p.add_argument('-o', '--output', default='mag_calibration.yaml', help='output ROS 2 parameters YAML')
    p.add_argument('--plot', metavar='FILE.png', help='also plot raw and calibrated samples')
    p.add_argument('--field-norm-ut', type=float, metavar='UT',
                   help='local field norm, uT: the radius of the calibrated sphere; None: scale to det S = 1')
    p.add_argument('--model', choices=MODELS, default='auto',
                   help='ellipsoid: offset and soft-iron matrix; offset: offset only; auto: the soft-iron matrix '
                   f'only where it lowers the RMS scatter below {SOFT_IRON_MIN_GAIN:g} x the offset-only fit\'s')
    p.add_argument('--imu-topic', default='/imu/data_raw',
                   help='sensor_msgs/Imu topic: its gyro tells the motion (--motion auto), its accelerometer up')
    p.add_argument('--motion', choices=MOTIONS, default='auto',
                   help='3d: ellipsoid fit (needs a sensor turned through all orientations); planar: ellipse fit in '
                   'the plane of a turn about one axis (a ground robot spinning in place); auto: planar where at most '
                   '10 %% of the rotation is off one axis')
    p.add_argument('--field-dip-deg', type=float, metavar='DEG',
                   help='planar: local field dip (inclination), deg, > 0 where it points down; with or without '
                   '--field-norm-ut it gives the offset along the turning axis (else left at 0)')
    p.add_argument('--overwrite', action='store_true', help='replace an existing output file')
    p.add_argument('--force', action='store_true',
                   help=f'write the calibration even if the coverage is below {COVERAGE_WARN * 100:.0f} %% '
                   '(planar: the turn coverage below 75 %%)')
    p.set_defaults(func=cmd_calibrate_mag)
    return p
