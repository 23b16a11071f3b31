"""The suite's ROS-domain allocation (conftest.ros_domain): each test, in this or a parallel suite, gets a domain
no other test holds while it runs."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from conftest import acquire_domain, domain_range


def test_domain_range_parses_and_rejects_bad_specs():
    assert domain_range('220-223') == range(220, 224)
    assert domain_range('150') == range(150, 151)
    for bad in ('a-b', '230-240', '20-10'):
        with pytest.raises(pytest.UsageError, match='CCF_TEST_DOMAINS'):
            domain_range(bad)


def test_this_test_holds_its_domain_and_others_are_handed_out_round_robin(ros_domain, tmp_path):
    assert os.environ['ROS_DOMAIN_ID'] == str(ros_domain)
    domains = range(ros_domain, ros_domain + 1)
    with pytest.raises(RuntimeError, match='no free ROS domain'):
        acquire_domain(domains, wait_s=0.0)  # held by this test
    # Round robin in a lock directory of this test's own: the machine-wide one is shared with other suites, which
    # may hold any domain (a fixed range there failed while a parallel suite ran on it).
    lo = 225
    got = [acquire_domain(range(lo, lo + 3), wait_s=0.0, lock_dir=tmp_path) for _ in range(3)]
    try:
        assert sorted(d for d, _ in got) == [lo, lo + 1, lo + 2]  # each held once
        with pytest.raises(RuntimeError):
            acquire_domain(range(lo, lo + 3), wait_s=0.0, lock_dir=tmp_path)
    finally:
        for _, fd in got:
            os.close(fd)


def test_a_parallel_suite_does_not_get_a_domain_this_one_holds(ros_domain):
    """Another process (a second suite on the machine) cannot take the domain this test holds."""
    code = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from conftest import acquire_domain
        try:
            acquire_domain(range({ros_domain}, {ros_domain + 1}), wait_s=0.5)
        except RuntimeError as err:
            print(err)
    """)
    r = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert 'no free ROS domain' in r.stdout


def test_a_tool_takes_a_locked_domain_outside_the_suites_and_keeps_the_users():
    """The demo, benchmarks and checks (ccf_ros.domains.own_domain): without ROS_DOMAIN_ID, a free domain of 215-232
    that stays locked while the process runs (a test suite or another tool cannot take it); with one, the user's."""
    code = textwrap.dedent("""
        import os
        from ccf_ros.domains import TOOL_DOMAINS, acquire_domain, own_domain
        d = own_domain()
        assert os.environ['ROS_DOMAIN_ID'] == str(d) and d in TOOL_DOMAINS, d
        assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
        try:
            acquire_domain(range(d, d + 1), wait_s=0.0)
            print('not locked')
        except RuntimeError:
            print('locked', d)
    """)
    env = {k: v for k, v in os.environ.items() if k != 'ROS_DOMAIN_ID'}
    r = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60, env=env)
    assert r.returncode == 0, r.stderr
    # (flock locks belong to the open file description: the process's own second open is refused too)
    assert r.stdout.startswith('locked '), r.stdout
    env['ROS_DOMAIN_ID'] = '7'
    r = subprocess.run([sys.executable, '-c', 'from ccf_ros.domains import own_domain; print(own_domain())'],
                       capture_output=True, text=True, timeout=60, env=env)
    assert r.stdout.strip() == '7', r.stderr
