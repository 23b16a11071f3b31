"""Run a bag through a live ``ccf_node`` process over loopback DDS and record its output (used by ``ccf demo``)."""

from __future__ import annotations

import contextlib
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
from ..domains import own_domain
from ..errors import CcfError
from ..messages.convert import seconds
from .play import load_messages, play


def isolate_dds() -> None:
    """Keep DDS on loopback and off the user's domain unless they chose one (the demo is self-contained)."""
    own_domain()


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


class Recorder:
    """A node of its own DDS context that records ``imu/data`` and a node's ``/diagnostics`` while it spins in a
    thread; use as a context manager (``with Recorder(...) as rec:``).

    Attributes:
        received: ``(stamp s, orientation [w, x, y, z], linear_acceleration m/s²)`` per ``imu/data`` message.
        diagnostics: the last diagnostics values of the node whose status name starts with ``diagnostics_of``, with
            ``level`` and ``message``.
    """

    def __init__(self, name: str, diagnostics_of: str) -> None:
        self._name = name
        self._prefix = diagnostics_of
        self.received: list[tuple[float, tuple[float, float, float, float], tuple[float, float, float]]] = []
        self.diagnostics: dict[str, str] = {}
        #: diagnostics messages of the node received so far
        self.n_diagnostics = 0

    def __enter__(self) -> Recorder:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
        from rclpy.impl.implementation_singleton import rclpy_implementation
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Imu

        RCLError = rclpy_implementation.RCLError

        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node(self._name, context=self.ctx)

        def on_out(msg: Imu) -> None:
            s, o, a = msg.header.stamp, msg.orientation, msg.linear_acceleration
            self.received.append((seconds(s.sec, s.nanosec), from_xyzw(o.x, o.y, o.z, o.w), (a.x, a.y, a.z)))

        def on_diag(msg: DiagnosticArray) -> None:
            for st in msg.status:
                if st.name.startswith(self._prefix):
                    self.diagnostics.clear()
                    self.diagnostics.update({kv.key: kv.value for kv in st.values})
                    level = st.level
                    self.diagnostics['level'] = str(int.from_bytes(level, 'little') if isinstance(level, bytes)
                                                    else int(level))
                    self.diagnostics['message'] = st.message
                    self.n_diagnostics += 1

        self.node.create_subscription(Imu, 'imu/data', on_out,
                                      QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE))
        self.node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
        self._ex = SingleThreadedExecutor(context=self.ctx)
        self._ex.add_node(self.node)
        self._spinning = threading.Event()
        self._spinning.set()

        def spin() -> None:
            try:
                while self._spinning.is_set():
                    self._ex.spin_once(timeout_sec=0.05)
            except ExternalShutdownException:
                pass  # SIGINT: rclpy's signal thread shut the context down; the main thread ends the run
            except RCLError:
                if self.ctx.ok():
                    raise

        self._thread = threading.Thread(target=spin, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        import rclpy

        self._spinning.clear()
        self._thread.join(timeout=5)
        self._ex.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)

    def wait_answered(self, n: int, timeout_s: float, quiet_s: float = 2.0, n_mag: int = 0) -> None:
        """Until ``n`` outputs arrived, or ``timeout_s`` passed, or the node's diagnostics say it answered ``n`` (or
        more) samples and nothing new came for ``quiet_s`` (the rest was lost on the way); then until its diagnostics
        count ``n_mag`` magnetometer samples in (or the count stays the same over three diagnostics messages: lost on
        the way); then until the next diagnostics message (the values returned describe the end of the run).

        Not "nothing new for ``quiet_s``" alone: on a loaded machine the node can stall longer than that. The
        magnetometer too: a topic stalled under load delivers its backlog after the last IMU sample is answered (seen:
        313 samples), and diagnostics read before it is in do not describe the end of the run."""
        deadline = time.time() + timeout_s
        last_n, quiet_since = -1, time.time()
        while len(self.received) < n and time.time() < deadline:
            if len(self.received) != last_n:
                last_n, quiet_since = len(self.received), time.time()
            elif time.time() - quiet_since > quiet_s and (
                    int(self.diagnostics.get('samples answered', -1)) >= n or time.time() - quiet_since > 10 * quiet_s):
                break  # answered and lost on the way, or (10 x quiet_s) samples the node could not answer
            time.sleep(0.05)
        last_mag, same, seen = -1, 0, self.n_diagnostics
        while n_mag and time.time() < deadline:
            got = int(self.diagnostics.get('magnetometer samples in', -1))
            if got >= n_mag:
                break
            if self.n_diagnostics != seen:
                seen = self.n_diagnostics
                same = same + 1 if got == last_mag else 0
                last_mag = got
                if same >= 3:
                    break
            time.sleep(0.05)
        n_diag = self.n_diagnostics
        end = time.time() + 5.0
        while self.n_diagnostics == n_diag and time.time() < end:
            time.sleep(0.05)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stamps ``(N,)`` s, orientations ``(N, 4)``, linear accelerations ``(N, 3)`` received."""
        r = self.received
        return (np.array([x[0] for x in r], dtype=float), np.array([x[1] for x in r], dtype=float).reshape(-1, 4),
                np.array([x[2] for x in r], dtype=float).reshape(-1, 3))


def stop(proc: subprocess.Popen[str]) -> int | None:
    """SIGINT a node process and wait for it (kill after 20 s); its exit code, None if it had to be killed."""
    proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        return None


def run_live(bag: Path, rate: float = 4.0, timeout_s: float = 120.0, node_qos: str = 'reliable',
             node_log: Path | None = None) -> LiveResult:
    """Start ``ccf_node``, play ``bag``'s IMU and magnetometer topics into it, record ``imu/data``, stop it.

    ``node_qos`` is the node's input reliability: ``reliable`` (nothing lost) or ``best_effort`` (its default).
    The last ``/diagnostics`` values of the node are returned too. ``node_log``: the node's log goes to this file,
    its own logger at debug level (e.g. its late magnetometer samples), else warnings only.
    """
    isolate_dds()
    types, messages = load_messages(bag, ['/imu/data_raw', '/imu/mag'])
    n_imu = sum(1 for _, topic, _ in messages if topic == '/imu/data_raw')
    n_mag = sum(1 for _, topic, _ in messages if topic == '/imu/mag')
    levels = ['--log-level', 'warn'] + (['--log-level', 'ccf_node:=debug'] if node_log is not None else [])
    with contextlib.ExitStack() as cleanup:  # the log is closed and the node stopped whatever fails on the way
        log = cleanup.enter_context(Path(node_log).open('w')) if node_log is not None else None
        proc = subprocess.Popen(
            [*node_command(), '--ros-args', '-p', f'qos_reliability:={node_qos}', '-p',
             f'qos_depth:={10000 if node_qos == "reliable" else 50}', *levels],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE if log is None else log, text=True,
        )
        stopped: list[int | None] = []
        cleanup.callback(lambda: stopped or stop(proc))
        rec = cleanup.enter_context(Recorder('ccf_demo_recorder', 'ccf_node'))
        try:
            deadline = time.time() + 30
            # Wait until the node is up and both directions are matched, so that nothing is sent into the void.
            while time.time() < deadline and (rec.node.count_subscribers('imu/data_raw') == 0
                                              or rec.node.count_publishers('imu/data') == 0):
                if proc.poll() is not None:
                    detail = (proc.stderr.read() if proc.stderr else Path(node_log).read_text() if node_log is not None
                              else '').strip().splitlines()
                    raise CcfError(f'ccf_node exited with code {proc.returncode}'
                                   + (f': {detail[-1]}' if detail else ''))
                time.sleep(0.05)
            # Both input topics matched (each on its own): a lost first magnetometer sample changes the heading.
            play(rec.node, {'/imu/data_raw': types['/imu/data_raw'], '/imu/mag': types['/imu/mag']}, messages,
                 rate=rate, qos_depth=10000, wait_matched_s=30.0)
            # Done when every sample is answered, or when nothing more arrives.
            rec.wait_answered(n_imu, timeout_s, n_mag=n_mag)
        finally:
            stopped.append(stop(proc))
        exit_code = stopped[0]
    t, q, _ = rec.arrays()
    return LiveResult(t_s=t, quat=q, n_imu_sent=n_imu, exit_code=exit_code, diagnostics=dict(rec.diagnostics))
