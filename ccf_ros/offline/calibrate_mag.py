"""``ccf calibrate-mag``: magnetometer hard-/soft-iron calibration from a bag, the command around the fit.

This module reads the bag, chooses the fit (3-D or planar, ``--motion``), reports it, writes the ROS 2 parameters
YAML and the plot. The fits themselves, as numpy with no bag or plot, and the model are :mod:`ccf_ros.magcal`.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import CcfError, ParameterError
from ..magcal import (
    COVERAGE_WARN,
    MIN_SPREAD_RATIO,
    MODELS,
    PLANAR_MAX_OFF_AXIS,
    SOFT_IRON_MIN_GAIN,
    TURN_COVERAGE_MIN,
    CalibrationError,
    MagCalibration,
    RotationAxes,
    fit,
    fit_planar,
    rotation_axes,
)
from .bagio import (
    DEFAULT_IMU_TOPIC,
    IMU_TYPE,
    connections_for,
    open_bag,
    read_imu_arrays,
    read_topic,
    refuse_existing,
    staged,
)
from .plot import check_plot_path, save_figure


def read_mag(bag: str | Path, topic: str = '/imu/mag', progress: str | None = None) -> np.ndarray:
    """All magnetic_field vectors (N, 3), T, of a sensor_msgs/MagneticField topic; :class:`BagError` if absent
    (``progress``: a bar's label, on a terminal)."""
    out = [(m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z)
           for _, _, m in read_topic(bag, topic, 'sensor_msgs/msg/MagneticField', progress=progress)]
    return np.array(out, dtype=float).reshape(-1, 3)


def _num(v: float) -> str:
    # Always a mantissa dot and a signed exponent: YAML 1.1 (PyYAML) reads '5e-05' as a string.
    return f'{v:.10e}'


def params_yaml(cal: MagCalibration) -> str:
    """A ROS 2 parameters file (``/**: ros__parameters:``) with mag_bias_x/y/z (T) and mag_soft_iron (9, row-major)."""
    b = cal.offset_t
    lines = [
        '# Magnetometer calibration by ccf calibrate-mag: m_cal = S (m_raw - b), b = mag_bias_* (T),',
        '# S = mag_soft_iron (row-major).',
        f'# model {cal.model}, residual {cal.residual_rel:.3%} RMS of |m_cal|, coverage {cal.coverage:.0%} of '
        f'directions, radius {cal.radius_t * 1e6:.3f} uT, n_samples {cal.n_samples}',
        '/**:',
        '  ros__parameters:',
        f'    mag_bias_x: {_num(b[0])}',
        f'    mag_bias_y: {_num(b[1])}',
        f'    mag_bias_z: {_num(b[2])}',
        f'    mag_soft_iron: [{", ".join(_num(v) for v in cal.soft_iron)}]',
    ]
    return '\n'.join(lines) + '\n'


def plot(path: str | Path, raw: ArrayLike, cal: MagCalibration) -> None:
    """PNG of the xy, yz and zx projections of raw and calibrated samples (µT) with the fitted radius circle."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    m = np.asarray(raw, dtype=float).reshape(-1, 3)
    m = m[np.all(np.isfinite(m), axis=1) & np.any(m != 0, axis=1)]
    if len(m) > 5000:  # a scatter of every sample of a long bag is slow and no clearer
        m = m[np.linspace(0, len(m) - 1, 5000).astype(int)]
    raw_ut, cal_ut = m * 1e6, cal.apply(m) * 1e6
    r = cal.radius_t * 1e6
    t = np.linspace(0, 2 * np.pi, 361)
    fig, axes = plt.subplots(1, 3, figsize=(15, 5.4))
    for ax, (i, j), name in zip(axes, ((0, 1), (1, 2), (2, 0)), ('xy', 'yz', 'zx'), strict=True):
        ax.plot(raw_ut[:, i], raw_ut[:, j], '.', ms=1.5, alpha=0.4, color='tab:red', label='raw')
        ax.plot(cal_ut[:, i], cal_ut[:, j], '.', ms=1.5, alpha=0.4, color='tab:blue', label='calibrated')
        ax.plot(r * np.cos(t), r * np.sin(t), 'k-', lw=1.0, label=f'radius {r:.1f} µT')
        ax.set_xlabel(f'{name[0]} [µT]')
        ax.set_ylabel(f'{name[1]} [µT]')
        ax.set_title(f'{name} plane')
        ax.set_aspect('equal', adjustable='datalim')
        ax.grid(alpha=0.3)
    axes[0].legend(loc='upper right', fontsize=8, markerscale=6)
    fig.suptitle(f'magnetometer calibration: residual {cal.residual_rel:.2%} RMS, coverage {cal.coverage:.0%}, '
                 f'{cal.n_samples} samples')
    save_figure(fig, path)


#: ``--motion`` choices: tell from the gyro, or force the 3-D (ellipsoid) or planar (ellipse) fit.
MOTIONS = ('auto', '3d', 'planar')


def _motion_axes(args: argparse.Namespace, raw: np.ndarray) -> tuple[str, RotationAxes | None]:
    """The fit to run (``'3d'`` or ``'planar'``) and the rotation axes (None without a gyro), printing which was
    chosen and why."""
    axes: RotationAxes | None = None
    imu_topic = args.imu_topic or DEFAULT_IMU_TOPIC
    try:
        imu = read_imu_arrays(args.bag, imu_topic, mag_topic=None, progress=imu_topic)
    except CcfError as err:
        if args.motion == 'planar':
            raise CalibrationError(f'--motion planar needs the gyro ({imu_topic}): {err}') from err
        if args.imu_topic is not None:
            raise  # named by the user: a typo must not pass as a run without the gyro
        if args.motion == 'auto':
            print(f'no gyro ({err}): motion from the magnetometer alone')
    else:
        dt = np.diff(imu.t_s, prepend=imu.t_s[:1])
        axes = rotation_axes(imu.gyr, dt, imu.acc)
        print(f'rotation: {axes.angle_rad:.1f} rad in all, {axes.off_axis:.1%} of it off the principal axis '
              f'[{axes.axis[0]:+.3f} {axes.axis[1]:+.3f} {axes.axis[2]:+.3f}] (body)')
    if args.motion != 'auto':
        print(f'motion: {args.motion} (forced by --motion)')
        return args.motion, axes
    if axes is not None:
        chosen = 'planar' if axes.planar else '3d'
        rel = 'at most' if axes.planar else 'more than'
        print(f'motion: {chosen} (auto: {rel} {PLANAR_MAX_OFF_AXIS:.0%} of the rotation off one axis)')
        return chosen, axes
    m = raw[np.all(np.isfinite(raw), axis=1) & np.any(raw != 0, axis=1)]
    spread = np.linalg.svd(m - m.mean(axis=0), compute_uv=False) if len(m) >= 3 else np.ones(3)
    chosen = 'planar' if spread[2] < 2 * MIN_SPREAD_RATIO * spread[0] else '3d'
    print(f'motion: {chosen} (auto: the magnetometer samples are {"" if chosen == "planar" else "not "}flat)')
    return chosen, None


def _planar(args: argparse.Namespace, raw: np.ndarray, axes: RotationAxes | None) -> MagCalibration:
    """The planar fit of ``cmd_calibrate_mag``, reported; returns the 3-D calibration to write."""
    if axes is None:
        m = raw[np.all(np.isfinite(raw), axis=1) & np.any(raw != 0, axis=1)]
        axis = np.linalg.svd(m - m.mean(axis=0))[2][2]
        print('axis: the normal of the magnetometer samples\' plane (no gyro: which way is up is unknown)')
    else:
        axis = np.array(axes.axis)
    norm = None if args.field_norm_ut is None else args.field_norm_ut * 1e-6
    dip = None if args.field_dip_deg is None else math.radians(args.field_dip_deg)
    if axes is None and (norm is not None or dip is not None):
        print('warning: without the accelerometer the axis has no sign: --field-norm-ut/--field-dip-deg ignored')
        norm = dip = None
    pc = fit_planar(raw, axis, field_norm_t=norm, field_dip_rad=dip, model=args.model, force=args.force)
    cal = pc.cal
    b = cal.offset * 1e6
    print(f'{cal.n_samples} samples from {args.mag_topic}')
    print(f'planar fit ({pc.model}) about the axis [{pc.axis[0]:+.3f} {pc.axis[1]:+.3f} {pc.axis[2]:+.3f}]: '
          f'residual {pc.residual_t * 1e6:.3f} uT RMS in the plane, turn coverage {pc.turn_coverage:.0%}, '
          f'horizontal radius {pc.radius_t * 1e6:.3f} uT')
    print(f'offset b [uT]: {b[0]:.3f} {b[1]:.3f} {b[2]:.3f}')
    if pc.axial_source == 'none':
        print('offset along the axis: not determined by turning about it, left at 0 (give --field-norm-ut and/or '
              '--field-dip-deg to fit it)')
    else:
        print(f'offset along the axis: {pc.axial_offset_t * 1e6:.3f} uT (from the field {pc.axial_source})')
        if pc.axial_source == 'norm':
            # The norm gives the vertical component's size, not its sign.
            print('  (the field taken to point down, as north of the magnetic equator: south of it give '
                  '--field-dip-deg, negative there)')
    print('soft iron S (m_cal = S (m_raw - b)), in the plane only:')
    for row in cal.matrix:
        print('  ' + ' '.join(f'{v:9.5f}' for v in row))
    if pc.turn_coverage < TURN_COVERAGE_MIN:
        print(f'warning: turn coverage {pc.turn_coverage:.0%} is low: turn full circles and record again')
    return cal


def cmd_calibrate_mag(args: argparse.Namespace) -> int:
    """Read, fit (3-D or planar, see ``--motion``), report, write the parameters YAML (atomically), optionally plot."""
    out = Path(args.output)
    refuse_existing(out, args.overwrite, bag=False)  # before the slow part, not after
    if args.imu_topic is not None:
        with open_bag(args.bag) as reader:  # named: must be an Imu topic of the bag, whatever --motion reads
            connections_for(reader, args.imu_topic, msgtype=IMU_TYPE)
    if args.plot:
        check_plot_path(args.plot)
    if args.field_norm_ut is not None and not (math.isfinite(args.field_norm_ut) and args.field_norm_ut > 0):
        raise ParameterError(f'--field-norm-ut must be a positive number of uT, got {args.field_norm_ut!r}')
    if args.field_dip_deg is not None and not (math.isfinite(args.field_dip_deg) and abs(args.field_dip_deg) < 89.9):
        raise ParameterError(f'--field-dip-deg must be a number within (-90, 90) deg, got {args.field_dip_deg!r}')
    raw = read_mag(args.bag, args.mag_topic, progress=args.mag_topic)
    motion, axes = ('3d', None) if args.motion == '3d' else _motion_axes(args, raw)
    cal = _planar(args, raw, axes) if motion == 'planar' else _fit_3d(args, raw)
    # Staged and renamed: a reader (or a crash) never sees half a file.
    with staged(out, bag=False) as tmp:
        try:
            tmp.write_text(params_yaml(cal))
        except OSError as err:
            raise CcfError(f'cannot write {out}: {err.strerror}') from err
    print(f'wrote {out}')
    if args.plot:
        plot(args.plot, raw, cal)
        print(f'plot: {args.plot}')
    return 0


def _fit_3d(args: argparse.Namespace, raw: np.ndarray) -> MagCalibration:
    """The 3-D (ellipsoid) fit of ``cmd_calibrate_mag``, reported; refuses low coverage unless ``--force``."""
    field_norm_t = None if args.field_norm_ut is None else args.field_norm_ut * 1e-6
    cal = fit(raw, field_norm_t=field_norm_t, model=args.model)
    b = cal.offset * 1e6
    dropped = len(raw) - cal.n_samples
    note = f' ({dropped} non-finite or zero dropped)' if dropped else ''
    print(f'{cal.n_samples} samples from {args.mag_topic}{note}')
    print(f'offset b [uT]: {b[0]:.3f} {b[1]:.3f} {b[2]:.3f}')
    print('soft iron S (m_cal = S (m_raw - b)):')
    for row in cal.matrix:
        print('  ' + ' '.join(f'{v:9.5f}' for v in row))
    scale = 'given field norm' if field_norm_t is not None else 'det S = 1'
    print(f'radius {cal.radius_t * 1e6:.3f} uT ({scale}), residual {cal.residual_rel:.2%} RMS, '
          f'coverage {cal.coverage:.0%} of directions')
    if cal.model == 'ellipsoid':
        why = 'forced by --model' if args.model == 'ellipsoid' else (
            f'it lowers the scatter below {SOFT_IRON_MIN_GAIN:g} x the offset-only fit\'s '
            f'({cal.offset_only_residual_rel:.2%} RMS)')
        print(f'model: offset and soft iron ({why})')
    else:
        why = 'forced by --model' if args.model == 'offset' else (
            f'a soft-iron matrix lowers the scatter by less than {1 - SOFT_IRON_MIN_GAIN:.0%}: what is left is '
            'the field\'s non-uniformity, not the sensor\'s')
        print(f'model: offset only, S a multiple of the identity ({why})')
    if cal.coverage < COVERAGE_WARN:
        advice = 'rotate the sensor through more orientations (all sides up, full turns) and record again'
        if not args.force:
            # An offset along directions the recording never turned through is a guess: on BROAD trial 16 (12 %)
            # the file written would have raised the heading error from 0.48 to 3.35 deg.
            raise CalibrationError(f'coverage {cal.coverage:.0%} of directions is below {COVERAGE_WARN:.0%}: the '
                                   f'offset is not determined; {advice} (or --force to write it anyway; a robot '
                                   'that can only turn about one axis: --motion planar)')
        print(f'warning: coverage {cal.coverage:.0%} is low: {advice}')
    return cal


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``calibrate-mag`` on an ``add_subparsers()`` object; returns the new parser."""
    p: argparse.ArgumentParser = subparsers.add_parser(
        'calibrate-mag',
        help='fit magnetometer hard-/soft-iron calibration from a bag (3-D, or planar for a robot turning about one '
        'axis), write a parameters YAML',
        description='Fit m_cal = S (m_raw - b) to the magnetometer samples of a bag: b hard-iron offset, '
        'S symmetric soft-iron matrix (kept only where the data show one, see --model); radius = --field-norm-ut '
        'if given, else det S = 1.',
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument('bag', help='input: rosbag2 directory (mcap or sqlite3) or ROS 1 .bag')
    p.add_argument('--mag-topic', default='/imu/mag', help='sensor_msgs/MagneticField topic')
    p.add_argument('-o', '--output', default='mag_calibration.yaml', help='output ROS 2 parameters YAML')
    p.add_argument('--plot', metavar='FILE.png', help='also plot raw and calibrated samples')
    p.add_argument('--field-norm-ut', type=float, metavar='UT',
                   help='local field norm, uT: the radius of the calibrated sphere; None: scale to det S = 1')
    p.add_argument('--model', choices=MODELS, default='auto',
                   help='ellipsoid: offset and soft-iron matrix; offset: offset only; auto: the soft-iron matrix '
                   f'only where it lowers the RMS scatter below {SOFT_IRON_MIN_GAIN:g} x the offset-only fit\'s')
    p.add_argument('--imu-topic',
                   help='sensor_msgs/Imu topic: its gyro tells the motion (--motion auto), its accelerometer up (a '
                   f'topic given here must be in the bag; if not given: {DEFAULT_IMU_TOPIC}, the magnetometer alone '
                   'if the bag has none)')
    p.add_argument('--motion', choices=MOTIONS, default='auto',
                   help='3d: ellipsoid fit (needs a sensor turned through all orientations); planar: ellipse fit in '
                   'the plane of a turn about one axis (a ground robot spinning in place); auto: planar where at most '
                   '10 %% of the rotation is off one axis')
    p.add_argument('--field-dip-deg', type=float, metavar='DEG',
                   help='planar: local field dip (inclination), deg, > 0 where it points down; with or without '
                   '--field-norm-ut it gives the offset along the turning axis (else left at 0)')
    p.add_argument('--overwrite', action='store_true', help='replace an existing output file')
    p.add_argument('--force', action='store_true',
                   help=f'write the calibration even if the coverage is below {COVERAGE_WARN * 100:.0f} %% '
                   '(planar: the turn coverage below 75 %%)')
    p.set_defaults(func=cmd_calibrate_mag)
    return p
