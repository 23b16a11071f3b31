"""Old import path, kept so existing imports work: the planar magnetometer fit is now :mod:`ccf_ros.magcal.planar`
(numpy only); the command that runs it, :mod:`ccf_ros.offline.calibrate_mag`.

``MAX_AXIS_RATIO`` here is the planar fit's (the ellipse's), :data:`ccf_ros.magcal.MAX_ELLIPSE_AXIS_RATIO`; the
3-D fit's is :data:`ccf_ros.magcal.MAX_AXIS_RATIO`.
"""

from .. import magcal as _moved
from ..magcal import *  # noqa: F403
from ..magcal import MAX_ELLIPSE_AXIS_RATIO as MAX_AXIS_RATIO  # noqa: F401 - the planar fit's, under its old name here

__all__ = _moved.__all__
