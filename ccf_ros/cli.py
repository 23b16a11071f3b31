"""``ccf``: offline tools on recorded bags, no ROS install needed.

Subcommands: replay, eval, simulate, play, demo, study, calibrate-mag, params, fleet.

A problem with the input (a bag, a parameter, an option, an output that exists) is one line on stderr and exit
code 2; Ctrl-C exits 130. Anything else is a bug in ccf_ros: it shows its traceback (exit code 1). ``--debug``
shows the traceback of input errors too.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import shlex
import sys
import tempfile
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .errors import BagError, CcfError, ParameterError

#: The magnetometer topic read when ``--mag-topic`` is not given (a bag without it runs 6-D, with a warning).
DEFAULT_MAG_TOPIC = '/imu/mag'
MAG_TOPIC_HELP = ('sensor_msgs/MagneticField input topic (if not given: the bag\'s one MagneticField topic, of '
                  f'several {DEFAULT_MAG_TOPIC}; 6-D with a warning if the bag has none; a topic given here must be in '
                  'the bag)')
#: The study's mask topic when ``--mask-topic`` is not given (BROAD's; a bag without it is scored everywhere).
DEFAULT_MASK_TOPIC = '/ground_truth/moving'
IMU_TOPIC_HELP = ("sensor_msgs/Imu input topic (if not given: the bag's one Imu topic, of several /imu/data_raw)")


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions as written; ``(default: X)`` after the help of every option that has a default.

    Flags (``store_true``) and options without a default (None) get none: their help says what absence means.
    """

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ''
        if (
            action.option_strings
            and action.nargs != 0
            and action.default is not None
            and action.default is not argparse.SUPPRESS
            and '%(default)' not in text
        ):
            text += ' (default: %(default)s)'
        return text


def _node_name(args: argparse.Namespace) -> str:
    """The node replayed: ``--node-name``, or the ``--profile`` executable's default name."""
    from .node.compat import PROFILES

    return getattr(args, 'node_name', None) or PROFILES[getattr(args, 'profile', None) or 'ccf_node'].node_name


def _settings(args: argparse.Namespace) -> tuple[dict[str, Any], dict[str, Any]]:
    """Settings from the parameters files (in order, a later file overriding an earlier one) and from the command
    line (``--param``, ``--no-mag``), which overrides the files."""
    from .offline.params_file import load_params_files, parse_assignments

    from_files = load_params_files(getattr(args, 'params_file', None) or [], _node_name(args))
    given: dict[str, Any] = dict(parse_assignments(getattr(args, 'param', None) or []))
    if getattr(args, 'no_mag', False):
        given['use_mag'] = False
    return from_files, given


def engine_settings(args: argparse.Namespace) -> tuple[dict[str, Any], bool]:
    """The merged settings the engine is built from (profile defaults, then files, then ``--param``) and whether
    they are checked strictly; checked here, so a bad value is one error before any bag is read."""
    from .core.registry import SELECTORS
    from .node.compat import PROFILES, apply_do_bias_estimation
    from .settings import build

    from_files, given = _settings(args)
    # The executable's defaults (e.g. complementary_filter_node: NWU, bias-corrected rate), then files, then --param.
    profile = PROFILES[getattr(args, 'profile', None) or 'ccf_node']
    merged = {**profile.defaults, **from_files, **given}
    # imu_tools' do_bias_estimation means the same offline as in the node.
    apply_do_bias_estimation(merged, profile)
    if from_files:
        # A parameters file holds the parameters of every filter; only the names given on the command line must
        # apply to the selected one.
        selected = {name: merged[name] for name in SELECTORS if name in merged}
        build({**selected, **given}, strict=True)
    build(merged, strict=not from_files)
    return merged, not from_files


def make_engine(merged: dict[str, Any], strict: bool) -> Any:
    """A fresh :class:`~ccf_ros.engine.ImuEngine` from :func:`engine_settings`' result (in any process)."""
    from .engine import ImuEngine
    from .settings import build

    filt, adapter = build(merged, strict=strict)
    return ImuEngine(filt, adapter)


def _writable(path: str | Path, what: str, overwrite: bool) -> Path:
    """``path`` if its directory exists and it does not (or is a file and ``overwrite``), checked before the slow
    part; :class:`CcfError` otherwise."""
    p = Path(path)
    if not p.parent.is_dir():
        raise CcfError(f'cannot write {what} {p}: no such directory {p.parent}')
    if p.is_dir():
        raise CcfError(f'cannot write {what} {p}: it is a folder')
    from .offline.bagio import refuse_existing

    refuse_existing(p, overwrite, bag=False)  # the rule of every output file: replaced only with --overwrite
    return p


def _need_rclpy(what: str) -> None:
    if importlib.util.find_spec('rclpy') is None:
        raise CcfError(f'{what} needs rclpy: install the ROS 2 Jazzy wheels (pip install -e .) or source ROS 2 Jazzy')


def motion_hint(args: argparse.Namespace, merged: dict[str, Any]) -> tuple[str | None, tuple[float, float, float]]:
    """The motion hint's topic (None: none) and thresholds (speed m/s, turn rate rad/s, timeout s), as replay and
    fleet read them, from :func:`engine_settings`' ``merged`` settings."""
    from .offline.params_file import resolve_topic
    from .settings import NODE_DEFAULTS, coerce

    st = {**NODE_DEFAULTS, **merged}
    # The option (replay's) wins over the parameter (--param or a parameters file); a relative name is resolved as
    # the node named by --node-name resolves it.
    option = getattr(args, 'motion_hint_topic', None)
    topic = option if option is not None else coerce('motion_hint_topic', st['motion_hint_topic'])
    thresholds = (coerce('motion_hint_linear_m_s', st['motion_hint_linear_m_s']),
                  coerce('motion_hint_angular_rad_s', st['motion_hint_angular_rad_s']),
                  coerce('motion_hint_timeout_s', st['motion_hint_timeout_s']))
    return (resolve_topic(topic, _node_name(args)) if topic else None), thresholds


def cmd_replay(args: argparse.Namespace) -> int:
    from .offline.params_file import parse_assignments
    from .offline.replay import replay
    from .settings import names

    merged, strict = engine_settings(args)
    engine = make_engine(merged, strict)
    hint_topic, hint = motion_hint(args, merged)
    summary = replay(
        args.bag,
        args.output,
        engine,
        motion_hint_topic=hint_topic,
        motion_hint=hint,
        imu_topic=args.imu_topic,
        mag_topic=args.mag_topic,
        detect=True,
        no_mag=args.no_mag,
        storage=args.storage,
        copy_input=args.copy_input,
        overwrite=args.overwrite,
    )
    hint_settings = {'motion_hint_topic', 'motion_hint_linear_m_s', 'motion_hint_angular_rad_s', 'motion_hint_timeout_s'}
    node_only = sorted(set(parse_assignments(args.param or [])) & set(names('node')) - hint_settings)
    if node_only:
        summary.warnings.append(f'{", ".join(node_only)}: node settings, without effect on replay (it writes '
                                '/imu/gyro_bias for every sample)')
    for w in summary.warnings:
        print(f'warning: {w}', file=sys.stderr)
    print(f'wrote {args.output}: {summary.line()}')
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from .offline.evaluate import evaluate, format_summary, load_aligned
    from .offline.plot import check_plot_path

    json_path = _writable(args.json, 'JSON', args.overwrite) if args.json else None
    plot_path = check_plot_path(_writable(args.plot, 'plot', args.overwrite)) if args.plot else None
    aligned = load_aligned(
        args.bag,
        args.reference,
        reference_bag=args.reference_bag,
        estimate_topic=args.estimate_topic,
        mask_topic=args.mask_topic,
        progress=True,
    )
    s = evaluate(aligned)
    print(format_summary(s, args.estimate_topic))
    if json_path:
        text = json.dumps(s.as_dict(), indent=2)
        tmp = json_path.with_name(f'.{json_path.name}.partial')
        try:
            # Written beside and renamed: an interrupted run never leaves a truncated file under the real name.
            tmp.write_text(text)
            tmp.replace(json_path)
        except OSError as err:
            tmp.unlink(missing_ok=True)
            raise CcfError(f'cannot write JSON {json_path}: {err.strerror}') from err
    if plot_path:
        from .offline.plot import plot_rpy

        plot_rpy(plot_path, aligned.t_s, aligned.q_ref, {args.estimate_topic: aligned.q_est}, title=str(args.bag))
        print(f'plot: {plot_path}')
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    from .offline.simulate import generate, generate_spin, generate_vehicle, with_mag_distortion, write_bag

    make: Any = {'vehicle': generate_vehicle, 'spin': generate_spin}.get(args.motion, generate)
    data = make(args.duration, args.rate, args.seed)
    if args.mag_offset_ut is not None:
        if not all(math.isfinite(v) for v in args.mag_offset_ut):
            raise ParameterError(f'--mag-offset-ut must be 3 finite numbers of uT, got {args.mag_offset_ut!r}')
        data = with_mag_distortion(data, [v * 1e-6 for v in args.mag_offset_ut])
    write_bag(data, args.output, overwrite=args.overwrite, storage=args.storage)
    print(f'wrote {args.output}: {len(data.t_s)} samples, {args.duration:g} s at {args.rate:g} Hz, {args.motion} '
          f'motion, seed {args.seed}')
    return 0


def cmd_play(args: argparse.Namespace) -> int:
    if not args.rate > 0:
        raise ParameterError(f'--rate must be > 0, got {args.rate!r}')
    if not 0 <= args.wait_for_subscribers < float('inf'):
        raise ParameterError(f'--wait-for-subscribers must be a finite number >= 0, got {args.wait_for_subscribers!r}')
    if args.qos_depth < 1:
        raise ParameterError(f'--qos-depth must be >= 1, got {args.qos_depth!r}')
    _need_rclpy('ccf play')
    import rclpy
    from rclpy.exceptions import NotInitializedException
    from rclpy.executors import ExternalShutdownException
    from tqdm import tqdm

    from .node.entry import RCLError, stop_signal_thread
    from .offline.play import load_messages, play

    topics = [t for t in (args.topics or '').split(',') if t] or None
    types, messages = load_messages(args.bag, topics, warn=lambda w: print(f'warning: {w}', file=sys.stderr))
    print(f'playing {len(messages)} messages on {len(types)} topics at {args.rate:g}x' + (' (loop)' if args.loop else '')
          + (f', after up to {args.wait_for_subscribers:g} s for a subscriber on each' if args.wait_for_subscribers else ''))
    rclpy.init()
    node = None
    bar = tqdm(total=None if args.loop else len(messages), unit='msg', disable=None, mininterval=0.5)
    n = 0  # counted here: a bar disabled off a TTY counts nothing

    def progress(k: int) -> None:
        nonlocal n
        n += k
        bar.update(k)

    try:
        node = rclpy.create_node('ccf_play')
        play(node, types, messages, rate=args.rate, loop=args.loop, clock=args.clock,
             should_stop=lambda: not rclpy.ok(), progress=progress, wait_matched_s=args.wait_for_subscribers,
             qos_depth=args.qos_depth)
        # rclpy's signal handler shuts the context down on SIGINT: play then ends early, without an exception.
        interrupted = not rclpy.ok()
    except (KeyboardInterrupt, ExternalShutdownException):
        interrupted = True
    except (RCLError, NotInitializedException):
        if rclpy.ok():
            raise
        interrupted = True  # SIGINT while the node was made: rclpy's signal thread shut the context down under it
    finally:
        bar.close()
        stop_signal_thread()  # (before the shutdown: rclpy's signal thread would race it, see there)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    print(f'published {n} messages')
    if interrupted:
        raise KeyboardInterrupt  # main's way out of Ctrl-C: 'interrupted', exit 130
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from .offline.demo import run_demo

    if not args.offline_only:
        _need_rclpy('the live part of ccf demo (or pass --offline-only)')
    if not args.live_rate > 0:
        raise ParameterError(f'--live-rate must be > 0, got {args.live_rate!r}')
    return run_demo(Path(args.output_dir), duration_s=args.duration, seed=args.seed, live=not args.offline_only,
                    live_rate=args.live_rate)


def cmd_study(args: argparse.Namespace) -> int:
    from .offline.bagio import message_counts, read_bools, require_topic
    from .study.datasets import Topics
    from .study.report import write_report
    from .study.run import StudyOptions, run_study

    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise CcfError(f'{out} is a file, not a folder (-o is the report\'s folder)')  # --overwrite or not
    if out.exists() and any(out.iterdir()) and not args.overwrite:
        raise CcfError(f'{out} exists and is not empty (use --overwrite)')
    for bag in args.bags:
        if not Path(bag).exists():
            raise BagError(f'{bag}: no such bag')
        if args.mag_topic is not None:
            require_topic(bag, args.mag_topic)
        elif not message_counts(bag).get(DEFAULT_MAG_TOPIC):
            print(f'warning: {bag}: no {DEFAULT_MAG_TOPIC}: 6-D, heading relative to the start', file=sys.stderr)
        if args.mask_topic:
            try:
                read_bools(bag, args.mask_topic)  # a mask named must be in every bag, a Bool topic (as in eval)
            except BagError as err:
                raise BagError(f'{bag}: {err}') from err
    opts = StudyOptions(
        long_run_s=args.long_run_s,
        jobs=args.jobs,
        lscf=not args.no_lscf,
        lscf_iterations=args.lscf_iterations,
        repetitions=args.repetitions,
        bode_frequencies=args.bode_frequencies,
    )
    mask = DEFAULT_MASK_TOPIC if args.mask_topic is None else args.mask_topic or None
    topics = Topics(args.imu_topic, args.mag_topic or DEFAULT_MAG_TOPIC, args.reference, mask)
    results = run_study(args.bags, opts, topics=topics, progress=not args.quiet)
    summary = write_report(results, out, 'ccf ' + shlex.join(args.argv))
    for v in summary['verdicts']:
        print(f'claim {v["claim"]} ({v["formulation"]}): {v["verdict"]}')
    print(f'report: {out / "report.md"}  ({len(summary["figures"])} figures, results.json; '
          f'{results["wall_time_s"] / 60:.1f} min)')
    return 0


def unit_of(name: str) -> str:
    """A parameter's SI unit as its definition gives it (:func:`ccf_ros.settings.schema`); ``-``: none."""
    from .settings import schema

    return schema()[name].unit


def format_value(value: Any) -> str:
    """A default as it is written in a parameters file or ``--param`` (:func:`ccf_ros.settings.format_value`)."""
    from .settings import format_value as fmt

    return fmt(value)


def params_rows(
    filter_name: str | None = None, formulation: str | None = None
) -> tuple[str, list[tuple[str, str, str, str]]]:
    """A title and ``(name, default, unit, description)`` rows: every setting, or those of one filter.

    Read from :func:`ccf_ros.settings.schema` when called. With ``filter_name``: the selected filter's own
    parameters (its defaults) and the settings that are not filter parameters (engine, node, imu_tools gains), which
    apply to every filter.
    """
    from .core.registry import FILTERS, SELECTORS, param_fields
    from .settings import format_value as fmt
    from .settings import schema

    entries = schema()
    if filter_name is None:
        title = 'every parameter (filter, engine, node) with its default; set with --param NAME=VALUE or --params-file'
        chosen = {name: p.default for name, p in entries.items()}
    else:
        forms = [f for k, f in FILTERS if k == filter_name]
        if not forms:
            raise ParameterError(f'no filter {filter_name!r} (choose: {", ".join(sorted({k for k, _ in FILTERS}))})')
        if formulation is None:
            formulation = SELECTORS['formulation'] if SELECTORS['formulation'] in forms else forms[0]
        if formulation not in forms:
            raise ParameterError(f'filter {filter_name} has no formulation {formulation!r} (choose: {", ".join(forms)})')
        fields = param_fields(FILTERS[(filter_name, formulation)][0])
        # The filter's own defaults (a baseline's may differ from the first filter's), then the non-filter settings.
        chosen = {name: fields[name].default if name in fields else p.default for name, p in entries.items()
                  if name in fields or p.group not in ('selector', 'filter')}
        title = (f'parameters of filter={filter_name} formulation={formulation}, and the engine and node settings '
                 'that apply to every filter')
    rows = [(name, fmt(value), entries[name].unit, entries[name].description) for name, value in chosen.items()]
    return title, rows


def cmd_params(args: argparse.Namespace) -> int:
    from .settings import config_yaml

    if args.yaml:
        print(config_yaml(), end='')
        return 0
    if args.formulation and not args.filter:
        raise ParameterError('--formulation needs --filter NAME')
    title, rows = params_rows(args.filter, args.formulation)
    header = ('NAME', 'DEFAULT', 'UNIT', 'DESCRIPTION')
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(3)]
    print(title)
    for row in [header, *rows]:
        print('  '.join(cell.ljust(w) for cell, w in zip(row[:3], widths, strict=True)) + '  ' + row[3])
    return 0


def cmd_fleet_run(args: argparse.Namespace) -> int:
    import math
    import os

    from .fleet.keys import code_version
    from .fleet.report import check_device_regex, write_report
    from .fleet.run import RunConfig, run_fleet
    from .fleet.task import FleetOptions

    if args.jobs < 0:
        raise ParameterError(f'-j/--jobs must be >= 0, got {args.jobs}')
    if args.retries < 0:
        raise ParameterError(f'--retries must be >= 0, got {args.retries}')
    # (finite: a timer of inf s cannot be started; NaN compares false with everything)
    if not (args.task_timeout >= 0 and math.isfinite(args.task_timeout)):
        raise ParameterError(f'--task-timeout must be a finite number >= 0 s, got {args.task_timeout!r}')
    if not (args.wait_workers > 0 and math.isfinite(args.wait_workers)):
        raise ParameterError(f'--wait-workers must be a finite number > 0 s, got {args.wait_workers!r}')
    check_device_regex(args.device)  # (the report is written after the run: a bad one must not cost the run)
    slow = os.environ.get('CCF_FLEET_SLOW_BAG_S', '0') or '0'
    try:
        slow_bag_s = float(slow)
    except ValueError:
        slow_bag_s = math.nan
    if not (slow_bag_s >= 0 and math.isfinite(slow_bag_s)):
        raise ParameterError(f'CCF_FLEET_SLOW_BAG_S must be a finite number >= 0 s, got {slow!r}')
    merged, strict = engine_settings(args)
    if merged.get('bias_file'):
        # One file per IMU: bags of many robots (or of one, processed in parallel) would overwrite each other's.
        raise ParameterError(f'bias_file is one IMU\'s state, not a fleet\'s: remove it (got {merged["bias_file"]!r})')
    out = Path(args.output).absolute()
    hint_topic, hint = motion_hint(args, merged)
    opts = FleetOptions(out=str(out), settings=merged, strict=strict, version=code_version(), imu_topic=args.imu_topic,
                        mag_topic=args.mag_topic, no_mag=args.no_mag, motion_hint_topic=hint_topic, motion_hint=hint,
                        write_bags=args.write_bags,
                        reference=args.reference, mask_topic=args.mask_topic, task_timeout_s=args.task_timeout,
                        # A test knob (not an option): every bag waits this long first, to kill a worker mid-bag.
                        slow_bag_s=slow_bag_s)
    cfg = RunConfig(inputs=args.inputs, out=out, options=opts, jobs=args.jobs,
                    scheduler=args.scheduler or os.environ.get('DASK_SCHEDULER_ADDRESS') or None,
                    retry_failed=args.retry_failed, force=args.force, retries=args.retries,
                    worker_wait_s=args.wait_workers,
                    progress=False if args.quiet else None, device_regex=args.device)
    s = run_fleet(cfg)
    report = write_report(out, args.device)
    if not s.n_submitted:
        print(f'nothing to do: all {s.n_bags} bags are done ({s.n_failed} failed; --retry-failed or --force to redo)')
    for r in s.records:
        if r['status'] != 'ok':
            print(f'failed: {r["bag"]}: {r.get("error", "")}', file=sys.stderr)
    rate = s.samples / s.wall_s if s.wall_s > 0 else 0.0
    print(f'{s.n_bags} bags: {s.n_ok} ok, {s.n_failed} failed; {s.n_submitted} processed now, {s.n_done_before} '
          f'done before; {s.wall_s:.1f} s. Results: {out / "results.jsonl"}, report: {report}'
          + (f' ({rate:,.0f} samples/s over all bags)' if s.n_submitted else ''))
    return 1 if s.n_failed else 0


def cmd_fleet_report(args: argparse.Namespace) -> int:
    from .fleet.report import write_report

    print(f'report: {write_report(args.output, args.device)}')
    return 0


def _add_filter_options(p: argparse.ArgumentParser) -> None:
    p.add_argument('--params-file', action='append', metavar='FILE',
                   help='ROS 2 parameters YAML, as for the node (config/ccf.yaml, a ccf calibrate-mag result); '
                   'repeatable, a later file overrides an earlier one')
    p.add_argument('--param', action='append', metavar='NAME=VALUE',
                   help='set one parameter, over the parameters files (repeatable; list: ccf params)')
    p.add_argument('--node-name', metavar='NAME',
                   help="the node (NAME or /NAMESPACE/NAME) whose sections of the parameters files apply, as that "
                   "node takes them: /**, NAME, /NAMESPACE/NAME and wildcards, a file of one section whatever its "
                   "name; a relative motion hint topic is resolved in its namespace (if not given: the --profile "
                   "executable's default name, ccf_node)")
    p.add_argument('--profile', choices=('ccf_node', 'imu_filter_madgwick_node', 'complementary_filter_node'),
                   default='ccf_node', help="start from this executable's defaults (replay an imu_tools YAML as the "
                   'drop-in node of that name would run it)')


def build_parser() -> argparse.ArgumentParser:
    from . import __version__
    from .core.registry import FILTERS
    from .offline import calibrate_mag as magcal
    from .offline.bagio import STORAGES

    p = argparse.ArgumentParser(prog='ccf', description=__doc__, formatter_class=HelpFormatter)
    p.add_argument('--version', action='version', version=f'ccf_ros {__version__}')
    p.add_argument('--debug', action='store_true', help='show the traceback of input errors too')
    sub = p.add_subparsers(dest='command', required=True, metavar='COMMAND')

    def add(name: str, text: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=text, description=text, formatter_class=HelpFormatter)

    r = add('replay', 'run the filter over a bag, write /imu/data and /imu/gyro_bias to a new bag')
    r.add_argument('bag', help='input: rosbag2 directory (mcap or sqlite3) or ROS 1 .bag')
    r.add_argument('-o', '--output', required=True, help='output rosbag2 directory')
    r.add_argument('--imu-topic', help=IMU_TOPIC_HELP)
    r.add_argument('--mag-topic', help=MAG_TOPIC_HELP)
    r.add_argument('--motion-hint-topic', metavar='TOPIC',
                   help='nav_msgs/Odometry or geometry_msgs/TwistStamped in the bag: the gyro bias is learnt at rest '
                        'only when it says still (motion_hint_* settings), as the node does (if not given: the '
                        'motion_hint_topic parameter; a topic named either way must be in the bag)')
    r.add_argument('--no-mag', action='store_true', help='ignore the magnetometer (6-D filter)')
    _add_filter_options(r)
    r.add_argument('--copy-input', action='store_true',
                   help="also copy every input message to the output, but the input's own /imu/data and "
                   "/imu/gyro_bias (the replay's answers replace them; a warning names them)")
    r.add_argument('--overwrite', action='store_true', help='replace an existing output bag')
    r.add_argument('--storage', choices=STORAGES, default='mcap', help='output storage')
    r.set_defaults(func=cmd_replay)

    e = add('eval', 'score an orientation topic against a reference')
    e.add_argument('bag', help='bag holding the estimate')
    e.add_argument('--reference', required=True, help='reference topic (Imu, PoseStamped, QuaternionStamped, Odometry)')
    e.add_argument('--reference-bag', help='bag holding the reference (if not given: BAG)')
    e.add_argument('--estimate-topic', default='/imu/data', help='orientation topic to score')
    e.add_argument('--mask-topic', help='std_msgs/Bool topic: score only where true (BROAD: /ground_truth/moving)')
    e.add_argument('--json', metavar='FILE', help='write the figures as JSON')
    e.add_argument('--plot', metavar='FILE.png', help='plot roll/pitch/yaw of estimate and reference')
    e.add_argument('--overwrite', action='store_true', help='replace an existing --json or --plot file')
    e.set_defaults(func=cmd_eval)

    s = add('simulate', 'write a synthetic IMU + magnetometer + ground-truth bag')
    s.add_argument('-o', '--output', required=True, help='output rosbag2 directory')
    s.add_argument('--duration', type=float, default=60.0, help='duration, s')
    s.add_argument('--rate', type=float, default=286.0, help='IMU and magnetometer rate, Hz')
    s.add_argument('--seed', type=int, default=0, help='random seed (same seed, same bag)')
    s.add_argument('--motion', choices=('hand', 'vehicle', 'spin'), default='hand',
                   help='hand-held motion, a ground vehicle (accelerations and braking that last seconds, turns, '
                        'stops, slopes), or a ground robot spinning in place (a magnetometer calibration)')
    s.add_argument('--mag-offset-ut', type=float, nargs=3, metavar=('X', 'Y', 'Z'),
                   help='add this hard-iron offset (uT, body frame) to the magnetometer')
    s.add_argument('--overwrite', action='store_true', help='replace an existing output bag')
    s.add_argument('--storage', choices=STORAGES, default='mcap', help='output storage')
    s.set_defaults(func=cmd_simulate)

    pl = add('play', 'publish a bag over DDS at recorded timing (needs the ROS 2 wheels)')
    pl.add_argument('bag', help='rosbag2 directory or ROS 1 .bag')
    pl.add_argument('--rate', type=float, default=1.0, help='speed factor')
    pl.add_argument('--loop', action='store_true', help='start over at the end (the node resets on the jump back)')
    pl.add_argument('--topics', help='comma-separated topics to play (if not given: all with a ROS 2 type)')
    pl.add_argument('--clock', action='store_true', help='also publish /clock from the recording times')
    pl.add_argument('--wait-for-subscribers', type=float, default=5.0, metavar='S',
                    help='first wait up to S s until each topic has a subscriber: DDS drops what is sent before, and '
                    "the first samples are the ones a filter starts from (0: don't wait)")
    pl.add_argument('--qos-depth', type=int, default=1000, metavar='N',
                    help='history of each publisher (reliable, keep last N): a subscriber more than N messages behind '
                    'loses the oldest (default 1000)')
    pl.set_defaults(func=cmd_play)

    d = add('demo', 'simulate, filter, evaluate and plot: the main job on built-in data')
    d.add_argument('--output-dir', default=str(Path(tempfile.gettempdir()) / 'ccf_demo'), help='where bags and plot go')
    d.add_argument('--duration', type=float, default=60.0, help='simulated duration, s')
    d.add_argument('--seed', type=int, default=1, help='random seed of the simulation')
    d.add_argument('--offline-only', action='store_true', help='skip the live ccf_node run')
    d.add_argument('--live-rate', type=float, default=4.0, help='playback speed factor into the live node')
    d.set_defaults(func=cmd_demo)

    st = add('study', "reproduce the paper's experiments on bags with a reference: report.md, figures, JSON")
    st.add_argument('bags', nargs='+', help='bags with IMU, magnetometer and reference orientation (BROAD layout)')
    st.add_argument('-o', '--output', required=True, help='output directory')
    st.add_argument('--imu-topic', default='/imu/data_raw', help='sensor_msgs/Imu topic')
    st.add_argument('--mag-topic', help=MAG_TOPIC_HELP)
    st.add_argument('--reference', default='/ground_truth/pose', help='reference orientation topic')
    st.add_argument('--mask-topic', help="Bool topic: score only where true ('' = all; a topic given here must be in "
                    f'every bag; if not given: {DEFAULT_MASK_TOPIC} where a bag has it)')
    st.add_argument('--long-run-s', type=float, default=7200.0, help='simulated long run, s (0 = skip)')
    st.add_argument('--jobs', type=int, default=0, help='worker processes (0 = one per CPU)')
    st.add_argument('--no-lscf', action='store_true', help='skip the least-squares gain fits (no scipy needed)')
    st.add_argument('--lscf-iterations', type=int, default=8, help='least-squares iterations per fit')
    st.add_argument('--repetitions', type=int, default=20, help='timing repetitions (Fig 12)')
    st.add_argument('--bode-frequencies', type=int, default=7, help='measured frequencies per Bode case')
    st.add_argument('--overwrite', action='store_true', help='write into a non-empty output directory')
    st.add_argument('--quiet', action='store_true', help='no progress bars')
    st.set_defaults(func=cmd_study)

    magcal.add_parser(sub).formatter_class = HelpFormatter

    fl = add('fleet', 'filter, score and health-check many bags on Dask (local cores or an existing cluster)')
    fsub = fl.add_subparsers(dest='fleet_command', required=True, metavar='ACTION')
    fr = fsub.add_parser('run', help='process bags: results.jsonl, results.csv, report.md', formatter_class=HelpFormatter,
                         description='process bags: results.jsonl, results.csv, report.md (exit 0: all ok, 1: some '
                         'failed, 2: usage error or unreachable scheduler)')
    fr.add_argument('inputs', nargs='+', metavar='INPUT',
                    help='a bag (rosbag2 folder, .mcap, .db3, ROS 1 .bag), a folder searched recursively, or @LIST.txt '
                    '(one path per line)')
    fr.add_argument('-o', '--output', required=True, help='output folder (results, per-bag files, report)')
    fr.add_argument('-j', '--jobs', type=int, default=0, help='local worker processes (0: one per core)')
    fr.add_argument('--scheduler', metavar='tcp://HOST:PORT',
                    help='run on this Dask scheduler (if not given: DASK_SCHEDULER_ADDRESS, else a local cluster)')
    fr.add_argument('--imu-topic', help=IMU_TOPIC_HELP)
    fr.add_argument('--mag-topic', help=MAG_TOPIC_HELP)
    fr.add_argument('--no-mag', action='store_true', help='ignore the magnetometer (6-D filter)')
    _add_filter_options(fr)
    fr.add_argument('--write-bags', action='store_true', help="also write each bag's ccf replay output (OUT/bags/)")
    fr.add_argument('--reference', default='/ground_truth/pose',
                    help="reference orientation topic: bags that have it get ccf eval's accuracy ('' = none)")
    fr.add_argument('--mask-topic', default='/ground_truth/moving', help='Bool topic: score only where true, when present')
    fr.add_argument('--retry-failed', action='store_true', help='process the bags that failed before again')
    fr.add_argument('--force', action='store_true', help='process every bag again')
    fr.add_argument('--retries', type=int, default=2, help='retries of a bag whose task errs on a worker')
    fr.add_argument('--task-timeout', type=float, default=0.0, metavar='S',
                    help="a bag still running after S s fails (0: no limit; a timer ends it, wherever it is in Python "
                    'code, reading included)')
    fr.add_argument('--wait-workers', type=float, default=300.0, metavar='S',
                    help='on a cluster with no workers yet (adaptive dask-jobqueue, Kubernetes): wait up to S s for '
                    'the first one, then exit 2')
    fr.add_argument('--device', metavar='REGEX', help="report: group bags by REGEX's first group on the path (if not "
                    "given: the bag's parent folder)")
    fr.add_argument('--quiet', action='store_true', help='no progress bar')
    fr.set_defaults(func=cmd_fleet_run)
    fp = fsub.add_parser('report', help='write OUT/report.md (+ PNG) from OUT/results.jsonl', formatter_class=HelpFormatter)
    fp.add_argument('output', help='output folder of ccf fleet run')
    fp.add_argument('--device', metavar='REGEX', help="group bags by REGEX's first group on the path (if not given: "
                    "the bag's parent folder)")
    fp.set_defaults(func=cmd_fleet_report)

    pa = add('params', 'list every parameter with its default, unit and description')
    what = pa.add_mutually_exclusive_group()
    what.add_argument('--yaml', action='store_true', help='print config/ccf.yaml instead: every parameter as a '
                      'ROS 2 parameters file')
    what.add_argument('--filter', choices=sorted({k for k, _ in FILTERS}),
                      help='only what applies to this filter (if not given: everything)')
    pa.add_argument('--formulation', choices=sorted({f for _, f in FILTERS}),
                    help='with --filter ccf: quaternion or euler (if not given: the filter\'s default)')
    pa.set_defaults(func=cmd_params)

    for sp in [*sub.choices.values(), *fsub.choices.values()]:
        # Also after the subcommand (`ccf replay ... --debug`); SUPPRESS keeps `ccf --debug replay` working.
        sp.add_argument('--debug', action='store_true', default=argparse.SUPPRESS,
                        help='show the traceback of input errors too')
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run one ``ccf`` command; returns the exit code. An exception other than :class:`CcfError` propagates."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    args.argv = argv
    try:
        return int(args.func(args))
    except CcfError as err:
        if args.debug:
            raise
        message = ' '.join(str(err).split('\n'))
        print(f'ccf {args.command}: error: {message}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        if args.debug:
            traceback.print_exc()
        print(f'ccf {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
