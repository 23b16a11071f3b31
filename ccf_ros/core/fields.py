"""How a parameter is defined once: a dataclass field with its SI unit, range and description, and the one parser
for flags and for lists of numbers written as text (``--param``, parameters files). Standard library only.

:func:`param` is used by the core's params dataclasses and by :mod:`ccf_ros.settings` (engine and node settings);
:mod:`ccf_ros.settings` builds the settings schema (node declarations, validation, ``ccf params``,
``config/ccf.yaml``, the README table) from these fields.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import field
from typing import Any

#: Text read as true / false by :func:`parse_bool` (stripped, any case).
TRUE_TEXT = ('true', '1', 'yes', 'on')
FALSE_TEXT = ('false', '0', 'no', 'off')


def param(default: Any, unit: str, description: str, lo: float | None = None, hi: float | None = None, *,
          above: bool = False, choices: tuple[str, ...] = (), per_axis: bool = False, what: str = '',
          lengths: tuple[int, ...] = ()) -> Any:
    """A params-dataclass field defined once: its default, SI unit (``-``: none), one-line description and, for
    numbers (each element of a list), the inclusive range ``[lo, hi]`` (``above``: ``lo`` itself excluded).

    ``choices``: the allowed strings; ``per_axis``: one number or ``[roll, pitch, yaw]``; a list's allowed
    ``lengths`` (default: the default's) and ``what`` it is called in an error (``'9 numbers'``).
    """
    if isinstance(default, tuple) and not lengths:
        lengths = (len(default),)
    meta = {'unit': unit, 'description': description, 'range': None if lo is None else (lo, hi), 'above': above,
            'choices': choices, 'per_axis': per_axis, 'what': what or f'{lengths[0] if lengths else 1} numbers',
            'lengths': lengths}
    return field(default=default, metadata=meta)


def parse_bool(name: str, value: Any) -> bool:
    """``value`` as a bool: a bool, or text ``true/false``, ``1/0``, ``yes/no``, ``on/off`` (any case); ValueError
    naming ``name`` otherwise (an integer too: YAML's ``1`` is not a flag)."""
    if isinstance(value, bool):
        return value
    if isinstance(value, str):
        low = value.strip().lower()
        if low in TRUE_TEXT:
            return True
        if low in FALSE_TEXT:
            return False
    raise ValueError(f'{name} must be true or false, got {value!r}')


def parse_number(name: str, value: Any) -> float:
    """``value`` as a float: an int or float (not a bool), or its text; ValueError naming ``name`` otherwise."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, str):
        try:
            return float(value.strip())
        except ValueError:
            pass
    raise ValueError(f'{name} must be a number, got {value!r}')


def parse_numbers(name: str, value: Any, what: str = 'a list of numbers') -> tuple[float, ...]:
    """A list of numbers as floats: a sequence (the ``array.array`` rclpy gives included) of numbers, or text
    ``[1, 0, 0]`` / ``1, 0, 0``; ValueError naming ``name`` and saying ``what`` is expected otherwise."""
    items: Iterable[Any]
    if isinstance(value, str):
        items = [v for v in value.strip().strip('[]()').split(',') if v.strip()]
    elif isinstance(value, bytes) or not isinstance(value, Iterable):
        raise ValueError(f'{name} must be {what}, got {value!r}')
    else:
        items = value
    try:
        return tuple(parse_number(name, v) for v in items)  # an element that is no number: its own error
    except TypeError:
        raise ValueError(f'{name} must be {what}, got {value!r}') from None
