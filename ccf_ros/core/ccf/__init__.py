"""The cascaded complementary filter (the ccf_ros default), :class:`QuaternionCcf`: an NCF stage that learns the gyro
bias feeding an LCF stage that publishes the orientation, on unit quaternions ``[w, x, y, z]`` (body -> ENU world),
SI units (rad, rad/s, m/s², s; the magnetometer in any unit). A sample is taken as the mean over the interval before
its stamp (what a MEMS decimation filter outputs); gains are exact per time step, so the defaults behave alike from
40 Hz to 1 kHz; the reported covariance is continuous-time. The derivation, transfer functions and sample timing:
doc/algorithm.md.

Per sample (:meth:`QuaternionCcf._step`, in this order):

1. **Attitude and errors.** The body->world rows of the LCF attitude; the LCF tilt error towards the filtered
   gravity ``g_lp``; the NCF's (its attitude is ``exp(dn) ⊗ q``).
2. **Magnetometer gate and heading** (:mod:`.mag_gate`): a field whose norm, dip or world direction departs from the
   reference is ignored for heading; an accepted one turns the LCF (and the NCF) about world up only. The reported
   variances grow while a correction is missing.
3. **Bias** (:mod:`.bias`): once the block of samples spans ``BIAS_UPDATE_PERIOD_S``, a Kalman update of the bias
   from the NCF's tilt and heading errors; at rest, the low-passed gyro pulls the bias; clamped to ±bias_max_rad_s.
4. **LCF output**: ``q`` integrates the bias-corrected rate plus the blend corrections (``tau_acc_s``,
   ``tau_mag_s``).
5. **Gravity low-pass**: ``g_lp`` and its rate are carried into the new body frame by the gyro step, then the
   accelerometer sample is filtered in (second-order Butterworth, group delay ``tau_acc_lp_s``).
6. **NCF offset** ``dn``: moved by the NCF's correction (``tau_ncf_s``) minus the LCF's.

Modules: :mod:`.params` (parameters, constants), :mod:`.discretisation` (per-sample and per-block gains, cached per
0.1 % bin of time spans; the low-pass's exact step), :mod:`.bias`, :mod:`.mag_gate`, :mod:`.analysis` (small-signal
transfer functions, for ``ccf study``), :mod:`.filter` (the filter and its state :class:`CcfState`).
"""

from .analysis import tilt_transfer
from .bias import BiasKalman
from .discretisation import _bin, _bin_range, _BlockCoefficients, _cached, _Coefficients, butterworth_step
from .filter import CcfState, QuaternionCcf
from .mag_gate import MagGate
from .params import (
    BIAS_UPDATE_PERIOD_S,
    CLIP_FRACTION,
    GRAVITY_M_S2,
    MAG_BAND_S,
    MAG_REJECT_SIGMAS,
    MAG_SCORE_S,
    NEW_FIELD_TURN_RAD,
    REST_BIAS_TOL_RAD_S,
    REST_RELEARN_S,
    CcfParams,
)

__all__ = [
    'BIAS_UPDATE_PERIOD_S',
    'CLIP_FRACTION',
    'GRAVITY_M_S2',
    'MAG_BAND_S',
    'MAG_REJECT_SIGMAS',
    'MAG_SCORE_S',
    'NEW_FIELD_TURN_RAD',
    'REST_BIAS_TOL_RAD_S',
    'REST_RELEARN_S',
    'BiasKalman',
    'CcfParams',
    'CcfState',
    'MagGate',
    'QuaternionCcf',
    '_BlockCoefficients',
    '_Coefficients',
    '_bin',
    '_bin_range',
    '_cached',
    'butterworth_step',
    'tilt_transfer',
]
