"""The linters as tests, so that ``colcon test`` (which runs pytest) checks them too, as CI does."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tool(name: str) -> str:
    exe = shutil.which(name, path=str(Path(sys.executable).parent)) or shutil.which(name)
    if exe is None:
        pytest.skip(f'{name} not installed (pip install .[test])')
    return exe


def test_ruff_passes_with_the_project_rules():
    r = subprocess.run([_tool('ruff'), 'check', 'ccf_ros', 'test', 'benchmarks', 'experiments', 'checks', 'launch', 'setup.py'], cwd=ROOT,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_mypy_passes_and_is_strict_on_the_core_engine_and_magcal():
    mypy = _tool('mypy')
    r = subprocess.run([mypy, 'ccf_ros'], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run([mypy, '--strict', 'ccf_ros/core', 'ccf_ros/engine.py', 'ccf_ros/magcal'], cwd=ROOT,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
