"""Read filter settings from ROS 2 parameters files (the same YAML the node takes) and ``NAME=VALUE`` pairs."""

from __future__ import annotations

import functools
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ..errors import ParameterError
from ..settings import refuse_text

#: The node whose sections are read when no name is given: ccf_node's default name.
DEFAULT_NODE_NAME = 'ccf_node'


def load_params_file(path: str | Path, node_name: str | None = None) -> dict[str, Any]:
    """Flat ``name: value`` settings of the node ``node_name`` (``name`` or ``/ns/name``) in ``<node>:
    ros__parameters: {...}`` sections, taken as rclpy takes them: every section whose name matches the node's
    (``/**``, ``name``, ``/ns/name``, ``ns: {name: ...}``, the wildcards ``/*`` (one name) and ``/**`` (any number)), in
    file order, a later one overriding. A file of one section is that node's, whatever its name.

    Raises:
        ParameterError: the file cannot be read, is not YAML, has no ``ros__parameters``, (several sections) none
            for the node, or text for a setting that is not text (``tau_acc_s: '2'``, refused by the node too).
    """
    return load_params_files([path], node_name)


def load_params_files(paths: Iterable[str | Path], node_name: str | None = None) -> dict[str, Any]:
    """The settings of several parameters files, in order: a later file overrides an earlier one."""
    out: dict[str, Any] = {}
    for path in paths:
        out.update(_node_params(path, node_name))
    return _typed(out)


def _typed(params: dict[str, Any]) -> dict[str, Any]:
    """``params``, text for a setting that is not text refused: YAML values have a type, as ROS parameters do."""
    for name, value in params.items():
        refuse_text(name, value)
    return params


def _node_params(path: str | Path, node_name: str | None) -> dict[str, Any]:
    """:func:`load_params_file`'s settings, not yet checked."""
    import yaml

    try:
        data = yaml.load(Path(path).read_text(), Loader=_loader())  # (a SafeLoader)
    except OSError as err:
        raise ParameterError(f'cannot read parameters file {path}: {err.strerror}') from err
    except (yaml.YAMLError, ValueError) as err:  # (ValueError: a scalar its resolver took for a number, not one)
        raise ParameterError(f'parameters file {path} is not valid YAML: {" ".join(str(err).split())}') from err
    if not isinstance(data, dict):
        raise ParameterError(f'parameters file {path}: expected "<node>: ros__parameters: {{...}}"')
    sections = _sections(path, data)
    if len(sections) > 1:
        fqn = node_fqn(node_name)
        matching = [(name, params) for name, params in sections if _matches(name, fqn)]
        if not matching:
            raise ParameterError(f'parameters file {path}: no section for node {fqn} (sections: '
                                 f'{", ".join(name for name, _ in sections)}; --node-name names the node)')
        sections = matching
    out: dict[str, Any] = {}
    for _, params in sections:
        out.update(params)
    return out


#: A real with an exponent and no point (``1e-4``, ``2e0``): YAML 1.1, which PyYAML follows, reads it as text; ROS 2's
#: parameters-file parser reads it as a number.
_EXPONENT_REAL = re.compile(r'^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$')


@functools.cache
def _loader() -> type:
    """PyYAML's safe loader, reading reals as rcl does (:data:`_EXPONENT_REAL`)."""
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    Loader.add_implicit_resolver('tag:yaml.org,2002:float', _EXPONENT_REAL, list('-+0123456789.'))
    return Loader


def node_fqn(node_name: str | None = None) -> str:
    """``/NAMESPACE/NAME`` of the node ``node_name`` (``NAME`` or ``/NAMESPACE/NAME``; if not given: ccf_node)."""
    return '/' + (node_name or DEFAULT_NODE_NAME).strip('/')


def resolve_topic(topic: str, node_name: str | None = None) -> str:
    """``topic`` as the node ``node_name`` resolves it (ROS 2 rules): an absolute name unchanged, ``~/NAME`` under the
    node's own name, a relative ``NAME`` in the node's namespace."""
    if topic.startswith('/'):
        return topic
    fqn = node_fqn(node_name)
    if topic == '~' or topic.startswith('~/'):
        return fqn + topic[1:]
    return f'{fqn.rpartition("/")[0]}/{topic}'


def _sections(path: str | Path, data: dict[Any, Any], namespace: str = '') -> list[tuple[str, dict[str, Any]]]:
    """``(full name, flat parameters)`` of every node section, in file order (a mapping without
    ``ros__parameters`` is a namespace holding nodes)."""
    out = []
    for key, body in data.items():
        name = f'{namespace}/{str(key).strip("/")}'
        if isinstance(body, dict) and 'ros__parameters' in body:
            params = body['ros__parameters'] or {}
            if not isinstance(params, dict):
                raise ParameterError(f'parameters file {path}: ros__parameters of {name!r} is not a mapping')
            out.append((name, _flatten(params)))
        elif isinstance(body, dict) and body:
            out += _sections(path, body, name)
        else:
            raise ParameterError(f'parameters file {path}: entry {name!r} has no ros__parameters')
    return out


def _matches(section: str, fqn: str) -> bool:
    """Whether the section ``section`` (``/ns/name``, with ``/*`` and ``/**`` wildcards) applies to the node ``fqn``."""
    pattern = ''.join('(/[^/]+)*' if token == '**' else '/[^/]+' if token == '*' else '/' + re.escape(token)
                      for token in section.strip('/').split('/'))
    return re.fullmatch(pattern, fqn) is not None


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
