"""Docstring style, as ament_pep257 configures pydocstyle."""

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# ament_pep257's default ignore list
IGNORE = 'D100,D101,D102,D103,D104,D105,D106,D107,D203,D212,D404'


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257():
    out = subprocess.run(
        [sys.executable, '-m', 'pydocstyle', '--convention=pep257', f'--add-ignore={IGNORE}',
         'rigidrot_ros', 'test'],
        cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, 'pydocstyle found problems:\n' + out.stdout + out.stderr
