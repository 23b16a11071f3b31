"""Run a bag through a live ``ccf_node`` process over loopback DDS and record its output (used by ``ccf demo``)."""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.quaternion import from_xyzw
from ..errors import CcfError
from .messages import seconds
from .play import load_messages, play


def isolate_dds() -> None:
    """Keep DDS on loopback and off the user's domain unless they chose one (the demo is self-contained)."""
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(100, 200)))


def node_command() -> list[str]:
    """The installed ``ccf_node`` next to this Python, else the module."""
    exe = shutil.which('ccf_node', path=str(Path(sys.executable).parent))
    return [exe] if exe else [sys.executable, '-m', 'ccf_ros.node']


@dataclass
class LiveResult:
    """Recorded ``imu/data``: stamps (N,) s, orientations (N, 4) [w, x, y, z]; inputs sent; node exit code."""

    t_s: np.ndarray
    quat: np.ndarray
    n_imu_sent: int
    exit_code: int | None
    diagnostics: dict[str, str] = field(default_factory=dict)


def run_live(bag: Path, rate: float = 4.0, timeout_s: float = 120.0, node_qos: str = 'reliable') -> LiveResult:
    """Start ``ccf_node``, play ``bag``'s IMU and magnetometer topics into it, record ``imu/data``, stop it.

    ``node_qos`` is the node's input reliability: ``reliable`` (nothing lost) or ``best_effort`` (its default).
    The last ``/diagnostics`` values of the node are returned too.
    """
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu

    isolate_dds()
    types, messages = load_messages(bag, ['/imu/data_raw', '/imu/mag'])
    n_imu = sum(1 for _, topic, _ in messages if topic == '/imu/data_raw')
    proc = subprocess.Popen(
        node_command() + ['--ros-args', '-p', f'qos_reliability:={node_qos}', '-p',
                          f'qos_depth:={10000 if node_qos == "reliable" else 50}', '--log-level', 'warn'],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('ccf_demo_recorder', context=ctx)
    received: list[tuple[float, tuple[float, float, float, float]]] = []

    def on_out(msg: Imu) -> None:
        s, o = msg.header.stamp, msg.orientation
        received.append((seconds(s.sec, s.nanosec), from_xyzw(o.x, o.y, o.z, o.w)))

    node.create_subscription(Imu, 'imu/data', on_out, QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE))
    diagnostics: dict[str, str] = {}

    def on_diag(msg: DiagnosticArray) -> None:
        for st in msg.status:
            if st.name.startswith('ccf_node'):
                diagnostics.clear()
                diagnostics.update({kv.key: kv.value for kv in st.values})
                level = st.level
                diagnostics['level'] = str(int.from_bytes(level, 'little') if isinstance(level, bytes) else int(level))
                diagnostics['message'] = st.message

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    spinning = threading.Event()
    spinning.set()

    def spin() -> None:
        while spinning.is_set():
            ex.spin_once(timeout_sec=0.05)

    th = threading.Thread(target=spin, daemon=True)
    th.start()
    exit_code = None
    try:
        deadline = time.time() + 30
        # Wait until the node is up and both directions are matched, so that nothing is sent into the void.
        while time.time() < deadline and (node.count_subscribers('imu/data_raw') == 0
                                          or node.count_publishers('imu/data') == 0):
            if proc.poll() is not None:
                detail = (proc.stderr.read() if proc.stderr else '').strip().splitlines()
                raise CcfError(f'ccf_node exited with code {proc.returncode}' + (f': {detail[-1]}' if detail else ''))
            time.sleep(0.05)
        # Both input topics matched (each on its own): a lost first magnetometer sample changes the initial heading.
        play(node, {'/imu/data_raw': types['/imu/data_raw'], '/imu/mag': types['/imu/mag']}, messages, rate=rate,
             qos_depth=10000, wait_matched_s=30.0)
        # Done when every sample is answered, or when nothing more arrives (skipped samples never will).
        deadline = time.time() + timeout_s
        last_n, quiet_since = -1, time.time()
        while len(received) < n_imu and time.time() < deadline and time.time() - quiet_since < 2.0:
            if len(received) != last_n:
                last_n, quiet_since = len(received), time.time()
            time.sleep(0.05)
        time.sleep(1.2)  # one more diagnostics period
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            exit_code = proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
        spinning.clear()
        th.join(timeout=5)
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    t = np.array([r[0] for r in received], dtype=float)
    q = np.array([r[1] for r in received], dtype=float).reshape(-1, 4)
    return LiveResult(t_s=t, quat=q, n_imu_sent=n_imu, exit_code=exit_code, diagnostics=dict(diagnostics))
