"""``ccf play``: publish a bag's messages over DDS at recorded timing (``ros2 bag play`` is not on PyPI).

Serialized rosbag2 messages are CDR, the DDS wire format: they are published as bytes, without conversion.
ROS 1 bags are converted with rosbags. Needs rclpy (the Jazzy wheels); runs as a node named ``ccf_play``.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import BagError, ParameterError
from .bagio import deserialize, open_bag, read_messages, ros1_to_cdr, typestore

if TYPE_CHECKING:  # rclpy is imported when messages are published, not with this module
    from rclpy.node import Node


def msg_class(msgtype: str) -> type[Any]:
    """rclpy message class of ``pkg/msg/Name``."""
    pkg, _, name = msgtype.split('/')
    try:
        return getattr(importlib.import_module(f'{pkg}.msg'), name)
    except (ImportError, AttributeError) as err:
        raise BagError(f'message type {msgtype} is not available in this ROS installation') from err


def load_messages(
    bag: str | Path, topics: Sequence[str] | None = None, warn: Callable[[str], None] | None = None,
) -> tuple[dict[str, str], list[tuple[int, str, bytes]]]:
    """Topic types and ``(t_rec_ns, topic, cdr_bytes)`` of a bag, in recording order.

    A ROS 1 topic whose type ROS 2 does not have (``/rosout``'s ``rosgraph_msgs/Log``), or defines otherwise (its first
    message decodes with the bag's definition but does not convert: ``visualization_msgs/Marker``), is skipped, named
    to ``warn``; one named in ``topics`` is a :class:`ParameterError`. A message that decodes with neither is a
    :class:`BagError` (a damaged bag), as is a later one that does not convert.
    """
    with open_bag(bag) as reader:
        conns = [c for c in reader.connections if not topics or c.topic in topics]
        if topics and (missing := set(topics) - {c.topic for c in conns}):
            raise BagError(f'topics not in bag: {", ".join(sorted(missing))}')
        ros1 = not reader.is2
        # The ROS 2 definitions (as replay converts): rosbags' ROS 1 -> CDR conversion drops a ROS 1 header's seq
        # only when the target Header has none; the reader's own store holds the bag's ROS 1 definitions.
        store = typestore()
        # topic -> why it does not convert
        foreign = {c.topic: f'{c.msgtype}, not in ROS 2' for c in conns if ros1 and c.msgtype not in store.fielddefs}
        if topics and foreign:
            raise ParameterError(f'--topics: not convertible to ROS 2: {_named(foreign)}')
        conns = [c for c in conns if c.topic not in foreign]
        converted: set[str] = set()
        msgs = []
        for c, t, raw in read_messages(reader, bag, conns):
            cdr: bytes | memoryview = raw
            if ros1:
                if c.topic in foreign:
                    continue
                try:
                    cdr = ros1_to_cdr(store, raw, c.msgtype, bag)
                except BagError:
                    if c.topic in converted:
                        raise
                    deserialize(reader, raw, c.msgtype, bag)  # (a damaged message raises here)
                    foreign[c.topic] = f'{c.msgtype}, defined otherwise in ROS 2'
                    continue
                converted.add(c.topic)
            msgs.append((t, c.topic, bytes(cdr)))
        if foreign:
            if topics:
                raise ParameterError(f'--topics: not convertible to ROS 2: {_named(foreign)}')
            if warn is not None:
                warn(f'{bag}: skipping topics not convertible to ROS 2: {_named(foreign)} (--topics chooses the topics)')
        types = {c.topic: c.msgtype for c in conns if c.topic not in foreign}
    return types, msgs


def _named(reasons: dict[str, str]) -> str:
    """``/topic (why), ...`` of topic -> why."""
    return ', '.join(f'{topic} ({why})' for topic, why in sorted(reasons.items()))


def _wait_for_subscribers(pubs: Iterable[Any], wait_s: float, should_stop: Callable[[], bool]) -> bool:
    """Wait up to ``wait_s`` (s) until each publisher is matched; False if ``should_stop`` said stop meanwhile."""
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and any(pub.get_subscription_count() == 0 for pub in pubs):
        if should_stop():
            return False
        time.sleep(0.01)
    if wait_s > 0.0:
        # The writers see the match first; give the readers' side a moment to match back before the first sample
        # (a lost first magnetometer sample would change the initial heading).
        time.sleep(min(0.5, wait_s))
    return True


def play(
    node: Node,
    types: dict[str, str],
    messages: list[tuple[int, str, bytes]],
    *,
    rate: float = 1.0,
    loop: bool = False,
    qos_depth: int = 1000,
    clock: bool = False,
    should_stop: Callable[[], bool] = lambda: False,
    progress: Callable[[int], None] | None = None,
    wait_matched_s: float = 0.0,
) -> int:
    """Publish ``messages`` from ``node`` at recorded timing scaled by ``rate`` (2.0 = twice as fast).

    Returns the number of messages published. With ``clock`` it also publishes ``/clock`` (for use_sim_time).
    With ``wait_matched_s`` > 0 it first waits (up to that long, s) until every topic's publisher is matched with
    a subscriber: DDS drops what a publisher sends before it is matched, and each topic matches on its own.
    A context shut down meanwhile (SIGINT: rclpy's signal thread shuts it down at any moment, e.g. between
    ``should_stop``'s check and a publish) ends the play as ``should_stop`` does; an RCL error while the context is
    valid propagates.
    """
    from rclpy.duration import Duration
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    if not rate > 0:
        raise ParameterError(f'--rate must be > 0, got {rate!r}')
    qos = QoSProfile(depth=qos_depth, reliability=ReliabilityPolicy.RELIABLE)
    classes = {topic: msg_class(t) for topic, t in types.items()}
    n = 0
    try:
        pubs = {topic: node.create_publisher(cls, topic, qos) for topic, cls in classes.items()}
        clock_pub = None
        if clock:
            from rosgraph_msgs.msg import Clock

            clock_pub = node.create_publisher(Clock, '/clock', 10)
            clock_msg = Clock()
        if not _wait_for_subscribers(pubs.values(), wait_matched_s, should_stop) or not messages:
            return 0
        while True:
            t0_bag = messages[0][0]
            t0_wall = time.monotonic()
            for t, topic, data in messages:
                due = t0_wall + (t - t0_bag) * 1e-9 / rate
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                if should_stop():
                    return n
                if clock_pub is not None:
                    clock_msg.clock.sec, clock_msg.clock.nanosec = divmod(t, 1_000_000_000)
                    clock_pub.publish(clock_msg)
                pubs[topic].publish(data)
                n += 1
                if progress is not None:
                    progress(1)
            if not loop:
                # Reliable writers still hold what the readers have not acknowledged: exiting now would drop the last
                # messages (seen: the last IMU and magnetometer sample of a bag).
                for pub in pubs.values():
                    pub.wait_for_all_acked(Duration(seconds=2))
                return n
    except _rclpy.RCLError:
        if node.context.ok():
            raise
        return n  # (what was published before the shutdown; the one that raised was not)
