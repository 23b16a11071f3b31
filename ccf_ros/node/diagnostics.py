"""The node's ``/diagnostics`` status as plain code (no ROS import): the values and the OK / WARN / ERROR level from
the input statistics (:mod:`.stats`), the engine and the IMU/magnetometer hold statistics (:mod:`.sync`)."""

from __future__ import annotations

import math
from typing import NamedTuple

from ..engine import ImuEngine
from .stats import InputStats
from .sync import HoldStats

#: Levels as in diagnostic_msgs/DiagnosticStatus.
OK, WARN, ERROR = 0, 1, 2
#: No IMU sample for this long (s) is an error.
NO_INPUT_S = 1.0
#: Messages lost upstream within this long (s) warn.
LOSS_WARN_S = 10.0
#: More than this share of the latest answers with a held orientation warns (the output is frozen).
STALE_WARN = 0.5


class Diagnostics(NamedTuple):
    """One diagnostics status: level (:data:`OK`, :data:`WARN`, :data:`ERROR`), message and key/value pairs."""

    level: int
    message: str
    values: dict[str, str]


def _yes(flag: bool) -> str:
    return 'true' if flag else 'false'


def diagnostics(
    now: float,
    stats: InputStats,
    engine: ImuEngine,
    hold: HoldStats,
    *,
    use_mag: bool,
    mag_timeout_s: float,
) -> Diagnostics:
    """The node's status from its input statistics, the engine (filter flags and counters) and the hold statistics.

    Rules, first match wins: ERROR no IMU input for more than :data:`NO_INPUT_S`, ERROR not initialised (no valid
    accelerometer yet); WARN more than :data:`STALE_WARN` of the latest answers held the orientation; WARN
    magnetometer in use but none for ``mag_timeout_s``, WARN magnetic disturbance, WARN
    non-finite filter state (re-initialised), WARN messages lost upstream in the last :data:`LOSS_WARN_S`; else OK.
    """
    filt = engine.filter
    flags = filt.flags
    mag_age = now - stats.last_mag
    bias = filt.gyro_bias
    bias_deg_s = math.degrees(math.sqrt(sum(b * b for b in bias)))
    n_nonfinite = engine.n_nonfinite_resets  # kept across resets (the filter's own counter starts over)
    level, message = OK, 'ok'
    if now - stats.last_imu > NO_INPUT_S:
        level, message = ERROR, f'no IMU input for more than {NO_INPUT_S:g} s'
    elif not flags.initialized:
        level, message = ERROR, 'waiting for a valid accelerometer sample'
    elif engine.stale_share > STALE_WARN:
        level, message = WARN, (
            f'{engine.stale_share:.0%} of the latest samples were answered with a held orientation (repeated, '
            'backward or zero stamps, or a bad gyro); set constant_dt if the driver does not stamp messages')
    elif use_mag and mag_age > mag_timeout_s:
        since = f'for {mag_age:.1f} s' if math.isfinite(mag_age) else 'sample yet'
        level, message = WARN, f'no magnetometer {since}: heading runs on the gyro'
    elif flags.mag_disturbed:
        level, message = WARN, 'magnetic disturbance: heading runs on the gyro'
    elif n_nonfinite:
        level, message = WARN, f'filter state became non-finite {n_nonfinite} times and was re-initialised'
    elif now - stats.last_loss <= LOSS_WARN_S:
        level, message = WARN, f'input messages lost upstream ({stats.n_lost} so far)'
    values = {
        'input rate (Hz)': f'{stats.rate_hz(now):.1f}',
        'samples in': str(engine.n_in),
        'magnetometer samples in': str(stats.n_mag),
        'magnetometer samples after their IMU sample': str(stats.n_mag_late),
        'stray magnetometer stamps dropped (far ahead or NaN)': str(engine.pairer.n_stray_ahead),
        'magnetometer samples pushed out of the pairing queue (too far ahead)': str(engine.pairer.n_pushed_out),
        'samples answered': str(engine.answered()),
        'samples answered with the current orientation (could not advance the filter)': str(engine.n_answered_stale),
        'share of the latest answers with a held orientation': f'{engine.stale_share:.2f}',
        'messages lost upstream (estimated)': str(stats.n_lost),
        'unreadable messages dropped': str(stats.n_unreadable),
        'magnetometer age (s)': f'{mag_age:.2f}' if math.isfinite(mag_age) else 'never',
        'gyro bias norm (deg/s)': f'{bias_deg_s:.3f}',
        'gyro bias 1-sigma per axis (deg/s)': (
            f'{math.degrees(sigma):.3f}' if (sigma := getattr(engine.filter, 'gyro_bias_sigma_rad_s', None)) is not None
            else 'not estimated'),
        'resets after clock jumps': str(engine.n_resets_jump),
        'gyro-only samples (bad accelerometer)': str(engine.n_no_acc),
        'samples without heading (bad magnetometer)': str(engine.n_no_mag),
        'non-finite state resets': str(n_nonfinite),
        'gyro samples clipped (at gyro_range_rad_s)': str(engine.n_gyro_clipped),
        'initialized': _yes(flags.initialized),
        'at rest': _yes(flags.at_rest),
        'accelerometer used': _yes(flags.acc_used),
        'magnetometer used': _yes(flags.mag_used),
        'magnetic disturbance': _yes(flags.mag_disturbed),
        'heading absolute': _yes(flags.heading_absolute),
        'magnetometer in lock-step': _yes(hold.lockstep),
        'samples held for magnetometer': str(hold.n_held),
        'hold timeouts': str(hold.n_timeouts),
        'hold max (ms)': f'{hold.max_ms:.2f}',
        'hold mean (ms)': f'{hold.mean_ms:.3f}',
    }
    hi = engine.hard_iron_status()
    if hi is None:
        values['online hard iron'] = 'off'
    else:
        # The field in tesla (sensor_msgs/MagneticField): shown in uT.
        values['online hard iron'] = hi.status
        values['online hard-iron offset applied (uT)'] = ' '.join(f'{v * 1e6:.2f}' for v in hi.offset)
        values['online hard-iron estimate (uT)'] = ' '.join(f'{v * 1e6:.2f}' for v in hi.estimate)
        values['online hard-iron 1-sigma (uT)'] = ' '.join(f'{v * 1e6:.2f}' for v in hi.sigma)
        values['online hard-iron model residual (share of the field)'] = f'{hi.residual_rel:.3f}'
    values.update({f'skipped: {k}': str(v) for k, v in engine.skipped_by_reason().items()})
    return Diagnostics(level, message, values)
