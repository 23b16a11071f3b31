"""``ccf fleet run`` resume rules, through the real command on a local cluster (``-j 1``): what a rerun submits
after nothing changed, ``--force``, a changed bag (size or mtime), changed settings and changed code (the code
version: ``__version__`` plus a hash of ccf_ros's sources)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip('distributed')

from ccf_ros import __version__
from ccf_ros.fleet.keys import bag_key, code_version, source_fingerprint
from ccf_ros.offline.simulate import generate, write_bag

BIN = Path(sys.executable).parent
N_BAGS = 3
PKG = Path(__file__).resolve().parents[1] / 'ccf_ros'


def _run(args: list[str], code_patch: str = '', timeout: float = 180) -> subprocess.CompletedProcess:
    """``ccf fleet run ARGS -j 1 --quiet --reference ''``; ``code_patch``: Python run in the driver before the
    command (the local cluster's worker processes are forked from it, so they see the same patch)."""
    argv = ['fleet', 'run', *args, '-j', '1', '--quiet', '--reference', '']
    if code_patch:
        cmd = [sys.executable, '-c', f'import sys\n{code_patch}\nfrom ccf_ros.cli import main\n'
               f'sys.exit(main({argv!r}))']
    else:
        cmd = [str(BIN / 'ccf'), *argv]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


def _processed(r: subprocess.CompletedProcess) -> tuple[int, int]:
    """(processed now, done before) from the command's summary line."""
    m = re.search(r'(\d+) processed now, (\d+) done before', r.stdout)
    assert m and r.returncode == 0, r.stdout + r.stderr
    return int(m[1]), int(m[2])


def _records(out: Path) -> dict[str, dict]:
    """results.jsonl by bag name."""
    return {Path(x['bag']).name: x for x in map(json.loads, (out / 'results.jsonl').read_text().splitlines())}


def _files(out: Path) -> dict[str, int]:
    """Result file name -> modification time, ns."""
    return {p.name: p.stat().st_mtime_ns for p in (out / 'bags').glob('*.json')}


@pytest.fixture(scope='module')
def first(tmp_path_factory) -> tuple[Path, Path]:
    """N_BAGS simulated bags (10 s at 100 Hz) and the output of one complete run over them."""
    root = tmp_path_factory.mktemp('resume')
    bags = root / 'bags'
    for i in range(N_BAGS):
        write_bag(generate(10.0, 100.0, 40 + i, rest_s=4.0), bags / f'b{i}')
    out = root / 'out0'
    assert _processed(_run([str(bags), '-o', str(out)])) == (N_BAGS, 0)
    return bags, out


def _copy(first: tuple[Path, Path], tmp_path: Path) -> tuple[Path, Path]:
    """The first run's bags and a copy of its output folder (the bags stay where they are: keys hold the path)."""
    bags, out0 = first
    out = tmp_path / 'out'
    shutil.copytree(out0, out)
    return bags, out


def test_rerun_with_nothing_changed_submits_nothing(first, tmp_path):
    bags, out = _copy(first, tmp_path)
    before, recs = _files(out), _records(out)
    r = _run([str(bags), '-o', str(out)])
    assert _processed(r) == (0, N_BAGS) and 'nothing to do' in r.stdout
    assert _files(out) == before and _records(out) == recs


def test_force_redoes_every_bag(first, tmp_path):
    bags, out = _copy(first, tmp_path)
    before = _files(out)
    assert _processed(_run([str(bags), '-o', str(out), '--force'])) == (N_BAGS, 0)
    after = _files(out)
    assert after.keys() == before.keys() and all(after[k] > before[k] for k in before)  # every file new
    assert {x['status'] for x in _records(out).values()} == {'ok'}


@pytest.mark.parametrize('change', ['mtime', 'size'])
def test_a_changed_bag_is_reprocessed_alone(first, tmp_path, change):
    bags, out = _copy(first, tmp_path)
    before = _records(out)
    meta = bags / 'b1' / 'metadata.yaml'
    st, text = meta.stat(), meta.read_bytes()
    try:
        if change == 'mtime':
            os.utime(meta, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
        else:  # one byte more, the modification time put back: the size alone tells
            meta.write_bytes(text + b'\n')
            os.utime(meta, ns=(st.st_atime_ns, st.st_mtime_ns))
        files = _files(out)
        assert _processed(_run([str(bags), '-o', str(out)])) == (1, N_BAGS - 1)
        after = _records(out)
        assert len(_files(out).keys() - files.keys()) == 1  # one new key, one new result
        assert after['b1']['wall_s'] != before['b1']['wall_s']
        assert all(after[k] == before[k] for k in before if k != 'b1')
    finally:
        meta.write_bytes(text)
        os.utime(meta, ns=(st.st_atime_ns, st.st_mtime_ns))


def test_changed_settings_reprocess_every_bag(first, tmp_path):
    bags, out = _copy(first, tmp_path)
    files = _files(out)
    assert _processed(_run([str(bags), '-o', str(out), '--param', 'tau_acc_s=2'])) == (N_BAGS, 0)
    assert len(_files(out).keys() - files.keys()) == N_BAGS  # new keys: results beside the first settings' ones
    # The first settings' results are still there: going back to them processes nothing.
    assert _processed(_run([str(bags), '-o', str(out)])) == (0, N_BAGS)


def test_changed_code_reprocesses_every_bag(first, tmp_path):
    """Other code under the same ``__version__`` (an upgrade from git, another commit): results of the old code are
    not kept. The patch stands for an edit of the sources (the hash of the installed ones is computed once, at import)."""
    bags, out = _copy(first, tmp_path)
    before = _records(out)
    assert {x['ccf_ros_version'] for x in before.values()} == {code_version()}
    patch = "import ccf_ros.fleet.keys as k\nk.source_fingerprint = lambda root: 'feedfacefeed'\nk.code_version.cache_clear()"
    files = _files(out)
    assert _processed(_run([str(bags), '-o', str(out)], code_patch=patch)) == (N_BAGS, 0)
    after = _records(out)
    assert {x['ccf_ros_version'] for x in after.values()} == {f'{__version__}+feedfacefeed'}
    assert len(_files(out).keys() - files.keys()) == N_BAGS


def test_code_version_is_the_version_plus_a_hash_of_the_sources():
    v = code_version()
    assert re.fullmatch(re.escape(__version__) + r'\+[0-9a-f]{12}', v), v
    assert v == f'{__version__}+{source_fingerprint(PKG)}'


def test_the_key_changes_when_the_code_fingerprint_changes(monkeypatch, tmp_path):
    import ccf_ros.fleet.keys as keys

    bag = tmp_path / 'x.mcap'
    bag.write_bytes(b'0' * 100)
    k0 = bag_key(str(bag), 's', keys.code_version())
    monkeypatch.setattr(keys, 'source_fingerprint', lambda root: '000000000000')
    keys.code_version.cache_clear()
    try:
        assert keys.code_version() == f'{__version__}+000000000000'
        assert bag_key(str(bag), 's', keys.code_version()) != k0
    finally:
        keys.code_version.cache_clear()


def test_the_fingerprint_changes_with_one_byte_of_the_sources(tmp_path):
    """Over a copy of the package: one changed byte of one .py file changes it; a .pyc (not the source) does not."""
    tree = tmp_path / 'ccf_ros'
    shutil.copytree(PKG, tree, ignore=shutil.ignore_patterns('__pycache__'))
    f0 = source_fingerprint(tree)
    assert f0 == source_fingerprint(PKG) and re.fullmatch(r'[0-9a-f]{12}', f0)
    target = tree / 'core' / 'ccf' / '__init__.py'
    data = bytearray(target.read_bytes())
    data[-1] ^= 0x01
    target.write_bytes(bytes(data))
    assert source_fingerprint(tree) != f0
    data[-1] ^= 0x01
    target.write_bytes(bytes(data))
    (tree / 'x.pyc').write_bytes(b'not a source')
    assert source_fingerprint(tree) == f0
