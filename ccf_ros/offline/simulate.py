"""``ccf simulate``: synthetic IMU, magnetometer and ground truth in the BROAD topic layout."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.quaternion import euler_to_quat, quat_conj, quat_from_rotvec, quat_mul, quat_rotate, to_xyzw
from ..errors import ParameterError
from .bagio import open_writer, refuse_existing, staged, typestore

G = 9.80665
#: Earth field in ENU (tesla): 50 µT, dip 60° (roughly central Europe).
MAG_WORLD = 50e-6 * np.array([0.0, np.cos(np.radians(60.0)), -np.sin(np.radians(60.0))])
#: µ0 / 4π, T m / A.
_MU0_4PI = 1e-7

#: A magnetic environment: the world field (N,3, T, ENU) at positions (N,3, m) and times (N,, s from the start).
Field = Callable[[np.ndarray, np.ndarray], np.ndarray]


def dipole_field(center_m: Any, moment_a_m2: Any, earth_t: Any = MAG_WORLD) -> Field:
    """The earth field plus a magnetic dipole fixed in the world at ``center_m`` (3, m) with moment ``moment_a_m2``
    (3, A m²): a magnet, a steel beam or a machine near the workspace. The field turns and changes its norm and dip
    with position, by tens of degrees within tens of centimetres of a strong source."""
    c = np.asarray(center_m, dtype=float)
    m = np.asarray(moment_a_m2, dtype=float)
    e = np.asarray(earth_t, dtype=float)

    def field(pos: np.ndarray, t: np.ndarray) -> np.ndarray:
        r = pos - c
        d = np.linalg.norm(r, axis=1, keepdims=True)
        u = r / d
        return e + _MU0_4PI * (3.0 * u * (u @ m)[:, None] - m) / d**3

    return field


def dipole_beside(
    rng: np.random.Generator, moment_a_m2: float, distance_m: float, orientation: str = 'across',
    earth_t: Any = MAG_WORLD,
) -> Field:
    """:func:`dipole_field` of a dipole ``distance_m`` (m) from the start, at a bearing drawn from ``rng`` and a
    height of ±0.3 ``distance_m``, its moment ``moment_a_m2`` (A m², sign drawn from ``rng``) across the line to the
    start (``'across'``: the field there turns with little change of norm and dip), along it (``'along'``) or
    vertical (``'vertical'``)."""
    ang = rng.uniform(0.0, 2.0 * np.pi)
    center = distance_m * np.array([np.cos(ang), np.sin(ang), rng.uniform(-0.3, 0.3)])
    sign = rng.choice([-1.0, 1.0])
    axis = {'across': [-np.sin(ang), np.cos(ang), 0.0], 'along': [np.cos(ang), np.sin(ang), 0.0],
            'vertical': [0.0, 0.0, 1.0]}[orientation]
    return dipole_field(center, moment_a_m2 * sign * np.asarray(axis), earth_t)


def wander_path(
    amplitude_m: float, rng: np.random.Generator, rest_s: float = 5.0, band_hz: tuple[float, float] = (0.02, 0.08)
) -> Callable[[np.ndarray], np.ndarray]:
    """A slow wander about the start: per axis a sine of ``amplitude_m`` (m) at a frequency drawn from ``band_hz``
    (Hz; random phase from ``rng``), starting smoothly over the 2 s after ``rest_s`` — a hand-guided sensor that stays
    seconds in each part of the workspace (for :func:`generate`'s ``path_m``)."""
    f = rng.uniform(band_hz[0], band_hz[1], 3)
    ph = rng.uniform(0.0, 2.0 * np.pi, 3)

    def path(t: np.ndarray) -> np.ndarray:
        return amplitude_m * (np.sin(2 * np.pi * f * t[:, None] + ph) - np.sin(ph)) * _ramp(t, rest_s)[:, None]

    return path


def field_change(t_change_s: float, norm_scale: float, dip_change_rad: float, earth_t: Any = MAG_WORLD) -> Field:
    """A uniform field that changes once at ``t_change_s`` (s from the start) to another uniform field: its norm times
    ``norm_scale``, its dip (downwards) plus ``dip_change_rad``, its horizontal direction (north) kept — a robot that
    drives into a steel-framed building, where the field is homogeneous again but not the one outside."""
    e = np.asarray(earth_t, dtype=float)
    norm = float(np.linalg.norm(e))
    dip = math.atan2(-e[2], math.hypot(e[0], e[1])) + dip_change_rad
    north = e[:2] / math.hypot(e[0], e[1])
    after = norm_scale * norm * np.array([north[0] * math.cos(dip), north[1] * math.cos(dip), -math.sin(dip)])

    def field(pos: np.ndarray, t: np.ndarray) -> np.ndarray:
        return np.where((t >= t_change_s)[:, None], after, e)

    return field


@dataclass
class SimData:
    """Synthetic recording. t_s (N,); q_true (N,4) body->ENU; gyr (N,3) rad/s; acc (N,3) m/s²; mag (N,3) T;
    bias (N,3) true gyro bias rad/s; moving (N,) bool."""

    t_s: np.ndarray
    q_true: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    bias: np.ndarray
    moving: np.ndarray


def _ramp(t: np.ndarray, rest: float) -> np.ndarray:
    """Smooth 0 -> 1 ramp over the 2 s after ``rest`` (s): motion starts gently."""
    r = np.clip((t - rest) / 2.0, 0.0, 1.0)
    return r * r * (3 - 2 * r)


def _sample_count(duration_s: float, rate_hz: float, seed: int) -> int:
    """Number of samples of a simulated recording; raises :class:`ParameterError` for an unusable request."""
    if not (0 < duration_s < math.inf and 0 < rate_hz < math.inf):
        raise ParameterError(f'duration and rate must be finite and > 0, got {duration_s!r} s, {rate_hz!r} Hz')
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise ParameterError(f'seed must be an integer >= 0, got {seed!r}')
    n = int(round(duration_s * rate_hz))
    if n < 2:
        raise ParameterError(f'{duration_s:g} s at {rate_hz:g} Hz is {n} sample(s): ask for at least 2')
    return n


def _sense(
    rng: np.random.Generator,
    q: np.ndarray,
    omega: np.ndarray,
    specific_force_world: np.ndarray,
    tr: np.ndarray,
    rate_hz: float,
    *,
    gyro_noise_rad_s: float,
    acc_noise_m_s2: float,
    mag_noise_t: float,
    bias_init_rad_s: float,
    bias_walk_rad_s_sqrt_s: float,
    bias_drift_rad_s: float = 0.0,
    bias_drift_period_s: float = 3600.0,
    field_world: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What the sensors read of a motion: ``(gyr, acc, mag, bias)``, (N,3) each, from the orientation ``q`` (N,4,
    body->ENU), the body rate ``omega`` (N,3, rad/s), the specific force in the world ``specific_force_world`` (N,3,
    m/s², gravity included) at times ``tr`` (N, s), in the world field ``field_world`` (N,3, T; None: the uniform
    :data:`MAG_WORLD`). The gyro bias starts at ``N(0, bias_init)`` per axis, random-walks, and (if
    ``bias_drift_rad_s`` > 0) drifts as a sinusoid of that amplitude and period."""
    n = len(tr)
    q_inv = quat_conj(q)
    acc = quat_rotate(q_inv, specific_force_world) + acc_noise_m_s2 * rng.standard_normal((n, 3))
    world = np.broadcast_to(MAG_WORLD, (n, 3)) if field_world is None else field_world
    mag = quat_rotate(q_inv, world) + mag_noise_t * rng.standard_normal((n, 3))
    bias = bias_init_rad_s * rng.standard_normal(3) + np.cumsum(
        bias_walk_rad_s_sqrt_s / np.sqrt(rate_hz) * rng.standard_normal((n, 3)), axis=0
    )
    if bias_drift_rad_s > 0.0:
        phase = rng.uniform(0, 2 * np.pi, 3)
        bias = bias + bias_drift_rad_s * (np.sin(2 * np.pi * tr[:, None] / bias_drift_period_s + phase) - np.sin(phase))
    gyr = omega + bias + gyro_noise_rad_s * rng.standard_normal((n, 3))
    return gyr, acc, mag, bias


def _record(
    rng: np.random.Generator, q: np.ndarray, acc_world: np.ndarray, tr: np.ndarray, rate_hz: float, t0_s: float,
    rest_s: float, noise: tuple[float, float, float, float, float],
) -> SimData:
    """The recording of a motion given by its orientation ``q`` (N,4, body->ENU) and specific force in the world
    ``acc_world`` (N,3, m/s², gravity included) at times ``tr`` (N, s, a uniform step of 1/``rate_hz``): the body
    rate from ``q``'s derivative (central differences, one-sided at the ends), the sensors read by :func:`_sense`
    with ``noise`` = (gyro_noise_rad_s, acc_noise_m_s2, mag_noise_t, bias_init_rad_s, bias_walk_rad_s_sqrt_s),
    ``moving`` from ``rest_s``."""
    omega = 2.0 * quat_mul(quat_conj(q), np.gradient(q, 1.0 / rate_hz, axis=0))[:, 1:]
    gyr, acc, mag, bias = _sense(
        rng, q, omega, acc_world, tr, rate_hz, gyro_noise_rad_s=noise[0], acc_noise_m_s2=noise[1],
        mag_noise_t=noise[2], bias_init_rad_s=noise[3], bias_walk_rad_s_sqrt_s=noise[4],
    )
    return SimData(t_s=t0_s + tr, q_true=q, gyr=gyr, acc=acc, mag=mag, bias=bias, moving=tr >= rest_s)


def _acceleration(pos: np.ndarray, dt: float) -> np.ndarray:
    """The specific force in the world (N,3, m/s²) of a sensor at positions ``pos`` (N,3, m) every ``dt`` (s):
    the positions' second derivative plus gravity (up)."""
    return np.gradient(np.gradient(pos, dt, axis=0), dt, axis=0) + [0.0, 0.0, G]


def generate(
    duration_s: float = 60.0,
    rate_hz: float = 286.0,
    seed: int = 0,
    *,
    rest_s: float = 5.0,
    gyro_noise_rad_s: float = 0.005,
    acc_noise_m_s2: float = 0.05,
    mag_noise_t: float = 0.5e-6,
    bias_init_rad_s: float = np.radians(0.5),
    bias_walk_rad_s_sqrt_s: float = 2e-4,
    t0_s: float = 1.7e9,
    rot_scale: float = 1.0,
    bias_drift_rad_s: float = 0.0,
    bias_drift_period_s: float = 3600.0,
    translation_m: float = 0.1,
    field: Field | None = None,
    path_m: Callable[[np.ndarray], np.ndarray] | None = None,
) -> SimData:
    """Hand-held-like motion: smooth rotations up to ~±80° (times ``rot_scale``), slow heading changes, and
    translations of about ``translation_m`` (m, at 0.2-1.5 Hz: linear accelerations up to several m/s²) about
    ``path_m(t)`` ((N,3) m at times t (N,) s from the start; None: the origin, a smooth path whose acceleration is
    added), in the magnetic environment ``field`` (:data:`Field`; None: the uniform :data:`MAG_WORLD`).

    Deterministic for a seed (the same seed gives the same motion and noise whatever ``field``). The gyro bias starts
    at ``N(0, bias_init)`` per axis, random-walks, and (if ``bias_drift_rad_s`` > 0) drifts as a sinusoid of that
    amplitude and ``bias_drift_period_s`` (thermal drift).
    """
    n = _sample_count(duration_s, rate_hz, seed)
    rng = np.random.default_rng(seed)
    tr = np.arange(n) / rate_hz
    rest = min(rest_s, duration_s / 4)
    ramp = _ramp(tr, rest)
    params_rot = [
        (rng.uniform(0.05, 0.4), rng.uniform(0, 2 * np.pi), rot_scale * rng.uniform(0.3, 0.9)) for _ in range(9)
    ]
    yaw_rate = rng.uniform(-0.3, 0.3)

    def rotvec(t: np.ndarray) -> np.ndarray:
        out = np.zeros((len(t), 3))
        for k, (f, ph, a) in enumerate(params_rot):
            out[:, k % 3] += a / 3 * np.sin(2 * np.pi * f * t + ph) - a / 3 * np.sin(2 * np.pi * f * rest + ph)
        return out * _ramp(t, rest)[:, None]

    def orientation(t: np.ndarray) -> np.ndarray:
        yaw = yaw_rate * np.maximum(t - rest, 0.0)
        q_yaw = np.stack((np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)), axis=-1)
        return quat_mul(q_yaw, quat_from_rotvec(rotvec(t)))

    q = orientation(tr)
    h = 1e-4
    dq = (orientation(tr + h) - orientation(tr - h)) / (2 * h)
    omega = 2.0 * quat_mul(quat_conj(q), dq)[:, 1:]
    pos_amp = translation_m
    acc_lin = np.zeros((n, 3))
    pos = np.zeros((n, 3))
    for axis in range(3):
        for _ in range(3):
            f = rng.uniform(0.2, 1.5)
            ph = rng.uniform(0, 2 * np.pi)
            acc_lin[:, axis] -= pos_amp / 3 * (2 * np.pi * f) ** 2 * np.sin(2 * np.pi * f * tr + ph)
            pos[:, axis] += pos_amp / 3 * np.sin(2 * np.pi * f * tr + ph)
    acc_lin *= ramp[:, None]
    # (The position is the wobble whose acceleration the accelerometer feels, to within the 2 s start ramp.)
    pos *= ramp[:, None]
    if path_m is not None:
        path = path_m(tr)
        pos += path
        acc_lin += np.gradient(np.gradient(path, tr, axis=0), tr, axis=0)
    gyr, acc, mag, bias = _sense(
        rng, q, omega, acc_lin + [0.0, 0.0, G], tr, rate_hz, gyro_noise_rad_s=gyro_noise_rad_s,
        acc_noise_m_s2=acc_noise_m_s2, mag_noise_t=mag_noise_t, bias_init_rad_s=bias_init_rad_s,
        bias_walk_rad_s_sqrt_s=bias_walk_rad_s_sqrt_s, bias_drift_rad_s=bias_drift_rad_s,
        bias_drift_period_s=bias_drift_period_s, field_world=None if field is None else field(pos, tr),
    )
    return SimData(t_s=t0_s + tr, q_true=q, gyr=gyr, acc=acc, mag=mag, bias=bias, moving=tr >= rest)


def generate_near_dipole(rate_hz: float, seed: int = 0, *, uniform: bool = False) -> SimData:
    """Issue 23's field that varies with position: 90 s of hand-guided motion (:func:`generate`'s, 0.1 m translations)
    about a point that wanders slowly over ±0.35 m (:func:`wander_path`), beside a 300 A m² dipole 1.2 m away whose
    moment lies across the line to the workspace (:func:`dipole_beside`: the field turns by tens of degrees with
    little change of norm and dip). ``uniform``: the same motion and noise in the uniform field. The layout and path
    are drawn from ``numpy.random.default_rng(1000 + seed)``, the motion and noise from ``seed``."""
    rng = np.random.default_rng(1000 + seed)
    dipole = dipole_beside(rng, 300.0, 1.2)
    return generate(90.0, rate_hz, seed, translation_m=0.1, field=None if uniform else dipole,
                    path_m=wander_path(0.35, rng))


def generate_vehicle(
    duration_s: float = 300.0,
    rate_hz: float = 100.0,
    seed: int = 0,
    *,
    rest_s: float = 5.0,
    gyro_noise_rad_s: float = 0.005,
    acc_noise_m_s2: float = 0.1,
    mag_noise_t: float = 0.5e-6,
    bias_init_rad_s: float = np.radians(0.3),
    bias_walk_rad_s_sqrt_s: float = 2e-4,
    t0_s: float = 1.7e9,
    accel_m_s2: tuple[float, float] = (0.3, 1.5),
    pitch_per_m_s2_rad: float = 0.01,
) -> SimData:
    """A ground vehicle: drives off at ``accel_m_s2`` (range, m/s²) for 2-6 s, cruises, turns at 0.15-0.5 rad/s
    (centripetal acceleration speed x yaw rate), cruises, brakes as hard as it accelerated and stops for 3-8 s, over
    and over, on a road that climbs and falls by up to ±3°; the body pitches and rolls on its suspension by
    ``pitch_per_m_s2_rad`` per m/s² of longitudinal and lateral acceleration. Unlike hand-held motion, its linear
    accelerations last seconds in one direction: they pass any low-pass that gravity passes.

    Deterministic for a seed; the same noise and bias model as :func:`generate`, ``moving`` after ``rest_s``.
    """
    n = _sample_count(duration_s, rate_hz, seed)
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    tr = np.arange(n) * dt
    along = np.zeros(n)  # longitudinal acceleration, m/s²
    yaw_rate = np.zeros(n)  # rad/s
    i = int(round(rest_s * rate_hz))
    while i < n:
        a = rng.uniform(*accel_m_s2)
        t_acc, cruise = rng.uniform(2.0, 6.0), rng.uniform(5.0, 20.0)
        turn, t_turn, stop = rng.choice([-1.0, 1.0]) * rng.uniform(0.15, 0.5), rng.uniform(2.0, 6.0), rng.uniform(3.0, 8.0)
        for dur, a_seg, w in ((t_acc, a, 0.0), (cruise / 2, 0.0, 0.0), (t_turn, 0.0, turn), (cruise / 2, 0.0, 0.0),
                              (t_acc, -a, 0.0), (stop, 0.0, 0.0)):
            k = int(round(dur * rate_hz))
            along[i:i + k] = a_seg
            yaw_rate[i:i + k] = w
            i += k
    # Drivers and steering are smooth over ~0.3 s.
    m = max(1, int(round(0.3 * rate_hz)))
    kernel = np.ones(m) / m
    along = np.convolve(along, kernel, 'same')
    yaw_rate = np.convolve(yaw_rate, kernel, 'same')
    speed = np.cumsum(along) * dt
    lateral = speed * yaw_rate
    # The road's slope (pitch) and camber (roll): slow sums of sinusoids in distance, up to ±3° and ±1.5°.
    dist = np.cumsum(speed) * dt
    slope = sum(np.radians(rng.uniform(0.5, 1.0)) * np.sin(2 * np.pi * dist / rng.uniform(50, 300) + rng.uniform(0, 6.3))
                for _ in range(3))
    camber = sum(np.radians(rng.uniform(0.2, 0.5)) * np.sin(2 * np.pi * dist / rng.uniform(50, 300) + rng.uniform(0, 6.3))
                 for _ in range(3))
    pitch = -slope - pitch_per_m_s2_rad * along
    roll = camber + pitch_per_m_s2_rad * lateral
    yaw = np.cumsum(yaw_rate) * dt + rng.uniform(-np.pi, np.pi)
    q = euler_to_quat(roll, pitch, yaw)
    # Specific force: the vehicle's acceleration in the world (along the heading, and centripetal), plus gravity.
    c, s = np.cos(yaw), np.sin(yaw)
    acc_world = np.stack((along * c - lateral * s, along * s + lateral * c, np.full(n, G)), axis=1)
    noise = (gyro_noise_rad_s, acc_noise_m_s2, mag_noise_t, bias_init_rad_s, bias_walk_rad_s_sqrt_s)
    return _record(rng, q, acc_world, tr, rate_hz, t0_s, rest_s, noise)


def generate_swing(
    duration_s: float = 200.0,
    rate_hz: float = 51.0,
    seed: int = 0,
    *,
    rest_s: float = 5.0,
    length_m: float = 0.5,
    amplitude_rad: tuple[float, float] = (np.radians(10.0), np.radians(45.0)),
    gyro_noise_rad_s: float = 0.005,
    acc_noise_m_s2: float = 0.05,
    mag_noise_t: float = 0.5e-6,
    bias_init_rad_s: float = np.radians(0.5),
    bias_walk_rad_s_sqrt_s: float = 2e-4,
    t0_s: float = 1.7e9,
) -> SimData:
    """A pendulum: the IMU on a rod of ``length_m`` (m) swinging about one horizontal axis (of random direction) at
    its natural frequency, pushed every 15-30 s to an amplitude in ``amplitude_rad`` (range, rad) and decaying in
    between, with a few degrees of wobble out of the plane and twist about the rod; the sensor is mounted on the rod
    at a random fixed orientation. The specific force stays nearly along the rod: gravity hardly changes direction
    in the body, and the body turns about one axis only — the case where a 6-D filter's heading drift is hardest to
    learn.

    Deterministic for a seed; the same noise and bias model as :func:`generate`, ``moving`` after ``rest_s``.
    """
    n = _sample_count(duration_s, rate_hz, seed)
    rng = np.random.default_rng(seed)
    tr = np.arange(n) / rate_hz
    w = math.sqrt(G / length_m)
    # Swing amplitude: pushed to a new amplitude every 15-30 s, decaying (damping time 40 s) in between.
    amp = np.zeros(n)
    t_push, a0 = rest_s, 0.0
    while t_push < duration_s:
        t_next = t_push + rng.uniform(15.0, 30.0)
        a_new = rng.uniform(*amplitude_rad)
        sel = (tr >= t_push) & (tr < t_next)
        # The push takes a few swings (smoothly: no jerk in the rod's force), then the amplitude decays.
        up = np.clip((tr[sel] - t_push) / 4.0, 0.0, 1.0)
        up = up * up * (3 - 2 * up)
        amp[sel] = (a0 + (a_new - a0) * up) * np.exp(-np.maximum(tr[sel] - t_push - 4.0, 0.0) / 40.0)
        a0 = a_new * math.exp(-max(t_next - t_push - 4.0, 0.0) / 40.0)
        t_push = t_next
    phase = np.cumsum(np.full(n, w / rate_hz))
    theta = amp * np.sin(phase)
    wobble = np.radians(rng.uniform(1.0, 3.0)) * _ramp(tr, rest_s) * np.sin(phase * 0.5 + rng.uniform(0, 6.3))
    twist = np.radians(rng.uniform(1.0, 4.0)) * _ramp(tr, rest_s) * np.sin(0.3 * tr + rng.uniform(0, 6.3))
    axis_yaw = rng.uniform(-np.pi, np.pi)
    q_axis = np.array([math.cos(axis_yaw / 2), 0.0, 0.0, math.sin(axis_yaw / 2)])
    # Rod frame: swing about its x axis (horizontal), wobble about its y axis, twist about the rod (z).
    q_rod = quat_mul(q_axis, quat_mul(quat_from_rotvec(np.stack((theta, wobble, 0 * tr), axis=1)),
                                      quat_from_rotvec(np.stack((0 * tr, 0 * tr, twist), axis=1))))
    mount = quat_from_rotvec(rng.uniform(-np.pi, np.pi, 3) * rng.uniform(0.0, 1.0))
    q = quat_mul(q_rod, mount)
    # The sensor hangs length_m below the pivot: its acceleration from the rod's rotation.
    acc_world = _acceleration(quat_rotate(q_rod, np.broadcast_to([0.0, 0.0, -length_m], (n, 3))), 1.0 / rate_hz)
    noise = (gyro_noise_rad_s, acc_noise_m_s2, mag_noise_t, bias_init_rad_s, bias_walk_rad_s_sqrt_s)
    return _record(rng, q, acc_world, tr, rate_hz, t0_s, rest_s, noise)


def generate_spin(
    duration_s: float = 60.0,
    rate_hz: float = 100.0,
    seed: int = 0,
    *,
    rest_s: float = 5.0,
    spin_rad_s: tuple[float, float] = (0.4, 0.8),
    wobble_rad: float = np.radians(1.0),
    gyro_noise_rad_s: float = 0.005,
    acc_noise_m_s2: float = 0.05,
    mag_noise_t: float = 0.5e-6,
    bias_init_rad_s: float = np.radians(0.3),
    bias_walk_rad_s_sqrt_s: float = 2e-4,
    t0_s: float = 1.7e9,
) -> SimData:
    """A ground robot spinning in place (a magnetometer calibration by turning): after ``rest_s`` it turns about the
    vertical at ``spin_rad_s`` (range, rad/s; a new rate and direction every 8-15 s, changed smoothly), rocking by
    ``wobble_rad`` (rad) in roll and pitch on its wheels; the IMU sits 0.1 m off the turning axis (centripetal
    acceleration). Deterministic for a seed; the same noise and bias model as :func:`generate`."""
    n = _sample_count(duration_s, rate_hz, seed)
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    tr = np.arange(n) * dt
    rate = np.zeros(n)
    t = rest_s
    sign = rng.choice([-1.0, 1.0])
    while t < duration_s:
        t_next = t + rng.uniform(8.0, 15.0)
        rate[(tr >= t) & (tr < t_next)] = sign * rng.uniform(*spin_rad_s)
        sign = -sign if rng.uniform() < 0.5 else sign
        t = t_next
    m = max(1, int(round(1.0 * rate_hz)))  # the rate changes over ~1 s
    rate = np.convolve(rate, np.ones(m) / m, 'same') * (tr >= rest_s)
    yaw = np.cumsum(rate) * dt + rng.uniform(-np.pi, np.pi)
    ramp = _ramp(tr, rest_s)
    roll = wobble_rad * ramp * np.sin(2 * np.pi * rng.uniform(0.2, 0.5) * tr + rng.uniform(0, 6.3))
    pitch = wobble_rad * ramp * np.sin(2 * np.pi * rng.uniform(0.2, 0.5) * tr + rng.uniform(0, 6.3))
    q = euler_to_quat(roll, pitch, yaw)
    lever = 0.1  # m, the IMU off the turning axis
    acc_world = _acceleration(lever * np.stack((np.cos(yaw), np.sin(yaw), 0 * yaw), axis=1), dt)
    noise = (gyro_noise_rad_s, acc_noise_m_s2, mag_noise_t, bias_init_rad_s, bias_walk_rad_s_sqrt_s)
    return _record(rng, q, acc_world, tr, rate_hz, t0_s, rest_s, noise)


def with_mag_distortion(data: SimData, offset_t: Any, soft_iron: Any = None) -> SimData:
    """``data`` with its magnetometer read through hard and soft iron: ``W m + offset_t`` (offset (3,) T, ``W``
    ``soft_iron`` (3, 3); None: the identity). The noise is distorted with the field (it is added before)."""
    w = np.eye(3) if soft_iron is None else np.asarray(soft_iron, dtype=float).reshape(3, 3)
    mag = data.mag @ w.T + np.asarray(offset_t, dtype=float).reshape(3)
    return SimData(t_s=data.t_s, q_true=data.q_true, gyr=data.gyr, acc=data.acc, mag=mag, bias=data.bias,
                   moving=data.moving)


def write_bag(data: SimData, path: str | Path, *, overwrite: bool = False, storage: str = 'mcap') -> None:
    """Write ``data`` as a rosbag2 with /imu/mag, /imu/data_raw, /ground_truth/pose, /ground_truth/moving.

    Written to a temporary sibling and renamed at the end. Raises :class:`BagError` if ``path`` exists (without
    ``overwrite``) or cannot be written.
    """
    path = Path(path)
    refuse_existing(path, overwrite)
    ts = typestore()
    T: dict[str, Any] = ts.types  # rosbags' message classes are generated: fields not known statically
    Header, Time = T['std_msgs/msg/Header'], T['builtin_interfaces/msg/Time']
    Vector3, Quaternion = T['geometry_msgs/msg/Vector3'], T['geometry_msgs/msg/Quaternion']
    Imu, MagneticField = T['sensor_msgs/msg/Imu'], T['sensor_msgs/msg/MagneticField']
    PoseStamped, Pose, Point = T['geometry_msgs/msg/PoseStamped'], T['geometry_msgs/msg/Pose'], T['geometry_msgs/msg/Point']
    Bool = T['std_msgs/msg/Bool']
    ser = ts.serialize_cdr
    cov0 = np.zeros(9)
    cov_unknown = np.array([-1.0] + [0.0] * 8)
    with staged(path) as tmp, open_writer(tmp, storage) as w:
        c_mag = w.add_connection('/imu/mag', MagneticField.__msgtype__, typestore=ts)
        c_imu = w.add_connection('/imu/data_raw', Imu.__msgtype__, typestore=ts)
        c_gt = w.add_connection('/ground_truth/pose', PoseStamped.__msgtype__, typestore=ts)
        c_mv = w.add_connection('/ground_truth/moving', Bool.__msgtype__, typestore=ts)
        ns = np.round(data.t_s * 1e9).astype(np.int64).tolist()
        gyr, acc, mag, qt = data.gyr.tolist(), data.acc.tolist(), data.mag.tolist(), data.q_true.tolist()
        moving = data.moving.tolist()
        for k, t_ns in enumerate(ns):
            hdr = Header(stamp=Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000), frame_id='imu_link')
            m = mag[k]
            w.write(c_mag, t_ns, ser(MagneticField(header=hdr, magnetic_field=Vector3(x=m[0], y=m[1], z=m[2]),
                                                   magnetic_field_covariance=cov0), MagneticField.__msgtype__))
            g, a = gyr[k], acc[k]
            w.write(c_imu, t_ns, ser(Imu(header=hdr, orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                                         orientation_covariance=cov_unknown,
                                         angular_velocity=Vector3(x=g[0], y=g[1], z=g[2]),
                                         angular_velocity_covariance=cov0,
                                         linear_acceleration=Vector3(x=a[0], y=a[1], z=a[2]),
                                         linear_acceleration_covariance=cov0), Imu.__msgtype__))
            x, y, z, ww = to_xyzw(tuple(qt[k]))
            gt_hdr = Header(stamp=hdr.stamp, frame_id='world')
            w.write(c_gt, t_ns, ser(PoseStamped(header=gt_hdr, pose=Pose(position=Point(x=0.0, y=0.0, z=0.0),
                                                                        orientation=Quaternion(x=x, y=y, z=z, w=ww))),
                                    PoseStamped.__msgtype__))
            w.write(c_mv, t_ns, ser(Bool(data=moving[k]), Bool.__msgtype__))
