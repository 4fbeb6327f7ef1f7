"""How the console scripts start and stop ROS: arguments, ``rclpy.init``, spin, clean-up.

- :func:`split_ros_args` separates a script's own arguments from ``--ros-args ... [--]``.
- :func:`init_ros` runs ``rclpy.init`` and turns a failure (a missing ``--params-file``, a
  malformed ``-p``) into one line of text instead of rcl's log line and a traceback; it
  makes the first Ctrl-C shut ROS down without a KeyboardInterrupt (:func:`_quiet_signals`),
  and SIGINTs within :data:`SIGNAL_MERGE_S` of the first one request.
- :func:`spin_until_shutdown` spins until Ctrl-C, SIGTERM or a shutdown, then cleans up,
  on the executor :func:`make_executor` makes.
  The clean-up (the node's ``destroy_node``: a recorder finishes its bag) runs to
  its end whatever signal arrives meanwhile, and a SIGINT or SIGTERM that arrives after it,
  while the process exits, is ignored (:func:`_stopping`).
"""

import os
import re
import signal
import sys
import tempfile
import threading
import time

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

from rigidrot_ros.bag.metadata import uninterrupted
from rigidrot_ros.run.rclyaml import MIXED_HINT

__all__ = ['split_ros_args', 'init_ros', 'spin_until_shutdown', 'make_executor',
           'SIGNAL_MERGE_S']

#: SIGINTs that arrive within this many seconds of the first are one request to stop: ``kill
#: -INT`` of ``timeout``, or of a shell's job, reaches the process twice within microseconds
#: (once directly, once through its process group), and a user's Ctrl-C that repeats at once
#: is one too. A SIGINT later than that is a second request: it raises KeyboardInterrupt.
SIGNAL_MERGE_S = 0.5


def split_ros_args(argv):
    """Split ``argv`` into ``(own, ros)``.

    ``ros`` holds every ``--ros-args ... [--]`` block (with its markers), ``own`` the rest,
    as ``rclpy.utilities.remove_ros_args`` would split them, but without parsing.

    Examples
    --------
    >>> split_ros_args(['--count', '5', '--ros-args', '-r', '__ns:=/a'])
    (['--count', '5'], ['--ros-args', '-r', '__ns:=/a'])
    """
    own, ros, in_ros = [], [], False
    for arg in argv:
        if arg == '--ros-args':
            in_ros = True
            ros.append(arg)
        elif in_ros and arg == '--':
            in_ros = False
            ros.append(arg)
        elif in_ros:
            ros.append(arg)
        else:
            own.append(arg)
    return own, ros


def _check_params_files(ros_args):
    """Return a one-line reason if a ``--params-file`` argument names no readable file."""
    for i, arg in enumerate(ros_args):
        if arg != '--params-file':
            continue
        if i + 1 >= len(ros_args) or ros_args[i + 1] in ('--', '--ros-args'):
            return '--params-file needs a file name'
        path = ros_args[i + 1]
        if not os.path.exists(path):
            return f'--params-file {path}: no such file'
        if not os.path.isfile(path):
            return f'--params-file {path}: not a file'
        if not os.access(path, os.R_OK):
            return f'--params-file {path}: not readable'
    return None


def _clean_rcl_message(text):
    """Drop rcl's source locations and prefix from an ``RCLError`` message."""
    text = re.sub(r',? at /[^,]*?:\d+', '', str(text))
    text = text.replace('failed to initialize rcl: ', '')
    return ' '.join(text.split())


#: Set once ``rclpy.init`` has installed its handlers (:func:`init_ros`).
_ROS_UP = threading.Event()


def _quiet_signals():
    """Let the first SIGINT shut ROS down without raising KeyboardInterrupt; a second raises.

    rclpy's SIGINT handler, installed by ``rclpy.init`` in front of the one found, shuts the
    context down, which ends every spin loop of the console scripts. Python's default
    handler then also raises KeyboardInterrupt at whatever line the main thread is on;
    inside rclpy's executor that can be half way through a ``Task``'s constructor, whose
    ``__del__`` then prints an AttributeError traceback at exit (rclpy's ``Future``; seen
    in a test of ours). Installed only over Python's default handler and from the main
    thread. SIGINTs within :data:`SIGNAL_MERGE_S` of the first are the same request; a
    later one raises KeyboardInterrupt, for a process that would not stop (its clean-up,
    :func:`spin_until_shutdown`'s, still runs to its end).

    SIGTERM is rclpy's: it shuts ROS down, however often it comes. The Python handler set
    here under rclpy's (which calls it after its own) does nothing once ROS is up; it is
    there so that a SIGTERM between rclpy's shutdown, which puts back the handler it found,
    and :func:`_stopping` finds a handler instead of the default action, which would end a
    process that has finished its clean-up by that signal. Before ``rclpy.init`` a SIGTERM
    takes the default action, as if nothing were installed.
    """
    if threading.current_thread() is not threading.main_thread():
        return
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        first = []

        def on_int(signum, frame):
            now = time.monotonic()
            if not first:
                first.append(now)
            elif now - first[0] > SIGNAL_MERGE_S:
                raise KeyboardInterrupt

        signal.signal(signal.SIGINT, on_int)
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:

        def on_term(signum, frame):
            if not _ROS_UP.is_set():
                signal.signal(signal.SIGTERM, signal.SIG_DFL)
                os.kill(os.getpid(), signal.SIGTERM)

        signal.signal(signal.SIGTERM, on_term)


def init_ros(prog, ros_args):
    """Run ``rclpy.init`` with ``ros_args``; return None, or one line saying why it failed.

    rcl prints its own ``[ERROR] ... Failed to parse global arguments`` line before it
    raises; that output is held back and dropped on failure (shown on success), so a user
    who mistyped an argument reads one line that names it.

    Parameters
    ----------
    prog : str
        Program name, passed as ``argv[0]``.
    ros_args : list of str
        The ``--ros-args ...`` part of the command line (may be empty).

    Returns
    -------
    str or None
        None when ROS is initialised; else the reason, e.g.
        ``'--params-file config/nope.yaml: no such file'``.
    """
    reason = _check_params_files(ros_args)
    if reason is not None:
        return reason
    _quiet_signals()
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with tempfile.TemporaryFile() as held:
            os.dup2(held.fileno(), 2)
            try:
                rclpy.init(args=[prog] + list(ros_args))
            except _rclpy.RCLError as exc:
                text = _clean_rcl_message(exc)
                where = 'environment' if 'ROS_' in text and 'parse' not in text else \
                    '--ros-args'
                reason = f'invalid {where}: {text}'
                if 'Sequence should be of same type' in text:
                    reason += f' ({MIXED_HINT})'
            finally:
                os.dup2(saved, 2)
            if reason is None:
                _ROS_UP.set()
                held.seek(0)
                data = held.read()
                if data:
                    os.write(2, data)
    finally:
        os.close(saved)
    return reason


def make_executor():
    """Return a new executor: rclpy's ``SingleThreadedExecutor``.

    rclpy's ``EventsExecutor`` (experimental in Jazzy) was measured and left out: its
    ``spin()`` stopped firing the node's timer after the first calls, and the node then
    ignored SIGINT and SIGTERM (CHANGELOG, issue 28).
    """
    return SingleThreadedExecutor()


def _spin(node):
    if not rclpy.ok():          # shut down while the node was made: nothing to spin (an
        return                  # executor made now fails half-built, and says so at exit)
    executor = make_executor()
    try:
        executor.add_node(node)
        executor.spin()
    finally:
        executor.remove_node(node)
        executor.shutdown()


def _stopping():
    """Ignore SIGINT and SIGTERM from now on: the stop they would ask for is done.

    Called once the clean-up has run. Without it a late signal kills a process that has
    finished everything: rclpy's uninstall leaves SIGTERM at its default action, and
    Python's finalisation resets SIGINT to its default action, so a SIGINT or SIGTERM that
    arrives while the process exits (the second of two SIGINTs sent "at once" by a process
    the scheduler holds between them) ended it by that signal instead of with its status.
    SIGKILL and SIGQUIT still end a process whose exit hangs. Main thread only.
    """
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)


def spin_until_shutdown(node, loop=None):
    """Run ``loop(node)`` (default: spin on :func:`make_executor`), then clean up.

    Destroys the node and shuts ROS down.

    Ctrl-C, an external shutdown (SIGINT/SIGTERM through rclpy's handlers) and a publish
    that races the shutdown (``RCLError`` once the context is gone) end it quietly; any
    other error propagates. The node's ``destroy_node`` runs in every case, to its end
    whatever signal arrives meanwhile (:func:`rigidrot_ros.bag.metadata.uninterrupted`), so
    a recorder finishes its file; a Ctrl-C during it is then taken as done. After the
    clean-up SIGINT and SIGTERM are ignored (:func:`_stopping`).
    """
    try:
        (loop or _spin)(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except _rclpy.RCLError:
        if rclpy.ok():
            raise               # a real failure; after a shutdown it is only the race
    finally:
        try:
            uninterrupted(_clean_up, node)
        except KeyboardInterrupt:
            pass                # the clean-up it asked for is done
        _stopping()


def _clean_up(node):
    """Destroy ``node``, then shut ROS down (even if the destruction raised)."""
    try:
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
