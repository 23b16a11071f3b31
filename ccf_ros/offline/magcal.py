"""Old import path, kept so existing imports work: the magnetometer calibration was split by role.

* the fit, the model and its limits (numpy only): :mod:`ccf_ros.magcal` (``fit``, ``MagCalibration``,
  ``CalibrationError``, ``coverage``, the constants);
* the command ``ccf calibrate-mag`` (bag reading, YAML, plot, argparse): :mod:`ccf_ros.offline.calibrate_mag`.

New code imports from those. Patching a name here (``read_mag``) does not reach the command: patch it in
:mod:`ccf_ros.offline.calibrate_mag`.
"""

from .. import magcal as _moved
from ..magcal import *  # noqa: F403
from .calibrate_mag import MOTIONS, add_parser, cmd_calibrate_mag, params_yaml, plot, read_mag

__all__ = [*_moved.__all__, 'MOTIONS', 'add_parser', 'cmd_calibrate_mag', 'params_yaml', 'plot', 'read_mag']
