"""Read filter settings from ROS 2 parameters files (the same YAML the node takes) and ``NAME=VALUE`` pairs."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ..errors import ParameterError


def load_params_file(path: str | Path) -> dict[str, Any]:
    """Flat ``name: value`` settings from ``<node or /**>: ros__parameters: {...}``.

    Raises:
        ParameterError: the file cannot be read, is not YAML, or has no ``ros__parameters``.
    """
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text())
    except OSError as err:
        raise ParameterError(f'cannot read parameters file {path}: {err.strerror}') from err
    except yaml.YAMLError as err:
        raise ParameterError(f'parameters file {path} is not valid YAML: {" ".join(str(err).split())}') from err
    if not isinstance(data, dict):
        raise ParameterError(f'parameters file {path}: expected "<node>: ros__parameters: {{...}}"')
    out: dict[str, Any] = {}
    for node, body in data.items():
        if not isinstance(body, dict) or 'ros__parameters' not in body:
            raise ParameterError(f'parameters file {path}: entry {node!r} has no ros__parameters')
        params = body['ros__parameters'] or {}
        if not isinstance(params, dict):
            raise ParameterError(f'parameters file {path}: ros__parameters of {node!r} is not a mapping')
        out.update(_flatten(params))
    return out


def load_params_files(paths: Iterable[str | Path]) -> dict[str, Any]:
    """The settings of several parameters files, in order: a later file overrides an earlier one."""
    out: dict[str, Any] = {}
    for path in paths:
        out.update(load_params_file(path))
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
    """``['a=1', 'b=x']`` -> ``{'a': '1', 'b': 'x'}``; :class:`ParameterError` on an item without ``=``."""
    out = {}
    for item in items:
        name, sep, value = item.partition('=')
        if not sep or not name.strip():
            raise ParameterError(f'--param expects NAME=VALUE, got {item!r}')
        out[name.strip()] = value.strip()
    return out
