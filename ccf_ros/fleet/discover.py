"""The bags of a fleet run's inputs: bags, folders searched recursively, ``@list.txt`` files."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import CcfError

__all__ = ['BAG_SUFFIXES', 'discover', 'is_bag']

#: Storage files that are a bag by themselves (rosbag2 MCAP or SQLite3 without metadata.yaml, ROS 1).
BAG_SUFFIXES = ('.mcap', '.db3', '.bag')


def is_bag(p: Path) -> bool:
    """A rosbag2 folder (with ``metadata.yaml``) or a bare storage file."""
    return (p.is_dir() and (p / 'metadata.yaml').is_file()) or (p.is_file() and p.suffix in BAG_SUFFIXES)


def _walk(folder: Path) -> list[Path]:
    """Bags under ``folder``: a rosbag2 folder is one bag (its storage files are not searched again)."""
    found: list[Path] = []
    for root, dirs, files in os.walk(folder, followlinks=True):
        here = Path(root)
        if 'metadata.yaml' in files:
            found.append(here)
            dirs.clear()
            continue
        dirs[:] = sorted(d for d in dirs if not d.startswith('.'))
        found += [here / f for f in sorted(files) if Path(f).suffix in BAG_SUFFIXES and not f.startswith('.')]
    return found


def discover(inputs: list[str], *, exclude: Path | None = None) -> list[str]:
    """Absolute paths of the bags in ``inputs`` (in the order given, each once). A folder is searched recursively;
    ``@FILE`` reads one path per line (blank lines and ``#`` comments skipped; relative to the list's folder).
    ``exclude``: a folder whose bags are left out (the run's own output). :class:`CcfError` for an input that is
    neither a bag nor a folder, and when no bag is found."""
    bags: list[str] = []
    seen: set[str] = set()

    def add(p: Path) -> None:
        key = str(p.absolute())
        if exclude is not None and (p.absolute() == exclude or exclude in p.absolute().parents):
            return
        if key not in seen:
            seen.add(key)
            bags.append(key)

    def visit(item: str, base: Path) -> None:
        if item.startswith('@'):
            listing = (base / item[1:]) if not Path(item[1:]).is_absolute() else Path(item[1:])
            try:
                lines = listing.read_text().splitlines()
            except OSError as err:
                raise CcfError(f'cannot read list {listing}: {err.strerror}') from err
            for line in lines:
                line = line.strip()
                if line and not line.startswith('#'):
                    visit(line, listing.parent)
            return
        p = Path(item) if Path(item).is_absolute() else base / item
        if is_bag(p):
            add(p)
        elif p.is_dir():
            for b in _walk(p):
                add(b)
        elif p.exists():
            raise CcfError(f'{p}: not a bag (a rosbag2 folder, .mcap, .db3 or ROS 1 .bag) nor a folder')
        else:
            raise CcfError(f'{p}: no such bag or folder')

    for item in inputs:
        visit(item, Path.cwd())
    if not bags:
        raise CcfError(f'no bags found in {", ".join(inputs)}')
    return bags
