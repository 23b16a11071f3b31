"""``ccf fleet`` on a real Dask cluster: a ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1 started
here, one of them SIGKILLed mid-run; resume, failures, exit codes, outputs equal to ``ccf replay``/``ccf eval``."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip('distributed')

from ccf_ros import __version__
from ccf_ros.cli import main
from ccf_ros.errors import CcfError
from ccf_ros.fleet.discover import discover
from ccf_ros.fleet.keys import code_version
from ccf_ros.offline.simulate import generate, write_bag

BIN = Path(sys.executable).parent
N_BAGS = 6


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return int(s.getsockname()[1])


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


class Cluster:
    """A scheduler and worker processes on 127.0.0.1 (no nanny: a killed worker stays dead)."""

    def __init__(self, log_dir: Path, scheduler_env: dict[str, str] | None = None) -> None:
        self.port = _free_port()
        self.address = f'tcp://127.0.0.1:{self.port}'
        self.log_dir = log_dir
        self.scheduler = self._spawn('scheduler', [str(BIN / 'dask'), 'scheduler', '--host', '127.0.0.1', '--port',
                                                   str(self.port), '--no-dashboard'], scheduler_env)
        self.workers: list[subprocess.Popen] = []

    def _spawn(self, name: str, cmd: list[str], env: dict[str, str] | None = None) -> subprocess.Popen:
        log = (self.log_dir / f'{name}.log').open('w')
        return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                                env={**os.environ, **(env or {})})

    def alive(self) -> dict[int, subprocess.Popen]:
        """The running worker processes by pid."""
        return {w.pid: w for w in self.workers if w.poll() is None}

    def n_clients(self) -> int:
        """Clients connected to the scheduler now (this one included)."""
        from distributed import Client

        with Client(self.address, timeout='30s', set_as_default=False) as c:
            return int(c.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.clients)))

    def add_worker(self) -> subprocess.Popen:
        w = self._spawn(f'worker{len(self.workers)}', [
            str(BIN / 'dask'), 'worker', self.address, '--nthreads', '1', '--no-dashboard', '--host', '127.0.0.1',
            '--no-nanny', '--name', f'w{len(self.workers)}'])
        self.workers.append(w)
        return w

    def wait_workers(self, n: int, timeout_s: float = 90.0) -> None:
        from distributed import Client

        with Client(self.address, timeout='30s', set_as_default=False) as c:
            c.wait_for_workers(n, timeout=timeout_s)

    def close(self) -> None:
        for p in [*self.workers, self.scheduler]:
            _stop(p)


@pytest.fixture(scope='module')
def cluster(tmp_path_factory):
    c = Cluster(tmp_path_factory.mktemp('dask'))
    try:
        c.add_worker()
        c.add_worker()
        c.wait_workers(2)
        yield c
    finally:
        c.close()


@pytest.fixture(scope='module')
def fleet_bags(tmp_path_factory) -> Path:
    """N_BAGS simulated bags (20 s at 100 Hz) in two 'device' folders, and one corrupt bag in a third."""
    root = tmp_path_factory.mktemp('fleet')
    first = root / 'robot_a' / 'day0'
    write_bag(generate(20.0, 100.0, 5, rest_s=6.0), first)
    for i in range(1, N_BAGS):
        dst = root / ('robot_a' if i < 3 else 'robot_b') / f'day{i}'
        dst.parent.mkdir(exist_ok=True)
        write_bag(generate(20.0, 100.0, 5 + i, rest_s=6.0), dst)
    return root


def _corrupt_copy(bag: Path, dst: Path) -> Path:
    shutil.copytree(bag, dst)
    mcap = next(dst.glob('*.mcap'))
    data = mcap.read_bytes()
    mcap.write_bytes(data[:len(data) // 3])  # truncated mid-chunk, as an interrupted copy leaves it
    return dst


def _run(args: list[str], env: dict[str, str] | None = None, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / 'ccf'), 'fleet', 'run', *args, '--quiet'], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, **(env or {})})


def _strict(constant: str) -> None:
    raise ValueError(f'results.jsonl must be strict JSON, found {constant}')


def _records(out: Path) -> list[dict]:
    return [json.loads(line, parse_constant=_strict) for line in (out / 'results.jsonl').read_text().splitlines()]


def _leftovers(out: Path) -> list[Path]:
    return [p for p in out.rglob('*') if p.name.startswith('.') or p.name.endswith(('.tmp', '.partial'))]


def _attempts(out: Path) -> list[tuple[str, int]]:
    """(key, worker pid) of every attempt at a bag so far: the markers tasks leave with CCF_FLEET_SLOW_BAG_S."""
    return [(p.name.split('.')[0], int(p.name.split('.')[1])) for p in (out / 'attempts').glob('*')]


def test_worker_killed_mid_run_every_bag_ok_exactly_once_then_resume(cluster, fleet_bags, tmp_path):
    out = tmp_path / 'out'
    cmd = [str(BIN / 'ccf'), 'fleet', 'run', str(fleet_bags), '-o', str(out), '--scheduler', cluster.address,
           '--quiet', '--reference', '']
    # Every bag waits 2 s after its attempt's marker is written: a worker that holds a marker of a bag without a
    # result is inside that bag.
    driver = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, 'CCF_FLEET_SLOW_BAG_S': '2'})
    try:
        deadline = time.monotonic() + 120
        while True:
            assert driver.poll() is None, driver.communicate()
            assert time.monotonic() < deadline, 'no attempt started'
            held = [(k, pid) for k, pid in _attempts(out)
                    if pid in cluster.alive() and not (out / 'bags' / f'{k}.json').exists()]
            if held:
                break
            time.sleep(0.02)
        killed_key, pid = held[0]
        n_before = len(list((out / 'bags').glob('*.json')))
        victim = cluster.alive()[pid]
        os.kill(pid, signal.SIGKILL)
        stdout, stderr = driver.communicate(timeout=180)
    finally:
        if driver.poll() is None:
            driver.kill()
    assert victim.wait(10) == -signal.SIGKILL
    assert n_before < N_BAGS  # killed mid-run
    assert driver.returncode == 0, stdout + stderr
    # The killed attempt had no result; the bag was attempted again, and recorded once.
    tries = [p for k, p in _attempts(out) if k == killed_key]
    assert len(tries) >= 2 and pid in tries, tries
    recs = _records(out)
    assert len(recs) == N_BAGS and {r['status'] for r in recs} == {'ok'}
    assert sorted(r['bag'] for r in recs) == sorted(discover([str(fleet_bags)]))
    assert len(list((out / 'bags').glob('*.json'))) == N_BAGS  # one result file per bag
    assert (out / 'bags' / f'{killed_key}.json').exists()
    assert _leftovers(out) == []
    # The csv has one row per bag too.
    assert len((out / 'results.csv').read_text().splitlines()) == N_BAGS + 1
    assert (out / 'report.md').exists() and list(out.glob('report_device*.png'))

    # A rerun submits nothing (it does not even need the cluster).
    again = _run([str(fleet_bags), '-o', str(out), '--scheduler', 'tcp://127.0.0.1:9', '--reference', ''])
    assert again.returncode == 0, again.stderr
    assert 'nothing to do' in again.stdout and '0 processed now' in again.stdout
    # (Exactly once: a bag Dask ran twice around the kill keeps the first result, in the file and in the table.)
    assert _records(out) == recs

    # Deleting one bag's result reprocesses that bag only.
    gone = next((out / 'bags').glob('*.json'))
    key = gone.stem
    gone.unlink()
    cluster.add_worker()  # the killed one's replacement
    one = _run([str(fleet_bags), '-o', str(out), '--scheduler', cluster.address, '--reference', ''])
    assert one.returncode == 0, one.stderr
    assert '1 processed now, 5 done before' in one.stdout
    assert (out / 'bags' / f'{key}.json').exists()
    assert [r['bag'] for r in _records(out)] == [r['bag'] for r in recs]


def test_corrupt_bag_fails_alone_exit_1_and_retry_failed(cluster, fleet_bags, tmp_path):
    bags = tmp_path / 'in'
    shutil.copytree(fleet_bags / 'robot_b', bags / 'robot_b')
    bad = _corrupt_copy(fleet_bags / 'robot_a' / 'day0', bags / 'robot_c' / 'broken')
    out = tmp_path / 'out'
    r = _run([str(bags), '-o', str(out), '--scheduler', cluster.address, '--reference', ''])
    assert r.returncode == 1, r.stdout + r.stderr
    recs = {Path(x['bag']).name: x for x in _records(out)}
    assert recs['broken']['status'] == 'failed'
    assert 'cannot open bag' in recs['broken']['error'] and '\n' not in recs['broken']['error']
    assert all(x['status'] == 'ok' for k, x in recs.items() if k != 'broken')
    assert f'failed: {bad}' in r.stderr
    assert 'failed' in (out / 'report.md').read_text()
    # A rerun leaves the failed bag failed; --retry-failed tries it (and only it) again.
    again = _run([str(bags), '-o', str(out), '--scheduler', cluster.address, '--reference', ''])
    assert again.returncode == 1 and '0 processed now' in again.stdout
    retry = _run([str(bags), '-o', str(out), '--scheduler', cluster.address, '--reference', '', '--retry-failed'])
    assert retry.returncode == 1 and '1 processed now' in retry.stdout


def test_unreachable_scheduler_exits_2_within_10_s(fleet_bags, tmp_path):
    port = _free_port()  # nothing listens there
    t0 = time.monotonic()
    r = _run([str(fleet_bags / 'robot_b'), '-o', str(tmp_path / 'out'), '--scheduler', f'tcp://127.0.0.1:{port}'],
             timeout=60)
    wall = time.monotonic() - t0
    assert r.returncode == 2, r.stdout + r.stderr
    assert wall < 10.0, wall
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and 'cannot reach the Dask scheduler' in lines[0]
    # DASK_SCHEDULER_ADDRESS names it as well.
    r = _run([str(fleet_bags / 'robot_b'), '-o', str(tmp_path / 'out2')],
             env={'DASK_SCHEDULER_ADDRESS': f'tcp://127.0.0.1:{port}'}, timeout=60)
    assert r.returncode == 2 and 'cannot reach the Dask scheduler' in r.stderr


def test_write_bags_equal_ccf_replay_and_accuracy_equals_ccf_eval(cluster, fleet_bags, tmp_path):
    from ccf_ros.offline.bagio import open_bag

    bag = fleet_bags / 'robot_b' / 'day3'
    out = tmp_path / 'out'
    # With a mounting too: fleet takes replay's settings, and its output is in the output frame as replay's is.
    mount = ['--param', 'mount_rotation=[0.1, -0.2, 1.5707963]', '--param', 'output_frame_id=base_link']
    r = _run([str(bag), '-o', str(out), '--scheduler', cluster.address, '--write-bags', *mount])
    assert r.returncode == 0, r.stdout + r.stderr
    (rec,) = _records(out)
    assert main(['replay', str(bag), '-o', str(tmp_path / 'replayed'), *mount]) == 0

    def messages(p: Path) -> list[tuple[str, int, bytes]]:
        with open_bag(p) as reader:
            return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]

    assert messages(Path(rec['output'])) == messages(tmp_path / 'replayed')
    assert main(['eval', str(tmp_path / 'replayed'), '--reference', '/ground_truth/pose', '--reference-bag', str(bag),
                 '--mask-topic', '/ground_truth/moving', '--json', str(tmp_path / 'eval.json')]) == 0
    want = json.loads((tmp_path / 'eval.json').read_text())
    assert rec['accuracy'] == want
    # The output is in the mount's output frame, the reference in the IMU's: off by about the mount's 91° turn
    # (measured 90.8°).
    assert 85 < rec['accuracy']['total_rmse_deg'] < 97


def test_fleet_reads_the_motion_hint_as_replay_does(fleet_bags, tmp_path, capsys):
    """motion_hint_topic (here --param, relative: in --node-name's namespace) is read as replay reads it (fleet
    ignored it): the same output bag; a bag without the topic fails with replay's error, the other bags go on."""
    from rosbags.rosbag2 import Writer

    from ccf_ros.offline.bagio import open_bag, typestore

    inputs = tmp_path / 'in'
    inputs.mkdir()
    hinted = inputs / 'hinted'
    ts = typestore()
    T = ts.types
    with open_bag(fleet_bags / 'robot_b' / 'day4') as reader, Writer(hinted, version=9) as w:
        conns = {c.id: w.add_connection(c.topic, c.msgtype, typestore=ts) for c in reader.connections}
        odom = w.add_connection('/robot/odom', 'geometry_msgs/msg/TwistStamped', typestore=ts)
        n_imu = 0
        for c, t, raw in reader.messages():
            w.write(conns[c.id], t, raw)
            n_imu += c.topic == '/imu/data_raw'
            if c.topic == '/imu/data_raw' and n_imu % 10 == 0:  # "moving" throughout: no bias learnt at rest
                stamp = reader.deserialize(raw, c.msgtype).header.stamp
                header = T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](sec=stamp.sec,
                                                                                        nanosec=stamp.nanosec),
                                                  frame_id='base_link')
                V = T['geometry_msgs/msg/Vector3']
                twist = T['geometry_msgs/msg/Twist'](linear=V(x=0.0, y=0.0, z=0.0), angular=V(x=0.0, y=0.0, z=1.0))
                msg = T['geometry_msgs/msg/TwistStamped'](header=header, twist=twist)
                w.write(odom, t, ts.serialize_cdr(msg, 'geometry_msgs/msg/TwistStamped'))
    plain = shutil.copytree(fleet_bags / 'robot_b' / 'day5', inputs / 'plain')
    hint = ['--param', 'motion_hint_topic=odom', '--node-name', '/robot/ccf_node']
    out = tmp_path / 'out'
    r = _run([str(inputs), '-o', str(out), '-j', '1', '--write-bags', '--reference', '', *hint], timeout=180)
    assert r.returncode == 1, r.stdout + r.stderr
    recs = {Path(rec['bag']).name: rec for rec in _records(out)}

    def messages(p: Path) -> list[tuple[str, int, bytes]]:
        with open_bag(p) as reader:
            return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]

    assert recs['hinted']['status'] == 'ok', recs['hinted']
    assert main(['replay', str(hinted), '-o', str(tmp_path / 'replayed'), *hint]) == 0
    assert main(['replay', str(hinted), '-o', str(tmp_path / 'unhinted')]) == 0
    assert messages(Path(recs['hinted']['output'])) == messages(tmp_path / 'replayed')
    assert messages(tmp_path / 'replayed') != messages(tmp_path / 'unhinted')  # (the hint matters here)
    capsys.readouterr()
    assert main(['replay', str(plain), '-o', str(tmp_path / 'no'), *hint]) == 2
    why = capsys.readouterr().err.removeprefix('ccf replay: error: ').strip()
    assert '/robot/odom' in why and recs['plain']['status'] == 'failed'
    assert recs['plain']['error'].endswith(why), recs['plain']


def test_a_bias_file_is_refused_it_is_one_imus_state(fleet_bags, tmp_path):
    r = _run([str(fleet_bags / 'robot_b'), '-o', str(tmp_path / 'out'), '--param', f'bias_file={tmp_path / "b.json"}'],
             timeout=60)
    assert r.returncode == 2 and 'bias_file is one IMU' in r.stderr, r.stdout + r.stderr
    assert not (tmp_path / 'out').exists()


def test_workers_of_another_version_are_one_clear_error(cluster, fleet_bags, tmp_path):
    from ccf_ros.cli import build_parser, engine_settings
    from ccf_ros.fleet.run import RunConfig, run_fleet
    from ccf_ros.fleet.task import FleetOptions, VersionMismatch, process_bag

    merged, strict = engine_settings(build_parser().parse_args(['fleet', 'run', 'x', '-o', 'y']))
    opts = FleetOptions(out=str(tmp_path / 'o'), settings=merged, strict=strict, version='0.0.0-driver')
    with pytest.raises(CcfError, match=r'workers run another ccf_ros than this driver \(0\.0\.0-driver\).*'
                       + __version__.replace('.', r'\.')):
        run_fleet(RunConfig([str(fleet_bags / 'robot_b')], tmp_path / 'o', opts, scheduler=cluster.address))
    with pytest.raises(VersionMismatch, match='install the same version'):
        process_bag(str(fleet_bags / 'robot_b' / 'day3'), 'k', opts)


def test_local_cluster_by_default_and_topics_detected(fleet_bags, tmp_path):
    """No --scheduler: a local cluster of -j single-threaded processes; bags with other topic names need no
    option when they hold one Imu and one MagneticField topic (and ccf replay detects them too)."""
    from rosbags.rosbag2 import Writer

    from ccf_ros.offline.bagio import open_bag, typestore

    renamed = tmp_path / 'in' / 'renamed'
    renamed.parent.mkdir()
    names = {'/imu/data_raw': '/sensors/imu', '/imu/mag': '/sensors/mag'}
    ts = typestore()
    with open_bag(fleet_bags / 'robot_b' / 'day4') as reader, Writer(renamed, version=9) as w:
        conns = {c.id: w.add_connection(names.get(c.topic, c.topic), c.msgtype, typestore=ts)
                 for c in reader.connections}
        for c, t, raw in reader.messages():
            w.write(conns[c.id], t, raw)
    out = tmp_path / 'out'
    r = _run([str(tmp_path / 'in'), '-o', str(out), '-j', '1', '--reference', ''], timeout=180)
    assert r.returncode == 0, r.stdout + r.stderr
    (rec,) = _records(out)
    assert rec['status'] == 'ok' and rec['samples'] == 2000 and rec['warnings'] == []
    assert main(['replay', str(renamed), '-o', str(tmp_path / 'rep')]) == 0


def test_discovery_of_folders_lists_and_bare_files(fleet_bags, tmp_path):
    mcap = next((fleet_bags / 'robot_a' / 'day0').glob('*.mcap'))
    bare = tmp_path / 'loose' / 'x.mcap'
    bare.parent.mkdir()
    shutil.copy(mcap, bare)
    listing = tmp_path / 'list.txt'
    listing.write_text(f'# two bags\n{fleet_bags / "robot_b" / "day3"}\n\nloose/x.mcap\n')
    found = discover([f'@{listing}', str(fleet_bags / 'robot_b'), str(tmp_path / 'loose')])
    assert found == [str(fleet_bags / 'robot_b' / 'day3'), str(bare), str(fleet_bags / 'robot_b' / 'day4'),
                     str(fleet_bags / 'robot_b' / 'day5')]
    assert len(discover([str(fleet_bags)])) == N_BAGS
    assert discover([str(fleet_bags)], exclude=fleet_bags / 'robot_b') == discover([str(fleet_bags / 'robot_a')])
    with pytest.raises(CcfError, match='no such bag or folder'):
        discover([str(tmp_path / 'nope')])
    with pytest.raises(CcfError, match='no bags found'):
        discover([str(tmp_path / 'loose' / '..' / 'empty')] if (tmp_path / 'empty').mkdir() is None else [])


def test_without_dask_one_line_says_what_to_install(monkeypatch, tmp_path, capsys, fleet_bags):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, 'find_spec', lambda name, *a: None if name == 'distributed' else real(name, *a))
    assert main(['fleet', 'run', str(fleet_bags / 'robot_b'), '-o', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pip install 'ccf_ros[fleet]'" in err


def _wait_attempt(out: Path, driver: subprocess.Popen, timeout_s: float = 120) -> tuple[str, int]:
    """(key, worker pid) of the first attempt that started."""
    deadline = time.monotonic() + timeout_s
    while not (found := _attempts(out)):
        assert driver.poll() is None, driver.communicate()
        assert time.monotonic() < deadline, 'no attempt started'
        time.sleep(0.02)
    return found[0]


def test_a_cluster_without_workers_is_waited_for_then_one_clear_error(fleet_bags, tmp_path):
    """Adaptive clusters (dask-jobqueue, Kubernetes) start with no worker: the run waits for the first one, and
    gives up after --wait-workers S with one line, exit 2."""
    c = Cluster(tmp_path)
    try:
        base = c.n_clients()  # (the scheduler is up)
        bag = str(fleet_bags / 'robot_b' / 'day3')
        t0 = time.monotonic()
        r = _run([bag, '-o', str(tmp_path / 'o1'), '--scheduler', c.address, '--wait-workers', '3'], timeout=60)
        wall = time.monotonic() - t0
        assert r.returncode == 2, r.stdout + r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and f'no worker joined the Dask cluster at {c.address} within 3 s' in lines[0], lines
        assert 3.0 <= wall < 30.0, wall
        # A worker that joins while the run waits: the run goes on.
        driver = subprocess.Popen([str(BIN / 'ccf'), 'fleet', 'run', bag, '-o', str(tmp_path / 'o2'), '--scheduler',
                                   c.address, '--quiet', '--reference', ''], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 60
            while c.n_clients() <= base:  # the driver is connected (and, with no worker, waiting)
                assert driver.poll() is None, driver.communicate()
                assert time.monotonic() < deadline, 'the driver did not connect'
                time.sleep(0.1)
            c.add_worker()
            stdout, stderr = driver.communicate(timeout=120)
        finally:
            if driver.poll() is None:
                driver.kill()
        assert driver.returncode == 0, stdout + stderr
        assert [x['status'] for x in _records(tmp_path / 'o2')] == ['ok']
    finally:
        c.close()


def test_a_bag_that_kills_its_worker_is_recorded_failed_and_a_rerun_leaves_it(fleet_bags, tmp_path):
    """A task lost with its worker beyond Dask's allowed failures (0 here: the first loss) is a failure known only
    to the driver: it is written as the bag's result, so a plain rerun does not send the bag that kills workers to
    the cluster again; --retry-failed does."""
    c = Cluster(tmp_path, scheduler_env={'DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES': '0'})
    try:
        c.add_worker()
        c.wait_workers(1)
        bag = str(fleet_bags / 'robot_b' / 'day3')
        out = tmp_path / 'out'
        driver = subprocess.Popen([str(BIN / 'ccf'), 'fleet', 'run', bag, '-o', str(out), '--scheduler', c.address,
                                   '--quiet', '--reference', '', '--retries', '0'], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True, env={**os.environ, 'CCF_FLEET_SLOW_BAG_S': '30'})
        try:
            key, pid = _wait_attempt(out, driver)
            assert pid in c.alive()
            os.kill(pid, signal.SIGKILL)
            stdout, stderr = driver.communicate(timeout=60)
        finally:
            if driver.poll() is None:
                driver.kill()
        assert driver.returncode == 1, stdout + stderr
        assert 'Traceback' not in stderr
        (rec,) = _records(out)
        assert rec['status'] == 'failed' and rec['error'].startswith('KilledWorker'), rec
        assert rec['ccf_ros_version'] == code_version()
        assert json.loads((out / 'bags' / f'{key}.json').read_text())['status'] == 'failed'
        # A plain rerun: nothing to do (not even a connection: the scheduler named does not exist).
        again = _run([bag, '-o', str(out), '--scheduler', 'tcp://127.0.0.1:9', '--reference', ''])
        assert again.returncode == 1 and '0 processed now' in again.stdout, again.stdout + again.stderr
        c.add_worker()
        retry = _run([bag, '-o', str(out), '--scheduler', c.address, '--reference', '', '--retry-failed'])
        assert retry.returncode == 0 and '1 processed now' in retry.stdout, retry.stdout + retry.stderr
        assert [x['status'] for x in _records(out)] == ['ok']
    finally:
        c.close()


def test_a_task_cancelled_on_the_cluster_fails_its_bag_with_a_reason(cluster, fleet_bags, tmp_path):
    """Another client cancelling the task (or a cluster shutting down): the bag is failed with a one-line reason,
    no traceback, and the driver writes no failed result for it (the cancellation is not the bag's fault). Dask
    cannot stop an attempt that already runs: it finishes and writes its own result, which the next run keeps."""
    from distributed import Client, Future

    bag = str(fleet_bags / 'robot_a' / 'day1')
    out = tmp_path / 'out'
    driver = subprocess.Popen([str(BIN / 'ccf'), 'fleet', 'run', bag, '-o', str(out), '--scheduler', cluster.address,
                               '--quiet', '--reference', ''], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, env={**os.environ, 'CCF_FLEET_SLOW_BAG_S': '4'})
    try:
        key, _ = _wait_attempt(out, driver)
        with Client(cluster.address, timeout='30s', set_as_default=False) as c:
            c.cancel([Future(f'ccf-fleet-{key}', client=c)], force=True)
        stdout, stderr = driver.communicate(timeout=60)
    finally:
        if driver.poll() is None:
            driver.kill()
    assert driver.returncode == 1, stdout + stderr
    assert 'Traceback' not in stderr and f'failed: {bag}: Cancelled' in stderr, stderr
    (rec,) = _records(out)
    assert rec['status'] == 'failed' and rec['error'].startswith('Cancelled: '), rec
    # The running attempt ends on its own (bounded; waited for here so that it does not run into the next test).
    result = out / 'bags' / f'{key}.json'
    deadline = time.monotonic() + 60
    while not result.exists():
        assert time.monotonic() < deadline, 'the cancelled attempt did not finish'
        time.sleep(0.05)
    assert json.loads(result.read_text())['status'] == 'ok'


@pytest.mark.parametrize('bad', [['--retries', '-1'], ['-j', '-2'], ['--task-timeout', '-1'],
                                 ['--task-timeout', 'inf'], ['--task-timeout', 'nan'], ['--wait-workers', '0']])
def test_bad_numeric_options_are_one_clear_error(bad, tmp_path, capsys, fleet_bags):
    assert main(['fleet', 'run', str(fleet_bags / 'robot_b'), '-o', str(tmp_path / 'o'), *bad]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and bad[0] in err and bad[1] in err, err
    assert not (tmp_path / 'o').exists()


def test_a_bad_device_regex_is_one_clear_error_before_any_work(tmp_path, capsys, fleet_bags):
    from ccf_ros.fleet.run import write_tables

    assert main(['fleet', 'run', str(fleet_bags / 'robot_b'), '-o', str(tmp_path / 'o'), '--device', '(']) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and '--device' in err and "'('" in err, err
    assert not (tmp_path / 'o').exists()  # (no bag was processed for a report that could not be written)
    out = tmp_path / 'done'
    out.mkdir()
    write_tables(out, [{'bag': '/fleet/robot_a/day0', 'key': 'k', 'status': 'failed', 'error': 'x'}])
    assert main(['fleet', 'report', str(out), '--device', '(']) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and '--device' in err and "'('" in err, err
    assert main(['fleet', 'report', str(out), '--device', 'robot_(.)']) == 0
    assert '(a)' in (out / 'report.md').read_text()


def test_an_output_that_is_a_file_is_one_clear_error(tmp_path, capsys, fleet_bags):
    afile = tmp_path / 'afile'
    afile.write_text('mine\n')
    assert main(['fleet', 'run', str(fleet_bags / 'robot_b'), '-o', str(afile)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(afile) in err and 'not a folder' in err, err
    assert afile.read_text() == 'mine\n'
    assert main(['fleet', 'run', str(fleet_bags / 'robot_b'), '-o', str(afile / 'sub')]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(afile / 'sub') in err, err


@pytest.mark.parametrize(('address', 'why'), [('foo', 'no port'), ('tcp://127.0.0.1', 'no port'),
                                              ('127.0.0.1:99999', "the port '99999'"), ('foo://x:1', "scheme 'foo'"),
                                              ('foo://127.0.0.1:8786', "scheme 'foo'"),
                                              # (a scheme this Dask has dropped: its FutureWarning was a traceback;
                                              # a Dask with distributed-ucxx takes it, and then cannot reach it)
                                              ('ucx://127.0.0.1:13337', 'ucx')])
def test_a_malformed_scheduler_address_is_one_line_and_exit_2_at_once(address, why, tmp_path, fleet_bags):
    """Dask's own forms are tcp://HOST:PORT and a bare HOST:PORT (its default scheme); anything else is refused in one
    line before any work (no output folder made; another scheme was checked only when there was work, after the
    output folder was made), without a Dask client left half started (which blocked 12 s when collected, then
    printed a traceback)."""
    out = tmp_path / 'out'
    for args, env in (([str(fleet_bags / 'robot_b'), '-o', str(out), '--scheduler', address], None),
                      ([str(fleet_bags / 'robot_b'), '-o', str(out)], {'DASK_SCHEDULER_ADDRESS': address})):
        t0 = time.monotonic()
        r = _run(args, env=env, timeout=60)
        wall = time.monotonic() - t0
        assert r.returncode == 2, r.stdout + r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and why in lines[0], lines
        assert f'not a Dask scheduler address: {address!r}' in lines[0] or (
            address.startswith('ucx://') and f'cannot reach the Dask scheduler at {address}' in lines[0]), lines
        assert wall < 10.0, wall
        assert not out.exists()  # (refused before discovery)


def test_an_unknown_scheme_is_refused_on_a_finished_output_too(fleet_bags, tmp_path):
    """(It was checked only when there was work: `nothing to do`, exit 0.)"""
    out = tmp_path / 'out'
    bag = str(fleet_bags / 'robot_b' / 'day3')
    assert _run([bag, '-o', str(out), '-j', '1', '--reference', ''], timeout=180).returncode == 0
    r = _run([bag, '-o', str(out), '--reference', '', '--scheduler', 'foo://127.0.0.1:8786'], timeout=60)
    assert r.returncode == 2 and r.stdout == '', r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "not a Dask scheduler address: 'foo://127.0.0.1:8786'" in lines[0], lines
    assert "scheme 'foo'" in lines[0], lines


def test_scheduler_addresses_read_as_dask_reads_them():
    from ccf_ros.fleet.run import _tcp_host_port

    assert _tcp_host_port('tcp://10.0.0.5:8786') == ('10.0.0.5', 8786)
    assert _tcp_host_port('sched.example:8786') == ('sched.example', 8786)  # (no scheme: Dask's default, tcp)
    assert _tcp_host_port('tcp://[::1]:8786') == ('::1', 8786)
    assert _tcp_host_port('[::1]:8786') == ('::1', 8786)
    assert _tcp_host_port('tls://sched:8786') is None  # (other schemes: Dask checks them)
    for bad in ('sched', '::1:8786', 'tcp://:8786', 'sched:port', '[::1]', 'tcp://sched:8786/'):
        with pytest.raises(CcfError, match='not a Dask scheduler address'):
            _tcp_host_port(bad)


def test_a_cancelled_future_that_raises_is_a_failed_record_too():
    """Dask versions differ: Future.exception() of a cancelled task returns None in some and raises CancelledError in
    others; either way the bag is failed with the reason."""
    import concurrent.futures

    from ccf_ros.fleet.run import _failed

    class Raising:
        status = 'lost'

        def exception(self):
            raise concurrent.futures.CancelledError('x')

    class Cancelled:  # (status 'cancelled' is not even asked for its exception)
        status = 'cancelled'

        def exception(self):
            raise AssertionError('not called')

    for fut in (Raising(), Cancelled()):
        rec, the_bags = _failed('/b', 'k', fut)
        assert not the_bags  # (not written: the next run does it)
        assert rec == {'bag': '/b', 'key': 'k', 'status': 'failed',
                       'error': 'Cancelled: the task was cancelled on the cluster before it finished'}


def test_only_a_bag_that_kills_its_workers_is_kept_failed_on_disk():
    """The driver writes a failure the task did not write itself only for KilledWorker (the bag's own doing: a plain
    rerun must not send it to the cluster again); a lost connection or a full disk is not the bag's: the next run
    does it."""
    from types import SimpleNamespace

    from distributed import KilledWorker

    from ccf_ros.fleet.run import _failed

    class Erred:
        status = 'error'

        def __init__(self, err):
            self.err = err

        def exception(self):
            return self.err

    rec, the_bags = _failed('/b', 'k', Erred(KilledWorker('ccf-fleet-k', SimpleNamespace(address='tcp://127.0.0.1:1'), 3)))
    assert the_bags and rec['error'].startswith('KilledWorker: '), rec
    for err in (OSError(28, 'No space left on device'), ConnectionResetError('lost')):
        rec, the_bags = _failed('/b', 'k', Erred(err))
        assert not the_bags and rec['status'] == 'failed' and type(err).__name__ in rec['error'], rec
