"""What a run publishes, as plain functions of its set-up (no rclpy, no node).

The node and the offline generator build the same messages through these: the truth of
one tick (:func:`truth_pair`, :func:`truth_extras`), the run description on ``~/run``
(:func:`run_description`, :func:`run_message`). Topics are the node's relative names.
"""

import json

import numpy as np
from std_msgs.msg import String

from rigidrot_ros import __version__
from rigidrot_ros.msgs import messages as msgs
from rigidrot_ros.run.scheduler import timing_of

__all__ = ['truth_pair', 'truth_extras', 'run_description', 'run_message', 'TRUTH_EXTRAS',
           'RUN_FORMAT']

#: The truth outputs beyond attitude and angular_velocity: (topic, switch parameter).
TRUTH_EXTRAS = (('transform', 'transform.enable'), ('odom', 'odom.enable'),
                ('markers', 'markers.enable'))
#: Version of the run description's layout (its ``rigidrot_run`` key).
RUN_FORMAT = 1
_EPS = float(np.finfo(float).eps)


def truth_pair(stamp_ns, sample, frames):
    """Return ``(attitude, angular_velocity)`` messages of a truth sample, one stamp.

    ``sample``: ``(q_NB (x, y, z, w), omega_BN_B rad/s, error_bound rad)``;
    ``frames``: ``(frame_id, body_frame_id)``.
    """
    frame, body = frames
    stamp = msgs.stamp(stamp_ns)
    return msgs.attitude(stamp, frame, sample[0]), msgs.vector(stamp, body, sample[1])


def truth_extras(stamp, sample, frames, setup):
    """Return ``[(topic, msg), ...]`` of the further truth outputs that ``setup`` turns on.

    ``stamp`` is the tick's builtin_interfaces/Time (the pair's header stamp); the order is
    transform, odom, markers. The odometry's rate variance is (32 eps |omega|)^2, its
    attitude variance the sample's bound squared.
    """
    cfg = setup.sensors
    if not (cfg.transform or cfg.odom or cfg.markers):
        return []
    frame, body = frames
    q, omega, bound = sample
    out = []
    if cfg.transform:
        out.append(('transform', msgs.transform(stamp, frame, body, q)))
    if cfg.odom:
        rate_sd = 32.0 * _EPS * float(np.linalg.norm(omega))
        out.append(('odom', msgs.odometry(stamp, frame, body, q, omega,
                                          attitude_variance=bound ** 2,
                                          rate_variance=rate_sd ** 2)))
    if cfg.markers:
        out.append(('markers', msgs.body_markers(stamp, frame, q,
                                                 setup.solution.scene.inertia)))
    return out


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

    ``sensor_timing`` holds each running sensor's timing model
    (:class:`rigidrot_ros.run.scheduler.Timing`: latency, stamp jitter, drop probability,
    clock offset; all 0 when off), so a scorer knows which stamps are not true sample times.
    """
    sol = setup.solution
    cfg = setup.sensors
    timing = {name: timing_of(setup.values, name).as_dict()
              for name, on in (('imu', cfg.imu), ('star_tracker', cfg.star_tracker),
                               ('mag', cfg.mag)) if on}
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
