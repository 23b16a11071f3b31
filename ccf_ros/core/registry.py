"""Build any core filter from flat ``name: value`` settings (the names of ``config/ccf.yaml`` and ``--param``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from .base import CommonParams, OrientationFilter
from .baselines import Madgwick, MadgwickParams, Mahony, MahonyParams
from .ccf import CcfParams, QuaternionCcf
from .euler_ccf import EulerCcf, EulerCcfParams, EulerNcf, Lcf, LcfParams, NcfParams
from .fields import parse_bool, parse_number, parse_numbers
from .kalman import Ckf, CkfParams, Ekf, EkfParams

#: (filter, formulation) -> (params class, filter class)
FILTERS: dict[tuple[str, str], tuple[type[CommonParams], type[OrientationFilter]]] = {
    ('ccf', 'quaternion'): (CcfParams, QuaternionCcf),
    ('ccf', 'euler'): (EulerCcfParams, EulerCcf),
    # Baselines of the paper's comparison; `formulation` does not apply to them.
    ('madgwick', 'quaternion'): (MadgwickParams, Madgwick),
    ('mahony', 'quaternion'): (MahonyParams, Mahony),
    ('lcf', 'euler'): (LcfParams, Lcf),
    ('ncf', 'euler'): (NcfParams, EulerNcf),
    ('ekf', 'euler'): (EkfParams, Ekf),
    ('ckf', 'euler'): (CkfParams, Ckf),
}

#: Settings that select the filter rather than parametrise it.
SELECTORS = {'filter': 'ccf', 'formulation': 'quaternion'}


def param_fields(cls: type[CommonParams]) -> dict[str, dataclasses.Field[Any]]:
    """Public init fields of a params dataclass by name."""
    return {f.name: f for f in dataclasses.fields(cls) if f.init and not f.name.startswith('_')}


def all_param_names() -> set[str]:
    """Every parameter name any filter accepts, plus the selectors."""
    names = set(SELECTORS)
    for params_cls, _ in FILTERS.values():
        names |= set(param_fields(params_cls))
    return names


def _coerce(name: str, value: Any, default: Any) -> Any:
    """Convert ``value`` to the type of ``default`` (from YAML/CLI strings or ROS parameter types); the params
    dataclass then checks it against its definition."""
    if isinstance(default, bool):
        return parse_bool(name, value) if isinstance(value, str) else value
    if isinstance(default, tuple):
        # lists, tuples, text, and the array.array rclpy returns for double-array parameters
        return parse_numbers(name, value, f'{len(default)} numbers')
    if isinstance(default, (int, float)):
        if isinstance(value, str):
            text = value.strip()
            return parse_numbers(name, text) if text.startswith('[') else parse_number(name, text)
        if isinstance(value, (list, tuple)):
            return tuple(float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v for v in value)
        if isinstance(value, int) and not isinstance(value, bool):
            return float(value)
    return value


def make_filter(settings: Mapping[str, Any] | None = None, *, strict: bool = True) -> OrientationFilter:
    """Create the filter selected by ``settings['filter']``/``['formulation']`` with the other settings applied.

    Args:
        settings: flat ``name: value`` mapping; values may be strings (CLI) and are converted.
        strict: raise ``ValueError`` for a name the selected filter does not use. With ``strict=False`` names of
            other filters are ignored (a parameters file holds them all); unknown names always raise.
    """
    settings = dict(settings or {})
    kind = str(settings.pop('filter', SELECTORS['filter']))
    formulation = str(settings.pop('formulation', SELECTORS['formulation']))
    formulations = [f for k, f in FILTERS if k == kind]
    if (kind, formulation) not in FILTERS and formulation == SELECTORS['formulation'] and len(formulations) == 1:
        # The baselines exist in one formulation only: `filter=ekf` needs no `formulation=euler`.
        formulation = formulations[0]
    if (kind, formulation) not in FILTERS:
        choices = ', '.join(f'filter={k} formulation={f}' for k, f in FILTERS)
        raise ValueError(f'no filter {kind!r} with formulation {formulation!r} (choose: {choices})')
    params_cls, filter_cls = FILTERS[(kind, formulation)]
    fields = param_fields(params_cls)
    known = all_param_names()
    kwargs = {}
    for name, value in settings.items():
        if name not in known:
            raise ValueError(f'unknown parameter {name!r} (known: {", ".join(sorted(known))})')
        if name not in fields:
            if strict:
                raise ValueError(f'parameter {name!r} does not apply to filter={kind} formulation={formulation}')
            continue
        kwargs[name] = _coerce(name, value, fields[name].default)
    return filter_cls(params_cls(**kwargs))


def defaults() -> dict[str, Any]:
    """Every parameter with its default value (first filter that declares it wins)."""
    out: dict[str, Any] = dict(SELECTORS)
    for params_cls, _ in FILTERS.values():
        for name, f in param_fields(params_cls).items():
            out.setdefault(name, f.default)
    return out
