"""Benchmark part ``generate``: offline generation speed, memory, and the CDR writer's cost.

``python -m rigidrot_ros.bench.generate [--generate-seconds S] [--quick] [--out DIR]``
(or ``rigidrot_bench --only generate``) generates the issue's scene (the default scene
with 100 Hz truth, a 1 kHz gyro with both increments and a 10 Hz star tracker) for S scene
seconds (default 3600, 20 with ``--quick``) in a child process, and reports its wall
time, the speed-up over real time and the child's peak RSS; the same loop's stages in
this process; the serialization cost per message of :mod:`rigidrot_ros.msgs.cdr` against
``rclpy.serialization.serialize_message`` (message building included for the latter, as
the node pays it); and the gyro's and accelerometer's cost per sample, read one interval
at a time and in a block. :func:`render_md` turns the results into ``OUT/generate.md``
(``doc/bench/generate.md``, included by ``doc/generate.md``).
"""

import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

from rigidrot_ros.bench import common

__all__ = ['NAME', 'NEEDS', 'run', 'main', 'render_md', 'add_arguments', 'SCENE']

NAME = 'generate'
NEEDS = ('rclpy', 'mcap')
#: The code this part measures (``rigidrot_bench --stale``): modules, with what they import.
MEASURES = ('rigidrot_ros.tools.generate',)
#: The issue's benchmark scene (overrides of the node's defaults).
SCENE = ['imu.enable:=true', 'imu.rate:=1000.0', 'star_tracker.enable:=true',
         'star_tracker.rate:=10.0', 'publish_rate:=100.0']


#: The child: ``rigidrot_generate``, then its own peak RSS on standard error.
_CHILD = '''
import sys
from rigidrot_ros.tools.generate import main
code = main(sys.argv[1:])
with open('/proc/self/status') as f:
    hwm = [line.split()[1] for line in f if line.startswith('VmHWM:')]
sys.stderr.write('\\nmaxrss_kb %s\\n' % hwm[0])
sys.exit(code)
'''


def _child(duration, root, out):
    """Run ``rigidrot_generate`` on the scene in a child process: wall, CPU, peak RSS, bag.

    ``root``: a checkout whose code runs (its directory first on the path), else this one.
    The child's peak RSS is its own: its ``VmHWM``, the high-water mark of its own memory.
    Not ``ru_maxrss``: Linux carries that across ``fork`` and ``exec``, so a child's is at
    least its parent's size when it was started (this benchmark's process, hundreds of MB
    after other parts had run).
    """
    cmd = [sys.executable, '-c', _CHILD, '-o', out, '--duration', str(duration), '--quiet']
    for s in SCENE:
        cmd += ['-p', s]
    env, cwd = dict(os.environ), None
    if root is not None:
        env['PYTHONPATH'] = os.pathsep.join([root] + [p for p in env.get(
            'PYTHONPATH', '').split(os.pathsep) if p])
        cwd = root
    t0 = time.perf_counter()
    c0 = os.times()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=cwd)
    wall = time.perf_counter() - t0
    c1 = os.times()
    if proc.returncode != 0:
        raise RuntimeError(f'rigidrot_generate failed: {proc.stderr.strip()}')
    rss = [ln for ln in proc.stderr.splitlines() if ln.startswith('maxrss_kb ')]
    size = sum(os.path.getsize(os.path.join(out, f)) for f in os.listdir(out))
    cpu = (c1.children_user + c1.children_system) - (c0.children_user + c0.children_system)
    return wall, cpu, int(rss[-1].split()[1]) / 1024.0, size


def _generate(duration, log, baseline=None, repeats=1):
    """Generate the scene in a child process ``repeats`` times; the fastest run's figures.

    ``baseline``: a checkout of the previous code, run alternately with this one in the same
    benchmark run (same machine, same load): its figures go under ``'baseline'``. Each code
    first generates one scene second untimed (its compiled kernels cached on disk, as
    after any first run); that child's peak RSS is the floor of the set-up
    (``setup_rss_mb``: the imports, the compiled kernels, the scene and its first
    samples), what the generation itself adds is the rest of the peak. Then the whole
    duration once, untimed: numba compiles some kernels only when a longer run first
    calls them, and a compile in a timed run would put numba's compiler into its peak.
    """
    runs = {'now': [], 'baseline': []}
    setup_rss = {}
    with tempfile.TemporaryDirectory(prefix='rigidrot_bench_gen_') as tmp:
        for key, root in (('baseline', baseline), ('now', None)):
            if key == 'now' or baseline is not None:     # compiled code cached, not timed
                setup_rss[key] = _child(1.0, root, os.path.join(tmp, f'warm_{key}', 'bag'))[2]
                _child(duration, root, os.path.join(tmp, f'warm_all_{key}', 'bag'))
                shutil.rmtree(os.path.join(tmp, f'warm_all_{key}'))
        for i in range(repeats):
            for key, root in (('baseline', baseline), ('now', None)):
                if key == 'baseline' and baseline is None:
                    continue
                out = os.path.join(tmp, f'{key}_{i}', 'bag')
                runs[key].append(_child(duration, root, out) + (os.getloadavg()[0],))
                if i:
                    shutil.rmtree(out)
        if baseline is not None:                # the same bag, byte for byte
            same = _same_bag(os.path.join(tmp, 'now_0', 'bag'),
                             os.path.join(tmp, 'baseline_0', 'bag'))
    res = {}
    for key, got in runs.items():
        if not got:
            continue
        wall, cpu, rss_mb, size, load = min(got)
        res[key] = {'scene_s': duration, 'wall_s': wall, 'cpu_s': cpu,
                    'speedup': duration / wall, 'peak_rss_mb': max(g[2] for g in got),
                    'setup_rss_mb': setup_rss[key],
                    'bag_mb': size / 1e6, 'load_average': load, 'cores': os.cpu_count(),
                    'runs': len(got)}
        label = ' (previous code)' if key == 'baseline' else ''
        log(f'generate{label}: {duration:g} scene s (100 Hz truth, 1 kHz gyro + increments, '
            f'10 Hz star tracker) in {wall:.3g} s wall ({cpu:.3g} s CPU; best of '
            f'{len(got)}): {duration / wall:.3g}x real time, peak RSS '
            f'{res[key]["peak_rss_mb"]:.0f} MB ({setup_rss[key]:.0f} MB for 1 scene s), bag '
            f'{size / 1e6:.3g} MB (load average '
            f'{load:.2f} on {os.cpu_count()} cores)')
    out = res['now']
    if baseline is not None:
        out['baseline'] = dict(res['baseline'], commit=_head(baseline), same_bag=same)
        log(f'generate: the bag of the previous code ({out["baseline"]["commit"][:12]}) is '
            f'{"byte for byte" if same else "NOT"} the same; '
            f'{out["speedup"] / out["baseline"]["speedup"]:.3g}x its speed, '
            f'{out["baseline"]["cpu_s"] / out["cpu_s"]:.3g}x less CPU')
    return out


def _same_bag(a, b):
    """Whether two bag directories of one name hold the same files, byte for byte."""
    names = sorted(os.listdir(a))
    if names != sorted(os.listdir(b)):
        return False
    for name in names:
        with open(os.path.join(a, name), 'rb') as fa, open(os.path.join(b, name), 'rb') as fb:
            while True:
                x, y = fa.read(1 << 20), fb.read(1 << 20)
                if x != y:
                    return False
                if not x:
                    break
    return True


def _head(root):
    proc = subprocess.run(['git', '-C', root, 'rev-parse', 'HEAD'], capture_output=True,
                          text=True)
    return proc.stdout.strip() if proc.returncode == 0 else '?'


def _stages(duration, log):
    """Wall time per stage of :func:`run.generate.generate_bag`'s loop, in this process.

    The same spans and chunks as the command, timed stage by stage, every stage on this
    thread (the command compresses and writes on a thread of its own): the truth ticks
    (``solution.at``), the gyro (the imu kind's read: ``Gyro.read_many``, quadrature, the
    attitudes at the ends, the error model), the star tracker, ``pack`` (the kinds' CDR,
    the MCAP records built in arrays, the merge order), ``chunk`` (records joined, message
    indexes, statistics) and ``compress + write`` (zstd, crc, the file).
    """
    from rigidrot_ros.bag import BagWriter
    from rigidrot_ros.bag import chunks
    from rigidrot_ros.run import generate as gen, spans
    values = dict(gen.parse_override(s) for s in SCENE)
    spent = dict.fromkeys(('set-up', 'truth', 'gyro', 'star tracker', 'pack', 'chunk',
                           'compress + write'), 0.0)
    clock = {'gyro': 0.0, 'star tracker': 0.0, 'compress + write': 0.0}
    keys = {'imu': 'gyro', 'star_tracker': 'star tracker'}

    def timed(fn, key):
        def call(*args, **kw):
            c = time.perf_counter()
            out = fn(*args, **kw)
            clock[key] += time.perf_counter() - c
            return out
        return call
    write_chunk = chunks.write_detached
    chunks.write_detached = timed(write_chunk, 'compress + write')
    try:
        with tempfile.TemporaryDirectory(prefix='rigidrot_bench_stages_') as tmp:
            t0 = time.perf_counter()
            run = gen._Run(values, duration, 0)
            writer = BagWriter(None, 'attitude_node', flush_period=float('inf'),
                               path=os.path.join(tmp, 'bag'), split_seconds=0.0)
            cids = {topic: writer.add_topic(topic, type_name)
                    for topic, type_name, _, _ in run.topics}
            seq = dict.fromkeys(cids, 0)
            for output, _, _ in run.sensors:    # each sensor kind's reading, timed apart
                output.sample = timed(output.sample, keys[output.name])
            spent['set-up'] = time.perf_counter() - t0
            step = round(gen.BLOCK_S * 1e9)
            blocks = run.blocks(gen.EVAL_BLOCKS)
            while True:
                c0 = time.perf_counter()
                got = next(blocks, None)
                if got is None:
                    break
                elo, ehi, parts = got
                c1 = time.perf_counter()
                span = spans.span_of(run, parts, cids, seq, gen._order(parts))
                c2 = time.perf_counter()
                for lo in range(elo, ehi, step):
                    a, b = np.searchsorted(span.log, [lo, min(ehi, lo + step)]).tolist()
                    pieces = spans.pieces(span, a, b, writer.chunk_size, writer.open_bytes)
                    for x, y, _ in pieces:
                        spans.write_piece(writer, span, x, y, run.start_ns)
                c3 = time.perf_counter()
                spent['truth'] += c1 - c0
                spent['pack'] += c2 - c1
                spent['chunk'] += c3 - c2
            c = time.perf_counter()
            writer.close()
            spent['chunk'] += time.perf_counter() - c
    finally:
        chunks.write_detached = write_chunk
    spent['truth'] -= clock['gyro'] + clock['star tracker']
    spent['chunk'] -= clock['compress + write']
    spent.update(clock)
    total = sum(spent.values())
    ms = {k: v / duration * 1e3 for k, v in spent.items()}
    log(f'stages over {duration:g} scene s ({total:.3g} s wall, {duration / total:.3g}x; '
        'ms per scene second): '
        + ', '.join(f'{k} {v:.3g}' for k, v in ms.items()))
    return {'scene_s': duration, 'wall_s': total, 'ms_per_scene_s': ms,
            'load_average': os.getloadavg()[0]}


def _serialize_costs(n, log):
    from rclpy.serialization import serialize_message

    from rigidrot_ros.msgs import cdr
    from rigidrot_ros.msgs import messages as msgs
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


#: The accelerometer of the per-sample row: gravity and a lever arm (centripetal terms).
ACCEL = {'lever_arm': (0.1, -0.05, 0.2), 'gravity': (0.0, 0.0, -9.80665)}


def _sensor_costs(quick, log):
    """Wall time per sample of the gyro and the accelerometer, single reads and a block.

    The default scene at 1 kHz, error models off: ``read(t0, t1)`` one interval at a time
    (``n_single`` intervals), then ``read_many`` over ``n_block`` intervals, each on a
    fresh sensor, the truth evaluated over the span first (so the figure is the sensor's).
    """
    from rigidrot_ros.run import params, settings
    from rigidrot_ros.sensors import Accelerometer, Gyro
    sol = settings.build_solution(params.defaults())
    n_single, n_block = (100, 300) if quick else (300, 1000)
    times = np.arange(max(n_single, n_block) + 1) * 1e-3
    sol.at(times)
    out = {}
    for name, make in (('gyro', lambda: Gyro(sol)),
                       ('accelerometer', lambda: Accelerometer(sol, **ACCEL))):
        sensor = make()
        t0 = time.perf_counter()
        for k in range(n_single):
            sensor.read(float(times[k]), float(times[k + 1]))
        single = (time.perf_counter() - t0) / n_single
        sensor = make()
        t0 = time.perf_counter()
        sensor.read_many(times[:n_block + 1])
        block = (time.perf_counter() - t0) / n_block
        out[name] = {'rate_hz': 1000.0, 'single_us': single * 1e6, 'single_reads': n_single,
                     'block_us': block * 1e6, 'block_size': n_block}
        log(f'{name} per sample at 1 kHz: single read {single * 1e6:.3g} us ({n_single} '
            f'reads), a block of {n_block} {block * 1e6:.3g} us')
    return out


def run(quick=False, log=print, generate_seconds=None, generate_baseline=None,
        generate_repeats=None):
    """Measure and return the figures (JSON-serialisable); ``quick``: 20 scene seconds.

    ``generate_seconds`` (option ``--generate-seconds``) sets the generated span instead;
    ``generate_baseline`` (``--generate-baseline DIR``) a checkout of the previous code,
    generated alternately with this one (``generate_repeats`` times each, default 1).
    """
    duration = generate_seconds or (20.0 if quick else 3600.0)
    return {'quick': bool(quick),
            'generation': _generate(float(duration), log, generate_baseline,
                                    int(generate_repeats or 1)),
            'stages': _stages(10.0 if quick else 120.0, log),
            'serialize': _serialize_costs(2000 if quick else 20000, log),
            'sensors': _sensor_costs(quick, log)}


def add_arguments(ap):
    """Add ``--generate-seconds``, ``--generate-baseline``, ``--generate-repeats`` to ``ap``."""
    ap.add_argument('--generate-seconds', type=common.positive_number, metavar='S',
                    help='generate: scene seconds to generate (default 3600, 20 with --quick)')
    ap.add_argument('--generate-baseline', metavar='DIR',
                    help='generate: a checkout of the previous code, generated alternately '
                         'with this one in the same run (its figures beside; the bags '
                         'compared byte for byte)')
    ap.add_argument('--generate-repeats', type=int, metavar='N',
                    help='generate: child runs of each code, the fastest kept (default 1)')


_SCENE_TEXT = '100 Hz truth, 1 kHz gyro + both increments, 10 Hz star tracker'


def failed(results):
    """Return a line if the previous code's bag (``--generate-baseline``) was not the same."""
    base = ((results.get('generate') or {}).get('generation') or {}).get('baseline')
    if base and not base['same_bag']:
        return [f'GENERATE: the bag of the previous code ({base["commit"][:12]}) differs from '
                'the bag of this code for the same parameters']
    return []


def _setup(gen):
    """Return `` (S MB for 1 scene s: ...)``, the set-up's peak RSS, where the results hold it."""
    if gen.get('setup_rss_mb') is None:
        return ''
    return (f' ({common.fmt(gen["setup_rss_mb"])} MB for 1 scene s: imports, compiled kernels, '
            'set-up)')


def render_md(results):
    """Return the part's table from merged results (``'generate'``), or None without them.

    One row per measurement present: the generation in a child process, its stages in
    process, the serialization cost per message type, the sensors per sample. The caption
    says a quick run and the load average where the results record them.
    """
    res = results.get('generate')
    if not res:
        return None
    fmt = common.fmt
    rows = []
    gen = res.get('generation')
    if gen:
        best = f' (best of {gen["runs"]})' if gen.get('runs', 1) > 1 else ''
        rows.append((f'benchmark scene ({_SCENE_TEXT}), {gen["scene_s"]:g} scene s, '
                     f'`rigidrot_generate` in a child process{best}',
                     f'{fmt(gen["wall_s"])} s wall, {fmt(gen["cpu_s"])} s CPU: '
                     f'**{fmt(gen["speedup"])}× real time** '
                     f'({fmt(gen["scene_s"] / gen["cpu_s"])} scene s per CPU s), peak RSS '
                     f'{fmt(gen["peak_rss_mb"])} MB{_setup(gen)}, bag {fmt(gen["bag_mb"])} MB'))
        base = gen.get('baseline')
        if base:
            rows.append((f'the same, the previous code (commit {base["commit"][:12]}), '
                         'run alternately in this run',
                         f'{fmt(base["wall_s"])} s wall, {fmt(base["cpu_s"])} s CPU: '
                         f'{fmt(base["speedup"])}× real time '
                         f'({fmt(base["scene_s"] / base["cpu_s"])} scene s per CPU s), peak RSS '
                         f'{fmt(base["peak_rss_mb"])} MB{_setup(base)}; now '
                         f'**{fmt(gen["speedup"] / base["speedup"])}×** its speed and '
                         f'{fmt(base["cpu_s"] / gen["cpu_s"])}× less CPU; the bag '
                         + ('byte for byte the same' if base['same_bag'] else
                            '**not** the same')))
    st = res.get('stages')
    if st:
        ms = sorted(st['ms_per_scene_s'].items(), key=lambda kv: -kv[1])
        rows.append((f'the same, {st["scene_s"]:g} scene s in process, ms per scene second',
                     f'{fmt(st["wall_s"])} s wall ({fmt(st["scene_s"] / st["wall_s"])}×): '
                     + ', '.join(f'{k} {fmt(v)}' for k, v in ms)))
    for kind, c in res.get('serialize', {}).items():
        rows.append((f'serialize `{kind}`',
                     f'io.cdr {fmt(c["cdr_us"])} µs/message; build + `serialize_message` '
                     f'{fmt(c["rclpy_us"])} µs ({fmt(c["ratio"])}×)'))
    for name, c in res.get('sensors', {}).items():
        rows.append((f'{name} per sample at {c["rate_hz"]:g} Hz: single `read` / '
                     f'`read_many` of {c["block_size"]}',
                     f'{fmt(c["single_us"])} µs / {fmt(c["block_us"])} µs '
                     f'({fmt(c["single_us"] / c["block_us"])}×)'))
    title = ('Offline generation (`rigidrot_bench --only generate`): the default scene with '
             + _SCENE_TEXT)
    if res.get('quick'):
        title += '; quick run (--quick: short spans, small batches)'
    if gen and gen.get('load_average') is not None:
        title += (f'; load average {gen["load_average"]:.2f} on {gen.get("cores", "?")} '
                  'cores at the end of the generation')
    return common.part_md(results, NAME, title, common.md_table(['what', 'figure'], rows))


def main(argv=None):
    """``python -m rigidrot_ros.bench.generate``: this part alone, into ``--out``."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
