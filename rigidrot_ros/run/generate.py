"""Offline generation: the bag ``attitude_node`` would record, without ROS running.

The node's sampling, reproduced on the scene's own grids (no clock, no timers):

- the truth tick k is stamped ``start_ns + round(k * 1e9 / publish_rate)`` and holds the
  scene at ``t = (stamp - start_ns) * 1e-9 * time_scale``: ``attitude``,
  ``angular_velocity`` and, where enabled, ``transform``, ``odom``, ``markers``;
- the imu sample k >= 1 has the true sample time ``start_ns + round(k * 1e9 / imu.rate)``
  and covers the interval from sample k - 1 to sample k: ``imu`` (with the
  accelerometer's ``linear_acceleration`` if ``accel.enable``), ``delta_angle``,
  ``delta_rotation`` (and ``delta_velocity``), the gyro and the accelerometer read a
  block at a time (:meth:`Gyro.read_many`, :meth:`Accelerometer.read_many`: the bits of
  the per-sample reads);
- the star tracker sample k >= 0 at ``start_ns + round(k * 1e9 / rate)``, the
  magnetometer's (``mag``) likewise on its own rate;
- ``~/run`` (``/attitude_node/run``) carries the run description with the first tick, and
  the bag holds it as a ``rigidrot_run`` metadata record too, as the node's recorder writes.

Sensor timing models (``<sensor>.latency``, ``.stamp_jitter``, ``.drop_probability``,
``.clock_offset``) are applied by the node's own :class:`rigidrot_ros.run.scheduler.Track`
(its seeded draws, once per sample in index order, dropped samples included): the sample
is taken at its true time, its messages carry the stamp ``true + offset + jitter``, a
dropped sample is read (noise runs on) but not written. What the generator writes as the
**log time** of a message: its true sample time plus the sensor's latency, i.e. when the
node publishes it on an executor that is never late (the node's recorder logs the clock
at publication, which is that plus the executor's delay); the truth's log time is its
stamp. The bag is in log-time order; messages of one instant in the node's order (true
time, then truth, imu, star tracker, mag). A sample belongs to the run if its true time
lies in ``[start_ns, start_ns + duration_s / time_scale)`` (``duration_s`` in scene
seconds); its log time may lie up to its latency past that. Parameters are validated by
the node's own code (:mod:`rigidrot_ros.run.settings` and the node's scene checks). Messages
are built by :mod:`rigidrot_ros.msgs.messages`; :func:`generate_bag` serializes them with
the vectorised CDR writer :mod:`rigidrot_ros.msgs.cdr` a block at a time and streams them to
the bag, so memory stays bounded whatever the duration.
"""

import difflib
import json
import math
import operator
import os
import pickle
import signal
import subprocess
import sys
import threading

import numpy as np
import yaml

from rigidrot_ros.bag import qos_yaml
from rigidrot_ros.msgs import cdr
from rigidrot_ros.msgs import messages as msgs
from rigidrot_ros.run import scheduler
from rigidrot_ros.run.streams import scene_time as _scene_time

__all__ = ['iter_run', 'iter_serialized', 'generate_bag', 'load_values', 'prepare_run',
           'parse_override', 'GenerationError', 'NODE_NAME', 'RUN_TOPIC']

#: The node whose recording is reproduced (its fully qualified name).
NODE_NAME = '/attitude_node'
#: Where the node publishes its run description.
RUN_TOPIC = NODE_NAME + '/run'
#: Clock seconds of samples handled together (evaluated, serialized, written).
BLOCK_S = 1.0
_SEC = 1_000_000_000
_RUN_ORDER = 99             # ~/run: after every message of the node's first call
#: Scene seconds from which :func:`generate_bag` evaluates the attitudes in a helper
#: process (a second core; below it the process's start-up costs more than it saves).
HELPER_MIN_S = 2.0
#: Blocks whose attitudes the helper process evaluates ahead of the one being written.
HELPER_AHEAD = 2
_EPS = float(np.finfo(float).eps)


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
    """Return the overrides of a params file, then of ``(name, value)`` pairs, as a dict.

    Raises
    ------
    GenerationError
        A missing or malformed params file.
    """
    from rigidrot_ros.run.settings import load_defaults
    values = {}
    if params_file is not None:
        try:
            values.update(load_defaults(params_file))
        except (OSError, ValueError, yaml.YAMLError) as exc:
            raise GenerationError(f'--params-file {params_file}: '
                                  f'{" ".join(str(exc).split())}') from None
    values.update(dict(overrides))
    return values


def prepare_run(values):
    """Validate ``values`` (overrides by name) as the node does: a ``RunSetup``.

    The overrides are merged over the parameter table's defaults and set up by
    :func:`rigidrot_ros.run.settings.prepare_run`, the node's own function (each value by its
    table entry, the scene solved, the sensors checked, the first samples tried), so a
    scene the node refuses is refused here with the same reason, and the solution has
    evaluated what the node's has before its first tick. A name the node does not
    declare is refused (the node warns and ignores it; offline, a typo would silently
    change the run). Raises :class:`GenerationError` (one line).
    """
    from rigidrot_ros.run import params, settings
    unknown = sorted(n for n in values if n not in params.BY_NAME)
    if unknown:
        close = difflib.get_close_matches(unknown[0], sorted(params.BY_NAME), n=1)
        hint = f' (did you mean {close[0]}?)' if close else ''
        raise GenerationError(f'unknown parameter(s) {", ".join(unknown)}{hint}: '
                              'attitude_node declares no such parameter')
    p = params.defaults()
    p.update(values)
    try:
        return settings.prepare_run(p)
    except settings.TrialError as exc:
        summary = ', '.join(f'{k} {p[k]!r}' for k in ('inertia', 'torque', 'omega0'))
        raise GenerationError(' '.join(f'scene {summary}: {exc}'.split())) from None
    except ValueError as exc:
        raise GenerationError(' '.join(str(exc).split())) from None


# -- the run -----------------------------------------------------------------------------------
def _grid_count(rate, span_ns, first=0):
    """Return the range of indices k >= first with ``round(k * 1e9 / rate) < span_ns``."""
    k = max(first, math.floor(span_ns * rate * 1e-9) - 1)
    while round(k * 1e9 / rate) < span_ns:
        k += 1
    while k > first and round((k - 1) * 1e9 / rate) >= span_ns:
        k -= 1
    return range(first, k)


def _stamps(start_ns, rate, ks):
    """Return :func:`grid.stamp_ns` of the indices ``ks`` (int64 array), vectorised.

    ``origin + round(k * 1e9 / rate)``: the same float64 product and quotient, and
    ``np.rint`` rounds half to even as Python's ``round`` does, so every stamp is the
    node's (the byte-identity tests compare them).
    """
    k = np.arange(ks.start, ks.stop, dtype=np.int64)
    return int(start_ns) + np.rint(k * 1e9 / rate).astype(np.int64)


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
        self.setup = setup = prepare_run(values)
        self.p, self.sol, self.cfg = setup.values, setup.solution, setup.sensors
        cfg = self.cfg
        self.time_scale = float(setup.time_scale)
        if self.time_scale <= 0:
            raise GenerationError('parameter time_scale = 0 freezes the scene: a duration in '
                                  'scene seconds needs time_scale > 0')
        self.span_ns = round(duration_s / self.time_scale * 1e9)
        if not 0 < self.span_ns < 2 ** 63 - start_ns:
            raise GenerationError(f'--duration {duration_s!r} s at time_scale '
                                  f'{self.time_scale:g} leaves the int64 nanosecond clock')
        self.start_ns = int(start_ns)
        self.frame, self.body = setup.frames
        self.rate = float(setup.publish_rate)
        self.truth_k = _grid_count(self.rate, self.span_ns)
        self.gyro, self.star = setup.gyro, setup.star_tracker
        self.accel, self.mag = getattr(setup, 'accel', None), getattr(setup, 'mag', None)
        # each sensor's grid and timing model, by the node's own Track (same seeded draws)
        self.tracks = {}
        if cfg.imu:
            self.imu_k = _grid_count(cfg.imu_rate, self.span_ns, first=1)
            self.tracks['imu'] = self._track('imu', cfg.imu_rate, 1)
        if cfg.star_tracker:
            self.star_k = _grid_count(cfg.star_tracker_rate, self.span_ns)
            self.tracks['star_tracker'] = self._track('star_tracker', cfg.star_tracker_rate, 0)
        if self.mag is not None:
            self.mag_k = _grid_count(cfg.mag_rate, self.span_ns)
            self.tracks['mag'] = self._track('mag', cfg.mag_rate, 0)
        #: clock ns past the last sample time until which samples are still published
        self.tail_ns = max([t.timing.latency_ns for t in self.tracks.values()] + [0])

    def _track(self, name, rate, first):
        return scheduler.Track(name, self.start_ns, rate, first,
                               scheduler.timing_of(self.p, name))

    # -- time ------------------------------------------------------------------------------
    def scene_time(self, ns):
        """Return the scene time (s) of clock stamp(s) ``ns``, by the node's own function.

        An int64 array gives each element the bits of the scalar call (the same integer
        difference, converted to float64 once, and the same two products).
        """
        return _scene_time(ns, self.start_ns, self.time_scale)

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
            if self.accel is not None:
                out.append(('/delta_velocity', 'geometry_msgs/msg/Vector3Stamped'))
        if cfg.star_tracker:
            out.append(('/star_tracker', 'geometry_msgs/msg/PoseWithCovarianceStamped'))
        if self.mag is not None:
            out.append(('/mag', 'sensor_msgs/msg/MagneticField'))
        return out

    def description(self):
        """Return the run description the node publishes on ``~/run`` (a dict)."""
        from rigidrot_ros.run.outputs import run_description
        topics = {'/parameter_events': 'rcl_interfaces/msg/ParameterEvent'}
        topics.update(self.topics)
        topics['/diagnostics'] = 'diagnostic_msgs/msg/DiagnosticArray'
        topics[RUN_TOPIC] = 'std_msgs/msg/String'
        return run_description(self.setup, self.start_ns, 1, NODE_NAME, topics)

    # -- truth -----------------------------------------------------------------------------
    def _truth_samples(self, ks, stamps, pre=None):
        """Return ``(q, omega, bound)`` arrays of the truth ticks ``ks`` (one call).

        A sample's bits depend on its time alone (the core's checkpoints), so one batch
        gives what the node's scalar ticks and look-ahead batches give; ``pre``: the same
        arrays evaluated already (by the helper process, :meth:`plan`).
        """
        if pre is not None:
            return pre
        s = self.sol.at(self.scene_time(stamps))
        return s.quaternion, s.omega, s.error_bound

    def plan(self, lo_ns, hi_ns):
        """Return ``(truth times, imu interval ends)`` (scene s) of block ``[lo, hi)``.

        The times at which :meth:`block` evaluates ``solution.at`` (either may be empty):
        what a helper process can evaluate ahead, since a sample's bits depend on its
        time alone.
        """
        ks = _sub(self.truth_k, self.rate, lo_ns, hi_ns)
        truth = self.scene_time(_stamps(self.start_ns, self.rate, ks))
        ends = np.empty(0)
        if self.gyro is not None:
            ki = self._window('imu', self.imu_k, self.cfg.imu_rate, lo_ns, hi_ns)
            if len(ki):
                ends = self.scene_time(_stamps(self.start_ns, self.cfg.imu_rate,
                                               range(ki.start - 1, ki.stop)))
        return truth, ends

    # -- one block ---------------------------------------------------------------------------
    def block(self, lo_ns, hi_ns, pre=None):
        """Return the messages logged in ``[lo_ns, hi_ns)`` (relative to start), as arrays.

        A list of streams ``(order, topic, stamps_ns, data, log_ns, true_ns)``: ``order``
        ranks the streams of one instant as the node publishes them; ``stamps_ns`` the
        header stamps, ``log_ns`` the log times (the true sample time plus the sensor's
        latency), ``true_ns`` the true sample times (int64 arrays, one per sample);
        ``data`` a dict of float arrays (one row a sample) that :func:`_messages` and
        :func:`_serialized` turn into messages. ``pre``: ``solution.at`` of the times of
        :meth:`plan` (``(q, omega, bound)`` of each), evaluated already (same bits).
        """
        pre_truth, pre_imu = (None, None) if pre is None else pre
        streams = []
        rate, cfg = self.rate, self.cfg
        ks = _sub(self.truth_k, rate, lo_ns, hi_ns)
        if len(ks):
            stamps = _stamps(self.start_ns, rate, ks)
            q, w, e = self._truth_samples(ks, stamps, pre_truth)
            streams += [(0, '/attitude', stamps, {'q': q}),
                        (1, '/angular_velocity', stamps, {'v': w})]
            if cfg.transform:
                streams.append((2, '/transform', stamps, {'q': q}))
            if cfg.odom:
                rate_sd = 32.0 * _EPS * np.array([float(np.linalg.norm(x)) for x in w])
                streams.append((3, '/odom', stamps, {'q': q, 'w': w, 'av': e ** 2,
                                                     'rv': rate_sd ** 2}))
            if cfg.markers:
                streams.append((4, '/markers', stamps, {'q': q}))
            if ks[0] == 0:      # ~/run goes out after everything of the first call
                streams.append((_RUN_ORDER, RUN_TOPIC, stamps[:1], {}))
        streams = [st + (st[2], st[2]) for st in streams]     # truth: log = stamp = true
        if self.gyro is not None:
            streams += self._imu_block(lo_ns, hi_ns, pre_imu)
        if self.star is not None:
            streams += self._star_block(lo_ns, hi_ns)
        if self.mag is not None:
            streams += self._mag_block(lo_ns, hi_ns)
        return streams

    def _window(self, name, krange, rate, lo_ns, hi_ns):
        """Return the indices whose log time (grid time + latency) is in ``[lo, hi)``."""
        lat = self.tracks[name].timing.latency_ns
        return _sub(krange, rate, lo_ns - lat, hi_ns - lat)

    def _timed(self, name, ks, parts):
        """Apply sensor ``name``'s timing model to the samples ``ks``: the streams.

        ``parts``: ``[(order, topic, data), ...]`` of the samples (rows in ``ks`` order).
        :meth:`Track.marks` draws the stamps (grid + clock offset + jitter) and drops of
        every sample, kept or not, in index order as the node does; dropped rows go.
        """
        track = self.tracks[name]
        t = track.timing
        true = _stamps(self.start_ns, track.rate, ks)
        if t.stamp_jitter > 0 or t.drop_probability > 0 or t.offset_ns != 0:
            stamps, keep = track.marks(ks)
        else:                           # marks() would draw nothing: the grid itself
            stamps, keep = true, np.ones(len(ks), dtype=bool)
        log = true + t.latency_ns
        if not keep.all():
            stamps, true, log = stamps[keep], true[keep], log[keep]
            parts = [(o, t, {k: v[keep] for k, v in d.items()}) for o, t, d in parts]
        return [(o, t, stamps, d, log, true) for o, t, d in parts]

    def _imu_block(self, lo_ns, hi_ns, pre=None):
        rate = self.cfg.imu_rate
        ks = self._window('imu', self.imu_k, rate, lo_ns, hi_ns)
        if not len(ks):
            return []
        ends = self.scene_time(_stamps(self.start_ns, rate, range(ks.start - 1, ks.stop)))
        # the gyro's block path (sensors.batch): the per-sample reads' bits, all at once
        b = self.gyro.read_many(ends, attitudes=None if pre is None else (pre[0], pre[2]))
        imu = {'w': b.omega, 'var': b.variance}
        parts = [(6, '/imu', imu), (7, '/delta_angle', {'v': b.delta_angle}),
                 (8, '/delta_rotation', {'v': b.delta_rotation})]
        if self.accel is not None:      # the same intervals, after the gyro (as the node)
            a = self.accel.read_many(ends)
            imu.update(f=a.specific_force, avar=a.variance)
            parts.append((8.5, '/delta_velocity', {'v': a.delta_velocity}))
        return self._timed('imu', ks, parts)

    def _star_block(self, lo_ns, hi_ns):
        rate = self.cfg.star_tracker_rate
        ks = self._window('star_tracker', self.star_k, rate, lo_ns, hi_ns)
        if not len(ks):
            return []
        q, cov = np.empty((len(ks), 4)), np.empty((len(ks), 3, 3))
        for i, t in enumerate(self.scene_time(_stamps(self.start_ns, rate, ks)).tolist()):
            r = self.star.read(t)
            q[i], cov[i] = r.quaternion, r.covariance
        return self._timed('star_tracker', ks, [(9, '/star_tracker', {'q': q, 'cov': cov})])

    def _mag_block(self, lo_ns, hi_ns):
        rate = self.cfg.mag_rate
        ks = self._window('mag', self.mag_k, rate, lo_ns, hi_ns)
        if not len(ks):
            return []
        dt = self.time_scale / rate             # as MagStream.messages
        field, cov = np.empty((len(ks), 3)), np.empty((len(ks), 3, 3))
        for i, t in enumerate(self.scene_time(_stamps(self.start_ns, rate, ks)).tolist()):
            r = self.mag.read(t, dt)
            field[i], cov[i] = r.field, r.covariance
        return self._timed('mag', ks, [(10, '/mag', {'m': field, 'cov': cov})])

    def blocks(self):
        """Yield ``(lo_ns, hi_ns, streams)`` over the run, :data:`BLOCK_S` of clock each.

        Blocks cut the log time; past the span they run on until the last sample's
        latency has passed (a sample of the span is published, however late).
        """
        step = round(BLOCK_S * _SEC)
        lo = 0
        end = self.span_ns + self.tail_ns
        while lo < end:
            hi = min(end, lo + step)
            yield lo, hi, self.block(lo, hi)
            lo = hi


def _sub(krange, rate, lo_ns, hi_ns):
    """Return the indices of ``krange`` whose grid offsets lie in ``[lo_ns, hi_ns)``."""
    a = _grid_count(rate, lo_ns, first=krange.start).stop if lo_ns > 0 else krange.start
    b = _grid_count(rate, hi_ns, first=krange.start).stop
    return range(max(a, krange.start), min(b, krange.stop))


def _order(streams):
    """Merge order of a block's messages: ``(stream index, row)`` pairs.

    By log time, then true sample time, then the node's rank of the stream, then row:
    the order an executor that calls the node's timer at every due time publishes in.
    """
    if not streams:
        return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
    which = np.concatenate([np.full(len(st[2]), i) for i, st in enumerate(streams)])
    row = np.concatenate([np.arange(len(st[2])) for st in streams])
    log = np.concatenate([st[4] for st in streams])
    true = np.concatenate([st[5] for st in streams])
    rank = np.concatenate([np.full(len(st[2]), st[0], dtype=float) for st in streams])
    order = np.lexsort((row, rank, true, log))
    return which[order], row[order]


def _merged(streams, items):
    """Return a block's ``(topics, items, log times)`` lists in the order the node publishes.

    ``items[i]`` holds stream i's messages (or payloads), one per sample.
    """
    which, rows = _order(streams)
    if not len(which):
        return [], [], []
    first = np.cumsum([0] + [len(st[2]) for st in streams])
    pick = (first[which] + rows).tolist()
    flat = [x for part in items for x in part]
    names = [st[1] for st in streams for _ in range(len(st[2]))]
    logs = np.concatenate([st[4] for st in streams])[pick]
    get = operator.itemgetter(*pick)
    if len(pick) == 1:
        return [get(names)], [get(flat)], logs.tolist()
    return list(get(names)), list(get(flat)), logs.tolist()


_VECTORS = ('/angular_velocity', '/delta_angle', '/delta_rotation', '/delta_velocity')


def _messages(run, order, topic, stamps, data, *_):
    """Build the ROS messages of one stream, built by :mod:`rigidrot_ros.msgs.messages`."""
    frame, body = run.frame, run.body
    st = [msgs.stamp(int(ns)) for ns in stamps]
    if topic == RUN_TOPIC:
        from std_msgs.msg import String
        return [String(data=json.dumps(run.description()))]
    if topic in ('/attitude',):
        return [msgs.attitude(s, frame, q) for s, q in zip(st, data['q'].tolist())]
    if topic in _VECTORS:
        return [msgs.vector(s, body, v) for s, v in zip(st, data['v'].tolist())]
    if topic == '/transform':
        return [msgs.transform(s, frame, body, q) for s, q in zip(st, data['q'].tolist())]
    if topic == '/odom':
        return [msgs.odometry(s, frame, body, q, w, attitude_variance=av, rate_variance=rv)
                for s, q, w, av, rv in zip(st, data['q'].tolist(), data['w'].tolist(),
                                           data['av'].tolist(), data['rv'].tolist())]
    if topic == '/markers':
        inertia = run.sol.scene.inertia
        return [msgs.body_markers(s, frame, q, inertia) for s, q in zip(st, data['q'].tolist())]
    if topic == '/imu' and 'f' in data:
        return [msgs.imu(s, body, w, v, f, a) for s, w, v, f, a in
                zip(st, data['w'], data['var'].tolist(), data['f'], data['avar'].tolist())]
    if topic == '/imu':
        return [msgs.imu(s, body, w, v) for s, w, v in zip(st, data['w'], data['var'].tolist())]
    if topic == '/mag':
        return [msgs.magnetic_field(s, body, m, c) for s, m, c in zip(st, data['m'], data['cov'])]
    if topic == '/star_tracker':
        return [msgs.star_tracker(s, frame, q, c) for s, q, c in zip(st, data['q'], data['cov'])]
    raise AssertionError(topic)


def _serialized(run, order, topic, stamps, data, *_):
    """Serialize one stream (:mod:`rigidrot_ros.msgs.cdr`), a list of ``bytes``."""
    frame, body = run.frame, run.body
    if topic == '/attitude':
        return cdr.attitude(stamps, data['q'], frame).tolist()
    if topic in _VECTORS:
        return cdr.vector(stamps, data['v'], body).tolist()
    if topic == '/transform':
        return cdr.transform(stamps, data['q'], frame, body).tolist()
    if topic == '/odom':
        return cdr.odometry(stamps, data['q'], data['w'], data['av'], data['rv'], frame,
                            body).tolist()
    if topic == '/imu' and 'f' in data:
        return cdr.imu(stamps, data['w'], data['var'], body, data['f'], data['avar']).tolist()
    if topic == '/imu':
        return cdr.imu(stamps, data['w'], data['var'], body).tolist()
    if topic == '/mag':
        return cdr.magnetic_field(stamps, data['m'], data['cov'], body).tolist()
    if topic == '/star_tracker':
        return cdr.star_tracker(stamps, data['q'], data['cov'], frame).tolist()
    from rclpy.serialization import serialize_message     # ~/run, markers: not fixed-size
    return [serialize_message(m) for m in _messages(run, order, topic, stamps, data)]


def iter_run(values, duration_s, start_ns=0):
    """Yield ``(topic, log_ns, msg)`` of the run in log-time order, as the node publishes.

    ``log_ns`` is the message's log time (its true sample time plus its sensor's latency;
    see the module text); without timing models it is the header stamp.

    Parameters
    ----------
    values : dict
        Parameter overrides by the node's dotted names (``-p name:=value``), merged over
        the defaults and validated as the node validates them.
    duration_s : float
        Scene seconds to cover: every true sample time lies in ``[start_ns, start_ns +
        duration_s / time_scale)``.
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
        built = [_messages(run, *st) for st in streams]
        for i, j in zip(*_order(streams)):
            yield streams[i][1], int(streams[i][4][j]), built[i][j]


def iter_serialized(values, duration_s, names=None, start_ns=0):
    """Yield ``(topic, log_ns, cdr_bytes)`` of the run in log-time order: the bag, unwritten.

    The messages :func:`generate_bag` writes, in its order, serialized the same way, without
    the file (no compression, no index): for a program that plays the run at once.
    ``names`` keeps only the topics whose last name component is one of them (``('imu',
    'star_tracker', 'run')``: the sensors and the run description); the other streams are
    neither serialized nor merged. Arguments and errors as :func:`iter_run`.
    """
    run = _Run(values, duration_s, start_ns)
    keep = None if names is None else set(names)
    return _iter_serialized(run, keep)


def _iter_serialized(run, keep):
    for _, _, streams in run.blocks():
        if keep is not None:
            streams = [st for st in streams if st[1].rsplit('/', 1)[-1] in keep]
        topics, datas, logs = _merged(streams, [_serialized(run, *st) for st in streams])
        yield from zip(topics, logs, datas)


def _blocks(run, values, helper):
    """Yield ``(lo, hi, streams)`` as :meth:`_Run.blocks`, with the helper if used."""
    if not _use_helper(run, helper):
        yield from run.blocks()
        return
    step = round(BLOCK_S * _SEC)
    end = run.span_ns + run.tail_ns
    cuts = [(lo, min(end, lo + step)) for lo in range(0, end, step)]
    proc = _Helper(values)
    try:
        for i in range(min(HELPER_AHEAD, len(cuts))):
            proc.submit(run.plan(*cuts[i]))
        for i, (lo, hi) in enumerate(cuts):
            got = proc.result()
            if i + HELPER_AHEAD < len(cuts):
                proc.submit(run.plan(*cuts[i + HELPER_AHEAD]))
            yield lo, hi, run.block(lo, hi, pre=got)
    finally:
        proc.close()


def _qos_yamls(p):
    """Return the offered QoS YAMLs as rosbag2 writes them: the streams and ``~/run``."""
    return (qos_yaml(depth=int(p['qos_depth'])),
            qos_yaml(depth=1, durability='transient_local'))


def _helper_main():
    """Serve ``solution.at`` as the helper process (``python -m rigidrot_ros.run.generate``).

    Reads pickles from stdin: first the parameter values, then tuples of time arrays
    (scene s), None to stop; answers each with a list of ``(q, omega, bound)`` (None for
    an empty array) or the exception it raised. The first answer is None (set up) or the
    set-up's exception.
    """
    src, dst = sys.stdin.buffer, sys.stdout.buffer
    try:
        sol = prepare_run(pickle.load(src)).solution
    except Exception as exc:    # noqa: B902 - the parent evaluates itself then
        pickle.dump(exc, dst)
        dst.flush()
        return
    pickle.dump(None, dst)
    dst.flush()
    while True:
        try:
            ts = pickle.load(src)
        except EOFError:
            return
        if ts is None:
            return
        try:
            out = []
            for t in ts:
                if len(t):
                    smp = sol.at(t)
                    out.append((smp.quaternion, smp.omega, smp.error_bound))
                else:
                    out.append(None)
        except Exception as exc:    # noqa: B902 - the parent evaluates itself then
            out = exc
        pickle.dump(out, dst, protocol=pickle.HIGHEST_PROTOCOL)
        dst.flush()


class _Helper:
    """A second process that evaluates ``solution.at`` for the blocks to come.

    It solves the same scene from the same values (:func:`prepare_run`); a sample's bits
    depend on its time alone (the core's checkpoints), so its attitudes are the ones this
    process would compute, and it uses the machine's second core while this one reads
    the sensors, serializes and writes. A plain child interpreter (``python -m``, no
    re-import of the caller's ``__main__``), SIGINT ignored (the parent finishes the bag
    on SIGINT and stops the helper), its stderr discarded. Any failure: ``None``, and
    the caller evaluates the block itself.
    """

    def __init__(self, values):
        before = signal.signal(signal.SIGINT, signal.SIG_IGN) \
            if threading.current_thread() is threading.main_thread() else None
        try:
            self._proc = subprocess.Popen(
                [sys.executable, '-m', 'rigidrot_ros.run.generate'], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        finally:
            if before is not None:
                signal.signal(signal.SIGINT, before)
        self._ok = self._send(values)
        self._ready = False

    def _send(self, obj):
        try:
            pickle.dump(obj, self._proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self._proc.stdin.flush()
            return True
        except (OSError, ValueError, pickle.PicklingError):
            return False

    def submit(self, times):
        """Queue the evaluation of ``times`` (a tuple of arrays of scene s)."""
        self._ok = self._ok and self._send(times)

    def result(self):
        """Return the next queued answer: a list of ``(q, omega, bound)`` (or None) per array."""
        if not self._ok:
            return None
        try:
            if not self._ready:         # the helper's first word: its set-up went well
                first = pickle.load(self._proc.stdout)
                if first is not None:
                    raise ValueError(first)
                self._ready = True
            out = pickle.load(self._proc.stdout)
        except Exception:           # noqa: B902 - the helper failed: evaluate here
            self._ok = False
            return None
        return None if isinstance(out, Exception) else out

    def close(self):
        """Stop the helper process."""
        try:
            self._send(None)
            self._proc.stdin.close()
        except (OSError, ValueError):
            pass
        try:
            self._proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(timeout=5.0)
        self._proc.stdout.close()


def _use_helper(run, helper):
    """Whether to use the helper: asked for, on 2 or more cores, a run long enough."""
    return bool(helper) and (os.cpu_count() or 1) >= 2 and \
        run.span_ns * 1e-9 * run.time_scale >= HELPER_MIN_S


def generate_bag(values, duration_s, out_dir, start_ns=0, progress=None, helper=None):
    """Write the run's bag to ``out_dir`` (created; must not exist or be empty); its path.

    ``progress(done_s, total_s)`` (scene seconds), if given, is called after each block.
    A KeyboardInterrupt finishes the bag (summary, index, metadata.yaml) with what was
    written so far, then propagates. ``helper=True``: evaluate the attitudes (truth,
    gyro interval ends) in a second process, :data:`HELPER_AHEAD` blocks ahead (the same
    bits: a sample depends on its time alone), on a machine of 2 or more cores for a
    run of :data:`HELPER_MIN_S` scene seconds or more. Off by default: it pays only
    where the second core is idle (on the shared 2-core machine, load average 3.5, the
    benchmark hour took 86.5 s with it and 64.4 s without).
    """
    from rigidrot_ros.bag import BagWriter
    run = _Run(values, duration_s, start_ns)
    qos, run_qos = _qos_yamls(run.p)
    try:
        # chunks cut by blocks, never by the wall clock: the same run gives the same file
        writer = BagWriter(None, 'attitude_node', flush_period=math.inf, path=out_dir,
                           split_seconds=0.0)
    except OSError as exc:
        raise GenerationError(f'cannot write the bag to {out_dir}: '
                              f'{" ".join(str(exc).split())}') from None
    stop = []
    previous = None
    if threading.current_thread() is threading.main_thread():
        # SIGINT between blocks, never inside a write: the bag is always finished whole
        previous = signal.signal(signal.SIGINT, lambda *_: stop.append(True))
    try:
        for topic, type_name in run.topics:
            writer.add_topic(topic, type_name, qos)
        writer.add_topic(RUN_TOPIC, 'std_msgs/msg/String', run_qos)
        total = run.span_ns * 1e-9 * run.time_scale
        for lo, hi, streams in _blocks(run, values, helper):
            raws = [_serialized(run, *st) for st in streams]
            topics, datas, stamps = _merged(streams, raws)
            cut = topics.index(RUN_TOPIC) if RUN_TOPIC in topics else len(topics)
            writer.write_many(topics[:cut], datas[:cut], stamps[:cut])
            if cut < len(topics):               # as the node's recorder: a metadata record
                writer.add_run(run.description())
                writer.write_many(topics[cut:], datas[cut:], stamps[cut:])
            writer.flush()
            if progress is not None:
                progress(min(hi, run.span_ns) * 1e-9 * run.time_scale, total)
            if stop:
                break
    finally:
        writer.close()
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    if stop:
        raise KeyboardInterrupt
    return writer.path


if __name__ == '__main__':
    _helper_main()
