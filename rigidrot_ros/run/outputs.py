"""The run description: what a run publishes about itself on ``~/run`` (no rclpy, no node).

:func:`run_description` builds it from a run's set-up; :class:`RunOutput` is its row of the
output table (:mod:`rigidrot_ros.run.table`): ``~/run`` (std_msgs/String, JSON,
transient-local with depth 1), published once at the start of each run, after every
message of that first call. The node and the offline generator both encode it here.
"""

import json

from std_msgs.msg import String

from rigidrot_ros import __version__
from rigidrot_ros.msgs import cdr
from rigidrot_ros.run.output import Output, Topic
from rigidrot_ros.run.scheduler import timing_of

__all__ = ['run_description', 'run_message', 'RunOutput', 'RUN_FORMAT']

#: Version of the run description's layout (its ``rigidrot_run`` key).
RUN_FORMAT = 1


def run_description(setup, start_ns, run_index, node_name, topics):
    """Return the run description (a JSON-ready dict) that ``~/run`` publishes.

    Parameters
    ----------
    setup : RunSetup
        The run (:func:`rigidrot_ros.run.settings.prepare_run`).
    start_ns : int
        ``t_start``: the clock time (ns) of scene time 0.
    run_index : int
        1 for the first run of a node, +1 at each ``~/reset``.
    node_name : str
        The node's fully qualified name, e.g. ``/attitude_node``.
    topics : dict
        Resolved topic name -> type name (``pkg/msg/Type``) of every publisher.

    ``sensor_timing`` holds the timing model of each sensor kind of the run
    (:class:`rigidrot_ros.run.scheduler.Timing`: latency, stamp jitter, drop probability,
    clock offset; all 0 when off), so a scorer knows which stamps are not true sample times.
    """
    sol = setup.solution
    timing = {kind.name: timing_of(setup.values, kind.name).as_dict()
              for kind in setup.outputs if kind.grid == 'sensor'}
    return {
        'rigidrot_run': RUN_FORMAT, 'run': run_index, 'start_ns': int(start_ns),
        'time_scale': setup.time_scale, 'scene': sol.scene.as_dict(), 'tol': sol.tol,
        'backend': sol.backend, 'model': sol.model, 'method': sol.method,
        'package': f'rigidrot_ros {__version__}', 'node': node_name, 'topics': dict(topics),
        'sensor_timing': timing,
    }


def run_message(info):
    """Return the std_msgs/String carrying a run description as JSON."""
    return String(data=json.dumps(info))


class RunOutput(Output):
    """``~/run``: the run description as JSON, once at the start of each run.

    Its one column ``info`` holds the description (a dict, :func:`run_description`).
    """

    name = 'run'
    grid = 'start'
    latched = True
    topics = (Topic('~/run', 'std_msgs/msg/String', 99),)

    def encode(self, topic, stamps, cols, frames):
        """Return the CDR of each description."""
        return [cdr.string(json.dumps(info)) for info in cols['info']]

    def messages(self, topic, stamps, cols, frames):
        """Return the std_msgs/String of each description."""
        return [run_message(info) for info in cols['info']]
