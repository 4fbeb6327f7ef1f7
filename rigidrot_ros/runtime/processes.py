"""Child processes of a run: find a console script, stop a process as Ctrl-C would."""

import os
import shutil
import signal
import subprocess
import sys


def script(name):
    """Return the path of console script ``name``: beside this Python first, else on PATH."""
    path = os.path.join(os.path.dirname(sys.executable), name)
    if os.path.exists(path):
        return path
    found = shutil.which(name)
    if found is None:
        raise FileNotFoundError(f'{name} is not installed (pip install -e . in this checkout)')
    return found


def stop(proc, timeout):
    """SIGINT ``proc`` if it runs, wait ``timeout`` s for it, else kill it; its status."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()
