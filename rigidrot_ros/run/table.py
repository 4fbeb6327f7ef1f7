"""The table of outputs: one row per kind of output a run can publish (no rclpy).

Each row is a subclass of :class:`rigidrot_ros.run.output.Output` that says its topics
(name, type, rank), the parameter that enables it, how a block of its samples is read and
how it is encoded to CDR and to messages. The node (its publishers, its look-ahead, its
schedule) and the offline generator (its topics, its blocks) both serve from here, so a
run's bag is the same whichever wrote it. A new sensor is one module (a
:class:`~rigidrot_ros.run.output.SensorOutput`) and one row in :data:`OUTPUTS` (or
:func:`register`, e.g. from a test).

The rows, in rank order: the truth (attitude and angular_velocity), transform, odom,
markers, the imu, the star tracker, the magnetometer, the run description.
"""

from rigidrot_ros.run.imu_output import ImuOutput
from rigidrot_ros.run.mag_output import MagOutput
from rigidrot_ros.run.outputs import RunOutput
from rigidrot_ros.run.star_output import StarTrackerOutput
from rigidrot_ros.run.truth_outputs import MarkersOutput, OdomOutput, TransformOutput, TruthOutput

__all__ = ['OUTPUTS', 'register', 'unregister', 'kinds_on', 'make', 'sensor_names',
           'resolve', 'NODE_TOPICS']

#: Every kind of output, in rank order: the table.
OUTPUTS = [
    TruthOutput,
    TransformOutput,
    OdomOutput,
    MarkersOutput,
    ImuOutput,
    StarTrackerOutput,
    MagOutput,
    RunOutput,
]

#: Topics every node has beside its outputs (rclpy's and the diagnostics), with their types.
NODE_TOPICS = {'/parameter_events': 'rcl_interfaces/msg/ParameterEvent',
               '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray'}


def _order(kind):
    return min(t.rank for t in kind.topics)


def register(kind):
    """Add a kind of output to the table, in its rank order; returns it (a decorator)."""
    if kind not in OUTPUTS:
        OUTPUTS.append(kind)
        OUTPUTS.sort(key=_order)
    return kind


def unregister(kind):
    """Remove a kind added by :func:`register`."""
    if kind in OUTPUTS:
        OUTPUTS.remove(kind)


def kinds_on(values):
    """Return the kinds that parameter ``values`` switch on, in rank order (a tuple)."""
    return tuple(kind for kind in OUTPUTS if kind.on(values))


def make(setup):
    """Return the outputs of a run: one instance of each kind that ``setup`` switched on."""
    return [kind(setup) for kind in setup.outputs]


def sensor_names():
    """Return the names of every sensor kind of the table, on or off (the diagnostics')."""
    return [kind.name for kind in OUTPUTS if kind.grid == 'sensor']


def resolve(topic, node_name):
    """Return the absolute name of a relative or private topic of node ``node_name``."""
    if topic.startswith('~/'):
        return f'{node_name}/{topic[2:]}'
    return topic if topic.startswith('/') else '/' + topic
