"""Offline generation: the bag ``attitude_node`` would record, without ROS running.

The node's sampling, reproduced on the scene's own grids (no clock, no timers), from the
same table of outputs (:mod:`rigidrot_ros.run.table`): each kind's topics, its reading of
a block of samples and its CDR.

- the truth tick k is stamped ``start_ns + round(k * 1e9 / publish_rate)`` and holds the
  scene at ``t = (stamp - start_ns) * 1e-9 * time_scale``: ``attitude``,
  ``angular_velocity`` and, where enabled, ``transform``, ``odom``, ``markers``, all read
  by one ``solution.at`` a block;
- a sensor's sample k (from its kind's ``first``: the imu's k >= 1 covers the interval
  from sample k - 1 to k) has the true sample time ``start_ns + round(k * 1e9 / rate)``
  on its own rate, and is read a block at a time by its kind (the gyro and the
  accelerometer by ``read_many``: the bits of the per-sample reads);
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
time, then the table's rank: truth, imu, star tracker, mag). A sample belongs to the run
if its true time lies in ``[start_ns, start_ns + duration_s / time_scale)``
(``duration_s`` in scene seconds); its log time may lie up to its latency past that.
Parameters are validated by the node's own code (:mod:`rigidrot_ros.run.settings`).
:func:`generate_bag` encodes each block with the kinds' vectorised CDR
(:mod:`rigidrot_ros.msgs.cdr`) and streams it to the bag, so memory stays bounded
whatever the duration (its records and chunks: :mod:`rigidrot_ros.run.spans`);
:func:`iter_run` gives the same messages as ROS messages.
"""

import difflib
import math
import operator
import signal
import threading
from typing import NamedTuple

import numpy as np
import yaml

from rigidrot_ros.bag import qos_yaml
from rigidrot_ros.run import grid, spans, table
from rigidrot_ros.run.output import scene_time
from rigidrot_ros.run.scheduler import timing_of, Track
from rigidrot_ros.run.truth_outputs import read_truth

__all__ = ['iter_run', 'iter_serialized', 'generate_bag', 'load_values', 'prepare_run',
           'parse_override', 'GenerationError', 'NODE_NAME', 'RUN_TOPIC', 'run_arrays']

#: The node whose recording is reproduced (its fully qualified name).
NODE_NAME = '/attitude_node'
#: Where the node publishes its run description.
RUN_TOPIC = table.resolve('~/run', NODE_NAME)
#: Clock seconds of samples handled together (evaluated, serialized, written); the bag's
#: chunks are cut at these blocks (and at 1 MiB of records).
BLOCK_S = 1.0
#: Blocks :func:`generate_bag` evaluates at once: the same samples, bit for bit, as block by
#: block (each kind's reading is independent of how its samples are batched, as the node's
#: look-ahead batches rely on), with fewer calls per sample. A span of blocks pays about
#: 2.4 ms of per-call costs on the benchmark scene (1.8 ms CPU per scene second less at 4
#: blocks than at 1). 8: about 0.3 ms per scene second less than at 4 (about a tenth of
#: the CPU), for about 9 MB more peak memory (measured when the peak was about 200 MB at 4
#: blocks, most of it numba and LLVM; 6 blocks: +3 MB, 16: +25 MB).
EVAL_BLOCKS = 8
_SEC = 1_000_000_000


class GenerationError(ValueError):
    """Invalid parameters or arguments: the message is one line naming the problem."""


# -- parameters ------------------------------------------------------------------------------
def parse_override(text):
    """Return ``(name, value)`` of ``name:=value``; the value read as rcl reads it.

    :func:`rigidrot_ros.run.rclyaml.load`: ``2e-4`` is a double, ``yes`` true, ``[0.1, 0, 0]``
    refused (a list of one type), an empty value refused, as ``attitude_node`` does.
    """
    from rigidrot_ros.run import rclyaml
    name, sep, raw = str(text).partition(':=')
    if not sep or not name:
        raise GenerationError(f'-p expects name:=value, got {text!r}')
    if not raw.strip():
        raise GenerationError(f"-p {name}: no value (ROS refuses an empty one; write '' for "
                              'an empty string)')
    try:
        value = rclyaml.load(raw)
    except (yaml.YAMLError, ValueError) as exc:
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
    evaluated what the node's has before its first tick. One exception: the node bounds
    the wall time of its first samples (it must publish in time), generation does not
    (``timed=False``): whether a run is generated never depends on how fast or loaded the
    machine is. A name the node does not
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
        return settings.prepare_run(p, timed=False)
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


class Part(NamedTuple):
    """One topic's messages in a block: what :func:`_order` merges and the kinds encode.

    ``stamps`` the header stamps, ``log`` the log times (the true sample time plus the
    sensor's latency), ``true`` the true sample times (int64 arrays, one per sample);
    ``cols`` the kind's columns; ``name`` the topic as the kind names it, ``topic`` as the
    bag does.
    """

    rank: float
    topic: str
    stamps: np.ndarray
    cols: dict
    log: np.ndarray
    true: np.ndarray
    name: str
    output: object


def _check_span(duration_s, start_ns):
    if isinstance(duration_s, bool) or not isinstance(duration_s, (int, float)) or \
            not math.isfinite(duration_s) or duration_s <= 0:
        raise GenerationError(f'--duration must be a positive number of scene seconds, '
                              f'got {duration_s!r}')
    if isinstance(start_ns, bool) or not isinstance(start_ns, int) or \
            not 0 <= start_ns < 2 ** 63:
        raise GenerationError(f'--start-ns must be an integer in [0, 2^63), '
                              f'got {start_ns!r}')


class _Run:
    """The outputs of one run (the table's kinds it switches on), a block of clock at a time."""

    #: where the run description goes (:func:`rigidrot_ros.run.spans.span_of` finds it)
    run_topic = RUN_TOPIC

    def __init__(self, values, duration_s, start_ns, setup=None):
        _check_span(duration_s, start_ns)
        self.setup = setup = prepare_run(values) if setup is None else setup
        self.p, self.sol = setup.values, setup.solution
        self.time_scale = float(setup.time_scale)
        if self.time_scale <= 0:
            raise GenerationError('parameter time_scale = 0 freezes the scene: a duration in '
                                  'scene seconds needs time_scale > 0')
        self.span_ns = round(duration_s / self.time_scale * 1e9)
        if not 0 < self.span_ns < 2 ** 63 - start_ns:
            raise GenerationError(f'--duration {duration_s!r} s at time_scale '
                                  f'{self.time_scale:g} leaves the int64 nanosecond clock')
        self.start_ns = int(start_ns)
        self.frames = setup.frames
        self.rate = float(setup.publish_rate)
        self.truth_k = _grid_count(self.rate, self.span_ns)
        self.outputs = table.make(setup)
        #: the solution's ``at`` for the truth ticks, answered from the gyro's attitudes at
        #: its interval ends where the times are the same (:class:`_KnownAt`)
        self.known = self.sol
        if setup.gyro is not None and any(o.name == 'imu' for o in self.outputs):
            self.known = _KnownAt(self.sol, setup.gyro)
        # each sensor's grid and timing model, by the node's own Track (same seeded draws)
        self.sensors = [(o, Track(o.name, self.start_ns, o.rate, o.first,
                                  timing_of(self.p, o.name)),
                         _grid_count(o.rate, self.span_ns, first=o.first))
                        for o in self.outputs if o.grid == 'sensor']
        #: clock ns past the last sample time until which samples are still published
        self.tail_ns = max([t.timing.latency_ns for _, t, _ in self.sensors] + [0])

    @property
    def topics(self):
        """``[(topic, pkg/msg/Type, latched), ...]`` of every output, in rank order."""
        return sorted(((table.resolve(t.name, NODE_NAME), t.type, o.latched, t.rank)
                       for o in self.outputs for t in o.active), key=lambda x: x[3])

    def description(self):
        """Return the run description the node publishes on ``~/run`` (a dict)."""
        from rigidrot_ros.run.outputs import run_description
        topics = {'/parameter_events': table.NODE_TOPICS['/parameter_events']}
        topics.update((name, type_name) for name, type_name, _, _ in self.topics
                      if name != RUN_TOPIC)
        topics['/diagnostics'] = table.NODE_TOPICS['/diagnostics']
        topics[RUN_TOPIC] = 'std_msgs/msg/String'
        return run_description(self.setup, self.start_ns, 1, NODE_NAME, topics)

    def _parts(self, output, stamps, cols, log, true):
        return [Part(t.rank, table.resolve(t.name, NODE_NAME), stamps, cols, log, true, t.name,
                     output) for t in output.active]

    def block(self, lo_ns, hi_ns, failures=None):
        """Return the :class:`Part` list of the messages logged in ``[lo_ns, hi_ns)``.

        Relative to the start; the order of the parts is free (:func:`_order` merges them
        as the node publishes). A sample that cannot be evaluated raises
        :class:`GenerationError`; with a ``failures`` list it is appended there instead, as
        ``(log time relative to the start, ns, the error)``, and its sensor's parts stop
        before it.
        """
        parts = []
        for output, track, krange in self.sensors:
            parts += self._sensor(output, track, krange, lo_ns, hi_ns, failures)
        ks = _sub(self.truth_k, self.rate, lo_ns, hi_ns)
        if len(ks):
            stamps = grid.stamps_ns(self.start_ns, self.rate, ks)
            cols = self._truth(scene_time(stamps, self.start_ns, self.time_scale))
            for o in self.outputs:
                if o.grid == 'truth':       # the truth: log = stamp = true time
                    parts += self._parts(o, stamps, cols, stamps, stamps)
                elif o.grid == 'start' and ks[0] == 0:    # after the first call's messages
                    parts += self._parts(o, stamps[:1], {'info': [self.description()]},
                                         stamps[:1], stamps[:1])
        return parts

    def _truth(self, times):
        """:func:`read_truth` at scene ``times``, from the gyro's samples where it has them."""
        return read_truth(self.known, times)

    def _sensor(self, output, track, krange, lo_ns, hi_ns, failures=None):
        """Read a sensor's samples logged in ``[lo, hi)`` (grid time + latency): its parts.

        :meth:`SensorOutput.sample` reads them and draws their stamps and drops (every
        sample, kept or not, in index order, as the node does); dropped rows go.
        """
        lat = track.timing.latency_ns
        ks = _sub(krange, output.rate, lo_ns - lat, hi_ns - lat)
        if not len(ks):
            return []
        b = output.sample(track, ks, self.time_scale)
        keep = b.keep
        bad = None if b.errors.count(None) == len(b.errors) else \
            next(i for i, e in enumerate(b.errors) if e is not None)
        if bad is not None:
            t = scene_time(int(b.true_ns[bad]), self.start_ns, self.time_scale)
            error = GenerationError(f'{output.name} sample {ks[bad]} (t = {t:.9g} s) cannot '
                                    f'be evaluated: {" ".join(str(b.errors[bad]).split())}')
            if failures is None:
                raise error
            failures.append((int(b.true_ns[bad]) + lat - self.start_ns, error))
            keep = keep & (np.arange(len(keep)) < bad)
        if keep.all():
            stamps, cols, true = b.stamps_ns, b.cols, b.true_ns
        else:
            stamps, cols = b.rows(keep)
            true = b.true_ns[keep]
        return self._parts(output, stamps, cols, true + lat, true)

    @property
    def end_ns(self):
        """Where the blocks end (from the start, ns): the span and the latest latency."""
        return self.span_ns + self.tail_ns

    def blocks(self, blocks=1, failures=None):
        """Yield ``(lo_ns, hi_ns, parts)`` over the run, ``blocks`` x :data:`BLOCK_S` each.

        Blocks cut the log time; past the span they run on until the last sample's
        latency has passed (a sample of the span is published, however late). ``failures``
        as :meth:`block`.
        """
        step = round(BLOCK_S * _SEC) * int(blocks)
        lo = 0
        end = self.end_ns
        while lo < end:
            hi = min(end, lo + step)
            yield lo, hi, self.block(lo, hi, failures)
            lo = hi


class _KnownAt:
    """A solution whose ``at`` takes the gyro's samples at its interval ends where it can.

    The gyro evaluates the attitude at its interval ends (``Gyro.last_ends``: one
    ``solution.at`` a block, read first in a block); ``at`` of an array of times takes
    the rows of those samples whose times are the same, which are the bits
    ``solution.at`` gives at those times (a sample's bits depend on its time alone), and
    evaluates the others (off the gyro's grid, or its first end, kept from the block
    before). Everything else is the solution's.
    """

    def __init__(self, solution, gyro):
        self.solution, self.gyro = solution, gyro

    def __getattr__(self, name):
        return getattr(self.solution, name)

    def at(self, t):
        """Evaluate the exact motion at time(s) t, as the solution does: its Samples."""
        got = self.gyro.last_ends
        if got is None or type(t) is float or np.ndim(t) != 1 or not len(got[0]) \
                or not len(t):
            return self.solution.at(t)
        times = np.asarray(t, dtype=float)
        ends, s = got
        at = np.minimum(np.searchsorted(ends, times), len(ends) - 1)
        hit = ends[at] == times
        if not hit.any():
            return self.solution.at(t)
        at = at[hit]
        cols = [s.quaternion[at], s.omega[at], s.error_bound[at]]
        if not hit.all():
            rest = self.solution.at(times[~hit])
            for i, part in enumerate((rest.quaternion, rest.omega, rest.error_bound)):
                full = np.empty((len(times),) + cols[i].shape[1:], dtype=cols[i].dtype)
                full[hit], full[~hit] = cols[i], part
                cols[i] = full
        return type(s)(times, *cols)


def _sub(krange, rate, lo_ns, hi_ns):
    """Return the indices of ``krange`` whose grid offsets lie in ``[lo_ns, hi_ns)``."""
    a = _grid_count(rate, lo_ns, first=krange.start).stop if lo_ns > 0 else krange.start
    b = _grid_count(rate, hi_ns, first=krange.start).stop
    return range(max(a, krange.start), min(b, krange.stop))


def _order(parts):
    """Merge order of a block's messages: ``(part index, row)`` pairs.

    By log time, then true sample time, then the table's rank of the topic, then row:
    the order an executor that calls the node's timer at every due time publishes in.
    Where the parts' ranks differ (every run: a topic is one part of a block), the parts
    taken in rank order and sorted stably by (log time, true time) give that order (two
    sort keys instead of four).
    """
    if not parts:
        return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
    ranks = [p.rank for p in parts]
    if len(set(ranks)) < len(ranks):
        which = np.concatenate([np.full(len(p.stamps), i) for i, p in enumerate(parts)])
        row = np.concatenate([np.arange(len(p.stamps)) for p in parts])
        log = np.concatenate([p.log for p in parts])
        true = np.concatenate([p.true for p in parts])
        rank = np.concatenate([np.full(len(p.stamps), p.rank, dtype=float) for p in parts])
        order = np.lexsort((row, rank, true, log))
        return which[order], row[order]
    by = sorted(range(len(parts)), key=ranks.__getitem__)
    lens = [len(parts[i].stamps) for i in by]
    which = np.repeat(np.array(by, dtype=np.int64), lens)
    row = np.arange(sum(lens), dtype=np.int64) - np.repeat(np.cumsum([0] + lens[:-1]), lens)
    order = np.lexsort((np.concatenate([parts[i].true for i in by]),
                        np.concatenate([parts[i].log for i in by])))
    return which[order], row[order]


def _merged(parts, items):
    """Return a block's ``(topics, items, log times)`` lists in the order the node publishes.

    ``items[i]`` holds part i's messages (or payloads), one per sample.
    """
    which, rows = _order(parts)
    if not len(which):
        return [], [], []
    first = np.cumsum([0] + [len(p.stamps) for p in parts])
    pick = (first[which] + rows).tolist()
    flat = [x for part in items for x in part]
    names = [p.topic for p in parts for _ in range(len(p.stamps))]
    logs = np.concatenate([p.log for p in parts])[pick]
    get = operator.itemgetter(*pick)
    if len(pick) == 1:
        return [get(names)], [get(flat)], logs.tolist()
    return list(get(names)), list(get(flat)), logs.tolist()


def _messages(run, part):
    """Return one part's ROS messages (its kind's :meth:`Output.messages`)."""
    return part.output.messages(part.name, part.stamps, part.cols, run.frames)


def _serialized(run, part):
    """Return one part's CDR payloads, a list of ``bytes`` (its kind's :meth:`Output.encode`)."""
    return part.output.encode(part.name, part.stamps, part.cols, run.frames)


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
        Before the first message, for invalid parameters or arguments (one line); later,
        for a sample that cannot be evaluated.
    """
    run = _Run(values, duration_s, start_ns)
    return _iter(run)


def run_arrays(values, duration_s, start_ns=0, setup=None):
    """Return the run's samples as arrays, in memory: what :func:`iter_run` would publish.

    A dict by topic (``'/attitude'``, ``'/imu'``, ``'/star_tracker'``, ``'/mag'``, ...) of
    dicts: ``stamps_ns`` (header stamps), ``true_ns`` (true sample times), ``t`` (their
    scene times, s) and the data arrays the messages are built from, one row a sample
    (``'/attitude'``: ``q`` (x, y, z, w) ``q_NB``; ``'/imu'``: ``w`` rad/s, ``var`` its
    per-axis variance, with the accelerometer ``f`` m/s^2 and ``avar``; ``'/mag'``: ``m``
    tesla and ``cov``; ``'/star_tracker'``: ``q`` and ``cov``); and ``'run'``, the run
    description. The same samples, bit for bit, as the messages (read :data:`EVAL_BLOCKS`
    blocks at a time, as :func:`generate_bag` reads them), without building a message: for
    estimators fed in memory. ``setup``, if given, is what :func:`prepare_run` returned for
    ``values`` (a run checked already), used instead of preparing it again.
    """
    run = _Run(values, duration_s, start_ns, setup)
    parts = {}
    for _, _, block in run.blocks(EVAL_BLOCKS):
        for p in block:
            if p.topic != RUN_TOPIC:
                parts.setdefault(p.topic, []).append((p.stamps, p.true, p.cols))
    out = {'run': run.description()}
    for topic, got in parts.items():
        true = np.concatenate([c[1] for c in got])
        d = {'stamps_ns': np.concatenate([c[0] for c in got]), 'true_ns': true,
             't': np.asarray(scene_time(true, run.start_ns, run.time_scale), dtype=float)}
        for key in got[0][2]:
            d[key] = np.concatenate([np.asarray(c[2][key]) for c in got])
        out[topic] = d
    return out


def _iter(run):
    for _, _, parts in run.blocks():
        built = [_messages(run, p) for p in parts]
        for i, j in zip(*_order(parts)):
            yield parts[i].topic, int(parts[i].log[j]), built[i][j]


def iter_serialized(values, duration_s, names=None, start_ns=0):
    """Yield ``(topic, log_ns, cdr_bytes)`` of the run in log-time order: the bag, unwritten.

    The messages :func:`generate_bag` writes, in its order, serialized the same way, without
    the file (no compression, no index): for a program that plays the run at once.
    ``names`` keeps only the topics whose last name component is one of them (``('imu',
    'star_tracker', 'run')``: the sensors and the run description); the other parts are
    neither serialized nor merged. Arguments and errors as :func:`iter_run`.
    """
    run = _Run(values, duration_s, start_ns)
    keep = None if names is None else set(names)
    return _iter_serialized(run, keep)


def _iter_serialized(run, keep):
    for _, _, parts in run.blocks():
        if keep is not None:
            parts = [p for p in parts if p.topic.rsplit('/', 1)[-1] in keep]
        topics, datas, logs = _merged(parts, [_serialized(run, p) for p in parts])
        yield from zip(topics, logs, datas)


def _qos_yamls(p):
    """Return the offered QoS YAMLs as rosbag2 writes them: the outputs, and the latched."""
    return (qos_yaml(depth=int(p['qos_depth'])),
            qos_yaml(depth=1, durability='transient_local'))


def generate_bag(values, duration_s, out_dir, start_ns=0, progress=None):
    """Write the run's bag to ``out_dir`` (created; must not exist or be empty); its path.

    ``progress(done_s, total_s)`` (scene seconds), if given, is called after each block.
    A KeyboardInterrupt finishes the bag (summary, index, metadata.yaml) with what was
    written so far, then propagates. A sample that cannot be evaluated raises
    :class:`GenerationError` after the blocks before its own are written.

    The samples are evaluated :data:`EVAL_BLOCKS` blocks at a time, their records built
    in arrays (:mod:`rigidrot_ros.run.spans`), and each block written as one chunk (a
    chunk closes at its block's end or past 1 MiB of records) by
    :meth:`BagWriter.write_chunk`, which compresses and writes it on a thread of its own
    (zstd and the file write release the interpreter) while the next blocks are
    evaluated: the file of the block-by-block writer, byte for byte.
    """
    from concurrent.futures import ThreadPoolExecutor

    from rigidrot_ros.bag import BagWriter
    run = _Run(values, duration_s, start_ns)
    qos, latched = _qos_yamls(run.p)
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix='rigidrot_generate_chunks')
    try:
        # chunks cut by blocks, never by the wall clock: the same run gives the same file
        writer = BagWriter(None, 'attitude_node', flush_period=math.inf, path=out_dir,
                           split_seconds=0.0, offload=pool.submit,
                           max_pending=2 * EVAL_BLOCKS)
    except OSError as exc:
        pool.shutdown()
        raise GenerationError(f'cannot write the bag to {out_dir}: '
                              f'{" ".join(str(exc).split())}') from None
    stop = []
    previous = None
    if threading.current_thread() is threading.main_thread():
        # SIGINT between blocks, never inside a write: the bag is always finished whole
        previous = signal.signal(signal.SIGINT, lambda *_: stop.append(True))
    try:
        cids = {topic: writer.add_topic(topic, type_name, latched if is_latched else qos)
                for topic, type_name, is_latched, _ in run.topics}
        seq = dict.fromkeys(cids, 0)
        total = run.span_ns * 1e-9 * run.time_scale
        step = round(BLOCK_S * _SEC)
        failures = []
        for elo, ehi, parts in run.blocks(EVAL_BLOCKS, failures):
            span = spans.span_of(run, parts, cids, seq, _order(parts))
            del parts                           # only its records are written
            for lo in range(elo, ehi, step):
                hi = min(ehi, lo + step)
                failed = [e for at, e in failures if at < hi]
                if failed:                      # a sample of this block cannot be evaluated
                    raise failed[0]
                spans.write_block(writer, run, span, lo, hi)
                if progress is not None:
                    progress(min(hi, run.span_ns) * 1e-9 * run.time_scale, total)
                if stop:
                    break
            del span            # freed before the next span is evaluated: one span at a time
            if stop:
                break
    finally:
        try:
            writer.close()
        finally:
            pool.shutdown()
            if previous is not None:
                signal.signal(signal.SIGINT, previous)
    if stop:
        raise KeyboardInterrupt
    return writer.path
