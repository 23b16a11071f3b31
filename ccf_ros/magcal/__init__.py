"""Magnetometer hard-/soft-iron calibration as numpy: the model, the 3-D (ellipsoid) and planar (ellipse) fits.

No bag, plot, YAML or ROS here (``ccf calibrate-mag``, the command around it, is :mod:`ccf_ros.offline.calibrate_mag`).

* :mod:`.model`: :class:`MagCalibration` (``m_cal = S (m_raw - b)``), :class:`CalibrationError`, the limits;
* :mod:`.sphere`: direction coverage and the offset-only sphere fit;
* :mod:`.ellipsoid`: :func:`fit`, the 3-D calibration (a sensor turned through all orientations);
* :mod:`.planar`: :func:`fit_planar` and :func:`rotation_axes` (a robot turning about one axis).
"""

from .ellipsoid import fit
from .model import (
    COVERAGE_BINS,
    COVERAGE_MIN_PER_BIN,
    COVERAGE_WARN,
    MAX_AXIS_RATIO,
    MIN_SAMPLES,
    MIN_SPAN_SNR,
    MIN_SPREAD_RATIO,
    MODELS,
    SOFT_IRON_MIN_GAIN,
    CalibrationError,
    MagCalibration,
)
from .planar import (
    AXIS_REFINE_MAX_RAD,
    MAX_ELLIPSE_AXIS_RATIO,
    MIN_RATE_RAD_S,
    PLANAR_MAX_OFF_AXIS,
    TURN_BINS,
    TURN_COVERAGE_MIN,
    TURN_MIN_PER_BIN,
    PlanarCalibration,
    RotationAxes,
    fit_planar,
    rotation_axes,
    turn_coverage,
)
from .sphere import coverage, fibonacci_directions, fit_sphere

__all__ = [
    'AXIS_REFINE_MAX_RAD',
    'COVERAGE_BINS',
    'COVERAGE_MIN_PER_BIN',
    'COVERAGE_WARN',
    'MAX_AXIS_RATIO',
    'MAX_ELLIPSE_AXIS_RATIO',
    'MIN_RATE_RAD_S',
    'MIN_SAMPLES',
    'MIN_SPAN_SNR',
    'MIN_SPREAD_RATIO',
    'MODELS',
    'PLANAR_MAX_OFF_AXIS',
    'SOFT_IRON_MIN_GAIN',
    'TURN_BINS',
    'TURN_COVERAGE_MIN',
    'TURN_MIN_PER_BIN',
    'CalibrationError',
    'MagCalibration',
    'PlanarCalibration',
    'RotationAxes',
    'coverage',
    'fibonacci_directions',
    'fit',
    'fit_planar',
    'fit_sphere',
    'rotation_axes',
    'turn_coverage',
]
