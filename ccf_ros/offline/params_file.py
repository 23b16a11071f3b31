"""Read filter settings from a ROS 2 parameters file (the same YAML the node takes) and ``NAME=VALUE`` pairs."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any


def load_params_file(path: str | Path) -> dict[str, Any]:
    """Flat ``name: value`` settings from ``<node or /**>: ros__parameters: {...}``; ValueError if malformed."""
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text())
    except OSError as err:
        raise ValueError(f'cannot read parameters file {path}: {err.strerror}') from None
    except yaml.YAMLError as err:
        raise ValueError(f'parameters file {path} is not valid YAML: {err}') from None
    if not isinstance(data, dict):
        raise ValueError(f'parameters file {path}: expected "<node>: ros__parameters: {{...}}"')
    out: dict[str, Any] = {}
    for node, body in data.items():
        if not isinstance(body, dict) or 'ros__parameters' not in body:
            raise ValueError(f'parameters file {path}: entry {node!r} has no ros__parameters')
        out.update(_flatten(body['ros__parameters'] or {}))
    return out


def _flatten(d: dict[str, Any], prefix: str = '') -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f'{prefix}{k}.'))
        else:
            out[f'{prefix}{k}'] = v
    return out


def parse_assignments(items: Iterable[str]) -> dict[str, str]:
    """``['a=1', 'b=x']`` -> ``{'a': '1', 'b': 'x'}``; ValueError on an item without ``=``."""
    out = {}
    for item in items:
        name, sep, value = item.partition('=')
        if not sep or not name.strip():
            raise ValueError(f'--param expects NAME=VALUE, got {item!r}')
        out[name.strip()] = value.strip()
    return out
