"""The node's parameter values as plain code (no ROS import): ranges and the check of a value as the node receives
it (an integer for a real parameter included, text only for a text parameter). The definitions are
:mod:`ccf_ros.settings` (one schema)."""

from __future__ import annotations

from typing import Any

from ..settings import coerce, refuse_text, schema

# The parameters' definitions, ranges and validation are in ccf_ros.settings (one schema); these names stay for
# existing imports.
#: Parameters whose value may be a number or a list of three (per axis).
PER_AXIS = frozenset(name for name, p in schema().items() if p.per_axis)
#: Range of a real parameter without its own.
DEFAULT_RANGE = (0.0, 1e9)


def parameter_range(name: str) -> tuple[float, float]:
    """The inclusive range of the real parameter ``name`` (its definition's)."""
    return schema()[name].range or DEFAULT_RANGE


def coerce_parameter(name: str, value: Any, default: Any = None) -> Any:
    """``value`` of the parameter ``name``, as the node receives it, as the settings take it:
    :func:`ccf_ros.settings.coerce`, and text refused for a setting that is not text (``default``, the executable's,
    is not needed: the definition has the type).

    coerce converts text because ``--param`` gives replay text; a ROS parameter has a type, and a string taken for a
    number (``ros2 param set`` of ``"'2'"`` on a dynamically typed parameter) would be stored as the string
    (:func:`ccf_ros.settings.refuse_text`, as replay's parameters files).

    Raises:
        ParameterError: not of the parameter's type, or out of range; the message names the parameter.
    """
    refuse_text(name, value)
    return coerce(name, value)
