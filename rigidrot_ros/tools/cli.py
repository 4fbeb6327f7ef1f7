"""Command-line conventions shared by the console scripts (no ROS imports).

Every script exits 0 after ``--help``, and 2 with one line on stderr for a bad argument:
``<prog>: error: <what is wrong> (see <prog> --help)``.
"""

import argparse
import sys

__all__ = ['OneLineParser', 'fail']


def fail(prog, message, status=2):
    """Print ``<prog>: <message>`` on one line to stderr and return ``status``.

    Any run of whitespace in ``message`` (newlines too) becomes one space.
    """
    print(f'{prog}: {" ".join(str(message).split())}', file=sys.stderr)
    return status


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line, exit status 2."""

    def error(self, message):
        """Print ``<prog>: error: <message> (see <prog> --help)`` and exit with status 2."""
        self.exit(2, f'{self.prog}: error: {message} (see {self.prog} --help)\n')
