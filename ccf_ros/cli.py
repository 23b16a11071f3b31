"""``ccf``: offline tools on recorded bags, no ROS install needed.

Subcommands: replay, eval, simulate, play, demo. Errors are one line on stderr and exit code 2; Ctrl-C exits 130.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

from .offline.bagio import BagError


def _settings(args: argparse.Namespace) -> dict[str, Any]:
    from .offline.params_file import load_params_file, parse_assignments

    settings: dict[str, Any] = {}
    if getattr(args, 'params_file', None):
        settings.update(load_params_file(args.params_file))
    settings.update(parse_assignments(getattr(args, 'param', None) or []))
    if getattr(args, 'no_mag', False):
        settings['use_mag'] = False
    return settings


def _engine(args: argparse.Namespace) -> Any:
    from .engine import ImuEngine
    from .settings import build

    settings = _settings(args)
    # A parameters file holds every parameter; only names given on the command line must apply.
    filt, adapter = build(settings, strict=not getattr(args, 'params_file', None))
    return ImuEngine(filt, adapter)


def cmd_replay(args: argparse.Namespace) -> int:
    from .offline.replay import replay

    engine = _engine(args)
    summary = replay(
        args.bag,
        args.output,
        engine,
        imu_topic=args.imu_topic,
        mag_topic=None if args.no_mag else args.mag_topic,
        storage=args.storage,
        copy_input=args.copy_input,
        overwrite=args.overwrite,
    )
    print(f'wrote {args.output}: {summary.line()}')
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from .offline.evaluate import evaluate, format_summary, load_aligned

    aligned = load_aligned(
        args.bag,
        args.reference,
        reference_bag=args.reference_bag,
        estimate_topic=args.estimate_topic,
        mask_topic=args.mask_topic,
    )
    s = evaluate(aligned)
    print(format_summary(s, args.estimate_topic))
    if args.json:
        Path(args.json).write_text(json.dumps(s.as_dict(), indent=2))
    if args.plot:
        from .offline.plot import plot_rpy

        plot_rpy(args.plot, aligned.t_s, aligned.q_ref, {args.estimate_topic: aligned.q_est}, title=str(args.bag))
        print(f'plot: {args.plot}')
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    from .offline.simulate import generate, write_bag

    data = generate(args.duration, args.rate, args.seed)
    write_bag(data, args.output, overwrite=args.overwrite, storage=args.storage)
    print(f'wrote {args.output}: {len(data.t_s)} samples, {args.duration:g} s at {args.rate:g} Hz, seed {args.seed}')
    return 0


def cmd_play(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from tqdm import tqdm

    from .offline.play import load_messages, play

    topics = [t for t in (args.topics or '').split(',') if t] or None
    types, messages = load_messages(args.bag, topics)
    print(f'playing {len(messages)} messages on {len(types)} topics at {args.rate:g}x' + (' (loop)' if args.loop else ''))
    rclpy.init()
    node = rclpy.create_node('ccf_play')
    bar = tqdm(total=None if args.loop else len(messages), unit='msg', disable=None, mininterval=0.5)
    try:
        n = play(node, types, messages, rate=args.rate, loop=args.loop, clock=args.clock,
                 should_stop=lambda: not rclpy.ok(), progress=bar.update)
    except (KeyboardInterrupt, ExternalShutdownException):
        n = bar.n
    finally:
        bar.close()
        node.destroy_node()
        rclpy.try_shutdown()
    print(f'published {n} messages')
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from .offline.demo import run_demo

    return run_demo(Path(args.output_dir), duration_s=args.duration, seed=args.seed, live=not args.offline_only,
                    live_rate=args.live_rate)


def cmd_study(args: argparse.Namespace) -> int:
    from .study.datasets import Topics
    from .study.report import write_report
    from .study.run import StudyOptions, run_study

    out = Path(args.output)
    if out.exists() and any(out.iterdir()) and not args.overwrite:
        raise ValueError(f'{out} exists and is not empty (use --overwrite)')
    for bag in args.bags:
        if not Path(bag).exists():
            raise BagError(f'{bag}: no such bag')
    opts = StudyOptions(
        long_run_s=args.long_run_s,
        jobs=args.jobs,
        lscf=not args.no_lscf,
        lscf_iterations=args.lscf_iterations,
        repetitions=args.repetitions,
        bode_frequencies=args.bode_frequencies,
    )
    topics = Topics(args.imu_topic, args.mag_topic, args.reference, args.mask_topic or None)
    results = run_study(args.bags, opts, topics=topics, progress=not args.quiet)
    command = 'ccf study ' + ' '.join(sys.argv[2:]) if len(sys.argv) > 2 else ''
    summary = write_report(results, out, command)
    for v in summary['verdicts']:
        print(f'claim {v["claim"]} ({v["formulation"]}): {v["verdict"]}')
    print(f'report: {out / "report.md"}  ({len(summary["figures"])} figures, results.json; '
          f'{results["wall_time_s"] / 60:.1f} min)')
    return 0


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    p = argparse.ArgumentParser(prog='ccf', description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--version', action='version', version=f'ccf_ros {__version__}')
    sub = p.add_subparsers(dest='command', required=True, metavar='COMMAND')

    r = sub.add_parser('replay', help='run the filter over a bag, write /imu/data and /imu/gyro_bias to a new bag')
    r.add_argument('bag', help='input: rosbag2 directory (mcap or sqlite3) or ROS 1 .bag')
    r.add_argument('-o', '--output', required=True, help='output rosbag2 directory')
    r.add_argument('--imu-topic', default='/imu/data_raw')
    r.add_argument('--mag-topic', default='/imu/mag')
    r.add_argument('--no-mag', action='store_true', help='ignore the magnetometer (6-D filter)')
    r.add_argument('--params-file', help='ROS 2 parameters YAML, as for the node (config/ccf.yaml)')
    r.add_argument('--param', action='append', metavar='NAME=VALUE', help='set one parameter (repeatable)')
    r.add_argument('--copy-input', action='store_true', help='also copy every input message to the output')
    r.add_argument('--overwrite', action='store_true', help='replace an existing output bag')
    r.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap')
    r.set_defaults(func=cmd_replay)

    e = sub.add_parser('eval', help='score an orientation topic against a reference')
    e.add_argument('bag', help='bag holding the estimate')
    e.add_argument('--reference', required=True, help='reference topic (Imu, PoseStamped, QuaternionStamped, Odometry)')
    e.add_argument('--reference-bag', help='bag holding the reference (default: BAG)')
    e.add_argument('--estimate-topic', default='/imu/data')
    e.add_argument('--mask-topic', help='std_msgs/Bool topic: score only where true (BROAD: /ground_truth/moving)')
    e.add_argument('--json', metavar='FILE', help='write the figures as JSON')
    e.add_argument('--plot', metavar='FILE.png', help='plot roll/pitch/yaw of estimate and reference')
    e.set_defaults(func=cmd_eval)

    s = sub.add_parser('simulate', help='write a synthetic IMU + magnetometer + ground-truth bag')
    s.add_argument('-o', '--output', required=True)
    s.add_argument('--duration', type=float, default=60.0, help='s (default 60)')
    s.add_argument('--rate', type=float, default=286.0, help='Hz (default 286)')
    s.add_argument('--seed', type=int, default=0)
    s.add_argument('--overwrite', action='store_true')
    s.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap')
    s.set_defaults(func=cmd_simulate)

    pl = sub.add_parser('play', help='publish a bag over DDS at recorded timing (needs the ROS 2 wheels)')
    pl.add_argument('bag')
    pl.add_argument('--rate', type=float, default=1.0, help='speed factor (default 1.0)')
    pl.add_argument('--loop', action='store_true', help='start over at the end (the node resets on the jump back)')
    pl.add_argument('--topics', help='comma-separated topics to play (default all)')
    pl.add_argument('--clock', action='store_true', help='also publish /clock from the recording times')
    pl.set_defaults(func=cmd_play)

    d = sub.add_parser('demo', help='simulate, filter, evaluate and plot: the main job on built-in data')
    d.add_argument('--output-dir', default=str(Path(tempfile.gettempdir()) / 'ccf_demo'))
    d.add_argument('--duration', type=float, default=60.0)
    d.add_argument('--seed', type=int, default=1)
    d.add_argument('--offline-only', action='store_true', help='skip the live ccf_node run')
    d.add_argument('--live-rate', type=float, default=4.0, help='playback speed into the live node (default 4x)')
    d.set_defaults(func=cmd_demo)
    st = sub.add_parser('study', help="reproduce the paper's experiments on bags with a reference: report.md, figures, JSON")
    st.add_argument('bags', nargs='+', help='bags with IMU, magnetometer and reference orientation (BROAD layout)')
    st.add_argument('-o', '--output', required=True, help='output directory')
    st.add_argument('--imu-topic', default='/imu/data_raw')
    st.add_argument('--mag-topic', default='/imu/mag')
    st.add_argument('--reference', default='/ground_truth/pose', help='reference orientation topic')
    st.add_argument('--mask-topic', default='/ground_truth/moving', help="Bool topic: score only where true ('' = all)")
    st.add_argument('--long-run-s', type=float, default=7200.0, help='simulated long run, s (default 7200; 0 = skip)')
    st.add_argument('--jobs', type=int, default=0, help='worker processes (default: CPUs)')
    st.add_argument('--no-lscf', action='store_true', help='skip the least-squares gain fits (no scipy needed)')
    st.add_argument('--lscf-iterations', type=int, default=8)
    st.add_argument('--repetitions', type=int, default=20, help='timing repetitions (Fig 12)')
    st.add_argument('--bode-frequencies', type=int, default=7, help='measured frequencies per Bode case')
    st.add_argument('--overwrite', action='store_true')
    st.add_argument('--quiet', action='store_true', help='no progress bars')
    st.set_defaults(func=cmd_study)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except (BagError, ValueError) as err:
        print(f'ccf {args.command}: error: {err}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'ccf {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
