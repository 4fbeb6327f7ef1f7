"""Lint with ament_flake8's settings (99 columns, single quotes, google import order)."""

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8():
    out = subprocess.run(
        [sys.executable, '-m', 'flake8', '--config', os.path.join(ROOT, 'setup.cfg'),
         'rigidrot_ros', 'test', 'setup.py'],
        cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, 'flake8 found problems:\n' + out.stdout + out.stderr
