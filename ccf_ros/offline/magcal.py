"""Old import path, kept so existing imports work: the magnetometer calibration was split by role.

* the fit, the model and its limits (numpy only): :mod:`ccf_ros.magcal` (``fit``, ``MagCalibration``,
  ``CalibrationError``, ``coverage``, the constants);
* the command ``ccf calibrate-mag`` (bag reading, YAML, plot, argparse): :mod:`ccf_ros.offline.calibrate_mag`.

New code imports from those. Patching a name here (``read_mag``) does not reach the command: patch it in
:mod:`ccf_ros.offline.calibrate_mag`.
"""

from ..magcal import (
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
    coverage,
    fibonacci_directions,
    fit,
)
from .calibrate_mag import MOTIONS, add_parser, cmd_calibrate_mag, params_yaml, plot, read_mag

__all__ = [
    'COVERAGE_BINS',
    'COVERAGE_MIN_PER_BIN',
    'COVERAGE_WARN',
    'MAX_AXIS_RATIO',
    'MIN_SAMPLES',
    'MIN_SPAN_SNR',
    'MIN_SPREAD_RATIO',
    'MODELS',
    'MOTIONS',
    'SOFT_IRON_MIN_GAIN',
    'CalibrationError',
    'MagCalibration',
    'add_parser',
    'cmd_calibrate_mag',
    'coverage',
    'fibonacci_directions',
    'fit',
    'params_yaml',
    'plot',
    'read_mag',
]
