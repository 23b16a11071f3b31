"""Build any core filter from flat ``name: value`` settings (the names of ``config/ccf.yaml`` and ``--param``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from .base import CommonParams, OrientationFilter
from .baselines import Madgwick, MadgwickParams, Mahony, MahonyParams
from .ccf import CcfParams, QuaternionCcf
from .euler_ccf import EulerCcf, EulerCcfParams, EulerNcf, Lcf, LcfParams, NcfParams
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
    """Convert ``value`` to the type of ``default`` (from YAML/CLI strings or ROS parameter types)."""
    if isinstance(default, bool):
        if isinstance(value, str):
            low = value.strip().lower()
            if low in ('true', '1', 'yes', 'on'):
                return True
            if low in ('false', '0', 'no', 'off'):
                return False
            raise ValueError(f'{name} must be true or false, got {value!r}')
        return value
    if isinstance(default, tuple):
        if isinstance(value, str):
            value = value.strip().strip('[]()').split(',')
        try:
            # lists, tuples, and the array.array rclpy returns for double-array parameters
            return tuple(float(v) for v in value)
        except (TypeError, ValueError):
            raise ValueError(f'{name} must be {len(default)} numbers, got {value!r}') from None
    if isinstance(default, (int, float)):
        if isinstance(value, str):
            text = value.strip()
            if text.startswith('['):
                return tuple(_coerce(name, v, 0.0) for v in text.strip('[]').split(',') if v.strip())
            try:
                return float(text)
            except ValueError:
                raise ValueError(f'{name} must be a number, got {value!r}') from None
        if isinstance(value, (list, tuple)):
            return tuple(float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v for v in value)
        if isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        return value
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
