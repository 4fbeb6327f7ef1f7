"""Command-line conventions shared by the console scripts (no ROS imports).

Every script exits 0 after ``--help``, and 2 with one line on stderr for a bad argument:
``<prog>: error: <what is wrong> (see <prog> --help)``.
"""

import argparse

__all__ = ['OneLineParser']


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line, exit status 2."""

    def error(self, message):
        """Print ``<prog>: error: <message> (see <prog> --help)`` and exit with status 2."""
        self.exit(2, f'{self.prog}: error: {message} (see {self.prog} --help)\n')
