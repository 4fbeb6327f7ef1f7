"""The run description: what a run publishes about itself on ``~/run`` (no rclpy, no node).

:func:`run_description` builds it from a run's set-up; :class:`RunOutput` is its row of the
output table (:mod:`rigidrot_ros.run.table`): ``~/run`` (std_msgs/String, JSON,
transient-local with depth 1), published once at the start of each run, after every
message of that first call. The node and the offline generator both encode it here.
With it, :func:`sensor_config`: the effective configuration of each running sensor.
"""

import json

import numpy as np

from rigidrot_ros import __version__
from rigidrot_ros.msgs import cdr
from rigidrot_ros.run.output import Output, Topic
from rigidrot_ros.run.params import PARAMS
from rigidrot_ros.run.scheduler import timing_of

__all__ = ['run_description', 'run_message', 'RunOutput', 'RUN_FORMAT', 'sensor_config',
           'SENSOR_GROUPS']

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
    ``sensors`` holds each running sensor's whole configuration (:func:`sensor_config`), so
    the bag says which error model produced it.
    """
    sol = setup.solution
    timing = {kind.name: timing_of(setup.values, kind.name).as_dict()
              for kind in setup.outputs if kind.grid == 'sensor'}
    return {
        'rigidrot_run': RUN_FORMAT, 'run': run_index, 'start_ns': int(start_ns),
        'time_scale': setup.time_scale, 'scene': sol.scene.as_dict(), 'tol': sol.tol,
        'backend': sol.backend, 'model': sol.model, 'method': sol.method,
        'package': f'rigidrot_ros {__version__}', 'node': node_name, 'topics': dict(topics),
        'sensor_timing': timing, 'sensors': sensor_config(setup),
    }


#: Each sensor of the run description and the parameter groups it is configured by (the
#: accelerometer's ``accel.`` parameters belong to ``imu``, whose messages carry it).
SENSOR_GROUPS = (('imu', ('imu.', 'accel.')), ('star_tracker', ('star_tracker.',)),
                 ('mag', ('mag.',)))


def sensor_config(setup):
    """Return the effective configuration of each running sensor (a JSON-ready dict).

    For every sensor that runs (``imu``, ``star_tracker``, ``mag``): ``rate_hz``, its rate
    (``0`` resolved to ``publish_rate``), and ``parameters``, the value of every parameter
    of its groups (:data:`SENSOR_GROUPS`; all but the ``.enable`` switches, the
    accelerometer's only where it is on) as the run uses it, after the import of a Kalibr
    file, by the parameter's name (units: ``attitude_node --help``). The imu adds
    ``turn_on_bias`` (the gyro's and the accelerometer's bias drawn from the seed,
    ``*.bias_stddev``, rad/s and m/s^2, in B) and, with ``imu.kalibr_yaml``, ``kalibr``:
    the values the file supplied.
    """
    values, cfg = setup.values, setup.sensors
    on = {'imu': cfg.imu, 'star_tracker': cfg.star_tracker, 'mag': cfg.mag}
    rates = {'imu': cfg.imu_rate, 'star_tracker': cfg.star_tracker_rate, 'mag': cfg.mag_rate}
    out = {}
    for sensor, groups in SENSOR_GROUPS:
        if not on[sensor]:
            continue
        if not cfg.accel:
            groups = tuple(g for g in groups if g != 'accel.')
        entry = {'rate_hz': float(rates[sensor]), 'parameters': {
            p.name: _plain(values[p.name]) for p in PARAMS
            if p.name.startswith(groups) and not p.name.endswith('.enable')}}
        if sensor == 'imu':
            entry['turn_on_bias'] = {'gyro': cfg.gyro.turn_on_bias.tolist()}
            if cfg.accel:
                entry['turn_on_bias']['accel'] = cfg.accel_noise.turn_on_bias.tolist()
            if values.get('imu.kalibr_yaml'):
                entry['kalibr'] = {k: _plain(v) for k, v in
                                   sorted(getattr(setup, 'kalibr', {}).items())}
        out[sensor] = entry
    return out


def _plain(v):
    """Return a parameter value as JSON writes it (tuples and arrays: lists of floats)."""
    if isinstance(v, (list, tuple, np.ndarray)):
        return [float(x) for x in v]
    return v


def run_message(info):
    """Return the std_msgs/String carrying a run description as JSON."""
    from std_msgs.msg import String
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
