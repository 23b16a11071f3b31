"""CPU time of one executor wake-up of ccf_node, without DDS traffic: what every message pays before its callback.

rclpy's executor rebuilds its wait set in Python on every wake-up, entity by entity (subscriptions, services, timers,
guard conditions, waitables such as QoS-event handlers). This process makes a ccf_node (or, with ``--bare``, a bare
rclpy node) in a context of its own, adds a guard condition, and measures the thread CPU time of ``N`` cycles of
trigger + ``spin_once`` until its callback ran, in rounds (median of the rounds' per-cycle time). Run it against two versions (e.g.
``PYTHONPATH=<old checkout>``) alternately and compare.

Usage: python benchmarks/node_wake.py [--bare] [--cycles 3000] [--rounds 5] [--executor rclpy|lean]
(sets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; uses ROS_DOMAIN_ID if set, else a free domain of 215-232, locked for the run)
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from ccf_ros.domains import own_domain

os.environ['ROS_DOMAIN_ID'] = str(own_domain())

import rclpy
from rclpy.executors import SingleThreadedExecutor


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--bare', action='store_true', help='a bare rclpy node instead of ccf_node')
    ap.add_argument('--cycles', type=int, default=3000)
    ap.add_argument('--rounds', type=int, default=5)
    ap.add_argument('--executor', choices=('rclpy', 'lean'), default='rclpy',
                    help="rclpy's SingleThreadedExecutor, or the executables' LeanExecutor (ccf_ros.node.executor)")
    args = ap.parse_args()
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    if args.bare:
        node = rclpy.create_node('bare', context=ctx)
    else:
        from ccf_ros.node import CcfNode

        node = CcfNode(context=ctx)
    if args.executor == 'lean':
        from ccf_ros.node.executor import LeanExecutor

        ex = LeanExecutor(context=ctx)
    else:
        ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    fired = [0]
    gc = node.create_guard_condition(lambda: fired.__setitem__(0, fired[0] + 1))
    per_cycle = []
    n_before = 0
    for _ in range(args.rounds):
        t0 = time.thread_time()
        for k in range(args.cycles):
            gc.trigger()
            while fired[0] <= k + n_before:  # (a spin_once may only finish the previous wake-up's work)
                ex.spin_once(timeout_sec=0)
        n_before += args.cycles
        per_cycle.append((time.thread_time() - t0) / args.cycles * 1e6)
    assert fired[0] == args.cycles * args.rounds, fired
    n = (len(list(node.subscriptions)), len(list(node.services)), len(list(node.timers)), len(list(node.waitables)))
    print(f'{"bare" if args.bare else "ccf_node"}, {args.executor} executor: {statistics.median(per_cycle):.1f} us CPU per wake-up (median of '
          f'{args.rounds} x {args.cycles}); subscriptions, services, timers, waitables: {n}')
    ex.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


if __name__ == '__main__':
    main()
