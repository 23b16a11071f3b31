"""Small-signal analysis of the cascade (used by ``ccf study`` and a test, not by the filter): the derivation is in
doc/algorithm.md."""

from __future__ import annotations

import cmath
import math

from .params import CcfParams


def tilt_transfer(p: CcfParams, f_hz: complex | float) -> tuple[complex, complex]:
    """Small-angle transfer functions of one tilt axis at ``f_hz``: ``(H_a, H_w)`` from the accelerometer angle
    (rad/rad) and from the measured rate (rad per rad/s) to the output, with the NCF's bias gain at its steady state
    in continuous motion (:attr:`CcfParams.bias_gain_per_s`); derived in doc/algorithm.md."""
    s = 2j * cmath.pi * f_hz
    wn = math.sqrt(2.0) / p.tau_acc_lp_s
    b = wn * wn / (s * s + math.sqrt(2.0) * wn * s + wn * wn)
    kn, ka, g = 1.0 / p.tau_ncf_s, 1.0 / p.tau_acc_s, p.bias_gain_per_s
    f = g * b * kn / ((s + kn) * (s + g))
    lcf = s + ka * (1.0 - b)
    return (f * lcf + ka * b) / (s + ka), (1.0 - f) * lcf / (s * (s + ka))
