"""Filter core: numpy and the standard library only, no ROS import (tested)."""

from .base import ANSWERED_BELOW, CommonParams, OrientationFilter, Status
from .batch import BatchResult, run_batch
from .ccf import CcfParams, QuaternionCcf
from .euler_ccf import EulerCcf, EulerCcfParams
from .pairing import MagPairer
from .registry import make_filter

__all__ = [
    'ANSWERED_BELOW',
    'BatchResult',
    'CcfParams',
    'CommonParams',
    'EulerCcf',
    'EulerCcfParams',
    'MagPairer',
    'OrientationFilter',
    'QuaternionCcf',
    'Status',
    'make_filter',
    'run_batch',
]
