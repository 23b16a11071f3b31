"""ROS domains on one machine: a lock file per domain, so that test suites, the demo, benchmarks and checks that run
at the same time never share one (DDS participants of the same domain on loopback see each other's topics).

No ROS import: the domain must be chosen before rclpy starts.
"""

from __future__ import annotations

import fcntl
import os
import random
import tempfile
import time
from pathlib import Path

__all__ = ['DOMAIN_LOCK_DIR', 'TOOL_DOMAINS', 'acquire_domain', 'own_domain']

#: Where the per-domain lock files live (one machine-wide directory, as the domains are machine-wide).
DOMAIN_LOCK_DIR = Path(tempfile.gettempdir()) / 'ccf_ros_test_domains'
#: The domains the demo, benchmarks and checks take when ROS_DOMAIN_ID is not set: above the test suites' default
#: 100-199, and 215-232 because the ports of domains 102-214 can fall in Linux's ephemeral port range (ROS 2's
#: "The ROS_DOMAIN_ID" concept page).
TOOL_DOMAINS = range(215, 233)

#: Index into the range of the next domain this process tries: round robin, so a domain just released (whose
#: processes' DDS participants may still be leaving) is the last one this process takes again.
_next_domain = [random.Random(os.getpid()).randrange(1 << 16)]
#: Lock files held for the life of the process (own_domain).
_held: list[int] = []


def acquire_domain(domains: range, wait_s: float = 120.0, lock_dir: Path = DOMAIN_LOCK_DIR) -> tuple[int, int]:
    """Lock a free domain of ``domains``: (domain, fd of its lock file; closing it releases the domain). Waits up to
    ``wait_s`` s while every one is held; then RuntimeError."""
    lock_dir.mkdir(mode=0o777, exist_ok=True)
    deadline = time.monotonic() + wait_s
    while True:
        for i in range(len(domains)):
            k = (_next_domain[0] + i) % len(domains)
            d = domains[k]
            fd = os.open(lock_dir / f'{d}.lock', os.O_CREAT | os.O_RDWR, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                continue
            _next_domain[0] = k + 1
            return d, fd
        if time.monotonic() > deadline:
            raise RuntimeError(f'no free ROS domain in {domains.start}-{domains.stop - 1} for {wait_s:.0f} s')
        time.sleep(0.2)  # every domain held by another process: wait for one to finish


def own_domain(domains: range = TOOL_DOMAINS) -> int:
    """Keep DDS on loopback and return this process's ROS domain: ROS_DOMAIN_ID if the user set it, else a free one
    of ``domains``, locked for the life of the process and put into the environment (children inherit it)."""
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    if 'ROS_DOMAIN_ID' not in os.environ:
        d, fd = acquire_domain(domains)
        _held.append(fd)
        os.environ['ROS_DOMAIN_ID'] = str(d)
    return int(os.environ['ROS_DOMAIN_ID'])
