"""rigidrot_replay: republish a bag's topics with their original timing.

Messages are published as the recorded CDR bytes, on publishers created with each
channel's recorded QoS (offered_qos_profiles). With --clock, /clock
(rosgraph_msgs/Clock) follows the log time so that nodes on use_sim_time run with it.

With ``--paced-by TOPIC``, the bag is played as fast as the subscriber answers on TOPIC
(:class:`rigidrot_ros.ros.paced.PacedPlayer`: reliable keep-all publishers, a window of
messages in flight, every message acknowledged at the end); ``-o DIR`` writes the answers
with the bag's run descriptions, for ``rigidrot_compare``.
"""

import os
import sys
import time

from builtin_interfaces.msg import Time
import rclpy
from rclpy.executors import ExternalShutdownException
from rosgraph_msgs.msg import Clock

from rigidrot_ros.bag import BagError, read_bag
from rigidrot_ros.ros.recorder import msg_class, qos_from_yaml
from rigidrot_ros.ros.spin import init_ros, spin_until_shutdown, split_ros_args
from rigidrot_ros.tools.cli import OneLineParser


#: Seconds the matched-subscriber counts must hold still before playing starts.
SETTLE = 0.5


def _wait_for_matching(node, pubs, limit, settle=SETTLE, required=()):
    """Wait until subscribers have matched and stopped arriving; ``limit`` seconds at most.

    Discovery on a loaded machine takes up to seconds (1.4 s measured here), and the
    first subscriber to match may be a recorder, not the node under test: a subscriber not
    yet matched would miss the first messages. Playing starts once some subscriber has
    matched, every subscriber the graph shows has matched, each publisher in ``required``
    has a matched subscriber, and these counts have not changed for ``settle`` seconds.
    Returns whether that happened within ``limit``.

    Without ``required`` this cannot tell a subscriber that has not been discovered yet
    from one that does not exist: a filter whose process is discovered after a recorder's
    has settled misses the start. ``required`` (``--wait-for``) names what must be there.
    """
    t0 = time.monotonic()
    state, since = None, t0
    while time.monotonic() - t0 < limit:
        rclpy.spin_once(node, timeout_sec=0.05)
        matched = [p.get_subscription_count() for p in pubs]
        graph = [node.count_subscribers(p.topic_name) for p in pubs]
        now = time.monotonic()
        if (matched, graph) != state:
            state, since = (matched, graph), now
        if (any(matched) and all(m >= g for m, g in zip(matched, graph))
                and all(p.get_subscription_count() for p in required)
                and now - since >= settle):
            return True
    return False


def _parser():
    ap = OneLineParser(prog='rigidrot_replay', description=__doc__.splitlines()[0])
    ap.add_argument('bag', help='bag directory or .mcap file')
    ap.add_argument('--rate', type=float,
                    help='speed factor (2: twice as fast; default 1); with --paced-by, the '
                         'fastest it may go (default: no limit)')
    ap.add_argument('--paced-by', nargs='+', metavar='TOPIC',
                    help="play as fast as the subscriber's answers on these topics show it "
                         'keeps up (their header stamps say how far it has read); at the end '
                         'every message must be acknowledged (exit 1 if not)')
    ap.add_argument('--window', type=int,
                    help='with --paced-by: messages in flight at most (default: the depth '
                         'of the subscriptions to the played topics, at most 64)')
    ap.add_argument('--clock-step', type=float, default=0.05, metavar='S',
                    help='with --paced-by --clock: seconds of log time between two /clock '
                         'at least (default 0.05; 0: one before every message)')
    ap.add_argument('-o', '--output',
                    help='with --paced-by: write the answers and the run descriptions to '
                         'this bag directory (for rigidrot_compare)')
    ap.add_argument('--loop', action='store_true', help='start again at the end')
    ap.add_argument('--topics', nargs='+', help='replay only these topics')
    ap.add_argument('--start', type=float, default=0.0, help='skip this many seconds')
    ap.add_argument('--duration', type=float, help='replay this many seconds')
    ap.add_argument('--clock', action='store_true', help='publish /clock from the log time')
    ap.add_argument('--quiet', action='store_true', help='no progress line')
    ap.add_argument('--wait', type=float, default=5.0,
                    help='wait at most this many seconds for subscribers to match before '
                         'playing (default 5; playing starts once one has and no other has '
                         f'matched for {SETTLE:g} s)')
    ap.add_argument('--wait-for', nargs='+', default=[], metavar='TOPIC',
                    help='do not play before each of these replayed topics (or /clock) has '
                         'a matched subscriber; exit 2 if one has none within --wait')
    return ap


def _refusal(opts):
    """Say what is wrong with the options (one line), or None; sets the default rate."""
    if opts.paced_by is None and (opts.window is not None or opts.output):
        return '--window and -o go with --paced-by'
    if opts.paced_by is not None and opts.loop:
        return '--loop does not go with --paced-by'
    if not 0 <= opts.clock_step <= 10:
        return '--clock-step must lie in [0, 10] s'
    if opts.window is not None and not 1 <= opts.window <= 1_000_000:
        return '--window must lie in [1, 1000000]'
    if opts.output and os.path.exists(opts.output) and (
            not os.path.isdir(opts.output) or os.listdir(opts.output)):
        return f'-o {opts.output}: exists and is not an empty directory'
    if opts.rate is None and opts.paced_by is None:
        opts.rate = 1.0
    if opts.rate is not None and not (opts.rate > 0 and opts.rate < float('inf')):
        return '--rate must be a positive finite number'
    if not 0 <= opts.wait < 3600:
        return '--wait must lie in [0, 3600) s'
    if not 0 <= opts.start < float('inf'):
        return '--start must be a finite number of seconds >= 0'
    if opts.duration is not None and not 0 < opts.duration < float('inf'):
        return '--duration must be a positive finite number of seconds'
    return None


def _load(opts):
    """Read the bag and pick what to play: ``(bag, classes, msgs)``; BagError says why not."""
    bag = read_bag(opts.bag)
    if bag.note:
        print(f'note: {bag.path}: {bag.note}', file=sys.stderr)
    topics = opts.topics or sorted(bag.topics)
    missing = [t for t in topics if t not in bag.topics]
    if missing:
        raise BagError(f'{bag.path}: no topic(s) {missing}; it has {sorted(bag.topics)}')
    classes = {t: msg_class(bag.topics[t][0], BagError) for t in topics}
    unplayed = [t for t in opts.wait_for
                if t not in classes and not (t == '/clock' and opts.clock)]
    if unplayed:
        raise BagError(f'--wait-for {unplayed}: not replayed (the replayed topics are '
                       f'{sorted(classes) + (["/clock"] if opts.clock else [])})')
    msgs = [m for m in bag.messages if m[0] in classes]
    if not msgs:
        raise BagError(f'{bag.path}: no messages to replay')
    t0 = msgs[0][2] + int(opts.start * 1e9)
    t1 = t0 + int(opts.duration * 1e9) if opts.duration is not None else None
    length = (msgs[-1][2] - msgs[0][2]) * 1e-9
    msgs = [m for m in msgs if m[2] >= t0 and (t1 is None or m[2] <= t1)]
    if not msgs:
        raise BagError(f'{bag.path}: nothing to replay: --start {opts.start:g} s is past the '
                       f'end of the log ({length:.3f} s long)')
    return bag, classes, msgs


def main(argv=None):
    """Entry point of ``rigidrot_replay``; returns the exit status."""
    argv, ros_args = split_ros_args(sys.argv[1:] if argv is None else list(argv))
    opts = _parser().parse_args(argv)
    reason = _refusal(opts)
    if reason is not None:
        print(f'rigidrot_replay: {reason}', file=sys.stderr)
        return 2
    try:
        bag, classes, msgs = _load(opts)
    except (BagError, OSError) as exc:
        print(f'rigidrot_replay: {exc}', file=sys.stderr)
        return 2
    if opts.paced_by is not None:
        from rigidrot_ros.ros.paced import fast_dds
        fast_dds()                  # before the first ROS context of this process
    reason = init_ros('rigidrot_replay', ros_args)
    if reason is not None:
        print(f'rigidrot_replay: {reason}', file=sys.stderr)
        return 2
    node = rclpy.create_node('rigidrot_replay')
    if opts.paced_by is not None:
        return _paced(node, opts, bag, classes, msgs)
    return _timed(node, opts, bag, classes, msgs)


def _timed(node, opts, bag, classes, msgs):
    """Play ``msgs`` at their recorded pace times ``--rate``; exit status."""
    pubs = {t: node.create_publisher(classes[t], t, qos_from_yaml(bag.topics[t][1]))
            for t in classes}
    clock_pub = node.create_publisher(Clock, '/clock', 10) if opts.clock else None
    every = dict(pubs, **({'/clock': clock_pub} if clock_pub else {}))
    if (not _wait_for_matching(node, list(every.values()), opts.wait,
                               required=[every[t] for t in opts.wait_for])
            and opts.wait_for):
        alone = [t for t in opts.wait_for if not every[t].get_subscription_count()]
        if alone:
            print(f'rigidrot_replay: no subscriber of {", ".join(alone)} matched within '
                  f'--wait {opts.wait:g} s; nothing was played', file=sys.stderr)
            node.destroy_node()
            rclpy.try_shutdown()
            return 2
    total = (msgs[-1][2] - msgs[0][2]) * 1e-9

    def play(_node):
        while True:
            wall0 = time.monotonic()
            base = msgs[0][2]
            last_print = 0.0
            for n, (topic, _, log_ns, _, data) in enumerate(msgs):
                target = wall0 + (log_ns - base) * 1e-9 / opts.rate
                delay = target - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                if not rclpy.ok():
                    raise ExternalShutdownException()
                if clock_pub is not None:
                    clock_pub.publish(Clock(clock=Time(sec=log_ns // 1_000_000_000,
                                                       nanosec=log_ns % 1_000_000_000)))
                pubs[topic].publish(data)           # the recorded CDR bytes, as they were
                now = time.monotonic()
                if not opts.quiet and (now - last_print > 0.5 or n == len(msgs) - 1):
                    last_print = now
                    print(f'\r[replay] {(log_ns - base) * 1e-9:8.2f} / {total:.2f} s  '
                          f'{n + 1}/{len(msgs)} messages', end='', file=sys.stderr,
                          flush=True)
            if not opts.loop:
                return

    spin_until_shutdown(node, play)
    if not opts.quiet:
        print(file=sys.stderr)
    return 0


def _paced(node, opts, bag, classes, msgs):
    """Play ``msgs`` at the pace of the answers on ``--paced-by``; exit status."""
    from rclpy.executors import SingleThreadedExecutor

    from rigidrot_ros.ros.paced import PacedPlayer, PlayError, write_answers
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    qos = {t: qos_from_yaml(bag.topics[t][1]) for t in classes
           if 'transient_local' in bag.topics[t][1]}       # a run description stays latched
    player = PacedPlayer(node, executor, classes, opts.paced_by, clock=opts.clock,
                         window=opts.window, qos=qos, clock_step=opts.clock_step)
    required = [player.pubs[t] for t in opts.wait_for if t in player.pubs]
    if opts.clock and '/clock' in opts.wait_for:
        required.append(player.clock_pub)
    end = time.monotonic() + opts.wait
    while time.monotonic() < end and (player.poll_outputs() or not player.outputs_matched()
                                      or not all(p.get_subscription_count() for p in required)
                                      or player.unmatched()):
        player.spin(0.02)
    player.settle_match(end)
    missing = [t for t in player.output_topics if t not in player.output_types]
    alone = [t for t in opts.wait_for if t in player.pubs and player.missing([t])]
    if missing or alone:
        what = (f'no publisher of {", ".join(missing)}' if missing else
                f'no subscriber of {", ".join(alone)}')
        print(f'rigidrot_replay: {what} matched within --wait {opts.wait:g} s; nothing was '
              f'played', file=sys.stderr)
        executor.shutdown(0)
        node.destroy_node()
        rclpy.try_shutdown()
        return 2
    played = [(t, log_ns, data) for t, _, log_ns, _, data in msgs]
    status = 0

    def check():
        if not rclpy.ok():
            raise ExternalShutdownException()

    t0 = time.monotonic()
    try:
        player.play(played, check=check, rate=opts.rate)
        took = time.monotonic() - t0
        player.confirm()
        player.settle(0.5, check=check)
    except PlayError as exc:
        print(f'rigidrot_replay: {exc}', file=sys.stderr)
        status = 1
        took = time.monotonic() - t0
    except (KeyboardInterrupt, ExternalShutdownException):
        status, took = 130, time.monotonic() - t0
    finally:
        answers, types = list(player.answers), dict(player.output_types)
        executor.shutdown(0)
        node.destroy_node()
        rclpy.try_shutdown()
    sent = sum(player.sent.values())
    if not opts.quiet:
        note = (f'; {", ".join(player.unconfirmed)}: best-effort subscription, delivery not '
                f'confirmed' if player.unconfirmed else '')
        print(f'[replay] {sent} messages sent{" and acknowledged" if status == 0 else ""} in '
              f'{took:.2f} s ({sent / max(took, 1e-9):.0f} a second, window '
              f'{player.used_window}, {player.stalls} stalls); {len(answers)} '
              f'answers{note}', file=sys.stderr)
    if opts.output:
        described = {t: d for t, _, _, _, d in bag.messages
                     if t.endswith('/run') and bag.topics[t][0] == 'std_msgs/msg/String'}
        try:
            path = write_answers(opts.output, answers, types, bag.runs, described)
        except (BagError, OSError) as exc:
            print(f'rigidrot_replay: -o {opts.output}: {exc}', file=sys.stderr)
            return 2
        if not opts.quiet:
            print(f'[replay] answers: {path}', file=sys.stderr)
    return status


if __name__ == '__main__':
    sys.exit(main())
