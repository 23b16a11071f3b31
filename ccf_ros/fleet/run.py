"""The driver of ``ccf fleet run``: discover bags, skip the done ones, run the rest on Dask, collect the results.

Workers write only their bag's result file (``OUT/bags/KEY.json``, atomically); this driver alone writes
``OUT/results.jsonl``, ``OUT/results.csv`` and the report, from those files, after the run.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import socket
import sys
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import CcfError
from .discover import discover
from .keys import bag_key, settings_hash
from .task import BAGS_DIR, FleetOptions, VersionMismatch, process_bag, result_path, write_first

__all__ = ['RunConfig', 'RunSummary', 'connect', 'load_results', 'run_fleet', 'write_tables']

#: Seconds to reach a scheduler before giving up (the command then exits 2 within 10 s).
CONNECT_TIMEOUT_S = 6.0
#: Seconds to wait for a first worker on a cluster that has none yet (adaptive dask-jobqueue or Kubernetes clusters
#: start workers on demand: a batch job may wait in its queue); ``--wait-workers``.
WORKER_WAIT_S = 300.0
#: Columns of results.csv before the metrics.
CSV_COLUMNS = ('bag', 'status', 'error', 'samples', 'health', 'flags', 'output')
#: Columns of results.csv after the metrics and the accuracy (added later: appended, so that positions stay).
CSV_LAST_COLUMNS = ('ccf_ros_version',)


class SchedulerUnreachable(CcfError):
    """The scheduler named by ``--scheduler`` or ``DASK_SCHEDULER_ADDRESS`` does not answer."""


@dataclass
class RunConfig:
    """A fleet run: inputs, output folder, cluster and resume choices, and the per-bag options."""

    inputs: list[str]
    out: Path
    options: FleetOptions
    jobs: int = 0  # local workers (0: one per core)
    scheduler: str | None = None
    retry_failed: bool = False
    force: bool = False
    retries: int = 2
    worker_wait_s: float = WORKER_WAIT_S
    progress: bool | None = None
    device_regex: str | None = None


@dataclass
class RunSummary:
    """What a run did: bags found, skipped as done, submitted, ok and failed in the end."""

    n_bags: int = 0
    n_done_before: int = 0
    n_submitted: int = 0
    n_ok: int = 0
    n_failed: int = 0
    samples: int = 0
    wall_s: float = 0.0
    records: list[dict[str, Any]] = field(default_factory=list)


def _need_dask() -> None:
    import importlib.util

    if importlib.util.find_spec('distributed') is None:
        raise CcfError("ccf fleet needs Dask: pip install 'ccf_ros[fleet]' (or: pip install 'dask[distributed]')")


def _bad_address(scheduler: str, why: str) -> CcfError:
    """The one-line error for a scheduler address that is not one (from --scheduler or DASK_SCHEDULER_ADDRESS)."""
    return CcfError(f'not a Dask scheduler address: {scheduler!r} ({why}; give tcp://HOST:PORT or HOST:PORT)')


def _tcp_host_port(scheduler: str) -> tuple[str, int] | None:
    """``(host, port)`` of a TCP scheduler address (``tcp://HOST:PORT``, or bare ``HOST:PORT``: Dask's default
    scheme, as its ``parse_address`` and ``parse_host_port`` read them; IPv6 in brackets); None for other schemes.
    :class:`CcfError` for one Dask would refuse (no port, a port that is not a number)."""
    scheme, sep, loc = scheduler.rpartition('://')
    if sep and scheme != 'tcp':
        return None
    if loc.startswith('['):
        host, sep, tail = loc[1:].partition(']')
        port = tail[1:] if sep and tail.startswith(':') else ''
    else:
        host, sep, port = loc.rpartition(':')
        if not sep:
            host, port = port, ''
        elif ':' in host:
            raise _bad_address(scheduler, 'an IPv6 host needs brackets, [::1]:PORT')
    if not port:
        raise _bad_address(scheduler, 'no port')
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise _bad_address(scheduler, f'the port {port!r} is not a number in 1-65535')
    if not host:
        raise _bad_address(scheduler, 'no host')
    return host, int(port)


def check_address(scheduler: str) -> None:
    """:class:`CcfError` for a scheduler address Dask cannot use (from --scheduler or DASK_SCHEDULER_ADDRESS): TCP
    ones checked here, other schemes by Dask (needs Dask)."""
    if _tcp_host_port(scheduler) is not None:
        return
    _need_dask()
    from distributed.comm import get_address_host

    try:
        # Dask's own check of another scheme's address: a Client that fails on one is left half started and blocks
        # for 12 s when it is collected. A scheme Dask has dropped (ucx:// without distributed-ucxx) warns, then
        # raises the FutureWarning: one error, without the warning's lines.
        with warnings.catch_warnings():
            warnings.simplefilter('error', FutureWarning)
            get_address_host(scheduler)
    except (ValueError, FutureWarning) as err:
        raise _bad_address(scheduler, ' '.join(str(err).split())[:200]) from err


def _probe(scheduler: str) -> None:
    """A plain TCP connect to a TCP scheduler first: a refused or unroutable address fails at once, before Dask is
    imported (Dask's client retries a refused connection until its timeout, and importing it takes seconds on a
    loaded machine: together they can pass the 10 s the command promises). Other schemes go to Dask."""
    where = _tcp_host_port(scheduler)
    if where is None:
        return
    try:
        socket.create_connection(where, timeout=CONNECT_TIMEOUT_S).close()
    except OSError as err:
        raise SchedulerUnreachable(f'cannot reach the Dask scheduler at {scheduler}: {type(err).__name__}: '
                                   f'{" ".join(str(err).split())[:200]}') from err


@contextlib.contextmanager
def connect(scheduler: str | None, jobs: int) -> Iterator[Any]:
    """A Dask client: on ``scheduler`` (an address :func:`check_address` passed) if given, else on a local cluster of
    ``jobs`` single-threaded worker processes (0: one per core) bound to 127.0.0.1, started and stopped here."""
    _need_dask()
    if scheduler:
        _probe(scheduler)
    import logging

    from distributed import Client, LocalCluster

    logging.getLogger('distributed').setLevel(logging.ERROR)
    if scheduler:
        try:
            client = Client(scheduler, timeout=f'{CONNECT_TIMEOUT_S}s', set_as_default=False)
        except (OSError, TimeoutError, ValueError) as err:
            raise SchedulerUnreachable(f'cannot reach the Dask scheduler at {scheduler}: {type(err).__name__}: '
                                       f'{" ".join(str(err).split())[:200]}') from err
        try:
            yield client
        finally:
            client.close()
        return
    n = jobs or os.cpu_count() or 1
    import dask

    with (
        # The workers' statistical profiler samples every 10 ms: a third more CPU on these pure-Python tasks.
        # Worker processes forked from this one (which has Dask and ccf_ros imported) instead of spawned: each
        # skips ~1 CPU s of imports (a one-bag run: 8.4 -> 6.7 CPU s). POSIX only; elsewhere Dask's default.
        # Monitors at Dask's defaults (event-loop tick 20 ms, system monitor 0.5 s, memory 0.1 s) cost an idle
        # 2-worker cluster 2.8 CPU s per 20 s here (14 % of a core, through the whole run); at these, 0.4.
        dask.config.set({'distributed.worker.profile.enabled': False,
                         'distributed.admin.tick.interval': '1s',
                         'distributed.admin.system-monitor.interval': '5s',
                         'distributed.worker.memory.monitor-interval': '1s',
                         **({'distributed.worker.multiprocessing-method': 'fork'} if sys.platform == 'linux' else {})}),
        LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host='127.0.0.1', dashboard_address=None,
                     silence_logs=logging.ERROR) as cluster,
        Client(cluster, set_as_default=False) as client,
    ):
        yield client


def wait_for_workers(client: Any, timeout_s: float, where: str) -> None:
    """Return once the cluster has a worker; :class:`CcfError` if none joined within ``timeout_s``."""
    if client.scheduler_info().get('workers'):
        return
    try:
        client.wait_for_workers(1, timeout=timeout_s)
    except TimeoutError as err:  # (also asyncio's and Dask's: the same class since Python 3.11)
        raise CcfError(f'no worker joined the Dask cluster at {where} within {timeout_s:g} s (start workers, or '
                       f'--wait-workers S for a cluster that takes longer)') from err


def check_versions(client: Any, version: str) -> None:
    """:class:`CcfError` naming the workers whose ccf_ros code version (:func:`.keys.code_version`) is not
    ``version`` (or that lack ccf_ros)."""

    def worker_version() -> str:
        try:
            from ccf_ros.fleet.keys import code_version
        except ImportError:
            try:
                from ccf_ros import __version__  # a ccf_ros from before code_version
            except ImportError:
                return 'none (ccf_ros not installed)'
            return str(__version__)
        return code_version()

    versions = client.run(worker_version)
    wrong = {w: v for w, v in versions.items() if v != version}
    if wrong:
        listed = ', '.join(f'{w} has {v}' for w, v in sorted(wrong.items()))
        raise CcfError(f'workers run another ccf_ros than this driver ({version}): {listed}; install the '
                       f'driver\'s ccf_ros (the same release and sources) on every worker')
    if not versions:
        raise CcfError('the Dask cluster has no workers')


def load_results(out: Path) -> dict[str, dict[str, Any]]:
    """The bag result files under ``out`` by key (unreadable ones are left out: their bags run again)."""
    found: dict[str, dict[str, Any]] = {}
    folder = out / BAGS_DIR
    if not folder.is_dir():
        return found
    for p in folder.glob('*.json'):
        if p.name.startswith('.'):
            continue
        try:
            rec = json.loads(p.read_text())
        except (OSError, ValueError):
            continue
        if isinstance(rec, dict) and rec.get('key') == p.stem:
            found[p.stem] = rec
    return found


def _clean_temporaries(out: Path) -> None:
    """Remove what killed workers left: half-written result files and output-bag staging folders."""
    import shutil

    folder = out / BAGS_DIR
    if folder.is_dir():
        for p in folder.iterdir():
            if p.name.startswith('.') and (p.name.endswith('.tmp') or p.name.endswith('.partial')):
                shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)


def _flat(rec: dict[str, Any]) -> dict[str, Any]:
    row: dict[str, Any] = {c: rec.get(c, '') for c in CSV_COLUMNS}
    row['flags'] = ';'.join(rec.get('flags', []))
    row.update(rec.get('metrics') or {})
    for k, v in (rec.get('accuracy') or {}).items():
        if not isinstance(v, list):
            row[f'accuracy_{k}'] = v
    row.update({c: rec.get(c, '') for c in CSV_LAST_COLUMNS})
    return row


def _no_nan(x: Any) -> Any:
    """``x`` with NaN and infinities as None (null): strict JSON, which DuckDB, pandas and jq all read."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _no_nan(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_no_nan(v) for v in x]
    return x


def write_tables(out: Path, records: list[dict[str, Any]]) -> None:
    """``results.jsonl`` (one object per bag) and ``results.csv`` (one row per bag), each written atomically."""
    lines = ''.join(json.dumps(_no_nan({k: v for k, v in r.items() if k != 'key'}), allow_nan=False) + '\n'
                    for r in records)
    rows = [_flat(r) for r in records]
    fixed = set(CSV_COLUMNS) | set(CSV_LAST_COLUMNS)
    columns = [*CSV_COLUMNS, *sorted({k for r in rows for k in r} - fixed), *CSV_LAST_COLUMNS]
    buf = io.StringIO()
    w = csv.DictWriter(buf, columns, restval='')
    w.writeheader()
    for r in rows:
        w.writerow({k: ('' if isinstance(v, float) and math.isnan(v) else v) for k, v in r.items()})
    for name, text in (('results.jsonl', lines), ('results.csv', buf.getvalue())):
        tmp = out / f'.{name}.tmp'
        tmp.write_text(text)
        tmp.replace(out / name)


def _failed(bag: str, key: str, fut: Any) -> tuple[dict[str, Any], bool]:
    """The record of a bag whose task did not return: cancelled (by another client, or the cluster shutting down),
    its workers lost beyond Dask's ``allowed-failures`` (``KilledWorker``), or a task error outside the bag's own
    handling; and whether it is the bag's own failure to keep on disk (only ``KilledWorker``: a bag that kills its
    workers; a lost connection, a result that could not be sent back or a full disk are not the bag's, and the next
    run tries it again). :class:`CcfError` for workers of another version."""
    import asyncio
    import concurrent.futures

    from distributed import KilledWorker

    try:
        err = None if fut.status == 'cancelled' else fut.exception()
    except (concurrent.futures.CancelledError, asyncio.CancelledError):
        err = None
    if err is None:
        reason = 'Cancelled: the task was cancelled on the cluster before it finished'
    elif isinstance(err, VersionMismatch):
        raise CcfError(str(err))
    else:
        reason = f'{type(err).__name__}: {" ".join(str(err).split())}'
    return {'bag': bag, 'key': key, 'status': 'failed', 'error': reason}, isinstance(err, KilledWorker)


def _submit_and_collect(client: Any, todo: list[tuple[str, str]], cfg: RunConfig, summary: RunSummary,
                        results: dict[str, dict[str, Any]]) -> None:
    from distributed import as_completed
    from tqdm import tqdm

    futures = {}
    for bag, key in todo:
        fut = client.submit(process_bag, bag, key, cfg.options, key=f'ccf-fleet-{key}', pure=False,
                            retries=cfg.retries)
        futures[fut] = (bag, key)
    summary.n_submitted = len(futures)
    disable = (not sys.stderr.isatty()) if cfg.progress is None else not cfg.progress
    bar = tqdm(total=len(futures), unit='bag', desc='fleet', disable=disable, mininterval=0.5)
    t0, samples, failed = time.perf_counter(), 0, 0
    try:
        for fut in as_completed(list(futures), loop=client.loop):
            bag, key = futures[fut]
            if fut.status == 'finished':
                rec = fut.result()
            else:
                rec, the_bags = _failed(bag, key, fut)
                rec['ccf_ros_version'] = cfg.options.version
                if the_bags:
                    # A bag that kills its workers (out of memory on every one, a crash in C) is recorded as
                    # failed like any other: a plain rerun does not resubmit it (--retry-failed does). A result an
                    # attempt wrote first is kept (exactly once). Anything else (cancelled, a lost connection) is
                    # not the bag's fault: no file, the next run does it.
                    _record_failure(cfg.out, rec)
            results[key] = rec
            samples += int(rec.get('samples', 0) or 0)
            failed += rec['status'] != 'ok'
            rate = samples / max(time.perf_counter() - t0, 1e-9)
            bar.set_postfix_str(f'failed {failed}, {rate:,.0f} samples/s', refresh=False)
            bar.update(1)
    finally:
        bar.close()


def _record_failure(out: Path, rec: dict[str, Any]) -> None:
    """Write a failure known only here as the bag's result file (unless an attempt's result is there already)."""
    path = result_path(out.absolute(), rec['key'])
    path.parent.mkdir(parents=True, exist_ok=True)
    write_first(path, json.dumps(rec))


def run_fleet(cfg: RunConfig) -> RunSummary:
    """Run ``cfg``; returns the summary (records: one per bag, in input order). Raises :class:`CcfError` for a
    usage problem, an unreachable scheduler or workers of another version."""
    t0 = time.perf_counter()
    out = cfg.out.absolute()
    if out.exists() and not out.is_dir():
        raise CcfError(f'the output {out} exists and is not a folder (-o/--output names the results folder)')
    if cfg.scheduler:
        check_address(cfg.scheduler)  # a malformed address is a usage error: before any work
    bags = discover(cfg.inputs, exclude=out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:  # (a parent that is a file, no permission)
        raise CcfError(f'cannot create the output folder {out}: {err.strerror}') from err
    opts = cfg.options
    settings = settings_hash({'engine': opts.settings, 'strict': opts.strict, 'imu': opts.imu_topic,
                              'mag': opts.mag_topic, 'no_mag': opts.no_mag, 'write_bags': opts.write_bags,
                              'reference': opts.reference, 'mask': opts.mask_topic,
                              'hint': [opts.motion_hint_topic, *opts.motion_hint]})
    keys = [(bag, bag_key(bag, settings, opts.version)) for bag in bags]
    results = load_results(out)
    summary = RunSummary(n_bags=len(bags))
    todo = []
    for bag, key in keys:
        rec = results.get(key)
        if rec is None or cfg.force or (cfg.retry_failed and rec.get('status') != 'ok'):
            todo.append((bag, key))
        else:
            summary.n_done_before += 1
    if todo:
        with connect(cfg.scheduler, cfg.jobs) as client:
            wait_for_workers(client, cfg.worker_wait_s, cfg.scheduler or 'the local cluster')
            check_versions(client, opts.version)
            # --force / --retry-failed: the old results go once the cluster is there (an unreachable scheduler or
            # workers of another version leave them as they were).
            for _, key in todo:
                result_path(out, key).unlink(missing_ok=True)
            _submit_and_collect(client, todo, cfg, summary, results)
    _clean_temporaries(out)
    if todo:
        # The files are the record (a task Dask ran twice returned its own result; the file kept the first).
        on_disk = load_results(out)
        for _, key in todo:
            if key in on_disk:
                results[key] = on_disk[key]
    summary.records = [results[key] for _, key in keys]
    for r in summary.records:
        summary.n_ok += r['status'] == 'ok'
        summary.n_failed += r['status'] != 'ok'
        summary.samples += int(r.get('samples', 0) or 0)
    write_tables(out, summary.records)
    summary.wall_s = time.perf_counter() - t0
    return summary
