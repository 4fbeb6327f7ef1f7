"""The live view: subscribe to the node's truth, its sensors and estimators, and log them.

Every topic is subscribed raw (serialized CDR) by a node that no executor spins: a
reader thread takes the waiting messages of each subscription every 10 ms (one C call a
message, no executor wake-up), reads a message's stamp from its first bytes (every
supported type starts with a ``std_msgs/Header``), and queues only the messages the
decimation keeps (at most ``max_rate`` Hz a topic, by stamp). A worker thread, every
``period`` seconds, deserializes what was kept, decodes it with the scorer's decoder,
scores it against the exact truth of the node's run description (``~/run``, transient
local: the view can start after the node) and logs it in one call per entity. Without a
run description (none after ``wait_run`` s) the box shows the node's ``attitude`` topic
and the estimates are drawn without errors, which the notes say.
"""

import collections
import json
import resource
import struct
import threading
import time

import numpy as np

from rigidrot_ros.bag import run_from_string
from rigidrot_ros.core import engine
from rigidrot_ros.ros.recorder import msg_class
from rigidrot_ros.scoring.decode import _fields, _stream, ORIENTATION, SUPPORTED
from rigidrot_ros.scoring.score import ScoreError
from rigidrot_ros.view import compute as cp
from rigidrot_ros.view.plan import Plan, plan_streams
from rigidrot_ros.view.rr_log import log_plan

__all__ = ['LiveView', 'node_topics_of', 'cdr_stamp', 'check_topic', 'MAX_BACKLOG']

#: Seconds between two takes of the data subscriptions' messages (their history holds
#: 1000: a second of a 1 kHz gyro).
TAKE_PERIOD = 0.01
#: Messages a topic may wait for the worker; past it the oldest are dropped and counted (the
#: view is behind: 2 s of a 1 kHz gyro shown in full).
MAX_BACKLOG = 2000

#: The node's topics the live view reads, by name: (type, role).
NODE_TOPICS = {
    'attitude': 'geometry_msgs/msg/QuaternionStamped',
    'imu': 'sensor_msgs/msg/Imu',
    'star_tracker': 'geometry_msgs/msg/PoseWithCovarianceStamped',
}


def _ignore(_):
    """Stand in for a callback: the data node is never spun, its messages are taken."""


def cdr_stamp(data):
    """Return the header stamp (ns) of a serialized message that starts with a Header."""
    endian = '<' if data[1] in (1, 3) else '>'
    sec, nsec = struct.unpack(endian + 'iI', bytes(data[4:12]))
    return sec * 1_000_000_000 + nsec


def node_topics_of(ns):
    """Return ``{topic: type}`` of the node's truth and sensors under namespace ``ns``."""
    base = '/' + ns.strip('/') if ns.strip('/') else ''
    return {f'{base}/{name}': t for name, t in NODE_TOPICS.items()}


def check_topic(text):
    """Split ``TOPIC:TYPE``; raise ValueError naming what is wrong."""
    topic, sep, type_name = text.rpartition(':')
    if not sep or not topic.startswith('/') or not type_name:
        raise ValueError(f'--topic {text!r}: expected /name:pkg/msg/Type, e.g. '
                         f'/estimator/odom:nav_msgs/msg/Odometry')
    return topic, type_name


class LiveView:
    """Subscriptions, batches and their logging for one rclpy node.

    Parameters
    ----------
    node : rclpy.node.Node
        Where the subscriptions are made.
    rec : rigidrot_ros.view.rr_log.Recorder
        Where it logs.
    ns : str
        The attitude node's namespace.
    estimators : dict
        ``{topic: type}`` of the estimates to show.
    run_topic : str
        The node's run description topic.
    max_rate : float
        Most messages a topic shown per second (0: all).
    """

    def __init__(self, node, rec, ns='', estimators=None, run_topic='/attitude_node/run',
                 max_rate=50.0, period=0.2, wait_run=10.0, say=print):
        from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile,
                               ReliabilityPolicy)
        self.node, self.rec, self.max_rate, self.say = node, rec, max_rate, say
        self.types = dict(node_topics_of(ns))
        self.user = {}
        self.problems = []
        for topic, type_name in (estimators or {}).items():
            if type_name not in SUPPORTED:
                self.problems.append(f'{topic}: {type_name} carries no attitude or body rate '
                                     f'the view reads (it reads {", ".join(SUPPORTED)}): '
                                     f'not shown')
                continue
            try:
                msg_class(type_name)
            except ValueError as exc:
                self.problems.append(f'{topic}: {exc}: not shown')
                continue
            self.user[topic] = type_name
            self.types[topic] = type_name
        for p in self.problems:
            say(p)
        self.truth = cp.Truth([], 'live')
        self.buffers = {t: collections.deque(maxlen=MAX_BACKLOG) for t in self.types}
        self.overflow = collections.Counter()
        self.new_runs = collections.deque()
        self.last_kept = {t: None for t in self.types}
        self.received = collections.Counter()
        self.shown = collections.Counter()
        self.first_seen = {}
        self.last_seen = {}
        self.t0 = None
        self.started = time.monotonic()
        self.wait_run = wait_run
        self.static_done = False
        self.boxes = []
        self.flush_cost = []
        self.notes_logged = None
        data_qos = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST,
                              reliability=ReliabilityPolicy.BEST_EFFORT)
        # the data subscriptions belong to a node no executor spins: the reader thread
        # takes their messages in batches (no executor wake-up per message)
        import rclpy
        self.data_node = rclpy.create_node(f'{node.get_name()}_data',
                                           context=node.context)
        self.subs = [(self.data_node.create_subscription(msg_class(t), topic, _ignore,
                                                         data_qos, raw=True),
                      self._callback(topic))
                     for topic, t in self.types.items()]
        from std_msgs.msg import String
        self.run_sub = node.create_subscription(
            String, run_topic, self._on_run,
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL), raw=True)
        self.run_topic = run_topic
        self.period = period
        self._stop = threading.Event()
        self._lock = threading.Lock()
        # the core's compiled kernels (numba) load here, in the main thread: imported first
        # in the worker while the executor spins, numba's import stalled both threads
        engine.kernels()
        self.reader = threading.Thread(target=self._read, name='rigidrot_view_read',
                                       daemon=True)
        self.worker = threading.Thread(target=self._work, name='rigidrot_view', daemon=True)
        self.reader.start()
        self.worker.start()

    def _read(self):
        """Take every subscription's waiting messages each :data:`TAKE_PERIOD` s."""
        while not self._stop.wait(TAKE_PERIOD):
            self.take()

    def take(self):
        """Take the messages waiting on the data subscriptions (raw CDR) into the queues."""
        for sub, on_message in self.subs:
            with sub.handle:
                while True:
                    got = sub.handle.take_message(sub.msg_type, True)
                    if got is None:
                        break
                    on_message(got[0])

    def _work(self):
        """Flush every ``period`` s, off the executor's thread."""
        while not self._stop.wait(self.period):
            self.flush()

    def close(self):
        """Stop the threads, flush what is left, destroy the data node."""
        self._stop.set()
        self.reader.join()
        self.worker.join()
        self.take()
        self.flush(final=True)
        self.data_node.destroy_node()

    def _callback(self, topic):
        period = int(round(1e9 / self.max_rate)) if self.max_rate else 0
        buf = self.buffers[topic]
        received = self.received

        def on_message(data):
            stamp = cdr_stamp(data)
            received[topic] += 1
            last = self.last_kept[topic]
            if last is None or stamp - last >= period or stamp < last:
                self.last_kept[topic] = stamp
                if len(buf) == MAX_BACKLOG:
                    self.overflow[topic] += 1       # the oldest goes: the view is behind
                buf.append((stamp, data))
            if topic not in self.first_seen:
                self.first_seen[topic] = (time.monotonic(), stamp)
            self.last_seen[topic] = (time.monotonic(), stamp)
        return on_message

    def _on_run(self, data):
        run = run_from_string(data)
        if run is not None and 'start_ns' in run:
            self.new_runs.append(run)           # taken by the worker (flush)

    def _take_runs(self):
        while self.new_runs:
            run = self.new_runs.popleft()
            if self.truth.add_run(run):
                self.say(f'run {run.get("run", "?")} of {run.get("node", "?")}: model '
                         f'{run.get("model", "?")}, inertia {run["scene"].get("inertia")}')
                self.static_done = False       # a reset may change the body
                self.rec.runs(self.truth.runs)
                self.truth.solution(run)       # solved here, in the worker

    # -- batches --------------------------------------------------------------------------------
    def _streams(self):
        from rclpy.serialization import deserialize_message
        streams = []
        for topic, buf in self.buffers.items():
            if not buf:
                continue
            items, type_name = [], self.types[topic]
            while buf:                  # the executor appends on the other end meanwhile
                items.append(buf.popleft())
            cls = msg_class(type_name)
            rows = {}
            for stamp, data in items:
                m = deserialize_message(data, cls)
                for fld, value, cov, frame in _fields(type_name, m):
                    rows.setdefault(fld, []).append((stamp, value, cov, frame))
            for fld, r in rows.items():
                streams.append(_stream(topic, type_name, fld, r))
            self.shown[topic] += len(items)
        return streams

    def _roles(self, streams):
        runs = self.truth.runs
        roles = cp.topic_roles(streams, runs)
        roles.notes = []
        for s in streams:
            if s.topic in self.user:
                roles.by_label[s.label] = cp.ESTIMATE if s.field == ORIENTATION \
                    else cp.RATE_ESTIMATE
            elif s.topic.rsplit('/', 1)[-1] == 'attitude':
                roles.by_label[s.label] = cp.TRUTH
        return roles

    def flush(self, final=False):
        """Decode, score and log what the decimation kept since the last call."""
        with self._lock:
            self._flush(final)

    def _flush(self, final):
        c0 = time.thread_time()
        self._take_runs()
        if (not final and not self.truth.runs
                and time.monotonic() - self.started < self.wait_run):
            return                              # the run description comes first
        streams = self._streams()
        if not streams:
            return
        runs = sorted(self.truth.runs, key=lambda r: int(r['start_ns']))
        if self.t0 is None:
            self.t0 = int(runs[0]['start_ns']) if runs else min(int(s.stamps.min())
                                                                for s in streams)
            self.rec.t0_ns = self.t0
        roles = self._roles(streams)
        plan = Plan(t0_ns=self.t0)
        truth = self.truth if runs else None
        truth_streams = [s for s in streams if roles.by_label.get(s.label) == cp.TRUTH]
        for s in truth_streams:
            if truth is not None:
                try:
                    _, q, w = truth.at(s.stamps)
                except ScoreError:
                    continue
                ok = np.all(np.isfinite(q), axis=1)
                plan.truth = dict(stamps=s.stamps[ok], q=q[ok], omega=w[ok])
            else:
                plan.truth = dict(stamps=s.stamps, q=s.values,
                                  omega=np.zeros((len(s.stamps), 3)))
        stand_in = not self.user
        plan_streams(streams, truth, roles, plan=plan, stand_in=stand_in)
        self._static(plan)
        log_plan(self.rec, plan, static=False)
        self._notes()
        self.flush_cost.append(time.thread_time() - c0)

    def _static(self, plan):
        inertia = self.truth.inertia()
        if not self.static_done:
            self.static_done = True
            half = cp.box_half_sizes(inertia or [1.0, 1.0, 1.0])
            self.half = half
            self.rec.body(half, [])
            self.boxes = []
            if inertia is not None:
                run = max(self.truth.runs, key=lambda r: int(r['start_ns']))
                w0 = np.linalg.norm(run['scene'].get('omega0', [1.0, 0, 0]))
                self.arrow_scale = 1.5 / w0 if w0 > 0 else 1.0
            else:
                self.arrow_scale = 0.0
        plan.arrow_scale = self.arrow_scale
        for e in plan.estimates:
            if e['label'] not in self.boxes:
                self.rec.estimate_box(len(self.boxes), e['label'], self.half)
                self.boxes.append(e['label'])

    def notes(self):
        """Return the notes: what is subscribed, decimated, missing (one line each)."""
        out = []
        runs = self.truth.runs
        if runs:
            out.append(f'truth: the exact solution of {len(runs)} run(s) of '
                       f'{runs[-1].get("node", "?")}, recomputed from {self.run_topic}')
        else:
            out.append(f'no run description on {self.run_topic}: the box shows the '
                       f"node's attitude topic; errors need the run description")
        out.append(f'each topic shown at most {self.max_rate:g} Hz (--max-rate); kept '
                   f'messages are batched every {self.period:g} s')
        for topic in self.types:
            n = self.received[topic]
            if not n:
                out.append(f'{topic}: nothing received yet')
                continue
            rate = self.rate(topic)
            out.append(f'{topic}: {n} received' + (f' ({rate:.4g} Hz)' if rate else '')
                       + f', {self.shown[topic]} shown'
                       + (f', {self.overflow[topic]} dropped: the view fell behind'
                          if self.overflow[topic] else ''))
        return out + self.problems

    def rate(self, topic):
        """Return a topic's message rate from its stamps (Hz), or None."""
        if topic not in self.first_seen or self.received[topic] < 2:
            return None
        span = (self.last_seen[topic][1] - self.first_seen[topic][1]) * 1e-9
        return (self.received[topic] - 1) / span if span > 0 else None

    def _notes(self):
        now = time.monotonic()
        if self.notes_logged is None or now - self.notes_logged > 2.0:
            self.notes_logged = now
            self.rec.notes(self.notes())

    def summary(self):
        """Return one line: per topic received/shown, and the process's CPU time."""
        use = resource.getrusage(resource.RUSAGE_SELF)
        parts = [f'{t} {self.received[t]} received, {self.shown[t]} shown'
                 for t in self.types if self.received[t]]
        cost = np.array(self.flush_cost) if self.flush_cost else np.zeros(1)
        return json.dumps({'topics': {t: {'received': self.received[t],
                                          'shown': self.shown[t], 'rate_hz': self.rate(t),
                                          'dropped_behind': self.overflow[t]}
                                      for t in self.types},
                           'cpu_s': use.ru_utime + use.ru_stime,
                           'flushes': len(self.flush_cost),
                           'flush_cpu_ms_median': float(np.median(cost) * 1e3),
                           'flush_cpu_ms_max': float(cost.max() * 1e3),
                           'text': '; '.join(parts)})
