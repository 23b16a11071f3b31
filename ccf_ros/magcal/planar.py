"""Planar magnetometer calibration: what turning about one axis (a ground robot spinning in place, driving circles)
determines, and how to tell such a recording from a full 3-D one.

Model as in :mod:`.model`: ``m_raw = W m_true + b``, calibration ``m_cal = S (m_raw - b)``. Turned
about one body axis ``a``, the true field's component along ``a`` stays constant and its component in the plane
normal to ``a`` draws a circle; the raw one draws an ellipse. The ellipse gives the offset in the plane and a 2x2
soft iron (``W`` restricted to the plane; ``W``'s coupling of the constant axial component into the plane is part
of that offset). The offset along ``a`` is not seen at all: the axial reading is ``W_aa m_a + b_a`` with ``m_a``
unknown. It follows from the local field: ``m_a = -F sin(dip)`` along ``a`` pointing up (dip > 0 where the field
points down, the northern hemisphere), with ``F`` the field norm; or from ``F`` alone through the horizontal
radius, ``|m_a| = sqrt(F^2 - r_h^2)``, the sign by the hemisphere. Without either it is left at 0.

Which way is up comes from the accelerometer (the specific force points up at rest, REP-145), which axis from the
gyro: the principal axis of the rotation, each sample's axis weighted by the angle it turned (see
:func:`rotation_axes`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .model import MIN_SAMPLES, MODELS, SOFT_IRON_MIN_GAIN, CalibrationError, MagCalibration
from .sphere import coverage as sphere_coverage

#: Gyro samples slower than this (rad/s) carry no axis (noise, a gyro offset).
MIN_RATE_RAD_S = 0.05
#: A recording is planar when at most this share of its rotation angle is off the principal axis.
PLANAR_MAX_OFF_AXIS = 0.1
#: The plane of the magnetometer samples replaces the gyro's axis when within this of it, rad.
AXIS_REFINE_MAX_RAD = math.radians(10.0)
#: Turn-angle coverage bins (10 deg each).
TURN_BINS = 36
#: A turn bin counts as covered with at least this many samples.
TURN_MIN_PER_BIN = 3
#: Below this turn coverage an ellipse is not determined: the planar fit refuses (``force`` writes it anyway).
TURN_COVERAGE_MIN = 0.75
#: Largest believable ratio of the fitted ellipse's axes.
MAX_ELLIPSE_AXIS_RATIO = 2.0


@dataclass(frozen=True)
class RotationAxes:
    """The gyro's view of a recording: ``axis`` (3,) unit principal rotation axis in the body frame (pointing up when
    the accelerometer says where up is); ``off_axis`` share of the rotation angle about the other two axes (0: one
    axis only); ``angle_rad`` total rotation angle of the samples faster than :data:`MIN_RATE_RAD_S`."""

    axis: tuple[float, float, float]
    off_axis: float
    angle_rad: float

    @property
    def planar(self) -> bool:
        """Whether the recording turns about one axis (:data:`PLANAR_MAX_OFF_AXIS`)."""
        return self.off_axis <= PLANAR_MAX_OFF_AXIS


def rotation_axes(gyr: ArrayLike, dt_s: ArrayLike, acc: ArrayLike | None = None) -> RotationAxes:
    """Principal rotation axis of gyro samples ``gyr`` (N, 3) rad/s over intervals ``dt_s`` (N,) s: the largest
    eigenvector of ``sum(angle_k u_k u_k^T)`` (``u_k`` the sample's unit axis, ``angle_k = |w_k| dt_k``), and the
    share of the trace off it. ``acc`` (N, 3) m/s²: the axis is signed to point up (along the mean specific force)."""
    w = np.asarray(gyr, dtype=float).reshape(-1, 3)
    dt = np.broadcast_to(np.asarray(dt_s, dtype=float), (len(w),))
    rate = np.linalg.norm(w, axis=1)
    ok = np.isfinite(rate) & np.isfinite(dt) & (rate > MIN_RATE_RAD_S) & (dt > 0)
    if not np.any(ok):
        raise CalibrationError('the gyro shows no rotation: turn the sensor (spin the robot in place) while recording')
    u = w[ok] / rate[ok, None]
    angle = rate[ok] * dt[ok]
    c = (u * angle[:, None]).T @ u
    ev, vec = np.linalg.eigh(c)
    axis = vec[:, 2]
    if acc is not None:
        a = np.asarray(acc, dtype=float).reshape(-1, 3)
        up = np.nanmean(a[np.all(np.isfinite(a), axis=1)], axis=0) if len(a) else np.zeros(3)
        if float(axis @ up) < 0:
            axis = -axis
    elif axis[np.argmax(np.abs(axis))] < 0:
        axis = -axis
    total = float(np.sum(angle))
    return RotationAxes(axis=(float(axis[0]), float(axis[1]), float(axis[2])), off_axis=float((ev[0] + ev[1]) / max(ev.sum(), 1e-300)),
                        angle_rad=total)


@dataclass(frozen=True)
class PlanarCalibration:
    """Result of :func:`fit_planar`: the 3-D calibration to write (``cal``: offset and S in the body frame) and what
    the planar fit can say of it.

    axis (3,) the body axis turned about (up); residual_t RMS of ``|S_p (p - c)| - r`` in the plane, T;
    turn_coverage fraction of the :data:`TURN_BINS` turn-angle bins covered; radius_t the calibrated horizontal
    radius, T; axial_offset_t the offset along the axis, T (0 when ``axial_source`` is ``'none'``); axial_source how
    it was found: ``'norm+dip'``, ``'dip'``, ``'norm'`` or ``'none'``; model ``'ellipse'`` or ``'circle'``.
    """

    cal: MagCalibration
    axis: tuple[float, float, float]
    residual_t: float
    turn_coverage: float
    radius_t: float
    axial_offset_t: float
    axial_source: str
    model: str


def _plane_basis(axis: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis of the plane normal to unit ``axis`` (right-handed with it)."""
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = np.cross(helper, axis)
    e1 /= np.linalg.norm(e1)
    return np.stack((e1, np.cross(axis, e1)), axis=1)


def _circle(p: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (2,) and radius of the least-squares circle ``|p|^2 = 2 c.p + d`` through ``p`` (N, 2) (Kasa)."""
    A = np.column_stack((2.0 * p, np.ones(len(p))))
    sol = np.linalg.lstsq(A, np.sum(p * p, axis=1), rcond=None)[0]
    return sol[:2], float(math.sqrt(max(sol[2] + sol[:2] @ sol[:2], 1e-300)))


def _ellipse(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre (2,) and symmetric ``M`` (2, 2) of ``(p - c)^T M (p - c) = 1`` through ``p`` (N, 2) (of order 1): the
    algebraic least-squares conic ``A x^2 + B xy + C y^2 + D x + E y = 1``."""
    x, y = p.T
    D = np.column_stack((x * x, x * y, y * y, x, y))
    A, B, C, Dx, Ey = np.linalg.lstsq(D, np.ones(len(p)), rcond=None)[0]
    M = np.array([[A, B / 2], [B / 2, C]])
    if np.min(np.linalg.eigvalsh(M)) <= 0:
        raise CalibrationError('the magnetometer samples in the turning plane do not lie on an ellipse: turn full '
                               'circles away from magnetic disturbances')
    c = -0.5 * np.linalg.solve(M, [Dx, Ey])
    return c, M / (1.0 + c @ M @ c)


def _true_axial(radius: float, field_norm_t: float | None, field_dip_rad: float | None) -> tuple[float | None, str]:
    """The true field along the up axis (T; None: unknown) of a horizontal field ``radius`` (T), and its source."""
    if field_dip_rad is not None:
        h = radius if field_norm_t is None else field_norm_t * math.cos(field_dip_rad)
        return -h * math.tan(field_dip_rad), 'norm+dip' if field_norm_t is not None else 'dip'
    if field_norm_t is not None:
        if field_norm_t <= radius:
            raise CalibrationError(f'the field norm {field_norm_t * 1e6:.2f} uT is below the horizontal radius '
                                   f'{radius * 1e6:.2f} uT the recording shows: check --field-norm-ut')
        # The norm gives the vertical component's size only: down (positive dip), as north of the magnetic equator.
        return -math.sqrt(field_norm_t**2 - radius**2), 'norm'
    return None, 'none'


def turn_coverage(p_cal: ArrayLike) -> float:
    """Fraction of :data:`TURN_BINS` bins of the in-plane direction of calibrated samples ``p_cal`` (N, 2) holding at
    least :data:`TURN_MIN_PER_BIN` samples."""
    p = np.asarray(p_cal, dtype=float).reshape(-1, 2)
    ang = np.arctan2(p[:, 1], p[:, 0])
    counts = np.bincount(((ang + np.pi) / (2 * np.pi) * TURN_BINS).astype(int) % TURN_BINS, minlength=TURN_BINS)
    return float(np.mean(counts >= TURN_MIN_PER_BIN))


def fit_planar(
    mag: ArrayLike,
    axis: ArrayLike,
    *,
    field_norm_t: float | None = None,
    field_dip_rad: float | None = None,
    model: str = 'auto',
    force: bool = False,
) -> PlanarCalibration:
    """Planar calibration of raw magnetometer samples ``mag`` (N, 3), T, turned about the body ``axis`` (3,) (up).

    The in-plane offset and 2x2 soft iron from an ellipse (``model='auto'`` keeps the soft iron only where it lowers
    the scatter below :data:`~.model.SOFT_IRON_MIN_GAIN` x the circle's, as the 3-D fit does; ``'ellipsoid'`` /
    ``'offset'`` force one);
    the axial offset from ``field_dip_rad`` (rad, > 0 where the field points down) and/or ``field_norm_t`` (T), else 0.
    The 2x2 soft iron's scale: the horizontal field ``F cos(dip)`` if both are given, else ``det = 1``; the axial
    scale is 1. Raises :class:`CalibrationError` on too few samples or turn coverage below
    :data:`TURN_COVERAGE_MIN` (unless ``force``), or an implausible ellipse.
    """
    if model not in MODELS:
        raise ValueError(f'model must be one of {", ".join(MODELS)}, got {model!r}')
    for name, v in (('field norm', field_norm_t), ('field dip', field_dip_rad)):
        if v is not None and not math.isfinite(v):
            raise ValueError(f'{name} must be a finite number, got {v!r}')
    if field_norm_t is not None and not field_norm_t > 0:
        raise ValueError(f'field norm must be a positive number, got {field_norm_t!r}')
    if field_dip_rad is not None and not abs(field_dip_rad) < 0.5 * math.pi - 1e-3:
        raise ValueError(f'field dip must be within (-90, 90) deg, got {math.degrees(field_dip_rad)!r} deg')
    a = np.asarray(axis, dtype=float).reshape(3)
    a = a / np.linalg.norm(a)
    m = np.asarray(mag, dtype=float).reshape(-1, 3)
    m = m[np.all(np.isfinite(m), axis=1) & np.any(m != 0, axis=1)]
    if len(m) < MIN_SAMPLES:
        raise CalibrationError(f'{len(m)} usable magnetometer samples; need at least {MIN_SAMPLES}')
    # The samples' own plane: the gyro's axis leans by its bias over the turn rate (0.3 deg/s at 0.6 rad/s: 0.5 deg,
    # which projects 0.4 uT of the vertical field into the plane as a false offset); the plane does not.
    normal = np.linalg.svd(m - m.mean(axis=0), full_matrices=False)[2][2]
    if abs(float(normal @ a)) > math.cos(AXIS_REFINE_MAX_RAD):
        a = normal if float(normal @ a) > 0 else -normal
    E = _plane_basis(a)
    p = m @ E
    mean = p.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((p - mean) ** 2, axis=1))))
    if not scale > 0:
        raise CalibrationError('the magnetometer does not change in the turning plane: turn the sensor while recording')
    x = (p - mean) / scale
    c_c, r_c = _circle(x)
    res_c = float(np.sqrt(np.mean((np.linalg.norm(x - c_c, axis=1) - r_c) ** 2)))
    chosen, c, S = 'circle', c_c, np.eye(2) / r_c
    if model != 'offset':
        c_e, M = _ellipse(x)
        w, V = np.linalg.eigh(M)
        if w[1] / w[0] > MAX_ELLIPSE_AXIS_RATIO**2:
            raise CalibrationError(f'fitted ellipse is implausibly elongated (axis ratio {math.sqrt(w[1] / w[0]):.1f}): '
                                   'turn full circles away from magnetic disturbances')
        S_e = (V * np.sqrt(w)) @ V.T
        r_e = float(np.prod(np.sqrt(w))) ** -0.5  # geometric-mean radius in the scaled units
        res_e = float(np.sqrt(np.mean((np.linalg.norm((x - c_e) @ S_e, axis=1) - 1.0) ** 2))) * r_e
        if model == 'ellipsoid' or res_e < SOFT_IRON_MIN_GAIN * res_c:
            chosen, c, S = 'ellipse', c_e, S_e
    centre = mean + scale * c
    S_unit = S / scale  # |S_unit (p - centre)| = 1 on the fit
    r_det1 = float(np.linalg.det(S_unit)) ** -0.5
    if field_norm_t is not None and field_dip_rad is not None:
        radius = field_norm_t * math.cos(field_dip_rad)
    else:
        radius = r_det1
    S_p = radius * S_unit
    p_cal = (p - centre) @ S_p.T
    coverage = turn_coverage(p_cal)
    if coverage < TURN_COVERAGE_MIN and not force:
        raise CalibrationError(f'the recording turns through {coverage:.0%} of a full turn: at least '
                               f'{TURN_COVERAGE_MIN:.0%} is needed (turn full circles; --force to write it anyway)')
    residual_t = float(np.sqrt(np.mean((np.linalg.norm(p_cal, axis=1) - radius) ** 2)))
    # Along the axis: the reading is m_a + b_a (axial scale 1); m_a from the field if known.
    m_axial = float(np.mean(m @ a))
    true_axial, source = _true_axial(radius, field_norm_t, field_dip_rad)
    if true_axial is None:
        true_axial = m_axial
    b_axial = m_axial - true_axial
    offset = E @ centre + a * b_axial
    S3 = E @ S_p @ E.T + np.outer(a, a)
    norm = float(np.sqrt(radius**2 + true_axial**2))
    m_cal = (m - offset) @ S3.T
    rel = np.linalg.norm(m_cal, axis=1) / norm - 1.0
    cal = MagCalibration(
        offset_t=tuple(float(v) for v in offset), soft_iron=tuple(float(v) for v in S3.ravel()), radius_t=norm,
        residual_rel=float(np.sqrt(np.mean(rel * rel))), coverage=sphere_coverage(m_cal), n_samples=len(m),
        model='planar-' + chosen, offset_only_residual_rel=res_c / r_c,
    )
    return PlanarCalibration(cal=cal, axis=(float(a[0]), float(a[1]), float(a[2])), residual_t=residual_t, turn_coverage=coverage,
                             radius_t=radius, axial_offset_t=b_axial if source != 'none' else 0.0,
                             axial_source=source, model=chosen)
