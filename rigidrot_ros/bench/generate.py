"""Benchmark part ``generate``: offline generation speed, memory, and the CDR writer's cost.

``python -m rigidrot_ros.bench.generate [--duration S] [--quick]`` generates the issue's
scene (the default scene with 100 Hz truth, a 1 kHz gyro with both increments and a 10 Hz
star tracker) for S scene seconds (default 3600) in a child process, and reports its wall
time, the speed-up over real time and the child's peak RSS; then the serialization cost
per message of :mod:`rigidrot_ros.io.cdr` against ``rclpy.serialization.serialize_message``
(message building included for the latter, as the node pays it).
"""

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

__all__ = ['NAME', 'NEEDS', 'run', 'main', 'SCENE']

NAME = 'generate'
NEEDS = ('rclpy', 'mcap')
#: The issue's benchmark scene (overrides of the node's defaults).
SCENE = ['imu.enable:=true', 'imu.rate:=1000.0', 'star_tracker.enable:=true',
         'star_tracker.rate:=10.0', 'publish_rate:=100.0']


def _generate(duration, log):
    with tempfile.TemporaryDirectory(prefix='rigidrot_bench_gen_') as tmp:
        out = os.path.join(tmp, 'bag')
        cmd = [sys.executable, '-m', 'rigidrot_ros.tools.generate', '-o', out, '--duration',
               str(duration), '--quiet']
        for s in SCENE:
            cmd += ['-p', s]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if proc.returncode != 0:
            raise RuntimeError(f'rigidrot_generate failed: {proc.stderr.strip()}')
        size = sum(os.path.getsize(os.path.join(out, f)) for f in os.listdir(out))
    rss_mb = after.ru_maxrss / 1024.0       # kB on Linux: the largest child so far
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    res = {'scene_s': duration, 'wall_s': wall, 'cpu_s': cpu, 'speedup': duration / wall,
           'peak_rss_mb': rss_mb, 'bag_mb': size / 1e6}
    log(f'generate: {duration:g} scene s (100 Hz truth, 1 kHz gyro + increments, 10 Hz star '
        f'tracker) in {wall:.3g} s wall ({cpu:.3g} s CPU): {res["speedup"]:.3g}x real time, '
        f'peak RSS {rss_mb:.0f} MB, bag {size / 1e6:.3g} MB (load average '
        f'{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores)')
    return res


def _stages(duration, log):
    """Wall time per stage of :func:`io.generate.generate_bag`'s loop, in this process.

    The same blocks as the command, timed stage by stage: the truth ticks (``solution.at``
    in the node's look-ahead batches), the gyro (``Gyro.read_many``: quadrature, the
    attitudes at the ends, the error model), the star tracker, serialization
    (:mod:`io.cdr`), merge order and the MCAP writer (``BagWriter.write_many``).
    """
    from rigidrot_ros.io import generate as gen
    from rigidrot_ros.io.bag import BagWriter
    values = dict(gen.parse_override(s) for s in SCENE)
    spent = dict.fromkeys(('set-up', 'truth', 'gyro', 'star tracker', 'serialize',
                           'order', 'write'), 0.0)
    with tempfile.TemporaryDirectory(prefix='rigidrot_bench_stages_') as tmp:
        t0 = time.perf_counter()
        run = gen._Run(values, duration, 0)
        writer = BagWriter(None, 'attitude_node', flush_period=0.5,
                           path=os.path.join(tmp, 'bag'), split_seconds=0.0)
        for topic, type_name in run.topics:
            writer.add_topic(topic, type_name)
        writer.add_topic(gen.RUN_TOPIC, 'std_msgs/msg/String')
        gyro, star = run._imu_block, run._star_block
        clock = {'gyro': 0.0, 'star tracker': 0.0}

        def timed(fn, key):
            def call(*args):
                c = time.perf_counter()
                out = fn(*args)
                clock[key] += time.perf_counter() - c
                return out
            return call
        run._imu_block, run._star_block = timed(gyro, 'gyro'), timed(star, 'star tracker')
        spent['set-up'] = time.perf_counter() - t0
        step = round(gen.BLOCK_S * 1e9)
        lo = 0
        while lo < run.span_ns:
            hi = min(run.span_ns, lo + step)
            c0 = time.perf_counter()
            streams = run.block(lo, hi)
            c1 = time.perf_counter()
            raws = [gen._serialized(run, *st) for st in streams]
            c2 = time.perf_counter()
            topics, datas, stamps = gen._merged(streams, raws)
            c3 = time.perf_counter()
            writer.write_many(topics, datas, stamps)
            c4 = time.perf_counter()
            spent['truth'] += c1 - c0
            spent['serialize'] += c2 - c1
            spent['order'] += c3 - c2
            spent['write'] += c4 - c3
            lo = hi
        c = time.perf_counter()
        writer.close()
        spent['write'] += time.perf_counter() - c
    spent['truth'] -= clock['gyro'] + clock['star tracker']
    spent.update(clock)
    total = sum(spent.values())
    ms = {k: v / duration * 1e3 for k, v in spent.items()}
    log(f'stages over {duration:g} scene s ({total:.3g} s wall, {duration / total:.3g}x; '
        'ms per scene second): '
        + ', '.join(f'{k} {v:.3g}' for k, v in ms.items()))
    return {'scene_s': duration, 'wall_s': total, 'ms_per_scene_s': ms}


def _serialize_costs(n, log):
    from rclpy.serialization import serialize_message

    from rigidrot_ros.io import cdr
    from rigidrot_ros.io import messages as msgs
    rng = np.random.default_rng(0)
    stamps = np.arange(n, dtype=np.int64) * 10_000_000 + 1_700_000_000_000_000_000
    q, w, var = rng.standard_normal((n, 4)), rng.standard_normal((n, 3)), rng.random(n)
    out = {}
    cases = {
        'QuaternionStamped': (lambda: cdr.attitude(stamps, q, 'inertial').tolist(),
                              lambda: [serialize_message(msgs.attitude(msgs.stamp(s), 'inertial',
                                                                       x))
                                       for s, x in zip(stamps.tolist(), q.tolist())]),
        'Imu': (lambda: cdr.imu(stamps, w, var, 'body').tolist(),
                lambda: [serialize_message(msgs.imu(msgs.stamp(s), 'body', x, v))
                         for s, x, v in zip(stamps.tolist(), w, var.tolist())]),
    }
    for kind, (fast, slow) in cases.items():
        times = {}
        for label, fn in (('cdr', fast), ('rclpy', slow)):
            best = np.inf
            for _ in range(3):
                t0 = time.perf_counter()
                fn()
                best = min(best, time.perf_counter() - t0)
            times[label] = best / n * 1e6
        out[kind] = {'cdr_us': times['cdr'], 'rclpy_us': times['rclpy'],
                     'ratio': times['rclpy'] / times['cdr']}
        log(f'serialize {kind}: io.cdr {times["cdr"]:.3g} us/message, build + '
            f'serialize_message {times["rclpy"]:.3g} us/message ({out[kind]["ratio"]:.3g}x; '
            f'batches of {n}, best of 3)')
    return out


def run(quick=False, log=print, duration=None):
    """Measure and return the figures (JSON-serialisable); ``quick``: 20 scene seconds."""
    if duration is None:
        duration = 20.0 if quick else 3600.0
    return {'generation': _generate(float(duration), log),
            'stages': _stages(10.0 if quick else 120.0, log),
            'serialize': _serialize_costs(2000 if quick else 20000, log)}


def main(argv=None):
    """Command line: ``python -m rigidrot_ros.bench.generate [--duration S] [--quick]``."""
    ap = argparse.ArgumentParser(prog='python -m rigidrot_ros.bench.generate',
                                 description=__doc__.splitlines()[0])
    ap.add_argument('--quick', action='store_true', help='20 scene seconds, small batches')
    ap.add_argument('--duration', type=float, help='scene seconds to generate')
    opts = ap.parse_args(argv)
    run(quick=opts.quick, duration=opts.duration)
    return 0


if __name__ == '__main__':
    sys.exit(main())
