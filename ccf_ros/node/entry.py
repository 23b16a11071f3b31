"""The node's executables: ``ccf_node``, ``ccf_lifecycle_node`` and the imu_tools drop-ins (setup.py's entry points
name them through :mod:`ccf_ros.node`)."""

from __future__ import annotations

import re
import signal
import threading
from typing import Any

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.qos_overriding_options import InvalidQosOverridesError

from .executor import LeanExecutor
from .lifecycle import CcfLifecycleNode
from .node import CcfNode

RCLError = _rclpy.RCLError
UnknownROSArgsError = _rclpy.UnknownROSArgsError


def _is_startup_error(err: BaseException) -> bool:
    """An error in the user's start-up parameters (shown as one line), not a bug."""
    if isinstance(err, (ValueError, ParameterException, InvalidQosOverridesError)):
        return True
    # rclpy's QoS override of an unknown policy value (e.g. reliability: sometimes)
    return isinstance(err, RuntimeError) and str(err).startswith('Unexpected QoS override')


def _command_line_error(err: BaseException) -> str:
    """The reason ``rclpy.init`` refused the command line, in one line (rcl itself logs only "Failed to parse global
    arguments"): rcl's message without its source locations (and its "Error: error not set" when it has no more to
    say), or the unknown ROS arguments."""
    if isinstance(err, UnknownROSArgsError):
        return f'unknown ROS arguments: {err}'
    return re.sub(r', at \S+:\d+|\. Error: error not set', '', str(err))


class _StopSignal:
    """SIGINT/SIGTERM noted as a flag by a Python handler installed before ``rclpy.init`` (rclpy's own handler, which
    wakes the executor and shuts the context down, chains to it).

    Why not rclpy's default (Python's KeyboardInterrupt, or the context shut down): a KeyboardInterrupt is raised
    wherever the main thread runs Python next, and one raised inside a ``__del__`` (rclpy frees a ``Task`` with a
    ``__del__`` after each callback) is printed as "Exception ignored" and lost; the signal's wake-up of the wait can
    then come before rclpy's signal thread has shut the context down, and the executor waits again, for ever when
    nothing else wakes it (an unconfigured lifecycle node has no timer). A flag cannot be lost, and the spin loop
    looks at it after every wait, which is never longer than :attr:`LeanExecutor.MAX_WAIT_S`.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: int | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> _StopSignal:
        if threading.current_thread() is threading.main_thread():  # (signal handlers exist only there)
            self._previous = {sig: signal.signal(sig, self._note) for sig in self.SIGNALS}
        return self

    def _note(self, signum: int, _frame: Any) -> None:
        self.received = signum

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def main(args: list[str] | None = None, profile: str = 'ccf_node', lifecycle: bool = False) -> None:
    """Entry point of ``ccf_node`` / ``ros2 run ccf_ros ccf_node`` (and, with ``profile``, of the drop-ins; with
    ``lifecycle``, of ``ccf_lifecycle_node``). Exits 0 on SIGINT/SIGTERM at any stage after start-up began, 2 with
    one line on a command line or start-up parameter that is invalid."""
    node: CcfNode | None = None
    executor: LeanExecutor | None = None
    initialized = False
    with _StopSignal() as stop:
        try:
            rclpy.init(args=args)
            initialized = True
            # (A signal by now has shut the context down: nothing made on it could live; rclpy's entities made in
            # the moment it does fail, as below, with "Exception ignored" noise from their __del__.)
            if stop.received is None:
                executor = LeanExecutor()
                node = CcfLifecycleNode(profile) if lifecycle else CcfNode(profile)
                executor.add_node(node)
            while stop.received is None and executor is not None and executor.context.ok():
                executor.spin_once(executor.MAX_WAIT_S)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except Exception as err:
            if not initialized and isinstance(err, (RCLError, UnknownROSArgsError)):
                # rclpy.init refused the command line (a parameters file or -p value that does not parse, an unknown
                # argument); no signal can make it fail (rclpy's handlers come after it), and the context is not ok,
                # which the next test would take for a signal.
                print(f'{profile}: error: {_command_line_error(err)}', flush=True)
                raise SystemExit(2) from None
            if stop.received is not None or (isinstance(err, RCLError) and not rclpy.ok()):
                # A signal: rclpy's signal thread shuts the context down concurrently, and whatever rclpy did on it
                # at that moment (making the node, building a wait set) raised RCLError ('the given context is not
                # valid'); the same clean exit. An RCLError while the context is valid is a bug (below).
                pass
            elif node is not None or not _is_startup_error(err):
                # Only what the start-up raised is the user's parameters; an error while running is a bug.
                raise
            else:
                # Invalid parameters at start-up: one clear line, non-zero exit.
                print(f'{profile}: error: {err}', flush=True)
                raise SystemExit(2) from None
        finally:
            if initialized:
                stop_signal_thread()
            if executor is not None:
                executor.shutdown()  # (releases the handles it holds)
            if node is not None:
                node.destroy_node()
            _try_shutdown()


def stop_signal_thread() -> None:
    """Uninstall rclpy's signal handlers, which joins its signal thread, before anything is destroyed (what
    ``rclpy.shutdown()`` does; ``try_shutdown`` does not).

    On a signal that thread triggers the executors' signal guard conditions from a list it reads without a lock, then
    shuts the contexts down; the executor destroys its guard condition in ``shutdown``. When this loop woke first (its
    timer, a message) and saw the flag, the thread, still waiting for a core under load, triggered a guard condition
    already freed: SIGSEGV in ``rcl_trigger_guard_condition`` (exit -11, once in ~100 SIGINTs with three test suites
    beside it). Joined first, it has either finished or, woken by the teardown, stops without triggering."""
    from rclpy.signals import SignalHandlerOptions, get_current_signal_handlers_options, uninstall_signal_handlers

    if get_current_signal_handlers_options() != SignalHandlerOptions.NO:  # (again, it would set SIG_DFL a moment)
        uninstall_signal_handlers()


def _try_shutdown() -> None:
    """``rclpy.try_shutdown()``, when rclpy's signal thread may be shutting the context down at the same moment: its
    check (context ok) and its shutdown are two steps, and the thread's shutdown between them made it raise "rcl_shutdown
    already called" (exit 1 with a traceback, once in 80 SIGINTs under load)."""
    try:
        rclpy.try_shutdown()
    except RCLError:
        if rclpy.ok():
            raise
        rclpy.try_shutdown()  # (shut down meanwhile: now only drops the default context)


def lifecycle_main(args: list[str] | None = None) -> None:
    """Entry point of ``ccf_lifecycle_node``: ccf_node as a managed node (starts unconfigured)."""
    main(args, lifecycle=True)


def imu_filter_madgwick_main(args: list[str] | None = None) -> None:
    """Entry point of ``imu_filter_madgwick_node``: the ccf filter as imu_filter_madgwick presents itself."""
    main(args, 'imu_filter_madgwick_node')


def complementary_filter_main(args: list[str] | None = None) -> None:
    """Entry point of ``complementary_filter_node``: the ccf filter as imu_complementary_filter presents itself."""
    main(args, 'complementary_filter_node')


