"""The executor of the node's executables: rclpy's single-threaded executor without its per-wake-up rebuild.

rclpy's ``SingleThreadedExecutor`` rebuilds its wait set in Python on every wake-up (every entity filtered, entered,
counted and added, a new ``WaitSet``), wraps every callback in a ``Task`` and, after each one, triggers its own
guard condition twice, which makes the next wait return at once only to rebuild again: ~2.2 wake-ups and as many
rebuilds per message pair at 200 Hz. :class:`LeanExecutor` keeps one wait set and the entities' handles for as long
as the entities do not change (rclpy's ``Node`` wakes its executor on every entity made or destroyed, and this
executor rebuilds then), refills it per wake-up with one C call per entity, and runs the ready callbacks in place
(the order rclpy uses: waitables, then timers, subscriptions, guard conditions, clients, services). Single-threaded;
callback groups are not consulted (one thread never runs two callbacks at once). Coroutine callbacks run as
``Task`` s as in rclpy. The wait set holds the entities' handles (as rclpy's does during a wait), so an entity
destroyed is freed when the wait set is let go: at once between spins, at the end of the ``spin_once`` running
otherwise (and :meth:`~LeanExecutor.shutdown` during a ``spin_once`` leaves the release to it).
"""

from __future__ import annotations

import inspect
import threading
from contextlib import ExitStack, suppress
from typing import Any

from rclpy.exceptions import InvalidHandle
from rclpy.executors import Executor, ExternalShutdownException, TimeoutObject
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.subscription import Subscription
from rclpy.task import Task
from rclpy.waitable import NumberOfEntities

_MESSAGE_ONLY = Subscription.CallbackType.MessageOnly


class _WaitSet:
    """One wait set and what is in it, the handles held (entered) so that none is freed while it is there."""

    def __init__(self, executor: LeanExecutor) -> None:
        self.stack = ExitStack()
        try:
            self._build(executor)
        except BaseException:
            self.close()  # (e.g. the context shut down meanwhile: the handles entered so far are released)
            raise

    def _build(self, executor: LeanExecutor) -> None:
        subs: list[Any] = []
        timers: list[Any] = []
        clients: list[Any] = []
        services: list[Any] = []
        guards: list[Any] = []
        waitables: list[Any] = []
        for node in executor.get_nodes():
            subs += node.subscriptions
            timers += node.timers
            clients += node.clients
            services += node.services
            guards += node.guards
            waitables += node.waitables
        #: (the callback is read at each message: rclpy's setter may replace it, and its kind, at run time)
        self.subs = [(s.handle, s.handle.pointer, s, s.msg_type, s.raw) for s in subs if self._enter(s.handle)]
        self.timers = [(t.handle, t.handle.pointer, t) for t in timers if self._enter(t.handle)]
        self.clients = [(c.handle, c.handle.pointer, c) for c in clients if self._enter(c.handle)]
        self.services = [(s.handle, s.handle.pointer, s) for s in services if self._enter(s.handle)]
        #: the nodes' guard conditions (with callbacks), then the executor's two (wake-up, signal)
        self.guards = [(g.handle, g.handle.pointer, g) for g in guards if self._enter(g.handle)]
        own = [g.handle for g in (executor._guard, executor._sigint_gc) if g is not None and self._enter(g.handle)]
        self.waitables = [w for w in waitables if self._enter(w)]
        self.stack.enter_context(executor.context.handle)  # type: ignore[arg-type]
        n = NumberOfEntities(len(self.subs), len(self.guards) + len(own), len(self.timers), len(self.clients),
                             len(self.services))
        for w in self.waitables:
            n += w.get_num_entities()
        self.wait_set = _rclpy.WaitSet(n.num_subscriptions, n.num_guard_conditions, n.num_timers, n.num_clients,
                                       n.num_services, n.num_events, executor.context.handle)
        self.sub_handles = [s[0] for s in self.subs]
        self.timer_handles = [t[0] for t in self.timers]
        self.client_handles = [c[0] for c in self.clients]
        self.service_handles = [s[0] for s in self.services]
        self.guard_handles = [g[0] for g in self.guards] + own

    def _enter(self, handle: Any) -> bool:
        """Hold ``handle`` (a destroyed entity's is left out)."""
        try:
            self.stack.enter_context(handle)
        except InvalidHandle:
            return False
        return True

    def close(self) -> None:
        """Release the handles (an entity destroyed meanwhile is freed now)."""
        self.wait_set = None
        self.stack.close()


class LeanExecutor(Executor):
    """A single-threaded executor that rebuilds its wait set only when the entities change (module docstring)."""

    #: Longest single wait, s: the loop looks at the context at least this often, whatever woke it or not.
    MAX_WAIT_S = 1.0
    #: (rclpy's ``Executor.__del__`` reads it: set here for an executor whose ``__init__`` failed before setting it,
    #: e.g. made just as a signal shut the context down)
    _sigint_gc: Any = None

    def __init__(self, *, context: Any = None) -> None:
        super().__init__(context=context)
        self._ws: _WaitSet | None = None
        #: the entities may have changed since the wait set was built
        self._stale = True
        self.n_builds = 0
        #: a spin_once is running (guarded by ``_spin_lock``): shutdown then leaves the release of the held handles
        #: to it, as its wait may be on them
        self._spinning = False
        self._spin_lock = threading.Lock()

    # rclpy calls these (and Node its executor's wake()) whenever a node or an entity is added or removed.
    def wake(self) -> None:
        self._stale = True
        with self._spin_lock:
            if not self._spinning:  # (an entity destroyed between spins is freed now, not at the next spin)
                self._release()
        super().wake()

    def add_node(self, node: Any) -> bool:
        self._stale = True
        return super().add_node(node)

    def remove_node(self, node: Any) -> None:
        self._stale = True
        super().remove_node(node)

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        # The handles are let go here when no spin_once runs (before rclpy destroys the executor's guard conditions,
        # as ever), else by that spin_once once its wait (woken by rclpy's shutdown) has returned; and again after,
        # for a spin_once that ended meanwhile.
        with self._spin_lock:
            if not self._spinning:
                self._release()
        done = super().shutdown(timeout_sec)
        with self._spin_lock:
            if not self._spinning:
                self._release()
        return done

    def spin(self) -> None:
        """Run callbacks until the context is shut down (a signal) or :meth:`shutdown`."""
        while self._context.ok() and not self._is_shutdown:
            self.spin_once(self.MAX_WAIT_S)

    def spin_once_until_future_complete(self, future: Any, timeout_sec: float | TimeoutObject | None = None) -> None:
        """:meth:`spin_once`, woken when ``future`` is done (for ``spin_until_future_complete``)."""
        future.add_done_callback(lambda _f: self._guard.trigger() if self._guard else None)
        self.spin_once(timeout_sec.timeout if isinstance(timeout_sec, TimeoutObject) else timeout_sec)

    def spin_once(self, timeout_sec: float | None = None) -> None:
        """Wait up to ``timeout_sec`` (None: no limit) and run every callback that is ready (nothing once shut
        down)."""
        with self._spin_lock:
            if self._is_shutdown:
                self._release()
                return
            self._spinning = True
        try:
            self._spin_once(timeout_sec)
        finally:
            with self._spin_lock:
                self._spinning = False
                # shutdown from another thread or a callback left the release here; an entity destroyed in this
                # spin is freed now, not at the next one
                if self._is_shutdown or self._stale:
                    self._release()

    def _spin_once(self, timeout_sec: float | None) -> None:
        if self._tasks:
            self._run_tasks()
        if self._stale or self._ws is None:
            self._release()
            self._stale = False
            self._ws = _WaitSet(self)
            self.n_builds += 1
            if self._is_shutdown:  # (meanwhile: the executor's guard conditions may be gone)
                return
        c = self._ws
        ws = c.wait_set
        ws.clear_entities()
        for h in c.sub_handles:
            ws.add_subscription(h)
        for h in c.timer_handles:
            ws.add_timer(h)
        for h in c.client_handles:
            ws.add_client(h)
        for h in c.service_handles:
            ws.add_service(h)
        for h in c.guard_handles:
            ws.add_guard_condition(h)
        for w in c.waitables:
            w.add_to_wait_set(ws)
        ws.wait(-1 if timeout_sec is None or timeout_sec < 0 else round(timeout_sec * 1e9))
        if self._is_shutdown:
            return
        if not self._context.ok():
            raise ExternalShutdownException()
        if self._stale:
            # Entities were made or destroyed (in another thread): rebuild first; what is ready stays ready (a
            # node's guard condition that fired is triggered again).
            self._rearm(c, ws, 0)
            return
        self._dispatch(c, ws)

    def _dispatch(self, c: _WaitSet, ws: Any) -> None:
        """Run the ready callbacks; stop when one of them made or destroyed an entity (the rest stay ready: a
        subscription, timer, client or service is ready again in the next wait, a guard condition is re-armed)."""
        if ((c.waitables and self._waitables(c, ws)) or (c.timers and self._timers(c, ws))
                or (c.subs and self._subscriptions(c, ws))):
            self._rearm(c, ws, 0)
            return
        if c.guards or c.clients or c.services:
            self._guards_clients_services(c, ws)

    @staticmethod
    def _rearm(c: _WaitSet, ws: Any, start: int) -> None:
        """Trigger again the nodes' guard conditions from ``start`` on that were ready in this wait (a guard
        condition is ready once per trigger: one whose callback has not run would be lost in the rebuild)."""
        if len(c.guards) > start:
            ready = ws.get_ready_entities('guard_condition')
            for _, ptr, gc in c.guards[start:]:
                if ptr in ready:
                    with suppress(InvalidHandle):  # (destroyed meanwhile)
                        gc.trigger()

    def _waitables(self, c: _WaitSet, ws: Any) -> bool:
        for w in c.waitables:
            if w.is_ready(ws):
                self._run(w.execute(w.take_data()))
                if self._stale:
                    return True
        return False

    def _timers(self, c: _WaitSet, ws: Any) -> bool:
        ready = ws.get_ready_entities('timer')
        for h, ptr, tmr in c.timers:
            if ptr in ready and h.is_timer_ready():
                h.call_timer()
                self._run(tmr.callback())
                if self._stale:
                    return True
        return False

    def _subscriptions(self, c: _WaitSet, ws: Any) -> bool:
        ready = ws.get_ready_entities('subscription')
        for h, ptr, sub, msg_type, raw in c.subs:
            if ptr in ready:
                taken = h.take_message(msg_type, raw)
                if taken is not None:
                    callback = sub._callback
                    self._run(callback(taken[0]) if sub._callback_type is _MESSAGE_ONLY else callback(*taken))
                    if self._stale:
                        return True
        return False

    def _guards_clients_services(self, c: _WaitSet, ws: Any) -> None:
        ready = ws.get_ready_entities('guard_condition') if c.guards else ()
        for i, (_, ptr, gc) in enumerate(c.guards):
            if ptr in ready and gc.callback is not None:
                self._run(gc.callback())
                if self._stale:
                    self._rearm(c, ws, i + 1)
                    return
        ready = ws.get_ready_entities('client') if c.clients else ()
        for _, ptr, client in c.clients:
            if ptr in ready:
                execute = self._take_client(client)
                if execute is not None:
                    self._run(execute())
        ready = ws.get_ready_entities('service')
        for h, ptr, srv in c.services:
            if ptr in ready:
                request, header = h.service_take_request(srv.srv_type.Request)
                if header is not None:
                    srv.send_response(self._await(srv.callback(request, srv.srv_type.Response())), header)
                if self._stale:
                    return

    def _run(self, result: Any) -> None:
        """A callback's result: a coroutine (an async callback) runs until it waits, then as a Task."""
        if inspect.iscoroutine(result):
            try:
                result.send(None)
            except StopIteration:
                return
            task = Task(result, executor=self)
            with self._tasks_lock:
                self._tasks.append((task, None, None))

    @staticmethod
    def _await(result: Any) -> Any:
        """A service callback's response (an async service callback must finish without waiting)."""
        if not inspect.iscoroutine(result):
            return result
        try:
            result.send(None)
        except StopIteration as done:
            return done.value
        raise RuntimeError('an async service callback that waits is not supported by LeanExecutor')

    def _run_tasks(self) -> None:
        """Run the pending tasks (coroutine callbacks that waited, ``create_task``) once each."""
        with self._tasks_lock:
            tasks = [t for t, _, _ in self._tasks]
        for task in tasks:
            if not task.done() and not task.executing():
                task()
                if task.exception() is not None:
                    raise task.exception()
        with self._tasks_lock:
            self._tasks = [e for e in self._tasks if not e[0].done()]

    def _release(self) -> None:
        if self._ws is not None:
            self._ws.close()
            self._ws = None
