"""Console scripts' entry points: every one in the guard's table; Ctrl-C while starting."""

from pathlib import Path
import re
import signal
import sys
import time

import pytest

from rigidrot_ros.tools.scripts import SCRIPTS
from ros_helpers import next_domain_id, ros_env, start, stop

ROOT = Path(__file__).resolve().parents[2]


def test_every_console_script_runs_through_the_guard():
    text = (ROOT / 'setup.py').read_text()
    found = dict(re.findall(r"'(\w+) = ([\w.:]+)'", text))
    assert found == {s: f'rigidrot_ros.tools.scripts:{s}' for s in SCRIPTS}


def _guarded(script):
    """The console script ``script`` as installed: its entry point, run by the interpreter."""
    return [sys.executable, '-c', 'import sys; from rigidrot_ros.tools import scripts; '
            f'sys.argv[0] = {script!r}; sys.exit(scripts.{script}())']


@pytest.mark.ros
@pytest.mark.parametrize('script, delay, status', [
    ('attitude_node', 0.3, 0), ('attitude_node', 1.0, 0), ('rigidrot_generate', 0.3, 130),
])
def test_ctrl_c_while_starting_ends_it_without_a_traceback(tmp_path, script, delay, status):
    """A Ctrl-C in the imports or in the node's construction: the status a Ctrl-C gives
    the program, never a traceback (once it runs: the node's own tests)."""
    # a scene long enough that the generator cannot finish before the Ctrl-C (600 s took
    # it 0.34 s, and a loaded test process slept past that: the run ended with status 0
    # before the signal was sent)
    args = ['--duration', '100000', '-o', str(tmp_path / 'bag')] \
        if script != 'attitude_node' else []
    proc = start(_guarded(script) + args, ros_env(next_domain_id()))
    time.sleep(delay)
    code, _, err = stop(proc, signal.SIGINT, timeout=60)
    assert code == status and 'Traceback' not in err, (code, err)
