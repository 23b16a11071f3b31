"""Run a filter over whole arrays through the very same per-sample :meth:`update` the node and replay use (its
``_update_floats``, which update() unpacks into)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .base import ANSWERED_BELOW, OrientationFilter


@dataclass
class BatchResult:
    """Per-sample outputs of :func:`run_batch`.

    Attributes:
        quat: ``(N, 4)`` orientations ``[w, x, y, z]`` in the filter's world frame; NaN where not answered.
        bias: ``(N, 3)`` gyro-bias estimates, rad/s, body frame; NaN where not answered.
        variance: ``(N, 3)`` roll/pitch/yaw error variances, rad²; NaN where not answered.
        status: ``(N,)`` :class:`~ccf_ros.core.base.Status` values.
    """

    quat: NDArray[np.float64]
    bias: NDArray[np.float64]
    variance: NDArray[np.float64]
    status: NDArray[np.int8]

    @property
    def answered(self) -> NDArray[np.bool_]:
        """``(N,)`` True where the sample has an orientation."""
        return self.status < ANSWERED_BELOW


def run_batch(
    filt: OrientationFilter,
    t_s: ArrayLike,
    gyr: ArrayLike,
    acc: ArrayLike,
    mag: ArrayLike | None = None,
) -> BatchResult:
    """Feed ``N`` samples to ``filt`` in order.

    Args:
        filt: any core filter (its state carries on from previous calls).
        t_s: ``(N,)`` stamps, s. gyr: ``(N, 3)`` rad/s. acc: ``(N, 3)`` m/s². mag: ``(N, 3)`` or None.
    """
    t_list = np.asarray(t_s, dtype=float).tolist()
    # Python floats, not numpy scalars: the scalar update is several times faster on them.
    g_list = np.asarray(gyr, dtype=float).tolist()
    a_list = np.asarray(acc, dtype=float).tolist()
    n = len(t_list)
    m_list = np.asarray(mag, dtype=float).tolist() if mag is not None else [None] * n
    quat = [(np.nan,) * 4] * n
    bias = [(np.nan,) * 3] * n
    var = [(np.nan,) * 3] * n
    status = [0] * n
    update = filt._update_floats  # (update() on the floats: one Python call per sample less)
    for i in range(n):
        gx, gy, gz = g_list[i]
        ax, ay, az = a_list[i]
        s = update(t_list[i], gx, gy, gz, ax, ay, az, m_list[i])
        status[i] = s
        if s < ANSWERED_BELOW:
            quat[i] = filt.quaternion
            bias[i] = filt.gyro_bias
            var[i] = filt.orientation_variance
    return BatchResult(
        quat=np.array(quat, dtype=float).reshape(n, 4),
        bias=np.array(bias, dtype=float).reshape(n, 3),
        variance=np.array(var, dtype=float).reshape(n, 3),
        status=np.array(status, dtype=np.int8),
    )
