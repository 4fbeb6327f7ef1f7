"""Offline generation: the bag ``attitude_node`` would record, without ROS running.

The node's sampling, reproduced on the scene's own grids (no clock, no timers):

- the truth tick k is stamped ``start_ns + round(k * 1e9 / publish_rate)`` and holds the
  scene at ``t = (stamp - start_ns) * 1e-9 * time_scale``: ``attitude``,
  ``angular_velocity`` and, where enabled, ``transform``, ``odom``, ``markers``;
- the gyro sample k >= 1 is stamped ``start_ns + round(k * 1e9 / imu.rate)`` and covers the
  interval from sample k - 1 to sample k: ``imu``, ``delta_angle``, ``delta_rotation``;
- the star tracker sample k >= 0 is stamped ``start_ns + round(k * 1e9 / rate)``;
- ``~/run`` (``/attitude_node/run``) carries the run description with the first tick, and
  the bag holds it as a ``rigidrot_run`` metadata record too, as the node's recorder writes.

Every message of the run has a stamp in ``[start_ns, start_ns + duration_s / time_scale)``
(``duration_s`` in scene seconds). Parameters are validated by the node's own code
(:mod:`rigidrot_ros.settings` and the node's scene checks). Messages are built by
:mod:`rigidrot_ros.io.messages`; :func:`generate_bag` serializes them with the vectorised
CDR writer :mod:`rigidrot_ros.io.cdr` a block at a time and streams them to the bag, so
memory stays bounded whatever the duration.
"""

import difflib
import json
import math

import numpy as np
import yaml

from rigidrot_ros.io import messages as msgs

__all__ = ['iter_run', 'generate_bag', 'load_values', 'prepare_run', 'parse_override',
           'GenerationError', 'NODE_NAME', 'RUN_TOPIC']

#: The node whose recording is reproduced (its fully qualified name).
NODE_NAME = '/attitude_node'
#: Where the node publishes its run description.
RUN_TOPIC = NODE_NAME + '/run'
#: Clock seconds of samples handled together (evaluated, serialized, written).
BLOCK_S = 1.0
#: The node's look-ahead batches (tick 0 alone, then doubling up to its ceiling).
_AHEAD = (8, 256)
_SEC = 1_000_000_000


class GenerationError(ValueError):
    """Invalid parameters or arguments: the message is one line naming the problem."""


# -- parameters ------------------------------------------------------------------------------
def parse_override(text):
    """Return ``(name, value)`` of ``name:=value``; the value is read as YAML, as ROS does."""
    name, sep, raw = str(text).partition(':=')
    if not sep or not name:
        raise GenerationError(f'-p expects name:=value, got {text!r}')
    try:
        value = yaml.safe_load(raw) if raw.strip() else ''
    except yaml.YAMLError as exc:
        raise GenerationError(f'-p {name}: cannot read {raw!r} as a value '
                              f'({" ".join(str(exc).split())})') from None
    return name, value


def load_values(params_file=None, overrides=()):
    """Return the node's defaults, merged with a params file and ``(name, value)`` overrides.

    Raises
    ------
    GenerationError
        A missing or malformed params file.
    """
    from rigidrot_ros.settings import load_defaults
    values = load_defaults()
    if params_file is not None:
        try:
            values.update(load_defaults(params_file))
        except (OSError, ValueError, yaml.YAMLError) as exc:
            raise GenerationError(f'--params-file {params_file}: '
                                  f'{" ".join(str(exc).split())}') from None
    values.update(dict(overrides))
    return values


def _node():
    from rigidrot_ros.node import attitude_node
    return attitude_node


def prepare_run(values):
    """Validate ``values`` (overrides merged over the defaults) as the node does.

    Returns ``(params, solution, sensor_settings)``; raises :class:`GenerationError` with
    the node's own one-line reason otherwise. The node's start-up trial (its first ticks
    and sensor samples) runs too, so a scene the node refuses is refused here, and the
    solution has evaluated what the node's has before its first tick.
    """
    from rigidrot_ros.settings import load_defaults, sensor_settings
    node = _node()
    p = load_defaults()
    known = set(node._DESCRIPTIONS)
    unknown = sorted(n for n in values if n not in known)
    if unknown:
        close = difflib.get_close_matches(unknown[0], sorted(known), n=1)
        hint = f' (did you mean {close[0]}?)' if close else ''
        raise GenerationError(f'unknown parameter(s) {", ".join(unknown)}{hint}: '
                              'attitude_node declares no such parameter')
    p.update(values)
    for name, rng in node._RANGES.items():      # what rclpy checks at declaration
        v = p[name]
        if isinstance(v, float) and not rng.from_value <= v <= rng.to_value:
            raise GenerationError(f'parameter {name}: value {v!r} is outside the range '
                                  f'[{rng.from_value:g}, {rng.to_value:g}]')
    try:
        sol = node.build_solution(p)
        cfg = sensor_settings(p)
        trial = node._trial(sol, p, cfg)
        if trial is not None:
            summary = ', '.join(f'{k} {p[k]!r}' for k in ('inertia', 'torque', 'omega0'))
            raise ValueError(f'scene {summary}: {trial}')
    except ValueError as exc:
        raise GenerationError(' '.join(str(exc).split())) from None
    return p, sol, cfg


# -- the run -----------------------------------------------------------------------------------
def _grid_count(rate, span_ns, first=0):
    """Indices k >= first of the grid ``round(k * 1e9 / rate)`` below ``span_ns``: a range."""
    k = max(first, math.floor(span_ns * rate * 1e-9) - 1)
    while round(k * 1e9 / rate) < span_ns:
        k += 1
    while k > first and round((k - 1) * 1e9 / rate) >= span_ns:
        k -= 1
    return range(first, k)


def _stamps(start_ns, rate, ks):
    return [start_ns + round(k * 1e9 / rate) for k in ks]


class _Run:
    """The streams of one run, sampled a block of clock time at a time."""

    def __init__(self, values, duration_s, start_ns):
        if isinstance(duration_s, bool) or not isinstance(duration_s, (int, float)) or \
                not math.isfinite(duration_s) or duration_s <= 0:
            raise GenerationError(f'--duration must be a positive number of scene seconds, '
                                  f'got {duration_s!r}')
        if isinstance(start_ns, bool) or not isinstance(start_ns, int) or \
                not 0 <= start_ns < 2 ** 63:
            raise GenerationError(f'--start-ns must be an integer in [0, 2^63), '
                                  f'got {start_ns!r}')
        from rigidrot_ros.sensors import Gyro, StarTracker
        self.p, self.sol, self.cfg = prepare_run(values)
        p, cfg = self.p, self.cfg
        self.time_scale = float(p['time_scale'])
        if self.time_scale <= 0:
            raise GenerationError('parameter time_scale = 0 freezes the scene: a duration in '
                                  'scene seconds needs time_scale > 0')
        self.span_ns = round(duration_s / self.time_scale * 1e9)
        if not 0 < self.span_ns < 2 ** 63 - start_ns:
            raise GenerationError(f'--duration {duration_s!r} s at time_scale '
                                  f'{self.time_scale:g} leaves the int64 nanosecond clock')
        self.start_ns = int(start_ns)
        self.frame, self.body = p['frame_id'], p['body_frame_id']
        self.rate = float(p['publish_rate'])
        self.truth_k = _grid_count(self.rate, self.span_ns)
        self.gyro = self.star = None
        if cfg.imu:
            self.gyro = Gyro(self.sol, cfg.gyro)
            self.imu_k = _grid_count(cfg.imu_rate, self.span_ns, first=1)
        if cfg.star_tracker:
            self.star = StarTracker(self.sol, cfg.attitude_noise)
            self.star_k = _grid_count(cfg.star_tracker_rate, self.span_ns)
        self._ahead_next = 0            # the next truth index to evaluate
        self._ahead_size = _AHEAD[0]
        self._buf = None

    # -- time ------------------------------------------------------------------------------
    def scene_time(self, ns):
        """Scene time (s) of clock stamp ``ns``, as the node computes it."""
        return (ns - self.start_ns) * 1e-9 * self.time_scale

    @property
    def topics(self):
        """``[(topic, pkg/msg/Type), ...]`` in the node's publisher order."""
        cfg = self.cfg
        out = [('/attitude', 'geometry_msgs/msg/QuaternionStamped'),
               ('/angular_velocity', 'geometry_msgs/msg/Vector3Stamped')]
        if cfg.transform:
            out.append(('/transform', 'geometry_msgs/msg/TransformStamped'))
        if cfg.odom:
            out.append(('/odom', 'nav_msgs/msg/Odometry'))
        if cfg.markers:
            out.append(('/markers', 'visualization_msgs/msg/MarkerArray'))
        if cfg.imu:
            out += [('/imu', 'sensor_msgs/msg/Imu'),
                    ('/delta_angle', 'geometry_msgs/msg/Vector3Stamped'),
                    ('/delta_rotation', 'geometry_msgs/msg/Vector3Stamped')]
        if cfg.star_tracker:
            out.append(('/star_tracker', 'geometry_msgs/msg/PoseWithCovarianceStamped'))
        return out

    def description(self):
        """The run description the node publishes on ``~/run`` (a dict)."""
        from rigidrot_ros import __version__
        sol = self.sol
        topics = {'/parameter_events': 'rcl_interfaces/msg/ParameterEvent'}
        topics.update(self.topics)
        topics['/diagnostics'] = 'diagnostic_msgs/msg/DiagnosticArray'
        topics[RUN_TOPIC] = 'std_msgs/msg/String'
        return {
            'rigidrot_run': 1, 'run': 1, 'start_ns': self.start_ns,
            'time_scale': self.time_scale, 'scene': sol.scene.as_dict(), 'tol': sol.tol,
            'backend': sol.backend, 'model': sol.model, 'method': sol.method,
            'package': f'rigidrot_ros {__version__}', 'node': NODE_NAME, 'topics': topics,
        }

    # -- truth -----------------------------------------------------------------------------
    def _truth_samples(self, ks):
        """Samples ``(q, omega, bound)`` (plain floats) of the truth ticks ``ks``, in order.

        Evaluated as the node's look-ahead does when it keeps within its budget: tick 0
        alone (a scalar call), then batches from tick 1 doubling from 8 to 256 samples.
        """
        out = []
        for k in ks:
            if k == 0:
                s = self.sol.at(self.scene_time(self.start_ns))
                out.append((s.quaternion.tolist(), s.omega.tolist(), float(s.error_bound)))
                self._ahead_next = 1
                continue
            if self._buf is None or k >= self._ahead_next:
                n = self._ahead_size
                start = max(self._ahead_next, k)
                ts = np.array([self.scene_time(self.start_ns + round(j * 1e9 / self.rate))
                               for j in range(start, start + n)])
                s = self.sol.at(ts)
                self._buf = (start, s.quaternion.tolist(), s.omega.tolist(),
                             s.error_bound.tolist())
                self._ahead_next = start + n
                self._ahead_size = min(_AHEAD[1], 2 * n)
            start, q, w, e = self._buf
            i = k - start
            out.append((q[i], w[i], e[i]))
        return out

    # -- one block ---------------------------------------------------------------------------
    def block(self, lo_ns, hi_ns):
        """Messages with stamps in ``[lo_ns, hi_ns)`` (relative to start): a list of streams.

        Each stream is ``(order, topic, stamps_ns, messages)``; ``order`` ranks the streams
        of one stamp as the node publishes them.
        """
        streams = []
        rate = self.rate
        ks = _sub(self.truth_k, rate, lo_ns, hi_ns)
        if len(ks):
            stamps = _stamps(self.start_ns, rate, ks)
            samples = self._truth_samples(ks)
            att, vel, tf, odom, mk = [], [], [], [], []
            cfg = self.cfg
            eps = float(np.finfo(float).eps)
            for ns, (q, w, bound) in zip(stamps, samples):
                stamp = msgs.stamp(ns)
                att.append(msgs.attitude(stamp, self.frame, q))
                vel.append(msgs.vector(stamp, self.body, w))
                if cfg.transform:
                    tf.append(msgs.transform(stamp, self.frame, self.body, q))
                if cfg.odom:
                    rate_sd = 32.0 * eps * float(np.linalg.norm(w))
                    odom.append(msgs.odometry(stamp, self.frame, self.body, q, w,
                                              attitude_variance=bound ** 2,
                                              rate_variance=rate_sd ** 2))
                if cfg.markers:
                    mk.append(msgs.body_markers(stamp, self.frame, q,
                                                self.sol.scene.inertia))
            streams += [(0, '/attitude', stamps, att), (1, '/angular_velocity', stamps, vel)]
            for order, topic, lst in ((2, '/transform', tf), (3, '/odom', odom),
                                      (4, '/markers', mk)):
                if lst:
                    streams.append((order, topic, stamps, lst))
            if ks[0] == 0:      # ~/run goes out with the first tick, after its truth
                from std_msgs.msg import String
                streams.append((5, RUN_TOPIC, stamps[:1],
                                [String(data=json.dumps(self.description()))]))
        if self.gyro is not None:
            streams += self._gyro_block(lo_ns, hi_ns)
        if self.star is not None:
            streams += self._star_block(lo_ns, hi_ns)
        return streams

    def _gyro_block(self, lo_ns, hi_ns):
        rate = self.cfg.imu_rate
        ks = _sub(self.imu_k, rate, lo_ns, hi_ns)
        if not len(ks):
            return []
        stamps = _stamps(self.start_ns, rate, ks)
        imu, da, dr = [], [], []
        for k, ns1 in zip(ks, stamps):
            ns0 = self.start_ns + round((k - 1) * 1e9 / rate)
            r = self.gyro.read(self.scene_time(ns0), self.scene_time(ns1))
            stamp = msgs.stamp(ns1)
            imu.append(msgs.imu(stamp, self.body, r.omega, r.variance))
            da.append(msgs.vector(stamp, self.body, r.delta_angle))
            dr.append(msgs.vector(stamp, self.body, r.delta_rotation))
        return [(6, '/imu', stamps, imu), (7, '/delta_angle', stamps, da),
                (8, '/delta_rotation', stamps, dr)]

    def _star_block(self, lo_ns, hi_ns):
        rate = self.cfg.star_tracker_rate
        ks = _sub(self.star_k, rate, lo_ns, hi_ns)
        if not len(ks):
            return []
        stamps = _stamps(self.start_ns, rate, ks)
        out = []
        for ns in stamps:
            r = self.star.read(self.scene_time(ns))
            out.append(msgs.star_tracker(msgs.stamp(ns), self.frame, r.quaternion,
                                         r.covariance))
        return [(9, '/star_tracker', stamps, out)]

    def blocks(self):
        """Yield ``(lo_ns, hi_ns, streams)`` over the run, :data:`BLOCK_S` of clock each."""
        step = round(BLOCK_S * _SEC)
        lo = 0
        while lo < self.span_ns:
            hi = min(self.span_ns, lo + step)
            yield lo, hi, self.block(lo, hi)
            lo = hi


def _sub(krange, rate, lo_ns, hi_ns):
    """The indices of ``krange`` whose grid offsets lie in ``[lo_ns, hi_ns)``."""
    a = _grid_count(rate, lo_ns, first=krange.start).stop if lo_ns > 0 else krange.start
    b = _grid_count(rate, hi_ns, first=krange.start).stop
    return range(max(a, krange.start), min(b, krange.stop))


def _merged(streams):
    """``(topic, stamp_ns, msg)`` of a block's streams in stamp order (node order within)."""
    rows = []
    for order, topic, stamps, items in streams:
        rows += [(ns, order, i, topic, m) for i, (ns, m) in enumerate(zip(stamps, items))]
    rows.sort(key=lambda r: (r[0], r[1], r[2]))
    return rows


def iter_run(values, duration_s, start_ns=0):
    """Yield ``(topic, stamp_ns, msg)`` of the run in stamp order, as the node publishes.

    Parameters
    ----------
    values : dict
        Parameter overrides by the node's dotted names (``-p name:=value``), merged over
        the defaults and validated as the node validates them.
    duration_s : float
        Scene seconds to cover: every stamp lies in ``[start_ns, start_ns + duration_s /
        time_scale)``.
    start_ns : int
        Clock stamp of scene time 0 (the node's ``t_start``, ``start_ns`` of its ``~/run``).

    Raises
    ------
    GenerationError
        Before the first message, for invalid parameters or arguments (one line).
    """
    run = _Run(values, duration_s, start_ns)
    return _iter(run)


def _iter(run):
    for _, _, streams in run.blocks():
        for ns, _, _, topic, msg in _merged(streams):
            yield topic, ns, msg


def _qos_yamls(p):
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rigidrot_ros.io.recorder import qos_to_yaml
    qos = QoSProfile(depth=int(p['qos_depth']), reliability=ReliabilityPolicy.RELIABLE)
    run = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    return qos_to_yaml([qos]), qos_to_yaml([run])


def generate_bag(values, duration_s, out_dir, start_ns=0, progress=None):
    """Write the run's bag to ``out_dir`` (created; must not exist or be empty); its path.

    ``progress(done_s, total_s)`` (scene seconds), if given, is called after each block.
    A KeyboardInterrupt finishes the bag (summary, index, metadata.yaml) with what was
    written so far, then propagates.
    """
    from rclpy.serialization import serialize_message

    from rigidrot_ros.io.bag import BagWriter
    run = _Run(values, duration_s, start_ns)
    qos, run_qos = _qos_yamls(run.p)
    try:
        writer = BagWriter(None, 'attitude_node', flush_period=0.5, path=out_dir,
                           split_seconds=0.0)
    except OSError as exc:
        raise GenerationError(f'cannot write the bag to {out_dir}: '
                              f'{" ".join(str(exc).split())}') from None
    try:
        for topic, type_name in run.topics:
            writer.add_topic(topic, type_name, qos)
        writer.add_topic(RUN_TOPIC, 'std_msgs/msg/String', run_qos)
        total = run.span_ns * 1e-9 * run.time_scale
        for lo, hi, streams in run.blocks():
            for ns, _, _, topic, msg in _merged(streams):
                if topic == RUN_TOPIC:          # as the node's recorder: a metadata record
                    writer.add_run(json.loads(msg.data))
                writer.write(topic, serialize_message(msg), ns)
            if progress is not None:
                progress(hi * 1e-9 * run.time_scale, total)
    finally:
        writer.close()
    return writer.path
