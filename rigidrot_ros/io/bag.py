"""rosbag2-compatible MCAP bags: a durable writer, a reader that survives a torn file, reindex.

A bag is a directory holding ``<dir>_0.mcap`` and a rosbag2 ``metadata.yaml`` (version 9),
so ``ros2 bag info`` and ``ros2 bag play`` accept it. The MCAP follows the ROS 2 profile:
header profile ``ros2``, schemas ``pkg/msg/Type`` encoded ``ros2msg`` with their
dependencies, messages ``cdr``, and every channel carries the ``offered_qos_profiles``
metadata rosbag2 writes. Chunks are zstd-compressed and are closed at least every
``flush_period`` seconds, so a killed writer loses at most that much.

Runs of the node are described twice: by MCAP metadata records named ``rigidrot_run``
(written by the node's own recorder) and by ``std_msgs/msg/String`` messages whose JSON
carries ``"rigidrot_run": 1`` (the node's transient-local ``~/run`` topic, which any
recorder keeps). :func:`read_bag` merges both into :attr:`BagContents.runs`.
"""

import collections
import contextlib
from dataclasses import dataclass, field
import datetime
import json
import os
import re
import struct
import threading
import time
import zlib

from mcap.data_stream import RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader, StreamReader
from mcap.records import Channel, Chunk, ChunkIndex, Message, MessageIndex, Metadata, Schema
from mcap.writer import CompressionType, IndexType, Writer
import numpy as np
import yaml
import zstandard

from rigidrot_ros.io.msgdefs import schema_text

__all__ = ['BagWriter', 'BagError', 'read_bag', 'BagContents', 'qos_yaml', 'RUN_RECORD',
           'bag_files', 'reindex', 'run_from_string', 'STRING_TYPE']

RUN_RECORD = 'rigidrot_run'
#: Chunks closed but not yet written that an offloading :class:`BagWriter` holds at most;
#: past it the caller writes them itself (waits for the disk).
MAX_PENDING_CHUNKS = 4
STRING_TYPE = 'std_msgs/msg/String'
MAGIC = b'\x89MCAP0\r\n'
_INFINITE = {'sec': 2147483647, 'nsec': 4294967295}


class BagError(ValueError):
    """A path that is not a readable bag, with the reason."""


def qos_yaml(depth=10, reliability='reliable', durability='volatile', history='keep_last'):
    """Return ``offered_qos_profiles`` as rosbag2 (Jazzy, v9) writes it: a YAML string."""
    profile = {
        'history': history, 'depth': int(depth), 'reliability': reliability,
        'durability': durability, 'deadline': dict(_INFINITE), 'lifespan': dict(_INFINITE),
        'liveliness': 'automatic', 'liveliness_lease_duration': dict(_INFINITE),
        'avoid_ros_namespace_conventions': False,
    }
    return yaml.safe_dump([profile], sort_keys=False)


def _unique_dir(root, name):
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime('%Y%m%dT%H%M%S_%fZ')
    base = os.path.join(root, f'{name}_{stamp}')
    path, n = base, 1
    while True:
        try:
            os.makedirs(path, exist_ok=False)        # never reuse: nothing is overwritten
            return path
        except FileExistsError:
            path = f'{base}_{n}'
            n += 1


def _exact_dir(path):
    if os.path.exists(path) and (not os.path.isdir(path) or os.listdir(path)):
        raise FileExistsError(f'{path} exists and is not an empty directory; nothing is '
                              f'overwritten: choose another output directory')
    os.makedirs(path, exist_ok=True)
    return path


class _PackedRecords:
    """Summary records kept as their bytes, in order (no Python object per record)."""

    __slots__ = ('data',)

    def __init__(self):
        self.data = bytearray()

    def add(self, record):
        builder = RecordBuilder()
        record.write(builder)
        self.data += builder.end()

    def write(self, builder):
        builder.write(bytes(self.data))


class _PackedIndex(MessageIndex):
    """A chunk's message index for one channel, written with one pack (not 2 per entry)."""

    def write(self, stream):
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(self.records) * 16)
        stream.write(np.array(self.records, dtype='<u8').tobytes())
        stream.finish_record()


class BagWriter:
    """Write a rosbag2-compatible MCAP bag directory.

    Parameters
    ----------
    root : str
        Directory under which a new bag directory ``<name>_<UTC time>`` is created.
    name : str
        Prefix of the bag directory (the node name).
    flush_period : float
        Seconds between forced chunk flushes: the most a hard kill can lose, provided
        :meth:`maybe_flush` is also called periodically when no message arrives.
    path : str, optional
        Write to exactly this directory instead (created; it must not exist or be empty).
    split_seconds : float
        Start a new file ``<dir>_<n>.mcap`` after this many seconds (a split bag, as
        rosbag2's ``--max-bag-duration`` writes it; 0 = never).
    offload : callable, optional
        ``offload(fn)`` runs ``fn()`` later on another thread (e.g. a
        :class:`rigidrot_ros.node.lookahead.BatchWorker`'s ``call``). Then closing a chunk
        (:meth:`flush`, :meth:`maybe_flush`, a chunk past its size) only detaches it on the
        caller's thread (its bytes, times and message indexes; the next messages go into a
        fresh chunk) and ``fn`` does the rest: zstd (which releases the interpreter), crc,
        the Chunk and MessageIndex records, the chunk index, the stream write and flush.
        The file is byte for byte what the inline writer writes: a detached chunk is
        written before anything written to the file after it (:meth:`add_metadata`, a
        split, :meth:`close` first write the chunks still queued, on the caller's thread).
        At most :data:`MAX_PENDING_CHUNKS` detached chunks wait; past that the caller
        writes them itself (a stalled disk makes it wait; memory stays bounded by about
        that many chunks). An ``offload`` that raises (a stopped worker raises
        RuntimeError) is bypassed: the chunk is written inline, never dropped. An error
        of an offloaded write (OSError: disk full) is raised by the caller's next
        :meth:`write`, :meth:`write_many`, :meth:`maybe_flush`, :meth:`flush`,
        :meth:`add_metadata` or :meth:`close`; what was written before it stays in the
        file. None (the default): every chunk is written inline, as always.
    on_wait : callable, optional
        Called on the caller's thread before it waits for an offloaded write in progress
        (e.g. a :class:`rigidrot_ros.node.lookahead.SlackGate`'s ``open``, so that a worker
        held by the gate finishes it).

    Notes
    -----
    Memory: an MCAP file's summary indexes every chunk, so a writer must keep one chunk
    index per flush until the file is finished (the mcap writer keeps each as an object of
    0.4 kB per channel). They are kept packed as bytes instead (about 225 bytes per chunk
    with 10 channels, 20x less; ``test_score.py`` holds it under 300), and a file is
    finished and a new one begun every ``split_seconds`` (default one hour: at most 9000
    chunks at the recorders' 0.4 s flush, about 2 MB), so a recording of any length runs
    in bounded memory.
    """

    def __init__(self, root, name, flush_period=0.5, path=None, split_seconds=3600.0,
                 offload=None, on_wait=None):
        if path is not None:
            self.path = _exact_dir(os.path.abspath(path))
        else:
            os.makedirs(root, exist_ok=True)
            self.path = _unique_dir(root, name.strip('/').replace('/', '_') or 'bag')
        self._base = os.path.basename(self.path)
        self._files = []                  # file names, in order
        self._per_file = {}               # file name -> [first_ns, last_ns, count]
        self._schemas = {}
        self._channels = {}
        self._topics = {}                 # topic -> (type, qos yaml)
        self._channel_args = {}           # topic -> (type, schema text, metadata)
        self._counts = {}
        self._first = None
        self._last = None
        self._flush_period = float(flush_period)
        self._split = float(split_seconds)
        self._last_flush = time.monotonic()
        self._dirty = False
        self._closed = False
        self._roll_due = False
        self._offload = offload
        self._on_wait = on_wait
        self._lock = threading.Lock()         # the file's records and stream (offload)
        self._pending = collections.deque()   # detached chunks, oldest first (offload)
        self._error = None                    # an offloaded write's error, not yet raised
        self._open_file()
        self._write_metadata_yaml()

    @property
    def file_name(self):
        """Name of the .mcap file being written."""
        return self._files[-1]

    def _open_file(self):
        name = f'{self._base}_{len(self._files)}.mcap'
        self._fh = open(os.path.join(self.path, name), 'xb')
        self._writer = Writer(self._fh, chunk_size=1 << 20, compression=CompressionType.ZSTD)
        self._writer.start(profile='ros2', library='rigidrot_ros')
        self._files.append(name)
        self._per_file[name] = [None, None, 0]
        self._file_started = time.monotonic()
        self._schemas = {}
        self._channels = {}
        for topic, (type_name, text, meta) in self._channel_args.items():
            self._register(topic, type_name, text, meta)
        self._chunk_list = getattr(self._writer, '_Writer__chunk_indices', None)
        if self._offload is not None:
            # a chunk past its size is detached too (mcap's add_message and write_many
            # call this name-mangled method; an instance attribute shadows it)
            self._writer._Writer__maybe_finalize_chunk = self._maybe_detach

    def add_topic(self, topic, type_name, qos=None, schema=None, metadata=None):
        """Register ``topic`` of ``pkg/msg/Type``; returns its channel id.

        ``metadata`` (optional) is the channel's whole metadata map, as read from another
        bag; otherwise it is ``offered_qos_profiles`` = ``qos`` (default: reliable,
        volatile, depth 10).
        """
        if topic in self._channels:
            return self._channels[topic]
        text = schema if schema is not None else (
            self._channel_args[topic][1] if topic in self._channel_args
            else schema_text(type_name))
        meta = dict(metadata) if metadata else {
            'offered_qos_profiles': qos or qos_yaml(), 'topic_type_hash': ''}
        meta.setdefault('offered_qos_profiles', qos or qos_yaml())
        cid = self._register(topic, type_name, text, meta)
        self._channel_args[topic] = (type_name, text, meta)
        self._topics[topic] = (type_name, meta['offered_qos_profiles'])
        self._counts.setdefault(topic, 0)
        return cid

    def _register(self, topic, type_name, text, meta):
        if type_name not in self._schemas:
            self._schemas[type_name] = self._writer.register_schema(
                name=type_name, encoding='ros2msg', data=text.encode('utf-8'))
        cid = self._writer.register_channel(
            topic=topic, message_encoding='cdr', schema_id=self._schemas[type_name],
            metadata=meta)
        self._channels[topic] = cid
        return cid

    def has_topic(self, topic):
        """Whether ``topic`` has a channel in this bag."""
        return topic in self._channels

    def write(self, topic, data, log_time_ns, publish_time_ns=None):
        """Write one serialized (CDR) message."""
        if self._error is not None:
            self._raise_error()
        if self._roll_due:
            self._roll()
        cid = self._channels[topic]
        self._writer.add_message(channel_id=cid, log_time=int(log_time_ns), data=bytes(data),
                                 publish_time=int(publish_time_ns or log_time_ns),
                                 sequence=self._counts[topic])
        self._counts[topic] += 1
        self._first = log_time_ns if self._first is None else min(self._first, log_time_ns)
        self._last = log_time_ns if self._last is None else max(self._last, log_time_ns)
        f = self._per_file[self._files[-1]]
        f[0] = log_time_ns if f[0] is None else min(f[0], log_time_ns)
        f[1] = log_time_ns if f[1] is None else max(f[1], log_time_ns)
        f[2] += 1
        self._dirty = True
        self.maybe_flush()

    def write_many(self, topics, datas, log_times_ns):
        """Write serialized (CDR) messages in order, as :meth:`write` one by one would.

        ``topics`` (one per message), ``datas`` (bytes) and ``log_times_ns`` (ints; the
        publish times are the log times) are sequences of one length. The message records
        are packed at once (numpy for the fixed fields) and go into the same chunks
        :meth:`write` would put them in (a chunk closes once it passes the writer's chunk
        size), with the same per-channel sequence numbers, message indexes and statistics;
        only :meth:`maybe_flush`'s clock is consulted once per call instead of per message.
        """
        n = len(datas)
        if not (len(topics) == n == len(log_times_ns)):
            raise ValueError('write_many needs one topic, one payload and one stamp per '
                             'message')
        if self._error is not None:
            self._raise_error()
        if n == 0:
            return
        if self._roll_due:
            self._roll()
        log = np.asarray(log_times_ns, dtype=np.int64)
        cids = np.array([self._channels[t] for t in topics], dtype=np.int64)
        seq = np.empty(n, dtype=np.int64)
        for topic in set(topics):
            mask = cids == self._channels[topic]
            seq[mask] = self._counts[topic] + np.arange(int(np.count_nonzero(mask)))
            self._counts[topic] += int(np.count_nonzero(mask))
        sizes = np.fromiter(map(len, datas), dtype=np.int64, count=n)
        head = np.zeros(n, dtype=np.dtype([('op', 'u1'), ('len', '<u8'), ('cid', '<u2'),
                                           ('seq', '<u4'), ('log', '<u8'), ('pub', '<u8')]))
        head['op'] = 0x05                               # MCAP Message record
        head['len'] = 22 + sizes
        head['cid'], head['seq'], head['log'], head['pub'] = cids, seq, log, log
        width = head.dtype.itemsize                     # 31 bytes
        heads = head.view(f'V{width}').tolist()         # each record's head, as bytes
        ends = np.cumsum(width + sizes)                 # record ends from the first
        writer = self._writer
        chunk = writer._Writer__chunk_builder
        stats = writer._Writer__statistics
        limit = writer._Writer__chunk_size
        lo = 0
        while lo < n:
            base = chunk.count
            start = ends[lo - 1] if lo else 0
            # as write(): a chunk is finished right after the message that passes the limit
            over = np.flatnonzero(base + ends[lo:] - start > limit)
            hi = lo + int(over[0]) + 1 if len(over) else n
            offsets = base + np.concatenate([[0], ends[lo:hi - 1] - start])
            times = log[lo:hi]
            parts = [b''] * (2 * (hi - lo))
            parts[0::2] = heads[lo:hi]
            parts[1::2] = datas[lo:hi]
            t_lo, t_hi = int(times.min()), int(times.max())
            if chunk.num_messages == 0:
                chunk.message_start_time = t_lo
            else:
                chunk.message_start_time = min(chunk.message_start_time, t_lo)
            chunk.message_end_time = max(chunk.message_end_time, t_hi)
            block = cids[lo:hi]
            for cid in dict.fromkeys(block.tolist()):       # in order of first appearance
                rows = np.flatnonzero(block == cid)
                index = chunk.message_indices.get(cid)
                if not index:
                    index = chunk.message_indices[cid] = _PackedIndex(channel_id=cid,
                                                                      records=[])
                index.records.extend(zip(times[rows].tolist(), offsets[rows].tolist()))
            chunk.num_messages += hi - lo
            chunk.record_writer.write(b''.join(parts))
            if stats.message_count == 0:
                stats.message_start_time = t_lo
            else:
                stats.message_start_time = min(stats.message_start_time, t_lo)
            stats.message_end_time = max(stats.message_end_time, t_hi)
            for cid, count in zip(*np.unique(cids[lo:hi], return_counts=True)):
                stats.channel_message_counts[int(cid)] += int(count)
            stats.message_count += hi - lo
            writer._Writer__maybe_finalize_chunk()
            lo = hi
        t_lo, t_hi = int(log.min()), int(log.max())
        self._first = t_lo if self._first is None else min(self._first, t_lo)
        self._last = t_hi if self._last is None else max(self._last, t_hi)
        f = self._per_file[self._files[-1]]
        f[0] = t_lo if f[0] is None else min(f[0], t_lo)
        f[1] = t_hi if f[1] is None else max(f[1], t_hi)
        f[2] += n
        self._dirty = True
        self.maybe_flush()

    def add_run(self, info):
        """Record a run (scene, start stamp, ...) as a ``rigidrot_run`` metadata record."""
        self.add_metadata(RUN_RECORD, {k: (v if isinstance(v, str) else json.dumps(v))
                                       for k, v in info.items()})

    def add_metadata(self, name, data):
        """Write an MCAP metadata record (a string map) and flush it to the file."""
        with self._exclusive():
            self._writer.add_metadata(name, dict(data))
            if self._offload is not None:
                self._fh.flush()
        self._dirty = True
        self.flush()

    def maybe_flush(self):
        """Flush if ``flush_period`` has passed since the last flush."""
        if self._error is not None:
            self._raise_error()
        if self._dirty and time.monotonic() - self._last_flush >= self._flush_period:
            self.flush()

    def flush(self):
        """Close the open chunk and push it to the operating system (or hand it to ``offload``)."""
        if self._closed:
            return
        if self._error is not None:
            self._raise_error()
        if self._offload is None:
            self._writer.flush()
            self._fh.flush()
            _pack_indexes(self._chunk_list)
        else:
            self._detach()
        self._dirty = False
        self._last_flush = time.monotonic()
        if (self._split > 0 and self._last_flush - self._file_started >= self._split
                and self._per_file[self._files[-1]][2]):
            self._roll_due = True           # the next message starts the next file

    def _roll(self):
        """Finish the current file and continue in the next one of the split bag."""
        self._roll_due = False
        with self._exclusive():
            self._writer.finish()
            self._fh.close()
            self._open_file()
        self._write_metadata_yaml()

    @property
    def counts(self):
        """Messages written per topic."""
        return dict(self._counts)

    @property
    def closed(self):
        """Whether :meth:`close` has run."""
        return self._closed

    def close(self):
        """Finish the MCAP (summary and index) and write the final metadata.yaml."""
        if self._closed:
            return
        self._closed = True
        error, self._error = self._error, None      # reported here, after the rest
        finished = False
        try:
            with self._exclusive():                 # the chunks in flight first
                self._writer.finish()
            finished = True
        except Exception:   # noqa: B902 - the first error is the one to report
            if error is None:
                raise
        finally:
            self._fh.close()
            self._pending.clear()                   # not written (an error): none later
        if finished:
            self._write_metadata_yaml()             # a finished file is described
        if error is not None:
            raise error

    # -- offload (chunks written off the caller's thread) ------------------------------------
    def _raise_error(self):
        error, self._error = self._error, None
        raise error

    @contextlib.contextmanager
    def _exclusive(self):
        """On the caller's thread: hold the file (the chunks in flight written first).

        Raises an offloaded write's error not yet reported. A no-op without ``offload``.
        """
        if self._offload is None:
            yield
            return
        if not self._lock.acquire(blocking=False):
            if self._on_wait is not None:
                self._on_wait()
            self._lock.acquire()
        try:
            self._write_held()
            if self._error is not None:
                self._raise_error()
            yield
        finally:
            self._lock.release()

    def _maybe_detach(self):
        """Detach the open chunk if it has passed the chunk size (mcap's own test)."""
        writer = self._writer
        if writer._Writer__chunk_builder.count > writer._Writer__chunk_size:
            self._detach()

    def _detach(self):
        """Close the open chunk on the caller's thread; its write goes to ``offload``.

        Takes the chunk builder's bytes (one copy), times and message indexes, and leaves
        the builder empty for the next messages (the same object: :meth:`write_many` holds
        it). The chunk count is mcap's statistics record's, as its own close counts it.
        """
        writer = self._writer
        chunk = writer._Writer__chunk_builder
        if chunk.num_messages == 0:
            return
        writer._Writer__statistics.chunk_count += 1
        self._pending.append((writer, chunk.end(), chunk.message_start_time,
                              chunk.message_end_time, chunk.message_indices))
        chunk.message_indices = {}
        chunk.message_start_time = chunk.message_end_time = 0
        chunk.num_messages = 0
        if len(self._pending) > MAX_PENDING_CHUNKS:
            with self._exclusive():                 # a stalled disk: the caller waits
                pass
            return
        try:
            self._offload(self._write_pending)
        except Exception:   # noqa: B902 - a stopped worker, or any: written here, not lost
            with self._exclusive():
                pass

    def _write_pending(self):
        """Write the detached chunks, oldest first (the offloaded call; any thread)."""
        with self._lock:
            self._write_held()

    def _write_held(self):
        # the lock is held: the chunks in order; a failed one is dropped (as inline, its
        # bytes may be half written) and its error kept for the caller; the rest wait
        while self._pending and self._error is None:
            item = self._pending[0]
            try:
                _write_chunk(*item)
            except Exception as exc:    # noqa: B902 - any error: raised on the caller's thread
                self._error = exc
                self._pending.popleft()
                return
            self._pending.popleft()

    def _write_metadata_yaml(self):
        write_metadata_yaml(self.path, list(self._files), self._topics, self._counts,
                            self._first, self._last,
                            {f: tuple(v) for f, v in self._per_file.items()})


def _pack_indexes(chunk_list):
    """Pack the mcap writer's new chunk indexes (``_Writer__chunk_indices``) into bytes."""
    if chunk_list is None:
        return
    if not chunk_list or not isinstance(chunk_list[0], _PackedRecords):
        chunk_list.insert(0, _PackedRecords())
    packed = chunk_list[0]
    for index in chunk_list[1:]:
        packed.add(index)
    del chunk_list[1:]


def _write_chunk(writer, data, start, end, indices):
    """Write a detached chunk into ``writer``'s file as mcap's own chunk close does.

    The same records in the same order as ``Writer.__finalize_chunk`` (mcap 1.6): the Chunk
    (zstd, crc of the uncompressed bytes), its MessageIndex records, the ChunkIndex kept
    for the summary (then packed), and the stream flushed to the operating system. zstd
    only: the compression :meth:`BagWriter._open_file` gives every file.
    """
    compressed = zstandard.compress(data)
    chunk = Chunk(compression='zstd', data=compressed, message_start_time=start,
                  message_end_time=end,
                  uncompressed_crc=zlib.crc32(data) if writer._Writer__enable_crcs else 0,
                  uncompressed_size=len(data))
    flush = writer._Writer__flush
    records = writer._Writer__record_builder
    stream = writer._Writer__stream
    flush()
    offset = stream.tell()
    chunk.write(records)
    index = ChunkIndex(message_start_time=start, message_end_time=end,
                       chunk_start_offset=offset, chunk_length=records.count,
                       message_index_offsets={}, message_index_length=0,
                       compression='zstd', compressed_size=len(compressed),
                       uncompressed_size=len(data))
    flush()
    index_start = stream.tell()
    if writer._Writer__index_types & IndexType.MESSAGE:
        for cid, message_index in indices.items():
            index.message_index_offsets[cid] = index_start + records.count
            message_index.write(records)
    index.message_index_length = records.count
    flush()
    chunk_list = writer._Writer__chunk_indices
    chunk_list.append(index)
    _pack_indexes(chunk_list)
    stream.flush()


def write_metadata_yaml(path, files, topics, counts, first, last, per_file=None):
    """Write a rosbag2 (v9) ``metadata.yaml`` into bag directory ``path`` atomically.

    ``topics`` maps topic -> (type, offered_qos_profiles YAML); ``counts`` topic -> count;
    ``per_file`` optionally maps file name -> (first_ns, last_ns, count).
    """
    start = first or 0
    duration = (last - first) if first is not None else 0
    total = sum(counts.values())
    if per_file is None:
        per_file = {files[0]: (first, last, total)} if files else {}
    info = {
        'version': 9,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': int(duration)},
        'starting_time': {'nanoseconds_since_epoch': int(start)},
        'message_count': total,
        'topics_with_message_count': [
            {'topic_metadata': {'name': t, 'type': ty, 'serialization_format': 'cdr',
                                'offered_qos_profiles': yaml.safe_load(q) or [],
                                'type_description_hash': ''},
             'message_count': counts.get(t, 0)}
            for t, (ty, q) in topics.items()],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': list(files),
        'files': [{'path': f,
                   'starting_time': {'nanoseconds_since_epoch':
                                     int(per_file.get(f, (0, 0, 0))[0] or 0)},
                   'duration': {'nanoseconds': int((per_file.get(f, (0, 0, 0))[1] or 0)
                                                   - (per_file.get(f, (0, 0, 0))[0] or 0))},
                   'message_count': int(per_file.get(f, (0, 0, 0))[2])}
                  for f in files],
        'custom_data': None,
        'ros_distro': 'jazzy',
    }
    tmp = os.path.join(path, 'metadata.yaml.tmp')
    with open(tmp, 'w', encoding='utf-8') as fh:
        yaml.safe_dump({'rosbag2_bagfile_information': info}, fh, sort_keys=False)
    os.replace(tmp, os.path.join(path, 'metadata.yaml'))


@dataclass
class BagContents:
    """Everything read from one bag, in log-time order."""

    path: str
    messages: list = field(default_factory=list)    # (topic, type, log_ns, pub_ns, data)
    topics: dict = field(default_factory=dict)      # topic -> (type, qos yaml, schema text)
    runs: list = field(default_factory=list)        # dicts from rigidrot_run records
    truncated: bool = False
    note: str = ''
    files: list = field(default_factory=list)       # the .mcap files read, in order
    channel_metadata: dict = field(default_factory=dict)   # topic -> channel metadata map
    metadata: list = field(default_factory=list)    # every (name, map) metadata record
    schemaless: list = field(default_factory=list)  # topics of channels with no schema


def _file_index(name):
    m = re.search(r'_(\d+)\.mcap$', name)
    return (int(m.group(1)) if m else -1, name)


def bag_files(path):
    """Return the .mcap files of a bag directory (in rosbag2 order), or ``[path]``.

    A directory's ``metadata.yaml``, where present, must be a rosbag2 metadata file; its
    ``relative_file_paths`` give the files and their order (a split bag). Without one, every
    ``.mcap`` of the directory is read, ordered by its ``_<n>.mcap`` index.

    Raises
    ------
    BagError
        Missing path, corrupt ``metadata.yaml``, a listed file missing, or no .mcap file.
    """
    if not os.path.exists(path):
        raise BagError(f'{path}: no such file or directory')
    if not os.path.isdir(path):
        return [path]
    present = sorted((f for f in os.listdir(path) if f.endswith('.mcap')), key=_file_index)
    meta_path = os.path.join(path, 'metadata.yaml')
    if os.path.exists(meta_path):
        listed = _listed_files(meta_path)
        missing = [f for f in listed if f not in present]
        if missing:
            raise BagError(f'{meta_path} lists {missing}, which the directory does not hold')
        unlisted = [f for f in present if f not in listed]
        if unlisted:
            raise BagError(f'{path}: holds {unlisted}, which metadata.yaml does not list '
                           f'(a different bag?); move them away or fix metadata.yaml')
        files = listed
    else:
        files = present
    if not files:
        raise BagError(f'{path}: a directory with no .mcap file is not a bag')
    return [os.path.join(path, f) for f in files]


def _listed_files(meta_path):
    """Return the file names a rosbag2 ``metadata.yaml`` lists; BagError if it is not one."""
    try:
        with open(meta_path, encoding='utf-8') as fh:
            meta = yaml.safe_load(fh)
        info = meta['rosbag2_bagfile_information']
        listed = info.get('relative_file_paths')
        if listed is None:
            listed = [f['path'] for f in info.get('files') or []]
        if not isinstance(listed, list) or not all(isinstance(f, str) for f in listed):
            raise TypeError('relative_file_paths is not a list of file names')
    except (yaml.YAMLError, KeyError, TypeError, AttributeError, UnicodeDecodeError,
            OSError) as exc:
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise BagError(f'{meta_path}: not a valid rosbag2 metadata file '
                       f'({type(exc).__name__}: {why}); move it away to read the .mcap '
                       f'files alone') from None
    return [os.path.basename(f) for f in listed]


def _decode_run(data):
    out = {}
    for k, v in data.items():
        try:
            out[k] = json.loads(v)
        except ValueError:
            out[k] = v
    return out


def run_from_string(data):
    """Return the run dict carried by a CDR ``std_msgs/String``, or None if it is not one."""
    data = bytes(data)
    if len(data) < 8:
        return None
    endian = '<' if data[1] in (1, 3) else '>'
    (n,) = struct.unpack(endian + 'I', data[4:8])
    try:
        text = data[8:8 + n].rstrip(b'\x00').decode('utf-8')
        run = json.loads(text)
    except (UnicodeDecodeError, ValueError):
        return None
    if not isinstance(run, dict) or RUN_RECORD not in run:
        return None
    return run


def _read_indexed(fpath, out):
    """Read a finished file through its summary; False if it has none (torn, unfinished)."""
    part = BagContents(path=fpath)
    try:
        with open(fpath, 'rb') as fh:
            reader = make_reader(fh)
            summary = reader.get_summary()
            if summary is None:
                return False
            for channel in summary.channels.values():
                _note(part, summary.schemas.get(channel.schema_id), channel)
            for rec in reader.iter_metadata():
                part.metadata.append((rec.name, dict(rec.metadata)))
            for schema, channel, msg in reader.iter_messages(log_time_order=True):
                if schema is None:
                    continue                  # no schema: noted above, not read
                part.messages.append((channel.topic, schema.name, msg.log_time,
                                      msg.publish_time, msg.data))
    except (McapError, struct.error, EOFError, ValueError, KeyError, OSError):
        return False
    _merge(out, part)
    return True


def _read_stream(fpath, out):
    """Read records in file order up to the last complete one; returns a note."""
    part = BagContents(path=fpath)
    schemas, channels = {}, {}
    note = ''
    with open(fpath, 'rb') as fh:
        try:
            for rec in StreamReader(fh, skip_magic=False, emit_chunks=False).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
                    _note(part, schemas.get(rec.schema_id), rec)
                elif isinstance(rec, Message):
                    ch = channels.get(rec.channel_id)
                    sc = schemas.get(ch.schema_id) if ch else None
                    if ch is None or sc is None:
                        continue              # unknown channel, or one with no schema
                    _note(part, sc, ch)
                    part.messages.append((ch.topic, sc.name, rec.log_time, rec.publish_time,
                                          rec.data))
                elif isinstance(rec, Metadata):
                    part.metadata.append((rec.name, dict(rec.metadata)))
            note = 'no summary section, but all records read'
        except Exception as exc:  # the tear: EndOfFile, struct.error, zstd errors...
            part.truncated = True
            note = f'read up to the last complete record ({type(exc).__name__})'
    if not part.messages and not part.metadata and not part.topics:
        raise BagError(f'{fpath}: MCAP file with no readable records ({note})')
    part.messages.sort(key=lambda m: m[2])
    _merge(out, part)
    return note


def _merge(out, part):
    for t, v in part.topics.items():
        if t in out.topics and out.topics[t][0] != v[0]:
            raise BagError(f'{part.path}: topic {t} is {v[0]} here but {out.topics[t][0]} '
                           f'in an earlier file of the bag')
        out.topics.setdefault(t, v)
    for t, v in part.channel_metadata.items():
        out.channel_metadata.setdefault(t, v)
    out.messages.extend(part.messages)
    out.metadata.extend(part.metadata)
    out.schemaless.extend(t for t in part.schemaless if t not in out.schemaless)
    out.truncated = out.truncated or part.truncated


def read_bag(path):
    """Read a bag directory (every file of a split bag, in order) or one .mcap file.

    A torn file (a killed writer) is read up to its last complete record and the
    contents are marked ``truncated`` with a ``note``.

    Raises
    ------
    BagError
        The path is missing, not MCAP, has a corrupt metadata.yaml, or holds no records.
    """
    files = bag_files(path)
    for fpath in files:
        with open(fpath, 'rb') as fh:
            magic = fh.read(8)
        if magic != MAGIC:
            raise BagError(f'{fpath}: not an MCAP file (bad magic {magic[:8]!r})')
    out = BagContents(path=files[0] if len(files) == 1 else path, files=list(files))
    notes = []
    for fpath in files:
        if not _read_indexed(fpath, out):
            notes.append((f'{os.path.basename(fpath)}: ' if len(files) > 1 else '')
                         + 'unfinished file, ' + _read_stream(fpath, out))
    if out.schemaless:
        notes.append(_schemaless_note(out.schemaless))
    out.note = '; '.join(notes)
    if len(files) > 1:
        out.messages.sort(key=lambda m: m[2])
    out.runs = _collect_runs(out)
    return out


def _collect_runs(bag):
    runs, seen = [], set()

    def add(run):
        key = (str(run.get('node', '')), int(run.get('start_ns', -1)), run.get('run'))
        if key not in seen:
            seen.add(key)
            runs.append(run)
    for name, data in bag.metadata:
        if name == RUN_RECORD:
            add(_decode_run(data))
    for topic, type_name, _, _, data in bag.messages:
        if type_name == STRING_TYPE:
            run = run_from_string(data)
            if run is not None and 'start_ns' in run:
                add(run)
    return runs


def _schemaless_note(topics):
    return (f'channel(s) {sorted(topics)} have no schema (legal MCAP, but no type to decode '
            f'them with): skipped')


def _note(out, schema, channel):
    """Note the topic of ``channel``; a channel with no schema (id 0) is listed apart."""
    if schema is None:
        if channel.topic not in out.schemaless:
            out.schemaless.append(channel.topic)
        return
    if channel.topic not in out.topics:
        out.topics[channel.topic] = (schema.name,
                                     channel.metadata.get('offered_qos_profiles', ''),
                                     schema.data.decode('utf-8', 'replace'))
        out.channel_metadata[channel.topic] = dict(channel.metadata)


def reindex(path, backup=True):
    """Rewrite a torn bag (killed writer) into a finished one, like ``ros2 bag reindex``.

    Every complete record of every file is kept: schemas, channels with their metadata,
    metadata records (the run descriptions), messages in their file order. Each file is
    rewritten in place with a summary, an index and the end magic, and ``metadata.yaml``
    is rebuilt with the true counts and times. With ``backup`` the original file is kept
    beside it as ``<file>.orig`` (no ``.mcap`` ending, so it is not read as part of the
    bag). A finished file is left as it is. The files are those ``metadata.yaml`` lists;
    only when it is missing or unreadable are they the directory's ``<dir>_<n>.mcap``
    (any other ``.mcap`` there is left alone, with a note).

    Parameters
    ----------
    path : str
        A bag directory (or a single .mcap file: then no metadata.yaml is written).
    backup : bool
        Keep each rewritten original as ``<file>.orig``.

    Returns
    -------
    dict
        ``{'files': [...], 'rewritten': [...], 'counts': {topic: n}, 'notes': [...]}``.

    Raises
    ------
    BagError
        Not a bag, not MCAP, or nothing readable.
    """
    if os.path.isdir(path) and not any(f.endswith('.mcap') for f in os.listdir(path)):
        raise BagError(f'{path}: a directory with no .mcap file is not a bag')
    notes = []
    if os.path.isdir(path):
        files = _reindex_files(path, notes)
    else:
        files = bag_files(path)
    topics, counts, per_file, rewritten = {}, {}, {}, []
    first = last = None
    for fpath in files:
        with open(fpath, 'rb') as fh:
            magic = fh.read(8)
        if magic != MAGIC:
            raise BagError(f'{fpath}: not an MCAP file (bad magic {magic[:8]!r})')
        part = BagContents(path=fpath)
        if not _read_indexed(fpath, part):
            notes.append(f'{os.path.basename(fpath)}: ' + _read_stream(fpath, part))
            _rewrite(fpath, part, backup)
            rewritten.append(fpath)
        if part.schemaless:
            notes.append(f'{os.path.basename(fpath)}: ' + _schemaless_note(part.schemaless)
                         + (' (not kept in the rewrite; the original is '
                            + ('kept as .orig)' if backup else 'gone: --no-backup)')
                            if fpath in rewritten else ''))
        for t, (ty, q, _) in part.topics.items():
            topics.setdefault(t, (ty, q))
        n = 0
        lo = hi = None
        for m in part.messages:
            counts[m[0]] = counts.get(m[0], 0) + 1
            n += 1
            lo = m[2] if lo is None else min(lo, m[2])
            hi = m[2] if hi is None else max(hi, m[2])
        per_file[os.path.basename(fpath)] = (lo, hi, n)
        if lo is not None:
            first = lo if first is None else min(first, lo)
            last = hi if last is None else max(last, hi)
    if os.path.isdir(path):
        write_metadata_yaml(path, [os.path.basename(f) for f in files], topics, counts,
                            first, last, per_file)
    return {'files': files, 'rewritten': rewritten, 'counts': counts, 'notes': notes}


def _reindex_files(path, notes):
    """Return the files of bag directory ``path`` to reindex.

    A readable ``metadata.yaml`` gives them (as for reading: a listed file missing, or an
    unlisted ``.mcap``, is refused). Only when it is missing or unreadable (it is what
    reindex rebuilds; a broken one is kept as ``metadata.yaml.orig``) are the files taken
    from the directory, and then only those named ``<dir>_<n>.mcap``, as rosbag2 names
    them: another ``.mcap`` lying there is no part of the bag and is left alone.
    """
    meta = os.path.join(path, 'metadata.yaml')
    if os.path.exists(meta):
        try:
            _listed_files(meta)
        except BagError as exc:
            notes.append(f'{exc}; rebuilt from the files named <dir>_<n>.mcap')
        else:
            return bag_files(path)
    base = os.path.basename(os.path.normpath(path))
    own = re.compile(re.escape(base) + r'_\d+\.mcap')
    present = sorted((f for f in os.listdir(path) if f.endswith('.mcap')), key=_file_index)
    names = [f for f in present if own.fullmatch(f)]
    if not names:
        raise BagError(f'{path}: no readable metadata.yaml and no file named {base}_<n>.mcap '
                       f'(it holds {present}); rename its files to {base}_0.mcap, ... '
                       f'or restore its metadata.yaml')
    others = [f for f in present if f not in names]
    if others:
        notes.append(f'{others}: not named {base}_<n>.mcap, so no part of the bag: left '
                     f'as they are (move them away to read the bag)')
    if os.path.exists(meta):
        os.replace(meta, meta + '.orig')
    return [os.path.join(path, f) for f in names]


def _rewrite(fpath, part, backup):
    tmp = fpath + '.reindex.tmp'
    with open(tmp, 'wb') as fh:
        w = Writer(fh, chunk_size=1 << 20, compression=CompressionType.ZSTD)
        w.start(profile='ros2', library='rigidrot_ros reindex')
        sids, cids, seq = {}, {}, {}
        for topic, (type_name, _, text) in part.topics.items():
            if type_name not in sids:
                sids[type_name] = w.register_schema(name=type_name, encoding='ros2msg',
                                                    data=text.encode('utf-8'))
            cids[topic] = w.register_channel(topic=topic, message_encoding='cdr',
                                             schema_id=sids[type_name],
                                             metadata=part.channel_metadata.get(topic, {}))
        for name, data in part.metadata:
            w.add_metadata(name, data)
        for topic, _, log_ns, pub_ns, data in part.messages:
            n = seq.get(topic, 0)
            w.add_message(channel_id=cids[topic], log_time=log_ns, publish_time=pub_ns,
                          data=data, sequence=n)
            seq[topic] = n + 1
        w.finish()
    # check the rewrite before it replaces anything
    check = BagContents(path=tmp)
    if not _read_indexed(tmp, check) or len(check.messages) != len(part.messages):
        os.remove(tmp)
        raise BagError(f'{fpath}: the rewritten file did not read back whole; nothing changed')
    if backup:
        os.replace(fpath, fpath + '.orig')
    os.replace(tmp, fpath)
