"""Old import path, kept so existing imports work: the planar magnetometer fit is now :mod:`ccf_ros.magcal.planar`
(numpy only); the command that runs it, :mod:`ccf_ros.offline.calibrate_mag`.

``MAX_AXIS_RATIO`` here is the planar fit's (the ellipse's), :data:`ccf_ros.magcal.MAX_ELLIPSE_AXIS_RATIO`; the
3-D fit's is :data:`ccf_ros.magcal.MAX_AXIS_RATIO`.
"""

from ..magcal.model import SOFT_IRON_MIN_GAIN
from ..magcal.planar import (
    AXIS_REFINE_MAX_RAD,
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
from ..magcal.planar import MAX_ELLIPSE_AXIS_RATIO as MAX_AXIS_RATIO

__all__ = [
    'AXIS_REFINE_MAX_RAD',
    'MAX_AXIS_RATIO',
    'MIN_RATE_RAD_S',
    'PLANAR_MAX_OFF_AXIS',
    'SOFT_IRON_MIN_GAIN',
    'TURN_BINS',
    'TURN_COVERAGE_MIN',
    'TURN_MIN_PER_BIN',
    'PlanarCalibration',
    'RotationAxes',
    'fit_planar',
    'rotation_axes',
    'turn_coverage',
]
