"""The magnetometer calibration model, its result and its limits (numpy and stdlib only).

Model: a raw reading is ``m_raw = W m_true + b`` (tesla, as in sensor_msgs/MagneticField) with soft-iron matrix
``W`` (3x3) and hard-iron offset ``b`` (3,). The calibration gives ``b`` and a symmetric positive-definite ``S`` with
``m_cal = S (m_raw - b)`` on a sphere. ``S`` equals ``W^-1`` up to a rotation and a scale; of the rotations we
take the one that makes ``S`` symmetric, and the scale is fixed by:

* a given field norm ``field_norm_t``: the sphere radius is that norm (``S = W^-1`` if ``|m_true|`` is it);
* otherwise ``det S = 1``: ``S`` preserves volume and the radius is the geometric mean of the raw ellipsoid's
  semi-axes (``S = W^-1`` if ``det W = 1``).

The fits: :mod:`.ellipsoid` (3-D), :mod:`.planar` (a turn about one axis); coverage: :mod:`.sphere`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import CcfError

#: Fewest usable samples :func:`~.ellipsoid.fit` accepts.
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
#: of the sphere's (offset-only) fit: the soft iron must explain a tenth of what the offset leaves, see :mod:`.ellipsoid`.
SOFT_IRON_MIN_GAIN = 0.9
#: Calibration models :func:`~.ellipsoid.fit` accepts.
MODELS = ('auto', 'ellipsoid', 'offset')

#: The advice every refusal of the samples ends with.
HINT = 'rotate the sensor through more orientations, away from magnetic disturbances'


class CalibrationError(CcfError, ValueError):
    """The samples cannot give a calibration; the message is meant for the user, one line.

    A :class:`~ccf_ros.errors.CcfError` (the ``ccf`` command shows it as one line, exit code 2) and, for callers of
    :func:`~.ellipsoid.fit`, a ``ValueError`` (the samples are an unusable value).
    """


@dataclass(frozen=True)
class MagCalibration:
    """Result of :func:`~.ellipsoid.fit`: ``m_cal = S (m_raw - offset)``.

    offset_t (3,) T; soft_iron (9,) ``S`` row-major, symmetric positive definite; radius_t sphere radius of
    ``m_cal``, T; residual_rel RMS of ``(|m_cal| - radius) / radius``; coverage fraction in [0, 1] of direction
    bins holding samples (see :func:`~.sphere.coverage`); n_samples samples used; model ``'ellipsoid'`` (offset and soft
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
        out: np.ndarray = (m - self.offset) @ self.matrix.T
        return out

