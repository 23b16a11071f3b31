"""LeanExecutor (the executables' executor, ccf_ros.node.executor) over real rclpy on loopback: the node's answers as
replay's, services and timers served, entities made and destroyed at run time, async callbacks, and the wait set
kept across wake-ups."""

from __future__ import annotations

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from lifecycle_msgs.msg import Transition  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.task import Future  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from test_lifecycle import ACTIVE, INACTIVE, Manager, lifecycle_node  # noqa: E402
from test_node import Harness, _imu_only, _ref_xyzw, _replay_reference, _xyzw, reliable_node  # noqa: E402

from ccf_ros.node.executor import LeanExecutor  # noqa: E402


@pytest.fixture(scope='module')
def inputs(sim_bag):
    from rosutil import read_inputs

    return read_inputs(sim_bag, 4.0)


def _call(h, client, request, timeout_s=3.0):
    """The response, asked again when a request was lost while the service was still matching."""
    assert client.wait_for_service(timeout_sec=10)
    for _ in range(5):
        fut = client.call_async(request)
        h.ex.spin_until_future_complete(fut, timeout_sec=timeout_s)
        if fut.done():
            return fut.result()
        client.remove_pending_request(fut)
    raise AssertionError('no response')


def test_node_on_lean_executor_answers_as_replay_and_serves_services_and_timer(context, inputs):
    ex = LeanExecutor(context=context)
    node = reliable_node(context)
    h = Harness(context, node, executor=ex)
    try:
        h.wait_connected()
        h.spin_until(lambda: False, 0.1)
        builds = ex.n_builds
        assert builds >= 1
        h.feed(inputs, len(_imu_only(inputs)))
        np.testing.assert_array_equal(_xyzw(h.out), _ref_xyzw(_replay_reference(inputs)))
        assert len(h.out) > 1000
        # One wait set for the whole feed: nothing was made or destroyed, so it was never rebuilt.
        assert ex.n_builds == builds
        # The timer (diagnostics once a second) and the services (reset, parameters) are served.
        n_diag = len(h.diag)
        assert h.spin_until(lambda: len(h.diag) > n_diag, 3.0)
        from rcl_interfaces.srv import SetParameters

        req = SetParameters.Request(parameters=[Parameter('tau_acc_s', value=2.0).to_parameter_msg()])
        assert _call(h, h.io.create_client(SetParameters, '/ccf_node/set_parameters'), req).results[0].successful
        assert node.engine.filter.params.tau_acc_s == 2.0
        assert _call(h, h.io.create_client(Trigger, '/ccf_node/reset'), Trigger.Request()).success
        assert not node.engine.filter.initialized
    finally:
        h.close()


def test_lean_executor_follows_entities_made_and_destroyed_by_a_lifecycle_node(context, inputs):
    """activate (subscriptions, publishers, timer made in a service callback) -> messages answered; deactivate
    (destroyed) -> the subscription leaves the graph; activate again -> answered again."""
    ex = LeanExecutor(context=context)
    node = lifecycle_node(context)
    h = Harness(context, node, executor=ex)
    try:
        m = Manager(h)
        assert m.transition(Transition.TRANSITION_CONFIGURE) and m.transition(Transition.TRANSITION_ACTIVATE)
        assert m.state() == ACTIVE
        h.wait_connected()
        n_diag = len(h.diag)  # the timer, made in the activate service's callback, runs (diagnostics at 1 Hz)
        assert h.spin_until(lambda: len(h.diag) >= n_diag + 2, 10.0)
        h.feed(inputs[:400], 200)
        assert len(h.out) == 200
        assert m.transition(Transition.TRANSITION_DEACTIVATE) and m.state() == INACTIVE
        assert h.spin_until(lambda: h.io.count_subscribers('/imu/data_raw') == 0)
        assert m.transition(Transition.TRANSITION_ACTIVATE)
        h.wait_connected()
        h.feed(inputs[400:800], 400)
        assert len(h.out) == 400
        np.testing.assert_array_equal(_xyzw(h.out), _ref_xyzw(_replay_reference(inputs[:800])))
    finally:
        h.close()


def test_lean_executor_runs_async_callbacks_and_tasks(context):
    """A coroutine callback that waits for a future finishes once the future is done; create_task runs."""
    ex = LeanExecutor(context=context)
    node = rclpy.create_node('lean_async', context=context)
    ex.add_node(node)
    gate, done, ran = Future(), [], []

    async def on_msg(msg):
        value = await gate
        done.append((msg.data, value))

    node.create_subscription(String, 'lean_async', on_msg, 10)
    pub = node.create_publisher(String, 'lean_async', 10)
    try:
        for _ in range(200):  # (until the subscription matches the publisher)
            if pub.get_subscription_count():
                break
            ex.spin_once(0.05)
        pub.publish(String(data='x'))
        for _ in range(40):
            ex.spin_once(0.05)
        assert not done  # waiting for the gate
        ex.create_task(lambda: ran.append(1))
        gate.set_result(7)
        for _ in range(40):
            if done and ran:
                break
            ex.spin_once(0.05)
        assert done == [('x', 7)] and ran == [1]
    finally:
        ex.shutdown()
        node.destroy_node()


def _spin_until(ex, cond, n=50, timeout_s=0.1):
    for _ in range(n):
        if cond():
            return True
        ex.spin_once(timeout_s)
    return cond()


def test_lean_executor_runs_a_ready_guard_condition_when_a_callback_made_an_entity(context):
    """A timer and a guard condition ready in the same wait, the timer's callback makes a timer (the wait set is
    rebuilt before the guard's turn): the guard condition's callback still runs."""
    ex = LeanExecutor(context=context)
    node = rclpy.create_node('lean_guard', context=context)
    ex.add_node(node)
    guard_ran, made = [], []

    def on_timer():
        tmr.cancel()
        made.append(node.create_timer(10.0, lambda: None))

    tmr = node.create_timer(0.001, on_timer)
    gc = node.create_guard_condition(lambda: guard_ran.append(1))
    try:
        while tmr.time_until_next_call() > 0:  # (the timer ready before the wait)
            pass
        gc.trigger()
        ex.spin_once(1.0)
        assert made  # the timer ran first (timers before guard conditions) and made one
        assert _spin_until(ex, lambda: guard_ran)
    finally:
        ex.shutdown()
        node.destroy_node()


def test_lean_executor_spin_once_after_shutdown_returns(context):
    ex = LeanExecutor(context=context)
    node = rclpy.create_node('lean_after_shutdown', context=context)
    ex.add_node(node)
    try:
        ex.spin_once(0.01)
        assert ex.shutdown()
        ex.spin_once(0.01)  # returns (nothing to run), does not raise
        ex.spin()
    finally:
        node.destroy_node()


def test_lean_executor_shutdown_during_a_spin_keeps_the_handles_until_it_ends(context):
    """shutdown() while spin_once runs (here from a callback; from another thread it may be in the wait): the
    entities' handles stay held until that spin_once ends, then are released."""
    ex = LeanExecutor(context=context)
    node = rclpy.create_node('lean_shutdown_in_spin', context=context)
    ex.add_node(node)
    seen = []

    def on_timer():
        ex.shutdown()
        node.destroy_timer(tmr)
        seen.append(tmr.handle.pointer)

    tmr = node.create_timer(0.001, on_timer)
    try:
        assert _spin_until(ex, lambda: seen)
        assert seen[0] != 0  # still held (the spin_once was in progress)
        assert tmr.handle.pointer == 0  # released when it ended
    finally:
        node.destroy_node()


def test_lean_executor_releases_the_handles_when_building_the_wait_set_fails(context, monkeypatch):
    """rclpy's WaitSet raising (the context shut down meanwhile) leaves no handle held."""
    import types

    import ccf_ros.node.executor as executor_module

    ex = LeanExecutor(context=context)
    node = rclpy.create_node('lean_failed_build', context=context)
    ex.add_node(node)
    tmr = node.create_timer(10.0, lambda: None)
    real = executor_module._rclpy

    def failing_wait_set(*_args):
        raise real.RCLError('the context is shut down')

    monkeypatch.setattr(executor_module, '_rclpy', types.SimpleNamespace(WaitSet=failing_wait_set))
    try:
        with pytest.raises(real.RCLError):
            ex.spin_once(0.01)
        node.destroy_timer(tmr)
        assert tmr.handle.pointer == 0  # freed at once: not held by the wait set that failed
    finally:
        monkeypatch.undo()
        ex.shutdown()
        node.destroy_node()


def test_lean_executor_follows_a_subscription_callback_replaced_at_run_time(context):
    """``sub.callback = f`` (rclpy's setter), here to a callback that also takes the message info: f gets the next
    message."""
    ex = LeanExecutor(context=context)
    node = rclpy.create_node('lean_callback', context=context)
    ex.add_node(node)
    first, second = [], []
    sub = node.create_subscription(String, 'lean_callback', lambda msg: first.append(msg.data), 10)
    pub = node.create_publisher(String, 'lean_callback', 10)
    try:
        assert _spin_until(ex, lambda: pub.get_subscription_count(), 200, 0.05)
        pub.publish(String(data='a'))
        assert _spin_until(ex, lambda: first)
        sub.callback = lambda msg, info: second.append((msg.data, info['publication_sequence_number'] > 0))
        pub.publish(String(data='b'))
        assert _spin_until(ex, lambda: second)
        assert first == ['a'] and second == [('b', True)]
    finally:
        ex.shutdown()
        node.destroy_node()


def test_lean_executor_frees_an_entity_destroyed_between_spins(context):
    """The wait set holds the entities' handles: one destroyed while the executor is not spinning is freed at once
    (not kept alive until the next spin_once)."""
    ex = LeanExecutor(context=context)
    node = rclpy.create_node('lean_destroyed', context=context)
    ex.add_node(node)
    tmr = node.create_timer(10.0, lambda: None)
    try:
        ex.spin_once(0.01)
        ex.spin_once(0.01)  # (the wait set built and kept)
        node.destroy_timer(tmr)
        assert tmr.handle.pointer == 0
    finally:
        ex.shutdown()
        node.destroy_node()
