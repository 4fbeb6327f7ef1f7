"""Why a tick costs more in the node than in a tight loop, and what the node does about it.

``python -m rigidrot_ros.bench.node_tick [--seconds S] [--preset NAME ...]`` measures, per
preset scene (wall clock, ``perf_counter``):

1. ``Solution.at(t)`` for successive 100 Hz scene times in a tight loop;
2. the same call after an idle gap of 0, 0.1, 1, 3 and 10 ms (``time.sleep``), and a second
   call right after it: how the cost of one call grows with the idle time before it (on
   a shared virtual CPU the other tenants empty the caches meanwhile: measured here, the
   first call after 10 ms costs about 10x the second, and every step of it is slower, the
   pure-Python float arithmetic as much as numpy), so a 100 Hz timer pays it every tick;
3. one 256-sample batch ``Solution.at(array)`` after a 10 ms gap, per sample: what the
   node's look-ahead (:mod:`rigidrot_ros.runtime.ahead`) pays instead;
4. the real ``AttitudeNode`` on that scene at 100 Hz with a subscriber to its two topics
   in the same process, as its own ``/diagnostics`` report it (1 s windows): evaluation
   (a tick's sample from the look-ahead buffer), the whole tick up to publication, the
   wake-up latency (the callback's start after the tick's grid time), the look-ahead's
   batches; the median and the worst window of each p99, and the same node with the
   look-ahead off (every tick evaluates its own sample) for comparison;
5. once, the ROS calls a tick makes, each after a 10 ms gap: reading the clock through
   ``get_clock().now()`` against ``time.time_ns()`` (what the node reads unless
   ``use_sim_time``), and publishing the attitude and rate messages as messages against
   publishing their bytes serialized ahead (what the node's look-ahead does).

ROS traffic stays on the machine: it sets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``
unless already set; use your own ``ROS_DOMAIN_ID``.
"""

import argparse
import os
import sys
import time

import numpy as np

from rigidrot_ros.bench import common
from rigidrot_ros.core import solve

NAME = 'node_tick'
NEEDS = ('rclpy',)
#: The code this part measures (``rigidrot_bench --stale``): modules, with what they import.
MEASURES = ('rigidrot_ros.ros.cli', 'rigidrot_ros.ros.attitude_node')
KEYS = ('node_tick',)
GAPS_S = (0.0, 1e-4, 1e-3, 3e-3, 1e-2)
#: The node's diagnostics keys summarised per setting (median and worst 1 s window).
DIAG_KEYS = ('eval_p99_us', 'tick_p99_us', 'latency_p99_us', 'eval_mean_us', 'tick_mean_us')


def _stats(us):
    us = np.asarray(us)
    return (f'mean {us.mean():7.1f}  p50 {np.percentile(us, 50):7.1f}  '
            f'p99 {np.percentile(us, 99):7.1f}  max {us.max():8.1f} us')


def tight(scene, n):
    """Latencies (us) of successive 100 Hz calls in a tight loop."""
    sol = solve(scene)
    out = []
    for k in range(1, n + 1):
        c = time.perf_counter()
        sol.at(0.01 * k)
        out.append(time.perf_counter() - c)
    return 1e6 * np.array(out)


def after_gap(scene, n, gap):
    """Latencies (us) of calls each made after ``gap`` s asleep, and of a call right after."""
    sol = solve(scene)
    out, again = [], []
    for k in range(1, n + 1):
        if gap:
            time.sleep(gap)
        c = time.perf_counter()
        sol.at(0.01 * k)
        c1 = time.perf_counter()
        sol.at(0.01 * k + 0.001)                  # the same work again, caches now warm
        again.append(time.perf_counter() - c1)
        out.append(c1 - c)
    return 1e6 * np.array(out), 1e6 * np.array(again)


def batch_after_gap(scene, reps=30, size=256):
    """Per-sample cost (us) of a ``size``-sample batch made after a 10 ms gap."""
    sol = solve(scene)
    out = []
    for j in range(reps):
        time.sleep(0.01)
        t = 0.01 * (j * size + np.arange(1, size + 1))
        c = time.perf_counter()
        s = sol.at(t)
        s.quaternion.tolist(), s.omega.tolist(), s.error_bound.tolist()
        out.append((time.perf_counter() - c) / size)
    return 1e6 * np.array(out)


def in_node(scene, seconds, lookahead=True):
    """Run an AttitudeNode on ``scene`` at 100 Hz; return its diagnostics windows (dicts)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from rigidrot_ros.ros import attitude_node as an
    from rigidrot_ros.run import truth_ahead    # where the node's truth builds its look-ahead

    rclpy.init()
    saved = truth_ahead.Lookahead
    if not lookahead:
        truth_ahead.Lookahead = _no_lookahead(saved)
    try:
        params = dict(scene.as_dict(), publish_rate=100.0)
        node = an.AttitudeNode(
            parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
        sub = rclpy.create_node('rigidrot_tick_listener')
        got, diags = [0], []
        sub.create_subscription(QuaternionStamped, 'attitude',
                                lambda m: got.__setitem__(0, got[0] + 1), 10)
        sub.create_subscription(Vector3Stamped, 'angular_velocity', lambda m: None, 10)
        sub.create_subscription(DiagnosticArray, '/diagnostics', lambda m: diags.append(
            {kv.key: kv.value for kv in m.status[0].values}), 10)
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        ex.add_node(sub)
        end = time.monotonic() + seconds + 1.0
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.1)
        ex.shutdown()
        node.destroy_node()
        sub.destroy_node()
        return diags[1:], got[0]              # the first window holds the start-up
    finally:
        truth_ahead.Lookahead = saved
        rclpy.try_shutdown()


def ros_calls(n):
    """Latencies (us) of a tick's ROS calls, each after 10 ms asleep: {label: array}."""
    import rclpy
    from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.serialization import serialize_message

    rclpy.init()
    try:
        node = rclpy.create_node('rigidrot_tick_calls')
        sub = rclpy.create_node('rigidrot_tick_calls_listener')
        att = node.create_publisher(QuaternionStamped, 'tick_calls_attitude', 10)
        rate = node.create_publisher(Vector3Stamped, 'tick_calls_rate', 10)
        sub.create_subscription(QuaternionStamped, 'tick_calls_attitude', lambda m: None, 10)
        sub.create_subscription(Vector3Stamped, 'tick_calls_rate', lambda m: None, 10)
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        ex.add_node(sub)
        clock = node.get_clock()
        out = {k: [] for k in ('clock: get_clock().now()', 'clock: time.time_ns()',
                               'publish two messages', 'publish their bytes')}
        for k in range(n):
            a, r = QuaternionStamped(), Vector3Stamped()
            a.header.frame_id, r.header.frame_id = 'inertial', 'body'
            a.header.stamp.sec = r.header.stamp.sec = k
            a.quaternion.w, r.vector.z = 1.0, 0.1
            raw = (serialize_message(a), serialize_message(r))
            for label, fn in (('clock: get_clock().now()', lambda: clock.now().nanoseconds),
                              ('clock: time.time_ns()', time.time_ns),
                              ('publish two messages', lambda: (att.publish(a),
                                                                rate.publish(r))),
                              ('publish their bytes', lambda: (att.publish(raw[0]),
                                                               rate.publish(raw[1])))):
                ex.spin_once(timeout_sec=0)
                time.sleep(0.01)
                c = time.perf_counter()
                fn()
                out[label].append(time.perf_counter() - c)
        ex.shutdown()
        node.destroy_node()
        sub.destroy_node()
        return {k: 1e6 * np.array(v) for k, v in out.items()}
    finally:
        rclpy.try_shutdown()


def _no_lookahead(cls):
    def make(*args, **kwargs):
        return cls(*args, **dict(kwargs, enabled=False))
    return make


def _windows(diags, key):
    """Median and worst window of diagnostics ``key``, or None where no window has it."""
    v = np.array([float(d[key]) for d in diags if d.get(key)])
    return {'median': float(np.median(v)), 'worst': float(v.max())} if len(v) else None


def _line(key, w):
    return f'{key[:-3]:14s} median {w["median"]:7.1f}  worst {w["worst"]:7.1f} us' if w \
        else f'{key}: no windows'


def _summary(us):
    us = np.asarray(us)
    return dict(common.percentiles(us), max_us=float(us.max()))


def run(quick=False, log=print, seconds=None, presets=None):
    """Measure the settings per preset; return ``{'node_tick': {...}}`` (latencies, us).

    ``seconds`` per setting (default 10, 1 with ``quick``); ``presets`` scene names
    (default all; with ``quick`` the default preset only).
    """
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    seconds = seconds or (1.0 if quick else 10.0)
    scenes = common.ratio_scenes()
    n = int(round(seconds * 100))
    res = {'seconds': seconds, 'ros_calls': {}, 'presets': {}}
    log("a tick's ROS calls, each after 10 ms idle:")
    for label, us in ros_calls(min(n, 300)).items():
        log(f'  {label:26s} {_stats(us)}')
        res['ros_calls'][label] = _summary(us)
    for name in presets or (['default'] if quick else list(scenes)):
        scene = scenes[name]
        row = res['presets'][name] = {'after_gap': {}, 'node': {}}
        log(f'{name}:')
        us = tight(scene, n)
        row['tight'] = _summary(us)
        log(f'  tight loop           {_stats(us)}')
        for gap in GAPS_S:
            first, again = after_gap(scene, min(n, 300), gap)
            row['after_gap'][f'{gap * 1e3:g} ms'] = _summary(first)
            log(f'  after {gap * 1e3:4.1f} ms idle   {_stats(first)}')
            if gap == GAPS_S[-1]:
                row['right_after'] = _summary(again)
                log(f'    a call right after {_stats(again)}')
        us = batch_after_gap(scene)
        row['batch_after_gap'] = _summary(us)
        log(f'  batch of 256 after 10 ms idle, per sample {_stats(us)}')
        for label, on in (('look-ahead on ', True), ('look-ahead off', False)):
            diags, got = in_node(scene, seconds, lookahead=on)
            log(f'  node, {label} ({len(diags)} windows, {got} attitude messages received,'
                f' ticks late {diags[-1]["ticks_late"] if diags else "?"}):')
            node = row['node']['on' if on else 'off'] = {
                'windows': len(diags), 'received': got,
                'ticks_late': diags[-1]['ticks_late'] if diags else None}
            for key in DIAG_KEYS:
                node[key] = _windows(diags, key)
                log(f'    {_line(key, node[key])}')
            if on and diags:
                node['lookahead'] = diags[-1]['lookahead']
                log(f'    look-ahead: {diags[-1]["lookahead"]}, worst batch '
                    f'{max(float(d["lookahead_batch_max_us"]) for d in diags):.0f} us, '
                    f'{diags[-1]["lookahead_sample_us"]} us a sample')
    return {'node_tick': res}


def render_md(results):
    """Per setting, the range over presets of the median and the worst window (us)."""
    res = results.get('node_tick')
    if not res or not res.get('presets'):
        return None
    rows = []
    for on, label in (('on', 'look-ahead on'), ('off', 'look-ahead off')):
        for key in DIAG_KEYS:
            ws = [p['node'][on][key] for p in res['presets'].values()
                  if p['node'].get(on, {}).get(key)]
            if ws:
                rows.append([f'{key[:-3]}, {label}',
                             common.span([w['median'] for w in ws], unit='µs'),
                             common.span([w['worst'] for w in ws], unit='µs')])
    rows += [[f'ROS call after 10 ms idle: {k} (p50, p99)',
              f'{common.fmt(v["p50_us"])} µs', f'{common.fmt(v["p99_us"])} µs']
             for k, v in res['ros_calls'].items()]
    return common.md_fragment(
        f'The node at 100 Hz, as its diagnostics report it ({len(res["presets"])} presets, '
        f'{res["seconds"]:g} s each, 1 s windows; ranges over the presets)',
        common.part_footer(results, NAME),
        common.md_table(['setting', 'median window', 'worst window'], rows))


def main(argv=None):
    """Print the settings' latencies per preset."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--seconds', type=float, default=10.0,
                    help='seconds per setting (the gap sweep takes 100 calls a second)')
    ap.add_argument('--preset', action='append', help='scene name (default: all)')
    opts = ap.parse_args(argv)
    run(log=lambda line: print(line, flush=True), seconds=opts.seconds,
        presets=opts.preset or list(common.ratio_scenes()))
    return 0


if __name__ == '__main__':
    sys.exit(main())
