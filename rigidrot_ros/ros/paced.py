"""Play messages to a ROS subscriber at the pace it consumes them, and take its answers.

A replay at a fixed multiple of real time either keeps a filter that could go faster
waiting, or overruns one that cannot. :class:`PacedPlayer` publishes each message as soon
as the subscriber has shown it keeps up, and never more than a window ahead of it:

- **Progress** is read from the subscriber's answers (``outputs``, any message type whose
  first field is a ``std_msgs/Header``): an answer stamped ``t`` counts every message up to
  the last one whose header stamp (or log time, without a header) is ``<= t`` as taken.
  An estimator stamps its estimates with its sensors' stamps, so its answers say how far
  it has read.
- **Window**: at most ``window`` messages beyond that point are in flight. By default the
  smallest history depth among the subscriptions to the played topics (a ``KEEP_LAST``
  subscription of depth N overwrites the oldest of N untaken messages), capped at
  :data:`WINDOW`.
- **Stalls**: an estimator whose answers lag its inputs by more than a window (one that
  answers every 100th sample, or at the end only) would wait forever. After ``stall``
  seconds without progress, once every message sent is acknowledged, the window opens by
  one more window; each such opening is counted in :attr:`PacedPlayer.stalls`.
- **Delivery**: the publishers are reliable and keep every message (``KEEP_ALL``), so DDS
  resends what a reliable subscription missed; :meth:`PacedPlayer.confirm` waits until
  each played topic's reliable subscriptions have acknowledged every message sent
  (acknowledged: in the subscription's history, taken or not). A best-effort subscription
  acknowledges nothing: its topics are reported in :attr:`PacedPlayer.unconfirmed`.
- **Clock**: with ``clock``, ``/clock`` (rosgraph_msgs/Clock) steps to a message's log
  time just before that message whenever that time is ``clock_step`` or more past the last
  ``/clock`` (and at the first and the last message), so a node on ``use_sim_time`` sees
  the data's time, never ahead of the data and less than ``clock_step`` behind it. Each
  ``/clock`` costs a node on ``use_sim_time`` one executor round: at every message of a
  100 Hz gyro it doubled the time the reference MEKF node took to read a run.
- **Lagging subscriptions**: progress read from answers assumes a subscriber takes its
  topics together. rclpy on Fast DDS can leave one subscription behind when messages
  arrive in bursts (seen here: a node answering two topics took one topic's messages at
  the rate new ones arrived, never catching up); its ``KEEP_LAST`` history then drops the
  oldest of that topic while the answers from the other topic keep the feed going. DDS has
  acknowledged them: the player cannot see it. A subscriber that takes every waiting
  message in each callback (``rigidrot_mekf``), answers from each topic it reads, or
  keeps a whole run (depth >= the messages of a topic) is not exposed.

Fast DDS acknowledges on its writers' heartbeats, every 3 s by default: a wait for the
last acknowledgements would take that long. And with ``ROS_AUTOMATIC_DISCOVERY_RANGE=
LOCALHOST`` (unicast discovery on 127.0.0.1), a participant that is already up learns of a
new one only at its next announcement, every 3 s by default: a new estimator process
waited 1.5-2.4 s to be matched here. :func:`fast_dds` points Fast DDS at a profile whose
reliable writers beat every 10 ms and whose participants announce themselves every 100 ms
(on loopback: a few datagrams a second); discovery then took 1 ms. Set it before the
process's first ROS context.
"""

import os
import struct
import tempfile
import time

from builtin_interfaces.msg import Time
import numpy as np
from rclpy.duration import Duration
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

__all__ = ['PacedPlayer', 'PlayError', 'fast_dds', 'header_stamp_ns', 'write_answers',
           'FEED_QOS', 'WINDOW', 'STALL', 'CLOCK_STEP']

#: The largest default window, messages in flight.
WINDOW = 64
#: Seconds without progress before the window opens by one more window.
STALL = 0.25
#: Seconds the player waits, once it has matched the subscriber's subscriptions and its
#: answers' publishers, before it plays: the subscriber's side matches the player's
#: answer subscription on its own time, which the player cannot see, and an answer
#: published before then is lost (volatile). Under a load average of 4 on 2 cores a
#: replay lost the answers to its first 0.6 s of data without it.
MATCH_SETTLE_S = 0.3
#: Default ``/clock`` step, seconds of log time (20 Hz of sim time).
CLOCK_STEP = 0.05
#: The played topics' QoS: reliable, every message kept until acknowledged, volatile.
FEED_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
#: The answers' QoS: reliable and keep-all too (matches reliable and best-effort writers of
#: either durability).
ANSWER_QOS = FEED_QOS
#: /clock: the last value only; reliable, so it matches reliable and best-effort readers.
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.RELIABLE)
_SEC = 1_000_000_000
_PROFILE = '''<?xml version="1.0" encoding="UTF-8"?>
<!-- rigidrot_ros: participants announce themselves every 100 ms (Fast DDS default: 3 s),
     so a participant that is up matches a new one at once under unicast (LOCALHOST)
     discovery; reliable writers send a heartbeat every 10 ms (default: 3 s), so waiting
     for the last acknowledgements of a played run takes milliseconds -->
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <participant profile_name="rigidrot_participant" is_default_profile="true">
    <rtps>
      <builtin>
        <discovery_config>
          <leaseAnnouncement><sec>0</sec><nanosec>100000000</nanosec></leaseAnnouncement>
        </discovery_config>
      </builtin>
    </rtps>
  </participant>
  <data_writer profile_name="rigidrot_writer" is_default_profile="true">
    <times>
      <heartbeatPeriod><sec>0</sec><nanosec>10000000</nanosec></heartbeatPeriod>
    </times>
  </data_writer>
</profiles>
'''


class PlayError(RuntimeError):
    """Playing cannot go on (a deadline passed, the subscriber is gone): one line why."""


def fast_dds(environ=None):
    """Point Fast DDS at the quick-discovery, quick-acknowledgement profile; its path.

    Sets ``FASTRTPS_DEFAULT_PROFILES_FILE`` in ``environ`` (default ``os.environ``) unless
    it is set already (a profile of the user's is kept, with its timing) or another RMW
    than Fast DDS is chosen; returns None then. Call it before the process creates its
    first ROS context: Fast DDS reads the file once.
    """
    env = os.environ if environ is None else environ
    rmw = env.get('RMW_IMPLEMENTATION', '') or 'rmw_fastrtps_cpp'
    if env.get('FASTRTPS_DEFAULT_PROFILES_FILE') or not rmw.startswith('rmw_fastrtps'):
        return None
    path = os.path.join(tempfile.gettempdir(), f'rigidrot_fast_dds_{os.getuid()}.xml')
    try:
        with open(path, encoding='utf-8') as fh:
            same = fh.read() == _PROFILE
    except OSError:
        same = False
    if not same:
        tmp = f'{path}.{os.getpid()}'
        with open(tmp, 'w', encoding='utf-8') as fh:
            fh.write(_PROFILE)
        os.replace(tmp, path)
    env['FASTRTPS_DEFAULT_PROFILES_FILE'] = path
    return path


def header_stamp_ns(data):
    """Return the header stamp (ns) of a CDR message that starts with a std_msgs/Header.

    ``data`` is the serialized message: a 4-byte encapsulation header (CDR, either byte
    order), then ``int32 sec``, ``uint32 nanosec``. None if it is too short or not CDR.
    """
    if len(data) < 12 or data[0] != 0 or data[1] not in (0, 1):
        return None
    sec, nsec = struct.unpack_from('<iI' if data[1] == 1 else '>iI', data, 4)
    return sec * _SEC + nsec


def _has_header(cls):
    fields = cls.get_fields_and_field_types()
    return bool(fields) and next(iter(fields.values())) == 'std_msgs/Header'


class PacedPlayer:
    """Publish messages as fast as the subscriber answers them; collect the answers.

    Parameters
    ----------
    node : rclpy.node.Node
        The node that publishes and subscribes.
    executor : rclpy.executors.Executor
        The executor ``node`` is added to; spun while waiting.
    inputs : dict
        Played topic -> message class (published from serialized bytes).
    outputs : iterable of str
        Topics of the subscriber's answers. Each is subscribed once a publisher of it shows
        in the graph (its type is taken from there: :meth:`poll_outputs`).
    clock : bool
        Publish ``/clock``, stepped with the messages.
    clock_step : float
        Seconds of log time between two ``/clock`` at least (0: at every message).
    qos : dict, optional
        Played topic -> QoS profile, in place of :data:`FEED_QOS` (a transient-local run
        description, say).
    window : int, optional
        Messages in flight at most; default from the subscriptions' depth (module text).
    stall : float
        Seconds without progress before the window opens by one more window.
    """

    def __init__(self, node, executor, inputs, outputs=(), clock=True, window=None,
                 stall=STALL, qos=None, clock_step=CLOCK_STEP):
        self.node, self.executor = node, executor
        self.window, self.stall = window, float(stall)
        self.problems = []           # incompatible QoS seen by a played topic's publisher
        qos = qos or {}
        self.pubs = {t: node.create_publisher(
            cls, t, qos.get(t, FEED_QOS), event_callbacks=PublisherEventCallbacks(
                incompatible_qos=self._incompatible(t)))
            for t, cls in inputs.items()}
        self._in_headered = {t: _has_header(cls) for t, cls in inputs.items()}
        self.clock_pub = node.create_publisher(Clock, '/clock', CLOCK_QOS) if clock else None
        self.clock_step_ns = int(round(float(clock_step) * _SEC))
        self.clocks = 0              # /clock messages of the last play
        self.output_topics = [node.resolve_topic_name(t) for t in outputs]
        self.output_types = {}       # topic -> type name, once subscribed
        self._subs = {}
        self._headered = {}
        self.answers = []            # (topic, serialized message, header stamp or None)
        self.reached_ns = None       # the latest answer stamp
        self.sent = {t: 0 for t in inputs}
        self.stalls = 0
        self.unconfirmed = []
        self.last_clock_ns = None
        self.end_ns = None           # the last message's stamp, once played
        self.used_window = None      # the window of the last play

    # -- the graph ---------------------------------------------------------------------
    def _incompatible(self, topic):
        def cb(info):
            kind = getattr(info.last_policy_kind, 'name', str(info.last_policy_kind))
            text = (f'a subscription to {topic} asks for a QoS the player cannot offer '
                    f'({kind.lower()} policy; it offers reliable, keep-all, volatile)')
            if text not in self.problems:
                self.problems.append(text)
        return cb

    def unmatched(self):
        """Return the played topics with fewer matched subscriptions than the graph shows.

        The graph (discovery) lists another node's subscription before this player's
        publisher has matched it; a message published then is not delivered to it.
        """
        own = (self.node.get_name(), self.node.get_namespace())
        out = []
        for topic, pub in self.pubs.items():
            listed = sum(1 for i in self.node.get_subscriptions_info_by_topic(topic)
                         if (i.node_name, i.node_namespace) != own)
            if pub.get_subscription_count() < listed:
                out.append(topic)
        return out

    def settle_match(self, limit, check=None):
        """Spin :data:`MATCH_SETTLE_S` more once matched (at most to ``limit``, monotonic).

        The subscriber's answer publishers match this player's subscriptions on their own
        time, which this side cannot see; an answer published before then is lost.
        ``check()`` (raises to stop) is called at each round.
        """
        end = min(time.monotonic() + MATCH_SETTLE_S, limit)
        while time.monotonic() < end:
            if check is not None:
                check()
            self.spin(0.02)

    def missing(self, topics=None):
        """Return the played topics (default: all) with no matched subscription yet."""
        return [t for t in (topics or self.pubs) if not self.pubs[t].get_subscription_count()]

    def poll_outputs(self):
        """Subscribe to each output topic whose publisher the graph shows; the ones left."""
        from rigidrot_ros.ros.recorder import msg_class
        for topic in self.output_topics:
            if topic in self._subs:
                continue
            infos = self.node.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            type_name = infos[0].topic_type
            cls = msg_class(type_name)
            self.output_types[topic] = type_name
            self._headered[topic] = _has_header(cls)
            self._subs[topic] = self.node.create_subscription(
                cls, topic, self._on_answer(topic), ANSWER_QOS, raw=True)
        return [t for t in self.output_topics if t not in self._subs]

    def outputs_matched(self):
        """Return whether every output topic is subscribed and matched to a publisher."""
        return all(t in self._subs and self._subs[t].get_publisher_count()
                   for t in self.output_topics)

    def output_publishers(self):
        """Return the number of publishers matched to the output subscriptions."""
        return sum(s.get_publisher_count() for s in self._subs.values())

    def subscriber_qos(self):
        """``(depth, best_effort_topics)`` of the subscriptions to the played topics.

        ``depth`` is the smallest ``KEEP_LAST`` depth among them (None if every one keeps
        all); ``best_effort_topics`` the played topics with a best-effort subscription.
        """
        depth, best_effort = None, []
        own = (self.node.get_name(), self.node.get_namespace())
        for topic in self.pubs:
            for info in self.node.get_subscriptions_info_by_topic(topic):
                if (info.node_name, info.node_namespace) == own:
                    continue
                q = info.qos_profile
                if q.reliability == ReliabilityPolicy.BEST_EFFORT and topic not in best_effort:
                    best_effort.append(topic)
                if q.history != HistoryPolicy.KEEP_ALL and q.depth > 0:
                    depth = q.depth if depth is None else min(depth, q.depth)
        return depth, best_effort

    def _on_answer(self, topic):
        headered = self._headered[topic]

        def cb(data):
            stamp = header_stamp_ns(data) if headered else None
            self.answers.append((topic, data, stamp))
            if stamp is not None and (self.reached_ns is None or stamp > self.reached_ns):
                self.reached_ns = stamp
        return cb

    # -- playing -----------------------------------------------------------------------
    def spin(self, timeout):
        """Spin the executor once (``timeout`` s at most)."""
        self.executor.spin_once(timeout_sec=timeout)

    def clear(self):
        """Forget the answers and the progress (a new run)."""
        self.answers = []
        self.reached_ns = None
        self.stalls = 0
        self.last_clock_ns = None
        self.clocks = 0
        self.end_ns = None
        self.sent = {t: 0 for t in self.pubs}

    def effective_window(self):
        """Return the window: ``window`` if given, else the subscriptions' depth capped."""
        if self.window:
            return int(self.window)
        depth, _ = self.subscriber_qos()
        return max(1, min(WINDOW, depth or WINDOW))

    def play(self, messages, deadline=None, check=None, rate=None):
        """Publish ``messages`` (``(topic, log_ns, cdr_bytes)`` in order) at the answers' pace.

        ``deadline`` (``time.monotonic()``) and ``check()`` (raises to stop, e.g. when the
        subscriber's process has exited) are looked at while waiting; a passed deadline
        raises :class:`PlayError`. ``rate`` adds a floor: no message before its log time
        divided by ``rate`` after the first (a multiple of real time).
        """
        if not messages:
            return
        stamps = []
        for topic, log_ns, data in messages:
            stamp = header_stamp_ns(data) if self._in_headered[topic] else None
            stamps.append(log_ns if stamp is None else stamp)
        reach = np.maximum.accumulate(np.array(stamps, dtype=np.int64))
        self.end_ns = int(reach[-1])
        window = self.used_window = self.effective_window()
        self.unconfirmed = self.subscriber_qos()[1]
        n, sent, consumed, extra = len(messages), 0, 0, 0
        base, wall0 = messages[0][1], time.monotonic()
        last_progress = time.monotonic()
        while sent < n:
            limit = min(n, consumed + window + extra)
            while sent < limit:
                topic, log_ns, data = messages[sent]
                if rate:
                    delay = wall0 + (log_ns - base) * 1e-9 / rate - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                if self.clock_pub is not None and (
                        self.last_clock_ns is None
                        or log_ns - self.last_clock_ns >= max(1, self.clock_step_ns)
                        or (sent == n - 1 and log_ns > self.last_clock_ns)):
                    self.clock_pub.publish(Clock(clock=Time(sec=log_ns // _SEC,
                                                            nanosec=log_ns % _SEC)))
                    self.last_clock_ns = log_ns
                    self.clocks += 1
                self.pubs[topic].publish(data)
                self.sent[topic] += 1
                sent += 1
            if sent >= n:
                break
            self.spin(0.01)
            if self.reached_ns is not None:
                c = min(sent, int(np.searchsorted(reach, self.reached_ns, side='right')))
                if c > consumed:
                    consumed, extra, last_progress = c, 0, time.monotonic()
            now = time.monotonic()
            if now - last_progress > self.stall and self.acknowledged(0.0):
                extra += window
                self.stalls += 1
                last_progress = now
            if check is not None:
                check()
            if deadline is not None and now > deadline:
                raise PlayError(f"timeout: {sent} of {n} messages sent when the run's "
                                f'time was up ({self.stalls} stalls, the last answer '
                                f'stamped {self.reached_ns} ns)')
            if len(self.output_topics) > len(self._subs):
                self.poll_outputs()

    def acknowledged(self, timeout):
        """Return whether every reliable subscription acknowledged all that was sent."""
        return not self.unacknowledged(timeout)

    def unacknowledged(self, timeout):
        """Return the played topics not fully acknowledged within ``timeout`` s."""
        left = []
        end = time.monotonic() + timeout
        for topic, pub in self.pubs.items():
            wait = max(0.0, end - time.monotonic())
            if not pub.wait_for_all_acked(Duration(seconds=wait)):
                left.append(topic)
        return left

    def confirm(self, timeout=5.0):
        """Wait until every message sent is acknowledged; PlayError naming what is not.

        Topics whose subscriptions are best effort acknowledge nothing: they are in
        :attr:`unconfirmed`, not an error.
        """
        left = self.unacknowledged(timeout)
        if left:
            counts = ', '.join(f'{t} ({self.sent[t]} sent)' for t in left)
            raise PlayError(f'not every message was acknowledged within {timeout:g} s on '
                            f'{counts}')

    def caught_up(self):
        """Return whether an answer is stamped at or after the last message played."""
        return (self.end_ns is not None and self.reached_ns is not None
                and self.reached_ns >= self.end_ns)

    def settle(self, quiet, deadline=None, check=None, early=True):
        """Spin until no answer has come for ``quiet`` seconds (or ``deadline``).

        With ``early``, returns at once when the answers have caught up with the last
        message played.
        """
        count, since = len(self.answers), time.monotonic()
        while True:
            now = time.monotonic()
            if (now - since >= quiet or (early and self.caught_up())
                    or (deadline is not None and now > deadline)):
                return
            self.spin(min(0.02, quiet))
            if len(self.answers) != count:
                count, since = len(self.answers), time.monotonic()
            if check is not None:
                check()


def write_answers(path, answers, types, runs, described=None):
    """Write answers and run descriptions to a new bag at ``path``; return its path.

    ``answers`` are :attr:`PacedPlayer.answers` (log time: their stamps), ``types`` their
    topics' type names, ``runs`` the run description dicts (``rigidrot_run`` records, what
    the scorer takes the truth from) and ``described`` maps a topic to the serialized
    ``std_msgs/String`` of a run description (written at log time 0).
    """
    from rigidrot_ros.bag import BagWriter
    writer = BagWriter(None, 'answers', flush_period=60.0, path=path, split_seconds=0.0)
    try:
        for run in runs:
            writer.add_run(run)
        for topic, data in (described or {}).items():
            writer.add_topic(topic, 'std_msgs/msg/String')
            writer.write(topic, bytes(data), 0)
        for topic, data, stamp in answers:
            if not writer.has_topic(topic):
                writer.add_topic(topic, types[topic])
            writer.write(topic, bytes(data), 0 if stamp is None else stamp)
    finally:
        writer.close()
    return writer.path
