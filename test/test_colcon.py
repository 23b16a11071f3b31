"""colcon build in a temporary workspace gives what `ros2 run ccf_ros ccf_node` resolves."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_colcon_build_installs_node_and_ament_marker(tmp_path):
    colcon = shutil.which('colcon', path=str(Path(sys.executable).parent)) or shutil.which('colcon')
    if colcon is None:
        pytest.skip('colcon not installed (pip install .[test])')
    src = tmp_path / 'src' / 'ccf_ros'
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns('.venv', '.git', 'build', 'install', 'log', '*.egg-info',
                                                              '__pycache__', '.pytest_cache', '.ruff_cache'))
    r = subprocess.run([colcon, 'build', '--event-handlers', 'console_direct-'], cwd=tmp_path,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    install = tmp_path / 'install' / 'ccf_ros'
    for exe in ('ccf_node', 'ccf_lifecycle_node', 'imu_filter_madgwick_node', 'complementary_filter_node'):
        node = install / 'lib' / 'ccf_ros' / exe
        assert node.exists() and os.access(node, os.X_OK), exe
    for launch in ('ccf.launch.py', 'imu_filter.launch.py', 'complementary_filter.launch.py',
                   'imu_filter_component.launch.py'):
        assert (install / 'share' / 'ccf_ros' / 'launch' / launch).exists(), launch
    assert (install / 'lib' / 'ccf_ros' / 'ccf').exists()
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'ccf_ros').exists()
    assert (install / 'share' / 'ccf_ros' / 'package.xml').exists()
    assert (install / 'share' / 'ccf_ros' / 'config' / 'ccf.yaml').exists()
    site = next(install.glob('lib/python3*/site-packages'))
    v = subprocess.run([str(install / 'lib' / 'ccf_ros' / 'ccf'), '--version'], capture_output=True, text=True,
                       env={**os.environ, 'PYTHONPATH': str(site)}, timeout=60)
    assert v.returncode == 0 and 'ccf_ros' in v.stdout
