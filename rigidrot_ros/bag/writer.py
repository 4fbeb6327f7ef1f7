"""A durable rosbag2-compatible MCAP writer.

The MCAP follows the ROS 2 profile: header profile ``ros2``, schemas ``pkg/msg/Type``
encoded ``ros2msg`` with their dependencies, messages ``cdr``, and every channel carries the
``offered_qos_profiles`` metadata rosbag2 writes. Chunks are zstd-compressed and are closed
at least every ``flush_period`` seconds, so a killed writer loses at most that much.
"""

import collections
import contextlib
import json
import os
import threading
import time

from mcap.writer import CompressionType, Writer
import numpy as np

from rigidrot_ros.bag import chunks
from rigidrot_ros.bag.metadata import (exact_bag_dir, MAX_PENDING_CHUNKS, new_bag_dir,
                                       qos_yaml, RUN_RECORD, uninterrupted,
                                       write_metadata_yaml)
from rigidrot_ros.msgs.msgdefs import schema_text


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
        :class:`rigidrot_ros.runtime.worker.BatchWorker`'s ``call``). Then closing a chunk
        (:meth:`flush`, :meth:`maybe_flush`, a chunk past its size) only detaches it on the
        caller's thread (its bytes, times and message indexes; the next messages go into a
        fresh chunk) and ``fn`` does the rest: zstd (which releases the interpreter), crc,
        the Chunk and MessageIndex records, the chunk index, the stream write and flush.
        The file is byte for byte what the inline writer writes: a detached chunk is
        written before anything written to the file after it (:meth:`add_metadata`, a
        split, :meth:`close` first write the chunks still queued, on the caller's thread).
        At most ``max_pending`` detached chunks wait; past that the caller writes them
        itself (a stalled disk makes it wait; memory stays bounded by about that many
        chunks). An ``offload`` that raises (a stopped worker raises RuntimeError) is
        bypassed: the chunk is written inline, never dropped. An error
        of an offloaded write (OSError: disk full) is raised by the caller's next
        :meth:`write`, :meth:`write_many`, :meth:`maybe_flush`, :meth:`flush`,
        :meth:`add_metadata` or :meth:`close`; what was written before it stays in the
        file. None (the default): every chunk is written inline, as always.
    on_wait : callable, optional
        Called on the caller's thread before it waits for an offloaded write in progress
        (e.g. a :class:`rigidrot_ros.runtime.gate.SlackGate`'s ``open``, so that a worker
        held by the gate finishes it).
    max_pending : int
        With ``offload``: detached chunks that may wait (default
        :data:`MAX_PENDING_CHUNKS`); past that the caller writes them itself.

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
                 offload=None, on_wait=None, max_pending=MAX_PENDING_CHUNKS):
        if path is not None:
            self.path = exact_bag_dir(os.path.abspath(path))
        else:
            os.makedirs(root, exist_ok=True)
            self.path = new_bag_dir(root, name.strip('/').replace('/', '_') or 'bag')
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
        self._max_pending = int(max_pending)
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

    def _begin(self, n):
        """Prepare for ``n`` messages; return whether there is anything to write.

        Raises an offloaded write's error not yet reported, and starts the next file of a
        split bag if one is due (only when ``n`` > 0).
        """
        if self._error is not None:
            self._raise_error()
        if n == 0:
            return False
        if self._roll_due:
            self._roll()
        return True

    def write(self, topic, data, log_time_ns, publish_time_ns=None):
        """Write one serialized (CDR) message."""
        self._begin(1)
        cid = self._channels[topic]
        self._writer.add_message(channel_id=cid, log_time=int(log_time_ns), data=bytes(data),
                                 publish_time=int(publish_time_ns or log_time_ns),
                                 sequence=self._counts[topic])
        self._counts[topic] += 1
        self._note_times(log_time_ns, log_time_ns, 1)

    def _note_times(self, t_lo, t_hi, count):
        """Note ``count`` messages logged between t_lo and t_hi (ns); flush if it is due."""
        self._first = t_lo if self._first is None else min(self._first, t_lo)
        self._last = t_hi if self._last is None else max(self._last, t_hi)
        f = self._per_file[self._files[-1]]
        f[0] = t_lo if f[0] is None else min(f[0], t_lo)
        f[1] = t_hi if f[1] is None else max(f[1], t_hi)
        f[2] += count
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
        if not self._begin(n):
            return
        log = np.asarray(log_times_ns, dtype=np.int64)
        cids = np.array([self._channels[t] for t in topics], dtype=np.int64)
        seq = self._sequence_numbers(topics, cids)
        sizes = np.fromiter(map(len, datas), dtype=np.int64, count=n)
        heads = chunks.message_heads(cids, seq, log, sizes)
        width = len(heads[0])                           # 31 bytes
        ends = np.cumsum(width + sizes)                 # record ends from the first
        writer = self._writer
        chunk = writer._Writer__chunk_builder
        limit = writer._Writer__chunk_size
        lo = 0
        while lo < n:
            base = chunk.count
            start = ends[lo - 1] if lo else 0
            # as write(): a chunk is finished right after the message that passes the limit
            over = np.flatnonzero(base + ends[lo:] - start > limit)
            hi = lo + int(over[0]) + 1 if len(over) else n
            offsets = base + np.concatenate([[0], ends[lo:hi - 1] - start])
            parts = [b''] * (2 * (hi - lo))
            parts[0::2] = heads[lo:hi]
            parts[1::2] = datas[lo:hi]
            chunks.add_records(writer, b''.join(parts), cids[lo:hi], log[lo:hi], offsets)
            writer._Writer__maybe_finalize_chunk()
            lo = hi
        self._note_times(int(log.min()), int(log.max()), n)

    @property
    def chunk_size(self):
        """Bytes of message records past which :meth:`write_many` closes a chunk."""
        return self._writer._Writer__chunk_size

    def channel_id(self, topic):
        """Return the channel id of ``topic`` (added by :meth:`add_topic`) in this file."""
        return self._channels[topic]

    def sequence(self, topic):
        """Return the sequence number of ``topic``'s next message (its messages so far)."""
        return self._counts[topic]

    @property
    def open_bytes(self):
        """Bytes in the open chunk: records written and not yet closed into a chunk.

        Schema and channel records count too (mcap puts them in the next chunk).
        """
        return self._writer._Writer__chunk_builder.count

    def write_chunk(self, records, cids, log_times_ns, offsets):
        """Append message records built by the caller to the open chunk, and close it.

        The bulk path of :meth:`write_many` then :meth:`flush`, with the same bytes:
        ``records`` (bytes-like) are MCAP Message records back to back, as a chunk holds
        them (:func:`.chunks.record_dtype`, :func:`.chunks.fill_records`); ``cids`` (n,)
        their channel ids
        (:meth:`channel_id`), ``log_times_ns`` (n,) their log times and ``offsets`` (n,)
        where each starts in ``records``. Their sequence numbers are the caller's: each
        channel's run on from :meth:`sequence`, in order. The chunk holds what was open
        before them (schema and channel records, messages of :meth:`write`), their
        message index per channel in order of first appearance, the statistics. The
        caller keeps the chunk size (:meth:`write_many` closes a chunk right after the
        record that takes it past :attr:`chunk_size`, counting :attr:`open_bytes`); with
        ``offload`` the compression and the file write go there.
        """
        cids = np.asarray(cids, dtype=np.int64)
        log = np.asarray(log_times_ns, dtype=np.int64)
        offsets = np.asarray(offsets, dtype=np.int64)
        n = len(cids)
        if not (len(log) == n == len(offsets)):
            raise ValueError('write_chunk needs one channel, one stamp and one offset per '
                             'record')
        if not self._begin(n):
            return
        by_cid = {cid: topic for topic, cid in self._channels.items()}

        def count(cid, k):
            self._counts[by_cid[cid]] += k
        item = chunks.close_with_records(self._writer, records, cids, log, offsets, count)
        if self._offload is None:
            chunks.write_detached(*item)
        else:
            self._pending.append(item)
            self._hand_over()
        self._note_times(item[2], item[3], n)
        self._closed_chunk()

    def _sequence_numbers(self, topics, cids):
        """Return each message's sequence number on its channel, and count them."""
        seq = np.empty(len(cids), dtype=np.int64)
        for topic in set(topics):
            mask = cids == self._channels[topic]
            seq[mask] = self._counts[topic] + np.arange(int(np.count_nonzero(mask)))
            self._counts[topic] += int(np.count_nonzero(mask))
        return seq

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
            chunks.pack_indexes(self._chunk_list)
        else:
            self._detach()
        self._closed_chunk()

    def _closed_chunk(self):
        """Note a flush: the clock of ``flush_period``, and a split that is due."""
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
        """Finish the MCAP (summary and index) and write the final metadata.yaml.

        Run to its end whatever signal arrives (:func:`metadata.uninterrupted`): a second
        Ctrl-C during it is raised after the bag is whole.
        """
        if self._closed:
            return
        uninterrupted(self._close)

    def _close(self):
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

        :func:`chunks.detach` takes the chunk out of the mcap writer (its builder stays
        empty for the next messages: :meth:`write_many` holds it).
        """
        item = chunks.detach(self._writer)
        if item is None:
            return
        self._pending.append(item)
        self._hand_over()

    def _hand_over(self):
        """Give the detached chunks to ``offload`` (past the bound: write them here)."""
        if len(self._pending) > self._max_pending:
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
                chunks.write_detached(*item)
            except Exception as exc:    # noqa: B902 - any error: raised on the caller's thread
                self._error = exc
                self._pending.popleft()
                return
            self._pending.popleft()

    def _write_metadata_yaml(self):
        write_metadata_yaml(self.path, list(self._files), self._topics, self._counts,
                            self._first, self._last,
                            {f: tuple(v) for f, v in self._per_file.items()})
