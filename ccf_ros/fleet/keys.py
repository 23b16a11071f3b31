"""What makes a bag's result current: the bag's identity (path, size, modification time), the settings and the
code (:func:`code_version`: the ccf_ros version plus a hash of its sources), hashed into the key that names its
result file."""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path
from typing import Any

__all__ = ['bag_identity', 'bag_key', 'code_version', 'settings_hash', 'source_fingerprint']


def bag_identity(bag: str) -> tuple[str, int, int]:
    """(absolute path, size in bytes, latest modification time in ns) of a bag file or folder (its files summed)."""
    p = Path(bag)
    if p.is_dir():
        files = [f for f in p.iterdir() if f.is_file()]
        stats = [f.stat() for f in files]
        return str(p.absolute()), sum(s.st_size for s in stats), max((s.st_mtime_ns for s in stats), default=0)
    st = p.stat()
    return str(p.absolute()), st.st_size, st.st_mtime_ns


def source_fingerprint(root: str | Path) -> str:
    """A short hash (12 hex digits) of the ``.py`` files under the package folder ``root``: their paths relative to
    it and their bytes. Any edit of the code (an upgrade, another commit on a worker) changes it."""
    root = Path(root)
    h = hashlib.sha256()
    for f in sorted(root.rglob('*.py'), key=lambda p: p.relative_to(root).as_posix()):
        data = f.read_bytes()
        h.update(f'{f.relative_to(root).as_posix()}\0{len(data)}\0'.encode())
        h.update(data)
    return h.hexdigest()[:12]


@functools.cache
def code_version() -> str:
    """The code a result was computed with: ``__version__`` plus :func:`source_fingerprint` of this installed
    ccf_ros, e.g. ``0.1.0+1a2b3c4d5e6f`` (read once per process: ~1 MB of sources, a few ms). It goes into every
    key and is what driver and workers must share: a fixed ``__version__`` alone would keep results of older code
    on a rerun after an upgrade, and let workers on another commit pass the check."""
    from .. import __version__

    return f'{__version__}+{source_fingerprint(Path(__file__).resolve().parents[1])}'


def settings_hash(settings: dict[str, Any]) -> str:
    """A stable hash of everything that changes a bag's result: engine settings, topics, outputs."""
    text = json.dumps(settings, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def bag_key(bag: str, settings: str, version: str) -> str:
    """The key of a bag's result: changes when the bag, the settings or the code (``version``: :func:`code_version`)
    change."""
    try:
        ident = bag_identity(bag)
    except OSError:
        ident = (str(Path(bag).absolute()), -1, -1)
    text = json.dumps([*ident, settings, version])
    return hashlib.sha256(text.encode()).hexdigest()[:24]


# The fingerprint of the sources as this process imported them (a worker imports the fleet modules with the rest of
# ccf_ros): an upgrade of the files on disk while it runs does not relabel results of the code it runs.
code_version()
