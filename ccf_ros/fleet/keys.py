"""What makes a bag's result current: the bag's identity (path, size, modification time), the settings and the
ccf_ros version, hashed into the key that names its result file."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

__all__ = ['bag_identity', 'bag_key', 'settings_hash']


def bag_identity(bag: str) -> tuple[str, int, int]:
    """(absolute path, size in bytes, latest modification time in ns) of a bag file or folder (its files summed)."""
    p = Path(bag)
    if p.is_dir():
        files = [f for f in p.iterdir() if f.is_file()]
        stats = [f.stat() for f in files]
        return str(p.absolute()), sum(s.st_size for s in stats), max((s.st_mtime_ns for s in stats), default=0)
    st = p.stat()
    return str(p.absolute()), st.st_size, st.st_mtime_ns


def settings_hash(settings: dict[str, Any]) -> str:
    """A stable hash of everything that changes a bag's result: engine settings, topics, outputs."""
    text = json.dumps(settings, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def bag_key(bag: str, settings: str, version: str) -> str:
    """The key of a bag's result: changes when the bag, the settings or the version change."""
    try:
        ident = bag_identity(bag)
    except OSError:
        ident = (str(Path(bag).absolute()), -1, -1)
    text = json.dumps([*ident, settings, version])
    return hashlib.sha256(text.encode()).hexdigest()[:24]
