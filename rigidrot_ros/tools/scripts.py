"""The console scripts' entry points: each program imported under a Ctrl-C guard.

A program's imports (rclpy, numpy, scipy) take up to a second or two on a loaded machine,
and Python's default answer to a Ctrl-C then is a KeyboardInterrupt traceback. Each entry
here imports its program's ``main`` and calls it; a Ctrl-C the program does not handle
itself (while it imports) ends it with one line and the status a Ctrl-C gives it once it
runs: 0 for the ROS programs (a node stops cleanly on Ctrl-C), 130 for the batch tools
(interrupted).
"""

import importlib
import sys

__all__ = ['SCRIPTS']

#: ``{script: (module whose main() it runs, status of a Ctrl-C while importing)}``.
SCRIPTS = {
    'attitude_node': ('rigidrot_ros.ros.attitude_node', 0),
    'rigidrot_echo': ('rigidrot_ros.tools.echo', 0),
    'rigidrot_compare': ('rigidrot_ros.tools.compare', 130),
    'rigidrot_replay': ('rigidrot_ros.tools.replay', 0),
    'rigidrot_demo_estimator': ('rigidrot_ros.tools.demo_estimator', 0),
    'rigidrot_record': ('rigidrot_ros.tools.record', 0),
    'rigidrot_reindex': ('rigidrot_ros.tools.reindex', 130),
    'rigidrot_bench': ('rigidrot_ros.bench.run', 130),
    'rigidrot_generate': ('rigidrot_ros.tools.generate', 130),
    'rigidrot_mekf': ('rigidrot_ros.estimators.mekf_node', 0),
    'rigidrot_campaign': ('rigidrot_ros.tools.campaign', 130),
    'rigidrot_view': ('rigidrot_ros.tools.view', 130),
}


def run(script):
    """Import ``script``'s program and return what its ``main()`` returns.

    A KeyboardInterrupt the program does not handle itself (one in its imports, or in
    the imports its ``main`` makes before its own handling is in place) ends it with one
    line and its status for a Ctrl-C.
    """
    module, status = SCRIPTS[script]
    try:
        return importlib.import_module(module).main()
    except KeyboardInterrupt:
        print(f'{script}: interrupted', file=sys.stderr)
        return status


def _entry(script):
    def entry():
        return run(script)
    entry.__name__ = entry.__qualname__ = script
    entry.__doc__ = f'Run ``{script}``.'
    return entry


for _script in SCRIPTS:
    globals()[_script] = _entry(_script)
