"""Record ROS topics into a rosbag2 MCAP bag: the component behind the node and rigidrot_record.

The pure file format lives in :mod:`rigidrot_ros.bag`; this module is the ROS side.
A :class:`Recorder` lives in a node and writes two kinds of message into one
:class:`~rigidrot_ros.bag.BagWriter`:

- messages the node publishes itself, handed over after publishing
  (:meth:`Recorder.record_published`), serialized once, with the node's clock as log time;
- any other topic, subscribed raw (the CDR bytes as they arrive, never deserialized).

Discovery and what it guarantees:

- The graph is polled every ``poll_period`` (50 ms): a listed topic is subscribed as soon
  as a publisher of it is seen, with its type taken from the graph. Its QoS follows the
  publishers' offered QoS the way rosbag2 adapts it: reliable unless a publisher is
  best-effort, transient-local when every publisher is transient-local, history depth
  at least 1000. The offered profiles are stored as the channel's
  ``offered_qos_profiles``.
- A transient-local publisher is recorded from its first message, whenever the recorder
  joins: DDS hands a late-joining transient-local subscription the publisher's kept
  history (its ``depth`` last messages). The node's ``~/run`` description is published
  that way, and so is the demo estimator's output.
- A topic given with its type, ``NAME:pkg/msg/Type``, is subscribed at once (reliable,
  volatile), before any publisher exists. A publisher that starts later discovers the
  subscription while it discovers the rest of this node, so an estimator fed by the node
  usually has it matched before its first answer. If the publisher turns out to be
  best-effort, the subscription is remade best-effort when the graph shows it.
- A topic given by name only is subscribed when a publisher of it appears in the graph
  (its type is needed first), about one poll period after it appears.
- What is guaranteed for a volatile publisher: every message it publishes once its end
  has matched this subscription (reliable QoS then redelivers what is still in its
  history). What it published before that cannot be had by any recorder (volatile
  samples are not kept). DDS matches the two ends some time after the publisher shows in
  the graph: tens of ms here, up to seconds on a loaded machine. The recorder says
  ``recording <topic>`` when it subscribes and ``matched <topic> (N publishers)`` when
  its subscription has matched; a program that must not lose a publisher's first
  messages starts feeding it after the second line (the campaign runner does).
- The bag is flushed at least every ``flush_period`` (0.4 s; a timer flushes even when no
  message arrives), so a SIGKILL loses at most about 0.5 s; :meth:`Recorder.close`
  finishes the file (summary, index, metadata.yaml).
"""

import importlib
import re
import time

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
import yaml

from rigidrot_ros.bag import qos_yaml, STRING_TYPE
from rigidrot_ros.msgs.msgdefs import schema_text

__all__ = ['Recorder', 'type_name_of', 'qos_to_yaml', 'qos_from_yaml', 'keep_last_qos',
           'msg_class', 'check_type']

_INFINITE = {'sec': 2147483647, 'nsec': 4294967295}
_ROS_TYPE = re.compile(r'[A-Za-z_][A-Za-z0-9_]*/msg/[A-Za-z_][A-Za-z0-9_]*')


def type_name_of(msg_or_class):
    """``pkg/msg/Type`` of a ROS message instance or class."""
    cls = msg_or_class if isinstance(msg_or_class, type) else type(msg_or_class)
    parts = cls.__module__.split('.')
    return f'{parts[0]}/{parts[1]}/{cls.__name__}'


def _profile(qos):
    rel = 'best_effort' if qos.reliability == ReliabilityPolicy.BEST_EFFORT else 'reliable'
    dur = ('transient_local' if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
           else 'volatile')
    hist = 'keep_all' if qos.history == HistoryPolicy.KEEP_ALL else 'keep_last'
    return {'history': hist, 'depth': int(qos.depth), 'reliability': rel, 'durability': dur,
            'deadline': dict(_INFINITE), 'lifespan': dict(_INFINITE),
            'liveliness': 'automatic', 'liveliness_lease_duration': dict(_INFINITE),
            'avoid_ros_namespace_conventions': False}


def qos_to_yaml(profiles):
    """``offered_qos_profiles`` YAML (rosbag2 v9) for a list of rclpy QoS profiles."""
    return yaml.safe_dump([_profile(q) for q in profiles], sort_keys=False)


def keep_last_qos(depth, best_effort=False, transient_local=False):
    """KEEP_LAST QoS of ``depth``: reliable unless best effort, volatile unless transient local."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=(ReliabilityPolicy.BEST_EFFORT if best_effort
                     else ReliabilityPolicy.RELIABLE),
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if transient_local
                    else DurabilityPolicy.VOLATILE))


def qos_from_yaml(text):
    """Build a QoS profile from a rosbag2 offered_qos_profiles YAML string (first one)."""
    try:
        prof = (yaml.safe_load(text) or [{}])[0]
    except yaml.YAMLError:
        prof = {}
    rel = str(prof.get('reliability', 'reliable')).lower()
    dur = str(prof.get('durability', 'volatile')).lower()
    return keep_last_qos(int(prof.get('depth', 10) or 10), rel in ('best_effort', '2'),
                         dur in ('transient_local', '1'))


def _normal_type(type_name):
    """``pkg/msg/Type`` from ``pkg/msg/Type`` or ``pkg/Type``; ValueError otherwise."""
    parts = type_name.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3 or parts[1] != 'msg' or not all(parts):
        raise ValueError(f'not a message type: {type_name!r} (expected pkg/msg/Type)')
    return '/'.join(parts)


def check_type(type_name):
    """Return ``pkg/msg/Type`` if that type can be recorded here; ValueError saying why not."""
    type_name = _normal_type(type_name)
    msg_class(type_name)
    try:
        schema_text(type_name)
    except (OSError, ValueError) as exc:
        raise ValueError(f'no message definition of {type_name}: {exc}') from None
    return type_name


def msg_class(type_name, error=ValueError):
    """Return the message class of ``pkg/msg/Type``; raise ``error`` if it is not installed.

    A name of another form (a protobuf ``foo.Bar``, a JSON schema) is not a ROS 2 message
    type: ``error`` too, with that reason.
    """
    if not _ROS_TYPE.fullmatch(str(type_name)):
        raise error(f'{type_name!r} is not a ROS 2 message type (pkg/msg/Type): a channel of '
                    f'another encoding cannot be published here')
    pkg, _, name = type_name.split('/')
    try:
        return getattr(importlib.import_module(f'{pkg}.msg'), name)
    except (ImportError, AttributeError):
        raise error(f'message type {type_name} is not installed here') from None


class Recorder:
    """Record topics of the ROS graph, and a node's own publications, into a bag.

    Parameters
    ----------
    node : rclpy.node.Node
        The node whose graph view, clock, timers and subscriptions are used.
    writer : rigidrot_ros.bag.BagWriter
        The open bag.
    topics : iterable of str
        Topic names to record as they appear (resolved against the node's namespace),
        each optionally with its type, ``NAME:pkg/msg/Type`` (subscribed at once).
    all_topics : bool
        Also record every other topic that appears, except the excluded ones.
    runs : bool
        Also record every ``std_msgs/msg/String`` topic whose name ends in ``/run``: the
        run descriptions of rigidrot nodes, which make the bag scorable.
    exclude_own : bool
        Never subscribe to topics this node publishes itself (the node hands those over
        through :meth:`record_published`).
    poll_period, flush_timer : float
        Graph poll period and flush timer period, seconds.
    on_event : callable, optional
        ``on_event(level, text)`` for 'info', 'warn' and 'error' events (default: the
        node's logger).
    """

    def __init__(self, node, writer, topics=(), all_topics=False, runs=False,
                 exclude_own=False, poll_period=0.05, flush_timer=0.1, on_event=None):
        self._node = node
        self._writer = writer
        self._wanted = []
        self._typed = {}          # topic -> type given by the user (subscribed at once)
        self._verified = set()    # typed topics whose publishers' QoS has been checked
        for entry in topics:
            if not entry:
                continue
            name, _, type_name = entry.partition(':')
            name = node.resolve_topic_name(name)
            self._wanted.append(name)
            if type_name:
                self._typed[name] = _normal_type(type_name)
        self._all = bool(all_topics)
        self._runs = bool(runs)
        self._exclude_own = bool(exclude_own)
        self._subs = {}           # topic -> subscription, or None when it cannot be recorded
        self._matched = set()     # subscribed topics with a matched publisher (reported once)
        self._direct = set()      # topics the node writes through record_published
        self._on_event = on_event or self._log
        self._failed = None
        self._started = time.monotonic()
        self._warned_waiting = False
        self._poll_timer = node.create_timer(poll_period, self._poll)
        self._flush_timer = node.create_timer(flush_timer, self._flush)
        own = ({p.topic_name for p in node.publishers} if self._exclude_own else set())
        for topic, type_name in self._typed.items():
            if topic not in own:
                self._subscribe(topic, [], type_name)
            else:
                self._verified.add(topic)        # written through record_published
        self._poll()

    # -- state -------------------------------------------------------------------------------
    @property
    def path(self):
        """The bag directory."""
        return self._writer.path

    @property
    def counts(self):
        """Messages written per topic."""
        return self._writer.counts

    @property
    def active(self):
        """False once the bag is closed or recording stopped on an error."""
        return not self._writer.closed and self._failed is None

    @property
    def pending(self):
        """Listed topics not subscribed yet."""
        return [t for t in self._wanted if t not in self._subs and t not in self._direct]

    def _log(self, level, text):
        logger = self._node.get_logger()
        {'info': logger.info, 'warn': logger.warning, 'error': logger.error}[level](text)

    # -- writing -----------------------------------------------------------------------------
    def _register_own(self, topic, msg):
        if not self._writer.has_topic(topic):
            self._direct.add(topic)
            self._writer.add_topic(topic, type_name_of(msg), self._own_qos(topic))

    def record_published(self, now_ns, published):
        """Write messages this node has just published: ``[(resolved_topic, msg, raw), ...]``.

        ``raw`` is the message serialized (CDR) if the node made those bytes to publish
        them, else None (serialized here). The log time is ``now_ns``; each topic's channel
        is registered on first use with the QoS of the node's publisher of that topic.
        """
        if not self.active:
            return
        try:
            for topic, msg, raw in published:
                self._register_own(topic, msg)
                self._writer.write(topic, serialize_message(msg) if raw is None else raw,
                                   now_ns)
        except OSError as exc:
            self._fail(exc)

    def record_many(self, published):
        """Write messages this node published, each at its own log time, in one batch.

        ``published``: ``[(resolved_topic, msg or its class, raw, log_ns), ...]`` in order
        (``raw`` as in :meth:`record_published`). The records go into the bag as
        :meth:`record_published` one by one would put them (``BagWriter.write_many``).
        """
        if not self.active or not published:
            return
        try:
            for topic, msg, _, _ in published:
                if topic not in self._direct:
                    self._register_own(topic, msg)
            self._writer.write_many(
                [p[0] for p in published],
                [serialize_message(m) if raw is None else raw for _, m, raw, _ in published],
                [p[3] for p in published])
        except OSError as exc:
            self._fail(exc)

    def add_run(self, info):
        """Write a ``rigidrot_run`` metadata record (the node's own recorder)."""
        if self.active:
            try:
                self._writer.add_run(info)
            except OSError as exc:
                self._fail(exc)

    def _own_qos(self, topic):
        pubs = [p for p in self._node.publishers if p.topic_name == topic]
        return qos_to_yaml([pubs[0].qos_profile]) if pubs else qos_yaml()

    def _on_raw(self, topic, data):
        if not self.active or topic in self._direct:
            return                              # closed, or the node writes it itself
        log_ns = self._node.get_clock().now().nanoseconds
        try:
            if not self._writer.has_topic(topic):       # a typed topic's first message
                self._add_channel(topic, self._typed[topic],
                                  self._node.get_publishers_info_by_topic(topic))
            self._writer.write(topic, data, log_ns)
        except OSError as exc:
            self._fail(exc)

    def _flush(self):
        if self.active:
            try:
                self._writer.maybe_flush()
            except OSError as exc:
                self._fail(exc)

    def _fail(self, exc):
        # disk full, directory removed: stop recording, keep the node running
        self._failed = exc
        self._on_event('error', f'recording stopped: {exc}')
        try:
            self._writer.close()
        except (OSError, ValueError):
            pass

    # -- discovery ---------------------------------------------------------------------------
    def _candidates(self):
        out = list(self.pending)
        if self._all or self._runs:
            for name, types in self._node.get_topic_names_and_types():
                if name in self._subs or name in self._direct or name in out:
                    continue
                if self._all or (name.endswith('/run') and STRING_TYPE in types):
                    out.append(name)
        return out

    def _poll(self):
        if not self.active:
            return
        own = ({p.topic_name for p in self._node.publishers} if self._exclude_own
               else set())
        for topic in self._candidates():
            if topic in own:
                continue
            infos = self._node.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            self._subscribe(topic, infos)
        for topic in [t for t in self._typed if t not in self._verified]:
            infos = self._node.get_publishers_info_by_topic(topic)
            if infos:
                self._verified.add(topic)
                if any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
                       for i in infos) and self._subs.get(topic) is not None:
                    self._node.destroy_subscription(self._subs.pop(topic))
                    self._matched.discard(topic)
                    self._subscribe(topic, infos, self._typed[topic])
        self._report_matches()
        if self.pending and not self._warned_waiting and time.monotonic() - self._started > 5:
            self._warned_waiting = True
            self._on_event('warn', f'still waiting for a publisher of {self.pending}')
        if (not self.pending and not self._all and not self._runs
                and len(self._verified) == len(self._typed)
                and all(t in self._matched for t, s in self._subs.items() if s is not None)):
            self._poll_timer.cancel()

    def _report_matches(self):
        """Say ``matched <topic>`` once a subscription has matched a publisher.

        Being in the graph is not being matched: DDS matches the two endpoints some time
        after the publisher is seen (tens of ms here, seconds on a loaded machine), and a
        volatile publisher's messages sent before that are not delivered to this
        subscription. A program that must not lose a publisher's first messages (the
        campaign's runner) waits for this line, not for ``recording <topic>``.
        """
        for topic, sub in self._subs.items():
            if sub is None or topic in self._matched:
                continue
            count = sub.get_publisher_count()
            if count:
                self._matched.add(topic)
                self._on_event('info', f'matched {topic} ({count} publisher'
                                       f'{"s" if count > 1 else ""})')

    def _subscribe(self, topic, infos, type_name=None):
        """Subscribe raw to ``topic``; QoS adapted to ``infos`` (the publishers) if any."""
        types = sorted({i.topic_type for i in infos} | ({type_name} if type_name else set()))
        if len(types) > 1:
            self._subs[topic] = None
            self._on_event('error', f'cannot record {topic}: its publishers (and the type '
                                    f'given) disagree on the type {types}')
            return
        type_name = types[0]
        offered = [i.qos_profile for i in infos]
        best_effort = any(q.reliability == ReliabilityPolicy.BEST_EFFORT for q in offered)
        transient = bool(offered) and all(
            q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
        depth = max([1000] + [int(q.depth) for q in offered])
        qos = keep_last_qos(depth, best_effort, transient)
        try:
            cls = msg_class(type_name)
            schema_text(type_name)              # fail now if its definition is missing
            if infos:
                self._add_channel(topic, type_name, infos)
        except (ImportError, AttributeError, ValueError, OSError) as exc:
            self._subs[topic] = None
            self._on_event('error', f'cannot record {topic} ({type_name}): {exc}')
            return
        self._subs[topic] = self._node.create_subscription(
            cls, topic, lambda data, tp=topic: self._on_raw(tp, data), qos, raw=True)
        kind = 'transient-local' if transient else 'volatile'
        when = '' if infos else ', subscribed before any publisher'
        self._on_event('info', f'recording {topic} ({type_name}, {kind}'
                               f'{", best-effort" if best_effort else ""}{when})')

    def _add_channel(self, topic, type_name, infos):
        if not self._writer.has_topic(topic):
            offered = [i.qos_profile for i in infos if i.topic_type == type_name]
            self._writer.add_topic(topic, type_name,
                                   qos_to_yaml(offered) if offered else qos_yaml(depth=1000))

    # -- end ---------------------------------------------------------------------------------
    def close(self):
        """Finish the bag; returns ``(path, counts)``. Safe to call twice."""
        for timer in (self._poll_timer, self._flush_timer):
            try:
                timer.cancel()
            except Exception:   # noqa: B902 - the context may be gone already
                pass
        if not self._writer.closed:
            self._writer.close()
        return self._writer.path, self._writer.counts
