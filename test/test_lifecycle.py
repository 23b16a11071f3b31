"""ccf_lifecycle_node: the lifecycle transitions driven over DDS through the standard lifecycle_msgs services
(ChangeState, GetState) from a client node, in process and as the installed executable."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from lifecycle_msgs.msg import State, Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosutil import stop_node  # noqa: E402
from test_node import Harness, _ref_xyzw, _replay_reference, _xyzw  # noqa: E402

from ccf_ros.node import CcfLifecycleNode  # noqa: E402

UNCONFIGURED, INACTIVE, ACTIVE, FINALIZED = (State.PRIMARY_STATE_UNCONFIGURED, State.PRIMARY_STATE_INACTIVE,
                                             State.PRIMARY_STATE_ACTIVE, State.PRIMARY_STATE_FINALIZED)
SHUTDOWN_FROM = {UNCONFIGURED: Transition.TRANSITION_UNCONFIGURED_SHUTDOWN,
                 INACTIVE: Transition.TRANSITION_INACTIVE_SHUTDOWN, ACTIVE: Transition.TRANSITION_ACTIVE_SHUTDOWN}

#: The primary state each transition leads to.
TARGET = {Transition.TRANSITION_CONFIGURE: INACTIVE, Transition.TRANSITION_ACTIVATE: ACTIVE,
          Transition.TRANSITION_DEACTIVATE: INACTIVE, Transition.TRANSITION_CLEANUP: UNCONFIGURED,
          **dict.fromkeys(SHUTDOWN_FROM.values(), FINALIZED)}


@pytest.fixture(scope='module')
def inputs(sim_bag):
    from rosutil import read_inputs

    return read_inputs(sim_bag, 3.0)


class Manager:
    """A lifecycle manager's view: the node's ChangeState/GetState services, called from the harness' client node."""

    def __init__(self, h: Harness, name: str = '/ccf_node'):
        self.h = h
        self.change = h.io.create_client(ChangeState, f'{name}/change_state')
        self.get = h.io.create_client(GetState, f'{name}/get_state')
        assert self.change.wait_for_service(timeout_sec=20) and self.get.wait_for_service(timeout_sec=20)

    def _call(self, client, request, timeout_s=3.0):
        """The response, or None when none came within ``timeout_s``: a request sent just after wait_for_service
        can be lost while the server's side of the service is still matching the client (DDS discovery is not
        symmetric), most often on a loaded machine."""
        fut = client.call_async(request)
        self.h.ex.spin_until_future_complete(fut, timeout_sec=timeout_s)
        if not fut.done():
            client.remove_pending_request(fut)
            return None
        return fut.result()

    def state(self) -> int:
        for _ in range(10):  # GetState is idempotent: asked again until answered
            r = self._call(self.get, GetState.Request())
            if r is not None:
                return r.current_state.id
        raise AssertionError('GetState did not answer')

    def transition(self, transition_id: int) -> bool:
        """Request a transition; True if it succeeded. Unanswered: the state says whether it happened (the
        response lost) or not (the request lost: sent again)."""
        req = ChangeState.Request()
        req.transition.id = transition_id
        for _ in range(5):
            r = self._call(self.change, req)
            if r is not None:
                return r.success
            if self.state() == TARGET[transition_id]:
                return True
        raise AssertionError('ChangeState did not answer')


def lifecycle_node(context, **params):
    overrides = [Parameter('qos_reliability', value='reliable'), Parameter('qos_depth', value=5000)]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    return CcfLifecycleNode(context=context, parameter_overrides=overrides)


def _count_subscribers(h: Harness) -> int:
    return h.io.count_subscribers('/imu/data_raw')


def test_lifecycle_transitions_over_dds(context, inputs):
    """unconfigured -> inactive -> active (answers as replay) -> inactive (no subscription) -> active (the estimate
    kept) -> cleanup (state dropped); a bad parameter fails configure, the node stays unconfigured."""
    node = lifecycle_node(context, tau_acc_s=0.0)  # invalid: configure must fail
    h = Harness(context, node)
    try:
        m = Manager(h)
        assert m.state() == UNCONFIGURED and not node.is_open
        assert not m.transition(Transition.TRANSITION_CONFIGURE)
        assert m.state() == UNCONFIGURED
        node.set_parameters([Parameter('tau_acc_s', value=1.0)])  # not checked while unconfigured
        assert m.transition(Transition.TRANSITION_CONFIGURE) and m.state() == INACTIVE
        assert node.engine.filter.params.tau_acc_s == 1.0
        assert _count_subscribers(h) == 0 and not node.is_open
        # Configured but inactive: parameters are checked live again.
        assert not node.set_parameters([Parameter('tau_acc_s', value=-1.0)])[0].successful

        assert m.transition(Transition.TRANSITION_ACTIVATE) and m.state() == ACTIVE
        h.wait_connected()
        first, second = inputs[:600], inputs[600:1200]
        h.feed(first, 300)
        assert len(h.out) == 300

        assert m.transition(Transition.TRANSITION_DEACTIVATE) and m.state() == INACTIVE
        assert not node.is_open
        assert h.spin_until(lambda: _count_subscribers(h) == 0), 'subscriptions not destroyed on deactivate'
        assert h.spin_until(lambda: h.io.count_publishers('/imu/data') == 0)

        assert m.transition(Transition.TRANSITION_ACTIVATE) and m.state() == ACTIVE
        h.wait_connected()
        h.feed(second, 600)
        assert len(h.out) == 600
        ref = _replay_reference(first + second, {'tau_acc_s': 1.0})
        np.testing.assert_array_equal(_xyzw(h.out), _ref_xyzw(ref))  # the estimate went on across deactivation

        assert m.transition(Transition.TRANSITION_DEACTIVATE) and m.transition(Transition.TRANSITION_CLEANUP)
        assert m.state() == UNCONFIGURED and not node.engine.filter.initialized
        assert m.transition(Transition.TRANSITION_UNCONFIGURED_SHUTDOWN) and m.state() == FINALIZED
    finally:
        h.close()


def test_a_start_up_value_rclpy_refuses_fails_configure_until_it_is_set(context):
    """Out of the declared range, rclpy refuses the value when configure declares the parameter: the parameter is
    declared with its default all the same, so that it can be set (it was left undeclared, and every configure
    failed), and configure fails until it is (not run with the default)."""
    node = lifecycle_node(context, tau_acc_s=-1.0)
    h = Harness(context, node)
    try:
        m = Manager(h)
        assert not m.transition(Transition.TRANSITION_CONFIGURE)
        assert not m.transition(Transition.TRANSITION_CONFIGURE) and m.state() == UNCONFIGURED
        assert not node.set_parameters([Parameter('tau_acc_s', value=-2.0)])[0].successful  # (rclpy's range)
        assert not m.transition(Transition.TRANSITION_CONFIGURE)
        assert node.set_parameters([Parameter('tau_acc_s', value=2.0)])[0].successful
        assert m.transition(Transition.TRANSITION_CONFIGURE) and m.state() == INACTIVE
        assert node.engine.filter.params.tau_acc_s == 2.0
    finally:
        h.close()


@pytest.mark.parametrize('start', [UNCONFIGURED, INACTIVE, ACTIVE])
def test_shutdown_from_every_state(context, inputs, start):
    node = lifecycle_node(context)
    h = Harness(context, node)
    try:
        m = Manager(h)
        if start != UNCONFIGURED:
            assert m.transition(Transition.TRANSITION_CONFIGURE)
        if start == ACTIVE:
            assert m.transition(Transition.TRANSITION_ACTIVATE)
            h.wait_connected()
            h.feed(inputs[:200], 100)
        assert m.state() == start
        assert m.transition(SHUTDOWN_FROM[start]) and m.state() == FINALIZED
        assert not node.is_open
        assert h.spin_until(lambda: _count_subscribers(h) == 0)
        assert not list(node.subscriptions)
        assert not {p.topic_name for p in node.publishers} & {'/imu/data', '/imu/gyro_bias', '/diagnostics'}
    finally:
        h.close()


@pytest.mark.parametrize('start', [UNCONFIGURED, ACTIVE])
def test_installed_lifecycle_node_exits_cleanly_on_sigint(context, inputs, start):
    # The installed console script itself (setup.py's entry point), not a stand-in: a missing one fails here.
    exe = shutil.which('ccf_lifecycle_node', path=str(Path(sys.executable).parent))
    assert exe is not None, f'ccf_lifecycle_node is not installed beside {sys.executable} (pip install -e .)'
    proc = subprocess.Popen([exe, '--ros-args', '-p', 'qos_reliability:=reliable', '-p', 'qos_depth:=5000'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    h = Harness(context, None)
    try:
        m = Manager(h)
        if start == ACTIVE:
            assert m.transition(Transition.TRANSITION_CONFIGURE) and m.transition(Transition.TRANSITION_ACTIVATE)
            h.wait_connected(timeout=20)
            h.feed(inputs[:400], 200)
            assert len(h.out) == 200
        assert m.state() == start
    finally:
        stop_node(proc, h)


def test_launch_file_starts_the_lifecycle_node_on_lifecycle_true():
    """launch_ros is not in the pip install: the file is checked for what it launches under which condition."""
    import ast

    tree = ast.parse((Path(__file__).resolve().parents[1] / 'launch' / 'ccf.launch.py').read_text())
    calls = {n.func.id: n for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    args = [c.args[0].value for c in ast.walk(tree) if isinstance(c, ast.Call)
            and getattr(c.func, 'id', '') == 'DeclareLaunchArgument']
    assert 'lifecycle' in args
    for action, executable, condition in (('Node', 'ccf_node', 'UnlessCondition'),
                                          ('LifecycleNode', 'ccf_lifecycle_node', 'IfCondition')):
        kw = {k.arg: k.value for k in calls[action].keywords if k.arg}
        assert kw['executable'].value == executable
        assert kw['condition'].func.id == condition
    setup = (Path(__file__).resolve().parents[1] / 'setup.py').read_text()
    assert "'ccf_lifecycle_node = ccf_ros.node:lifecycle_main'" in setup


def test_component_launch_file_starts_the_plain_drop_in():
    """launch/imu_filter_component.launch.py (for users of imu_tools' component launch file) includes
    imu_filter.launch.py, the plain imu_filter_madgwick_node, and loads no component container."""
    import ast

    text = (Path(__file__).resolve().parents[1] / 'launch' / 'imu_filter_component.launch.py').read_text()
    tree = ast.parse(text)
    names = {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    assert 'IncludeLaunchDescription' in names and 'ComposableNodeContainer' not in names
    assert "'imu_filter.launch.py'" in text


#: Runs a node's entry point with SIGINT sent to itself at one stage (argv[1]); argv[2]: 'lifecycle' or 'plain'.
_SIGINT_AT = r'''
import os, signal, sys
import rclpy
import ccf_ros.node.entry as entry
from ccf_ros.node.node import CcfNode

stage, kind = sys.argv[1], sys.argv[2]
def kill():
    os.kill(os.getpid(), signal.SIGINT)
if stage == 'after_init':  # rclpy's handlers installed, no node yet
    real_init = rclpy.init
    def init(*args, **kwargs):
        real_init(*args, **kwargs)
        kill()
    rclpy.init = init
elif stage == 'constructing':  # as the node is being made: rclpy shuts the context down under it
    real_init_profile = CcfNode._init_profile
    def init_profile(self, profile):
        kill()
        return real_init_profile(self, profile)
    CcfNode._init_profile = init_profile
elif stage == 'in_del':
    # The signal is handled inside a __del__ (as when rclpy frees a callback's Task) while rclpy's own signal
    # handling does nothing (as when its signal thread runs late: the context stays up, no wake-up comes).
    from rclpy.signals import SignalHandlerOptions
    real_init = rclpy.init
    rclpy.init = lambda args=None: real_init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    class Freed:
        def __del__(self):
            kill()
            len(())  # a call: the pending signal's Python handler runs here, inside __del__
    real_timer = CcfNode._on_timer
    def on_timer(self):
        Freed()
        return real_timer(self)
    CcfNode._on_timer = on_timer
elif stage == 'shutdown_race':
    # SIGINT once running; rclpy's signal thread shuts the context down between try_shutdown's check and its
    # shutdown (emulated: rclpy's own handling off, the check sees the context as it was a moment before).
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    real_init = rclpy.init
    rclpy.init = lambda args=None: real_init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    real_timer = CcfNode._on_timer
    def on_timer(self):
        kill()
        return real_timer(self)
    CcfNode._on_timer = on_timer
    real_try_shutdown = Context.try_shutdown
    def try_shutdown(self):
        real = self._Context__context
        if real is None or not real.ok():
            return real_try_shutdown(self)
        real.shutdown()  # the signal thread, just after the check below
        class Seen:
            def __enter__(self):
                return real.__enter__()
            def __exit__(self, *exc):
                return real.__exit__(*exc)
            def ok(self):
                return True
            def shutdown(self):
                return real.shutdown()
        self._Context__context = Seen()
        try:
            real_try_shutdown(self)
        finally:
            self._Context__context = real
    Context.try_shutdown = try_shutdown
elif stage == 'signal_thread':
    # SIGINT while the node's loop is awake (its timer): it sees the flag at once, while rclpy's signal thread may
    # not have run yet. That thread triggers the executors' signal guard conditions from a list it reads without a
    # lock: one freed before it is stopped is a use after free (SIGSEGV, seen once in ~100 SIGINTs under load).
    from rclpy.signals import SignalHandlerGuardCondition, SignalHandlerOptions, get_current_signal_handlers_options
    real_destroy = SignalHandlerGuardCondition.destroy
    def destroy(self):
        if get_current_signal_handlers_options() != SignalHandlerOptions.NO:
            print('signal guard condition freed while the signal thread runs', flush=True)
        return real_destroy(self)
    SignalHandlerGuardCondition.destroy = destroy
    real_timer = CcfNode._on_timer
    def on_timer(self):
        kill()
        return real_timer(self)
    CcfNode._on_timer = on_timer
print('stage', stage, flush=True)
entry.main([], lifecycle=kind == 'lifecycle')
print('exited', flush=True)
'''


@pytest.mark.parametrize(('stage', 'kind'), [('after_init', 'lifecycle'), ('constructing', 'plain'),
                                             ('constructing', 'lifecycle'), ('in_del', 'plain'),
                                             ('shutdown_race', 'plain'), ('signal_thread', 'plain')])
def test_sigint_at_any_stage_exits_cleanly(stage, kind):
    """SIGINT right after rclpy.init, while the node is being made, handled inside a __del__ while rclpy's signal
    thread has not (yet) shut the context down, and shutting the context down while the node does: exit code 0, no
    traceback, within the wait bound. (in_del: the node used to run on, its KeyboardInterrupt printed as ignored and
    lost; shutdown_race: it exited 1 with "rcl_shutdown already called"; signal_thread: rclpy's signal thread was
    still installed when the executor freed the guard condition it triggers, SIGSEGV when it ran late.)"""
    proc = subprocess.run([sys.executable, '-c', _SIGINT_AT, stage, kind], capture_output=True, text=True,
                          timeout=60)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert 'Traceback' not in out and 'Exception ignored' not in out, out
    assert 'exited' in proc.stdout, out
    assert 'while the signal thread runs' not in out, out
