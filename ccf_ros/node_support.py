"""Moved to :mod:`ccf_ros.node` (``parameters``, ``stats``, ``diagnostics``, ``debug``) and
:func:`ccf_ros.messages.cdr.header` (``imu_header``); these names stay for existing imports."""

from .messages.cdr import header as imu_header
from .node.debug import raw_rpy
from .node.diagnostics import ERROR, LOSS_WARN_S, NO_INPUT_S, OK, STALE_WARN, WARN, Diagnostics, diagnostics
from .node.parameters import DEFAULT_RANGE, PER_AXIS, coerce_parameter, parameter_range
from .node.stats import (
    HOLE_FACTOR,
    HOLE_SIGMAS,
    INTERVAL_MIN,
    INTERVAL_REFRESH,
    INTERVAL_WINDOW,
    RATE_WINDOW_S,
    InputStats,
)

__all__ = [
    'DEFAULT_RANGE', 'ERROR', 'HOLE_FACTOR', 'HOLE_SIGMAS', 'INTERVAL_MIN', 'INTERVAL_REFRESH', 'INTERVAL_WINDOW',
    'LOSS_WARN_S', 'NO_INPUT_S', 'OK', 'PER_AXIS', 'RATE_WINDOW_S', 'STALE_WARN', 'WARN', 'Diagnostics', 'InputStats',
    'coerce_parameter', 'diagnostics', 'imu_header', 'parameter_range', 'raw_rpy',
]
