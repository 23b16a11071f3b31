"""Each subpackage names what it holds in ``__all__``, and the magnetometer calibration's old import paths still
give the same objects as its new packages."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / 'ccf_ros'


def _all(package: str) -> list[str]:
    """``__all__`` of ``ccf_ros/<package>/__init__.py``, read without importing it."""
    for node in ast.parse((ROOT / package / '__init__.py').read_text()).body:
        if isinstance(node, ast.Assign) and [getattr(t, 'id', None) for t in node.targets] == ['__all__']:
            return list(ast.literal_eval(node.value))
    raise AssertionError(f'ccf_ros/{package}/__init__.py has no __all__')


@pytest.mark.parametrize('package', ['messages', 'offline', 'study'])
def test_module_packages_list_every_module_in_all(package):
    # Read, not imported: `import *` of these would load rosbags, matplotlib and scipy.
    names = _all(package)
    assert len(names) == len(set(names))
    assert sorted(names) == sorted(p.stem for p in (ROOT / package).glob('*.py') if p.stem != '__init__')


def test_magcal_all_is_its_public_names_and_each_resolves():
    magcal = importlib.import_module('ccf_ros.magcal')
    names = _all('magcal')
    assert len(names) == len(set(names)) and names == magcal.__all__
    public = {n for n in vars(magcal) if not n.startswith('_')} - {'model', 'sphere', 'ellipsoid', 'planar'}
    assert set(names) == public
    for name in names:
        assert getattr(magcal, name) is not None


def test_old_magnetometer_import_paths_give_the_new_objects():
    from ccf_ros import magcal
    from ccf_ros.magcal import planar
    from ccf_ros.offline import calibrate_mag, magfit
    from ccf_ros.offline import magcal as old

    for name in old.__all__:
        new = calibrate_mag if hasattr(calibrate_mag, name) and not hasattr(magcal, name) else magcal
        assert getattr(old, name) is getattr(new, name), name
    for name in magfit.__all__:
        new_name = 'MAX_ELLIPSE_AXIS_RATIO' if name == 'MAX_AXIS_RATIO' else name
        assert getattr(magfit, name) is getattr(magcal, new_name), name
    # The two axis-ratio limits keep their old values under their old names.
    assert (old.MAX_AXIS_RATIO, magfit.MAX_AXIS_RATIO) == (3.0, 2.0)
    assert planar.MAX_ELLIPSE_AXIS_RATIO == magfit.MAX_AXIS_RATIO
