"""The imu_tools drop-in, scripted acceptance check: imu_tools' own parameters files on ccf_ros' compatibility
executables, run as installed (subprocesses, DDS on loopback), a bag played into them, ``imu/data`` recorded.

1. ``imu_filter_madgwick_node`` renamed ``imu_filter`` with imu_filter_madgwick's own ``config/imu_filter.yaml``
   (test/data, verbatim) plus a second file: ``mag_bias_x/y/z`` = a hard-iron offset of (30, -12, 8) µT that this
   script adds to the bag's magnetometer, ``yaw_offset`` 0.3, ``declination`` 0.1, ``remove_gravity_vector`` true.
   Checks: every parameter of the files declared with the file's value (and imu_filter_madgwick's read-only flags);
   every input answered; the output is the clean ``ccf replay`` of the unmodified bag (same imu_filter.yaml) turned
   by yaw_offset - declination = 0.2 rad about world up: RMSE(node vs reference turned by 0.2 rad) <= 1.5 x
   RMSE(clean replay vs reference) (BROAD's total error over the moving samples); median |linear_acceleration|
   <= 1 m/s² (gravity removed).
2. ``complementary_filter_node`` renamed ``complementary_filter_gain_node`` with imu_complementary_filter's own
   ``config/filter_config.yaml`` (use_mag false, QoS overrides reliable depth 10; no yaw turn, no gravity removal):
   parameters declared with the file's values, every input answered, the QoS override in effect.

The bag: the shared BROAD trial 02_undisturbed_slow_rotation_B, or a simulated one (60 s) where ../shared is absent.
Input QoS: the Madgwick executable gets ``-p qos_reliability:=reliable -p qos_depth:=10000`` on top of the files (its
default is best effort, as imu_filter_madgwick's sensor-data QoS: over a played bag a dropped message would be DDS's,
not the node's, and "every input answered" checks the node); the complementary filter keeps its file's QoS
(reliable, depth 10), so its bag is played at a pace its queue of 10 keeps up with.

Usage: python checks/imu_tools_dropin.py [--rate 4] [--complementary-rate 1] [--bag BAG]
(sets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; uses ROS_DOMAIN_ID if set, else a free domain of 215-232, locked for the run)
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from ccf_ros.domains import own_domain

os.environ['ROS_DOMAIN_ID'] = str(own_domain())

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'test'))

import numpy as np  # noqa: E402
from conftest import TRIAL, with_mag_distortion  # noqa: E402

from ccf_ros.core.metrics import summarize  # noqa: E402
from ccf_ros.core.quaternion import quat_mul  # noqa: E402
from ccf_ros.offline.bagio import read_bools, read_orientations  # noqa: E402
from ccf_ros.offline.evaluate import align, mask_at  # noqa: E402
from ccf_ros.offline.live import Recorder, stop  # noqa: E402
from ccf_ros.offline.params_file import load_params_file, load_params_files  # noqa: E402
from ccf_ros.offline.play import load_messages, play  # noqa: E402

DATA = ROOT / 'test' / 'data'
MADGWICK_YAML = DATA / 'imu_filter.yaml'
COMPLEMENTARY_YAML = DATA / 'filter_config.yaml'
#: The hard-iron offset added to the magnetometer, T.
HARD_IRON_T = (30e-6, -12e-6, 8e-6)
YAW_OFFSET, DECLINATION = 0.3, 0.1
TURN = YAW_OFFSET - DECLINATION
#: imu_filter_madgwick's read-only parameters (Jazzy) and its dynamic ones.
MADGWICK_READ_ONLY = {'stateless', 'use_mag', 'publish_tf', 'reverse_tf', 'fixed_frame', 'constant_dt',
                      'remove_gravity_vector', 'publish_debug_topics', 'yaw_offset', 'declination', 'world_frame'}
MADGWICK_DYNAMIC = {'gain', 'zeta', 'mag_bias_x', 'mag_bias_y', 'mag_bias_z', 'orientation_stddev'}
IMU, MAG = '/imu/data_raw', '/imu/mag'


def executable(name: str, func: str) -> list[str]:
    """The installed console script next to this Python, else the entry point through the module."""
    exe = shutil.which(name, path=str(Path(sys.executable).parent))
    return [exe] if exe else [sys.executable, '-c', f'from ccf_ros.node import {func}; {func}()']


@dataclass
class Run:
    """What one node run gave: recorded imu/data, the node's parameters as it reports them, its log."""

    n_sent: int
    t_s: np.ndarray
    quat: np.ndarray  # (N, 4) [w, x, y, z]
    lin_acc: np.ndarray  # (N, 3)
    params: dict[str, object]
    read_only: dict[str, bool]
    sub_reliability: str
    diagnostics: dict[str, str]
    log: str
    exit_code: int | None
    wall_s: float
    extra: dict[str, object] = field(default_factory=dict)


def run_node(cmd: list[str], node_name: str, bag: Path, topics: list[str], rate: float,
             param_names: list[str]) -> Run:
    """Start the node, play ``topics`` of ``bag`` into it, record imu/data, ask for its parameters, stop it."""
    from rclpy.parameter import parameter_value_to_python
    from rclpy.parameter_client import AsyncParameterClient

    types, messages = load_messages(bag, topics)
    n_imu = sum(1 for _, topic, _ in messages if topic == IMU)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    log_lines: list[str] = []
    reader = threading.Thread(target=lambda: log_lines.extend(proc.stdout or []), daemon=True)
    reader.start()

    def wait(future, timeout: float = 10.0):
        deadline = time.time() + timeout
        while not future.done() and time.time() < deadline:
            time.sleep(0.01)
        return future.result()

    params: dict[str, object] = {}
    read_only: dict[str, bool] = {}
    reliability = '?'
    exit_code = None
    t0 = time.time()
    with Recorder('dropin_check', node_name) as rec:
        try:
            client = AsyncParameterClient(rec.node, node_name)
            if not client.wait_for_services(timeout_sec=30):
                raise RuntimeError(f'{node_name} did not come up: {"".join(log_lines)[-2000:]}')
            listed = set(wait(client.list_parameters([], 0)).result.names)
            names = [n for n in param_names if n in listed]  # the others are not declared
            got = wait(client.get_parameters(names))
            params = {n: parameter_value_to_python(v) for n, v in zip(names, got.values, strict=True)}
            described = wait(client.describe_parameters(names))
            read_only = {d.name: d.read_only for d in described.descriptors}
            deadline = time.time() + 30
            while time.time() < deadline and not rec.node.get_subscriptions_info_by_topic(IMU):
                time.sleep(0.05)
            infos = rec.node.get_subscriptions_info_by_topic(IMU)
            reliability = ','.join(sorted({i.qos_profile.reliability.name.lower() for i in infos}))
            play(rec.node, {t: types[t] for t in topics}, messages, rate=rate, qos_depth=10000, wait_matched_s=30.0)
            rec.wait_answered(n_imu, 120.0, quiet_s=3.0)
        finally:
            exit_code = stop(proc)
            reader.join(timeout=5)
    t, q, lin = rec.arrays()
    return Run(
        n_sent=n_imu, t_s=t, quat=q, lin_acc=lin,
        params=params, read_only=read_only, sub_reliability=reliability, diagnostics=dict(rec.diagnostics),
        log=''.join(log_lines), exit_code=exit_code, wall_s=time.time() - t0,
    )


def total_rmse_deg(t_est: np.ndarray, q_est: np.ndarray, bag: Path, turn: float = 0.0) -> float:
    """BROAD's total error RMSE (deg) over the moving samples of ``bag``'s reference, turned by ``turn`` rad about
    world up."""
    t_ref, q_ref = read_orientations(bag, '/ground_truth/pose')
    q_ref = quat_mul([math.cos(turn / 2), 0.0, 0.0, math.sin(turn / 2)], q_ref)
    mask = mask_at(t_ref, *read_bools(bag, '/ground_truth/moving'))
    return summarize(align(t_est, q_est, t_ref, q_ref), q_ref, mask).total_rmse_deg


def angle_deg(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    return np.degrees(2.0 * np.arccos(np.clip(np.abs(np.sum(q1 * q2, axis=1)), 0.0, 1.0)))


def imu_stamps(bag: Path) -> np.ndarray:
    """Header stamps (s) of the bag's IMU messages."""
    from ccf_ros.messages.cdr import read_imu

    _, messages = load_messages(bag, [IMU])
    return np.array([read_imu(raw)[0] for _, _, raw in messages])


def simulated_bag(tmp: Path) -> Path:
    from ccf_ros.cli import main as ccf

    path = tmp / 'sim'
    assert ccf(['simulate', '-o', str(path), '--duration', '60', '--rate', '286', '--seed', '11']) == 0
    return path


def with_hard_iron(src: Path, dst: Path) -> Path:
    return with_mag_distortion(src, dst, HARD_IRON_T, topic=MAG)


class Table:
    def __init__(self) -> None:
        self.rows: list[tuple[str, str, str, bool | None]] = []

    def add(self, check: str, measured: object, target: str, ok: bool | None) -> None:
        self.rows.append((check, str(measured), target, ok))

    def print(self, title: str) -> bool:
        w = [max(len(r[i]) for r in self.rows + [('check', 'measured', 'target', None)]) for i in range(3)]
        print(f'\n{title}')
        print(f'  {"check":<{w[0]}}  {"measured":<{w[1]}}  {"target":<{w[2]}}  result')
        print('  ' + '-' * (sum(w) + 12))
        for check, measured, target, ok in self.rows:
            verdict = '' if ok is None else ('PASS' if ok else 'FAIL')
            print(f'  {check:<{w[0]}}  {measured:<{w[1]}}  {target:<{w[2]}}  {verdict}')
        return all(ok is not False for *_, ok in self.rows)


def check_params(table: Table, run: Run, expected: dict[str, object], read_only: dict[str, bool],
                 undeclared: set[str] | None = None) -> None:
    undeclared = undeclared or set()
    wanted = {k: v for k, v in expected.items() if k not in undeclared}
    wrong = {k: (run.params.get(k, '<not declared>'), v) for k, v in wanted.items() if run.params.get(k) != v}
    table.add('parameters of the files declared with their values', f'{len(wanted) - len(wrong)}/{len(wanted)}',
              'all', not wrong)
    for k, (got, want) in wrong.items():
        table.add(f'  {k}', got, repr(want), False)
    if undeclared:
        not_there = sorted(k for k in undeclared if k not in run.params)
        table.add('  not declared (no imu/mag subscription: use_mag false, as the anchor)', len(not_there),
                  f'{len(undeclared)}', len(not_there) == len(undeclared))
    bad_ro = {k: run.read_only.get(k) for k, ro in read_only.items() if run.read_only.get(k) is not ro}
    table.add("read-only flags as the anchor's", f'{len(read_only) - len(bad_ro)}/{len(read_only)}', 'all',
              not bad_ro)
    for k, v in bad_ro.items():
        table.add(f'  {k}', v, str(read_only[k]), False)


def check_answered(table: Table, run: Run, t_in: np.ndarray) -> None:
    table.add('inputs answered (imu/data messages / IMU messages sent)', f'{len(run.t_s)}/{run.n_sent}', 'all',
              len(run.t_s) == run.n_sent)
    same = len(run.t_s) == len(t_in) and np.array_equal(np.sort(run.t_s), np.sort(t_in))
    table.add('  output stamps = input stamps', same, 'True', same)
    d = run.diagnostics
    table.add('  node diagnostics: samples in / answered / lost upstream',
              f'{d.get("samples in")} / {d.get("samples answered")} / {d.get("messages lost upstream (estimated)")}',
              '', None)
    table.add('  node exit code (SIGINT)', run.exit_code, '0', run.exit_code == 0)


def true_linear_acceleration(bag: Path, t_s: np.ndarray) -> np.ndarray:
    """``(N, 3)`` specific force minus gravity (9.80665 m/s², up) in the IMU frame by the reference orientation, at
    the stamps ``t_s`` (NaN where the reference has none)."""
    from ccf_ros.core.quaternion import quat_conj, quat_rotate
    from ccf_ros.messages.cdr import read_imu

    _, messages = load_messages(bag, [IMU])
    acc = {t: a for t, _, _, a in (read_imu(raw) for _, _, raw in messages)}
    t_ref, q_ref = read_orientations(bag, '/ground_truth/pose')
    q = align(t_ref, q_ref, t_s, q_ref)  # the reference resampled at the output stamps
    g = quat_rotate(quat_conj(q), np.array([0.0, 0.0, 9.80665]))
    return np.array([acc.get(t, (np.nan,) * 3) for t in t_s]).reshape(-1, 3) - g


def madgwick(bag: Path, tmp: Path, rate: float, simulated: bool) -> bool:
    from ccf_ros.cli import main as ccf
    from ccf_ros.node import TF_UNAVAILABLE, tf_message_type

    extra = tmp / 'offsets.yaml'
    # Exponents with a dot (3.000000e-05): YAML 1.1 readers (PyYAML) take 3e-05 for a string.
    extra.write_text('imu_filter:\n  ros__parameters:\n'
                     f'    mag_bias_x: {HARD_IRON_T[0]:.6e}\n    mag_bias_y: {HARD_IRON_T[1]:.6e}\n'
                     f'    mag_bias_z: {HARD_IRON_T[2]:.6e}\n    yaw_offset: {YAW_OFFSET}\n'
                     f'    declination: {DECLINATION}\n    remove_gravity_vector: true\n')
    expected = load_params_files([MADGWICK_YAML, extra])
    # The clean reference: ccf replay of the unmodified bag with imu_tools' file (no offsets).
    clean_out = tmp / 'clean_replay'
    assert ccf(['replay', str(bag), '-o', str(clean_out), '--params-file', str(MADGWICK_YAML)]) == 0
    t_clean, q_clean = read_orientations(clean_out, '/imu/data')
    modified = with_hard_iron(bag, tmp / 'hard_iron')
    cmd = executable('imu_filter_madgwick_node', 'imu_filter_madgwick_main') + [
        '--ros-args', '-r', '__node:=imu_filter', '--params-file', str(MADGWICK_YAML), '--params-file', str(extra),
        '-p', 'qos_reliability:=reliable', '-p', 'qos_depth:=10000']
    print('$ ' + ' '.join(cmd))
    run = run_node(cmd, 'imu_filter', modified, [IMU, MAG], rate,
                   sorted(set(expected) | MADGWICK_READ_ONLY | MADGWICK_DYNAMIC))
    table = Table()
    check_params(table, run, expected, {k: k in MADGWICK_READ_ONLY for k in MADGWICK_READ_ONLY | MADGWICK_DYNAMIC})
    check_answered(table, run, imu_stamps(modified))
    rmse_clean = total_rmse_deg(t_clean, q_clean, bag)
    rmse_node = total_rmse_deg(run.t_s, run.quat, bag, TURN)
    rmse_node_unturned = total_rmse_deg(run.t_s, run.quat, bag)
    table.add('RMSE clean ccf replay vs reference (deg)', f'{rmse_clean:.3f}', '', None)
    table.add('RMSE node vs reference turned by 0.2 rad (deg)', f'{rmse_node:.3f}',
              f'<= 1.5 x {rmse_clean:.3f} = {1.5 * rmse_clean:.3f}', rmse_node <= 1.5 * rmse_clean)
    table.add('  (node vs the unturned reference, deg)', f'{rmse_node_unturned:.3f}', '', None)
    if len(run.t_s) == len(t_clean):
        order = np.argsort(run.t_s, kind='stable')
        turned = quat_mul([math.cos(TURN / 2), 0.0, 0.0, math.sin(TURN / 2)], q_clean[np.argsort(t_clean)])
        diff = angle_deg(run.quat[order], turned)
        table.add('node vs clean replay turned by 0.2 rad: max / median angle (deg)',
                  f'{diff.max():.2e} / {np.median(diff):.2e}', '', None)
    lin = np.linalg.norm(run.lin_acc, axis=1) if len(run.lin_acc) else np.array([np.nan])
    true_lin = true_linear_acceleration(modified, run.t_s)
    if simulated:
        # The simulated hand-held motion has metres per second squared of true linear acceleration: compared below.
        table.add('median |linear_acceleration| (m/s^2; simulated motion: the true one is '
                  f'{np.median(np.linalg.norm(true_lin, axis=1)):.2f})', f'{np.median(lin):.3f}', '', None)
    else:
        table.add('median |linear_acceleration| (m/s^2)', f'{np.median(lin):.3f}', '<= 1',
                  bool(np.median(lin) <= 1.0))
    # Where the reference has a pose (BROAD's cameras lose the marker now and then: NaN).
    err = np.nanmedian(np.linalg.norm(run.lin_acc - true_lin, axis=1)) if len(run.lin_acc) else np.nan
    table.add('  median |linear_acceleration - (acc - gravity by the reference)| (m/s^2)', f'{err:.3f}', '<= 1',
              bool(err <= 1.0))
    if tf_message_type() is None:
        n_warn = run.log.count(TF_UNAVAILABLE)
        table.add('publish_tf true, tf2_msgs absent: warnings', n_warn, '1', n_warn == 1)
    table.add('wall time of the run (s)', f'{run.wall_s:.0f}', '', None)
    return table.print(f'imu_filter_madgwick_node as imu_filter, imu_filter.yaml + offsets, bag {bag.name} '
                       f'played at {rate:g}x')


def complementary(bag: Path, tmp: Path, rate: float) -> bool:
    expected = load_params_file(COMPLEMENTARY_YAML)
    mag_keys = {k for k in expected if k.startswith('qos_overrides./imu/mag.')}
    cmd = executable('complementary_filter_node', 'complementary_filter_main') + [
        '--ros-args', '-r', '__node:=complementary_filter_gain_node', '--params-file', str(COMPLEMENTARY_YAML)]
    print('$ ' + ' '.join(cmd))
    read_only = {'fixed_frame': True, 'use_mag': True, 'publish_tf': True, 'reverse_tf': True, 'constant_dt': True,
                 'publish_debug_topics': True, 'gain_acc': True, 'gain_mag': True, 'do_bias_estimation': True,
                 'bias_alpha': True, 'do_adaptive_gain': True, 'orientation_stddev': False}
    run = run_node(cmd, 'complementary_filter_gain_node', bag, [IMU], rate, sorted(set(expected) | set(read_only)))
    table = Table()
    check_params(table, run, expected, read_only, mag_keys)
    depth = run.params.get('qos_overrides./imu/data_raw.subscription.depth')
    table.add('QoS override of /imu/data_raw: reliability as DDS sees it, depth', f'{run.sub_reliability}, {depth}',
              'reliable, 10', run.sub_reliability == 'reliable' and depth == 10)
    check_answered(table, run, imu_stamps(bag))
    table.add('wall time of the run (s)', f'{run.wall_s:.0f}', '', None)
    return table.print(f'complementary_filter_node as complementary_filter_gain_node, filter_config.yaml, bag '
                       f'{bag.name} (IMU only) played at {rate:g}x')


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--rate', type=float, default=4.0, help='play rate of the Madgwick run (x recorded time)')
    ap.add_argument('--complementary-rate', type=float, default=1.0, help='play rate of the complementary run')
    ap.add_argument('--bag', type=Path, help='bag to use instead of the shared BROAD trial')
    ap.add_argument('--simulated', action='store_true', help='--bag is a `ccf simulate` bag (strong motion)')
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix='imu_tools_dropin_'))
    bag = args.bag or (TRIAL if TRIAL.exists() else None)
    simulated = args.simulated
    if bag is None:
        print(f'{TRIAL} not found: a simulated bag instead')
        bag, simulated = simulated_bag(tmp), True
    print(f'ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; bag {bag}')
    ok = madgwick(bag, tmp, args.rate, simulated)
    ok = complementary(bag, tmp, args.complementary_rate) and ok
    print(f'\n{"ALL CHECKS PASS" if ok else "SOME CHECKS FAIL"}')
    shutil.rmtree(tmp, ignore_errors=True)
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
