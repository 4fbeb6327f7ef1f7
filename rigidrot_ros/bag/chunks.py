"""MCAP chunks below the mcap writer's API: message records in bulk, a chunk closed apart.

The fast paths of :class:`~rigidrot_ros.bag.writer.BagWriter` work on the open chunk of an
``mcap.writer.Writer`` (mcap 1.6) directly, and every function here keeps the bytes the
writer itself would write: message records packed with numpy (:data:`MESSAGE_HEAD`,
:func:`record_dtype`, :func:`fill_records`, :func:`message_heads`) and appended with their
message indexes and statistics (:func:`add_records`); the open chunk detached on the
caller's thread (:func:`detach`, :func:`close_with_records`) and written later, on any
thread, as mcap's own chunk close writes it (:func:`write_detached`: zstd, crc, the Chunk,
MessageIndex and ChunkIndex records); the summary's chunk indexes kept packed as bytes
(:func:`pack_indexes`); the records of several channels placed straight into one buffer at
their final offsets, head and payload, by one compiled loop per channel
(:func:`place_records`, :func:`place_batch`).
"""

import struct
import threading
import zlib

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Chunk, ChunkIndex, MessageIndex
from mcap.writer import IndexType
import numpy as np
import zstandard


#: An MCAP Message record's head: opcode, record length, channel, sequence, log and
#: publish times (31 bytes, packed, little endian); the payload follows.
MESSAGE_HEAD = np.dtype([('op', 'u1'), ('len', '<u8'), ('cid', '<u2'), ('seq', '<u4'),
                         ('log', '<u8'), ('pub', '<u8')])


def record_dtype(sizes):
    """Return the packed dtype of one row of message records, one per payload size.

    Row field ``m<j>`` is message j's record: a :data:`MESSAGE_HEAD` then ``data``
    (``sizes[j]`` bytes), the records back to back (an MCAP chunk's layout). An array of
    such rows laid out in memory is the records of its rows' messages in row order.
    """
    fields, offset = {}, 0
    for j, size in enumerate(sizes):
        one = np.dtype(MESSAGE_HEAD.descr + [('data', 'u1', (int(size),))])
        fields[f'm{j}'] = (one, offset)
        offset += one.itemsize
    return np.dtype({'names': list(fields), 'formats': [f[0] for f in fields.values()],
                     'offsets': [f[1] for f in fields.values()], 'itemsize': offset})


def fill_records(rows, j, cid, seq0, log_ns, payloads):
    """Fill message j of each row of ``rows`` (a :func:`record_dtype` array) in place.

    ``cid`` the channel, ``seq0`` the sequence number of the first row's message (the next
    rows count up), ``log_ns`` (n,) the log times (the publish times too), ``payloads``
    ``(n, size)`` uint8: the serialized messages.
    """
    rec = rows[f'm{j}']
    n = len(rows)
    size = payloads.shape[1]
    rec['op'] = Opcode.MESSAGE
    rec['len'] = 22 + size
    rec['cid'] = cid
    rec['seq'] = np.arange(seq0, seq0 + n, dtype=np.int64)
    rec['log'] = log_ns
    rec['pub'] = log_ns
    rec['data'] = payloads


def _put_head(buf, d, rec, seq, t):
    """Write a Message record's head (``rec``: its first 11 bytes set) at ``buf[d:]``.

    The sequence number ``seq``, the log time ``t`` and the publish time (the same);
    returns where the payload goes.
    """
    for b in range(4):
        rec[11 + b] = (seq >> (8 * b)) & 255
    for b in range(8):
        x = (t >> (8 * b)) & 255
        rec[15 + b] = x                         # log time
        rec[23 + b] = x                         # publish time (the same)
    for b in range(np.uint64(31)):
        buf[d + b] = rec[b]
    return d + np.uint64(31)


def _place(buf, dst, payload, head, seq0, log, rec):
    """Write message records into ``buf``: row r's at ``dst[r]`` (see :func:`place_records`).

    ``rec``: 31 bytes of scratch (a record's head; the kernel allocates nothing). The byte
    loops index with unsigned integers: numba then drops its negative-index checks and
    copies a payload as fast as memcpy (ten times faster than signed).
    """
    n = payload.shape[0]
    size = np.uint64(payload.shape[1])
    for b in range(11):
        rec[b] = head[b]                        # opcode, record length, channel
    for r in range(n):
        d = _put_head(buf, np.uint64(dst[r]), rec, seq0 + r, log[r])
        for b in range(size):
            buf[d + b] = payload[r, b]


def _place_plan(buf, dst, head, seq0, log, row, sec, nsec, raw, slots, rec):
    """Write message records into ``buf`` from a CDR plan (see :func:`place_batch`)."""
    n = raw.shape[0]
    size = np.uint64(row.shape[0])
    m = slots.shape[0]
    for b in range(11):
        rec[b] = head[b]
    for r in range(n):
        d = _put_head(buf, np.uint64(dst[r]), rec, seq0 + r, log[r])
        for b in range(size):
            buf[d + b] = row[b]
        s, ns = sec[r], nsec[r]
        for b in range(4):
            buf[d + np.uint64(4 + b)] = (s >> (8 * b)) & 255
            buf[d + np.uint64(8 + b)] = (ns >> (8 * b)) & 255
        for j in range(m):
            at = d + np.uint64(slots[j])
            for b in range(8):
                buf[at + np.uint64(b)] = raw[r, 8 * j + b]


_PLACE = {}


def _u1(ndim=1, out=False):
    return ('u1', ndim, None if ndim == 2 else 0, out)


_I8 = ('i8', 1, 0, False)
#: The placers' Python arguments and result, as :mod:`rigidrot_ros.runtime.native` loads
#: them (the interpreter released during the loop, as numba's ``nogil``).
_NATIVE = {
    'records': ([_u1(out=True), _I8, _u1(2), _u1(), 'i', _I8, _u1(out=True)], 'int', True),
    'plan': ([_u1(out=True), _I8, _u1(), 'i', _I8, _u1(), _I8, _I8, _u1(2), _I8,
              _u1(out=True)], 'int', True)}


def _c_placers():
    """Compile both placers as C functions (numba imported): ``{name: (cfunc, *how)}``."""
    import numba
    from numba import carray
    from rigidrot_ros.runtime.native import c_signature
    flags = dict(error_model='numpy')
    g = globals()
    g['_put_head'] = numba.njit(**flags)(getattr(g['_put_head'], 'py_func', g['_put_head']))
    records, plan = (numba.njit(**flags)(f) for f in (_place, _place_plan))

    @numba.cfunc(c_signature(*_NATIVE['records'][:2]), **flags)
    def c_records(buf, nbuf, dst, ndst, pay, n0, n1, head, nhead, seq0, log, nlog, rec, nrec):
        records(carray(buf, (nbuf,)), carray(dst, (ndst,)), carray(pay, (n0, n1)),
                carray(head, (nhead,)), seq0, carray(log, (nlog,)), carray(rec, (nrec,)))
        return 0

    @numba.cfunc(c_signature(*_NATIVE['plan'][:2]), **flags)
    def c_plan(buf, nbuf, dst, ndst, head, nhead, seq0, log, nlog, row, nrow, sec, nsec,
               ns, nns, raw, r0, r1, slots, nslots, rec, nrec):
        plan(carray(buf, (nbuf,)), carray(dst, (ndst,)), carray(head, (nhead,)), seq0,
             carray(log, (nlog,)), carray(row, (nrow,)), carray(sec, (nsec,)),
             carray(ns, (nns,)), carray(raw, (r0, r1)), carray(slots, (nslots,)),
             carray(rec, (nrec,)))
        return 0

    return {'records': (c_records, *_NATIVE['records']), 'plan': (c_plan, *_NATIVE['plan'])}


def _native_placers():
    """Both placers loaded as object code (:mod:`rigidrot_ros.runtime.native`), or None."""
    from rigidrot_ros.runtime import native, switches
    if switches.no_jit() or switches.no_native():
        return None
    try:
        return native.load_kernels(__file__, 'chunks', _c_placers)[0]
    except native.NativeError:
        return None             # numba's own load, below


def _placer(name='records'):
    """Return :func:`_place` (``'plan'``: :func:`_place_plan`) compiled, or None.

    Loaded as object code where it can be (:mod:`rigidrot_ros.runtime.native`), else
    compiled by numba (cached on disk), once a process; None without numba (or with the
    core's ``RIGIDROT_NO_JIT``).
    """
    if name not in _PLACE:
        if 'native' not in _PLACE:
            _PLACE['native'] = _native_placers()
        if _PLACE['native'] is not None:
            _PLACE[name] = _PLACE['native'][name]
            return _PLACE[name]
        from rigidrot_ros.runtime import switches
        fn = None
        if not switches.no_jit():
            try:
                import numba
            except ImportError:
                pass
            else:
                py = _place if name == 'records' else _place_plan
                head = globals()['_put_head']
                head = getattr(head, 'py_func', head)
                try:
                    globals()['_put_head'] = numba.njit(cache=True, nogil=True)(head)
                    fn = numba.njit(cache=True, nogil=True)(py)
                except Exception:   # noqa: B902 - no writable cache: compiled in memory
                    globals()['_put_head'] = numba.njit(nogil=True)(head)
                    fn = numba.njit(nogil=True)(py)
                _warm(name, fn)
        _PLACE[name] = fn
    return _PLACE[name]


def _warm(name, fn):
    """Compile or load ``fn`` now, for the argument types of its callers.

    Through :func:`rigidrot_ros.runtime.jit.cached_load`: a cache load without numba's
    compiler registries, and no BLAS probe (nothing here calls one).
    """
    from rigidrot_ros.runtime.jit import cached_load
    buf, one = np.zeros(64, dtype=np.uint8), np.zeros(1, dtype=np.int64)
    head, rec = np.zeros(11, dtype=np.uint8), np.empty(31, dtype=np.uint8)
    with cached_load():
        if name == 'records':
            fn(buf, one, np.zeros((1, 2), dtype=np.uint8), head, 0, one, rec)
            return
        raw = np.zeros((1, 8), dtype=np.uint8)
        for row in (np.zeros(2, dtype=np.uint8), np.frombuffer(bytes(2), dtype=np.uint8)):
            fn(buf, one, head, 0, one, row, one, one, raw, np.zeros(1, dtype=np.int64), rec)


def can_place():
    """Whether :func:`place_records` runs compiled (numba); else callers take another way."""
    return _placer() is not None and _placer('plan') is not None


def _head(cid, size):
    """Return the 11 constant bytes of a Message record's head: opcode, length, channel."""
    head = np.empty(11, dtype=np.uint8)
    head[0] = Opcode.MESSAGE
    head[1:9] = np.array([22 + size], dtype='<u8').view(np.uint8)
    head[9:11] = np.array([cid], dtype='<u2').view(np.uint8)
    return head


def place_records(buf, dst, cid, seq0, log, payloads):
    """Write n MCAP Message records of one channel into ``buf`` (uint8) at offsets ``dst``.

    Record r is at ``buf[dst[r]:dst[r] + 31 + size]``: its head (channel ``cid``, sequence
    ``seq0 + r``, log and publish time ``log[r]``) then ``payloads[r]`` (``(n, size)``
    uint8, the serialized messages): the bytes :func:`fill_records` gives a row's record.
    Compiled (:func:`can_place`); the caller keeps the records within ``buf``.
    """
    payloads = np.ascontiguousarray(payloads, dtype=np.uint8)
    _placer()(buf, np.ascontiguousarray(dst, dtype=np.int64), payloads,
              _head(cid, payloads.shape[1]), int(seq0),
              np.ascontiguousarray(log, dtype=np.int64), np.empty(31, dtype=np.uint8))


def place_batch(buf, dst, cid, seq0, log, batch):
    """:func:`place_records` of a :class:`rigidrot_ros.msgs.cdr.Batch`'s messages.

    A batch with its plan is written from it (its row, stamps and values straight into
    ``buf``: the bytes its :attr:`~rigidrot_ros.msgs.cdr.Batch.data` holds, without
    building them); another from its ``data``.
    """
    if not batch.planned:
        return place_records(buf, dst, cid, seq0, log, batch.data)
    values, slots = batch.plan()
    _placer('plan')(buf, np.ascontiguousarray(dst, dtype=np.int64),
                    _head(cid, batch.size), int(seq0),
                    np.ascontiguousarray(log, dtype=np.int64), batch.row,
                    np.ascontiguousarray(batch.sec, dtype=np.int64),
                    np.ascontiguousarray(batch.nsec, dtype=np.int64),
                    values.view(np.uint8), slots, np.empty(31, dtype=np.uint8))


def message_heads(cids, seq, log, sizes):
    """Return each MCAP Message record's head (opcode to publish time) as bytes."""
    head = np.zeros(len(cids), dtype=np.dtype([('op', 'u1'), ('len', '<u8'), ('cid', '<u2'),
                                               ('seq', '<u4'), ('log', '<u8'),
                                               ('pub', '<u8')]))
    head['op'] = 0x05                               # MCAP Message record
    head['len'] = 22 + sizes
    head['cid'], head['seq'], head['log'], head['pub'] = cids, seq, log, log
    width = head.dtype.itemsize                     # 31 bytes
    return head.view(f'V{width}').tolist()


class PackedRecords:
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


class PackedIndex(MessageIndex):
    """A chunk's message index for one channel, written with one pack (not 2 per entry)."""

    def write(self, stream):
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(self.records) * 16)
        stream.write(np.array(self.records, dtype='<u8').tobytes())
        stream.finish_record()


class RawIndex:
    """A chunk's message index for one channel, as its finished record bytes."""

    __slots__ = ('data',)

    def __init__(self, data):
        self.data = data

    def write(self, stream):
        stream.write(self.data)


def add_records(writer, records, block, times, offsets):
    """Append packed message records to ``writer``'s open chunk: indexes, statistics.

    ``block``: their channel ids, ``times``: log times, ``offsets``: where each record
    starts in the chunk.
    """
    chunk = writer._Writer__chunk_builder
    stats = writer._Writer__statistics
    t_lo, t_hi = int(times.min()), int(times.max())
    if chunk.num_messages == 0:
        chunk.message_start_time = t_lo
    else:
        chunk.message_start_time = min(chunk.message_start_time, t_lo)
    chunk.message_end_time = max(chunk.message_end_time, t_hi)
    for cid in dict.fromkeys(block.tolist()):       # in order of first appearance
        rows = np.flatnonzero(block == cid)
        index = chunk.message_indices.get(cid)
        if not index:
            index = chunk.message_indices[cid] = PackedIndex(channel_id=cid, records=[])
        index.records.extend(zip(times[rows].tolist(), offsets[rows].tolist()))
    chunk.num_messages += len(block)
    chunk.record_writer.write(records)
    if stats.message_count == 0:
        stats.message_start_time = t_lo
    else:
        stats.message_start_time = min(stats.message_start_time, t_lo)
    stats.message_end_time = max(stats.message_end_time, t_hi)
    for cid, count in zip(*np.unique(block, return_counts=True)):
        stats.channel_message_counts[int(cid)] += int(count)
    stats.message_count += len(block)


def detach(writer):
    """Take ``writer``'s open chunk out of it; return it, or None if it holds no message.

    Returns ``(writer, bytes, start, end, message indexes)``, what :func:`write_detached`
    writes: the chunk builder's bytes (one copy), times and message indexes. The builder is
    left empty for the next messages (the same object: a caller may hold it). The chunk
    count is mcap's statistics record's, as its own close counts it.
    """
    chunk = writer._Writer__chunk_builder
    if chunk.num_messages == 0:
        return None
    writer._Writer__statistics.chunk_count += 1
    item = (writer, chunk.end(), chunk.message_start_time, chunk.message_end_time,
            chunk.message_indices)
    chunk.message_indices = {}
    chunk.message_start_time = chunk.message_end_time = 0
    chunk.num_messages = 0
    return item


def _frozen(records):
    """Whether ``records`` can be kept as is: ``bytes``, or a memoryview of ``bytes``.

    Or of a read-only numpy array that owns its data (nothing can write it any more: the
    buffers of :func:`place_records` once filled).
    """
    if isinstance(records, bytes):
        return True
    if not isinstance(records, memoryview) or not records.contiguous:
        return False
    obj = records.obj
    return isinstance(obj, bytes) or (isinstance(obj, np.ndarray) and obj.base is None
                                      and not obj.flags.writeable)


def close_with_records(writer, records, cids, log, offsets, count):
    """Close ``writer``'s open chunk with message records appended; return it, detached.

    ``records`` (bytes-like) are MCAP Message records back to back, ``cids`` (n,) their
    channel ids, ``log`` (n,) their log times and ``offsets`` (n,) where each starts in
    ``records`` (int64 arrays, n > 0). The chunk holds what was open before them, then
    them; their message index per channel in order of first appearance; the statistics
    count them and the chunk. ``count(cid, k)`` is called once per channel, in ascending
    channel id, with its k records. Returns what :func:`detach` returns (the builder is
    left empty). ``records`` that cannot change (``bytes``, a memoryview of ``bytes``)
    are kept as they are when nothing was open before them; others are copied.
    """
    n = len(cids)
    chunk = writer._Writer__chunk_builder
    base = chunk.count
    t_lo, t_hi = int(log.min()), int(log.max())
    held = chunk.num_messages
    if held:
        t_lo = min(t_lo, chunk.message_start_time)
        t_hi = max(t_hi, chunk.message_end_time)
    if base:
        data = chunk.end() + bytes(records)
    else:
        data = records if _frozen(records) else bytes(records)
    indices = {cid: index.records for cid, index in chunk.message_indices.items()}
    chunk.message_indices = {}
    chunk.message_start_time = chunk.message_end_time = 0
    chunk.num_messages = 0
    # the records of each channel together, in their order (a stable sort by channel)
    # (as 16-bit keys, which numpy sorts stably by radix: the same order, faster)
    by = np.argsort(cids.astype(np.uint16) if n and 0 <= cids.min() and cids.max() < 1 << 16
                    else cids, kind='stable')
    pairs = np.empty((n, 2), dtype='<u8')
    pairs[:, 0] = log[by]
    pairs[:, 1] = offsets[by]
    if base:
        pairs[:, 1] += base
    counts = np.bincount(cids)
    present = np.flatnonzero(counts)
    ends = np.cumsum(counts[present])
    starts = ends - counts[present]
    stats = writer._Writer__statistics
    rows_of = {}
    for cid, k, a, b in zip(present.tolist(), counts[present].tolist(), starts.tolist(),
                            ends.tolist()):                 # ascending: write_many's
        rows_of[cid] = (a, b)
        stats.channel_message_counts[cid] += k
        count(cid, k)
    appear = present[np.argsort(by[starts], kind='stable')].tolist()
    for cid in appear:                                       # in order of appearance
        a, b = rows_of[cid]
        indices[cid] = (indices.get(cid) or []) + [pairs[a:b].tobytes()]
    for cid, got in indices.items():
        raw = b''.join(x if isinstance(x, bytes) else struct.pack('<QQ', *x) for x in got)
        indices[cid] = RawIndex(struct.pack('<BQHI', Opcode.MESSAGE_INDEX, 6 + len(raw),
                                            cid, len(raw)) + raw)
    if stats.message_count == 0:
        stats.message_start_time = t_lo
    else:
        stats.message_start_time = min(stats.message_start_time, t_lo)
    stats.message_end_time = max(stats.message_end_time, t_hi)
    stats.message_count += n
    stats.chunk_count += 1
    return writer, data, t_lo, t_hi, indices


_ZSTD = threading.local()


def _compress(data):
    """Return ``zstandard.compress(data)`` (level 3, mcap's): the same bytes, a kept context.

    A compression context per thread, made once (``zstandard.compress`` makes one per
    call, about a fifth of the time of a 0.5 MB chunk).
    """
    cctx = getattr(_ZSTD, 'cctx', None)
    if cctx is None:
        cctx = _ZSTD.cctx = zstandard.ZstdCompressor(level=3)
    return cctx.compress(data)


def pack_indexes(chunk_list):
    """Pack the mcap writer's new chunk indexes (``_Writer__chunk_indices``) into bytes."""
    if chunk_list is None:
        return
    if not chunk_list or not isinstance(chunk_list[0], PackedRecords):
        chunk_list.insert(0, PackedRecords())
    packed = chunk_list[0]
    for index in chunk_list[1:]:
        packed.add(index)
    del chunk_list[1:]


#: A Chunk record's fixed fields: opcode, record length, start and end times, uncompressed
#: size and crc, the compression name ('zstd', length-prefixed), the compressed size.
_CHUNK_HEAD = struct.Struct('<BQQQQII4sQ')
#: A ChunkIndex record's fields before its message index offsets, and after them.
_INDEX_HEAD = struct.Struct('<BQQQQQI')
_INDEX_TAIL = struct.Struct('<QI4sQQ')


def _index_bytes(index):
    """Return a message index record's bytes (a :class:`RawIndex`'s as they are)."""
    if isinstance(index, RawIndex):
        return index.data
    builder = RecordBuilder()
    index.write(builder)
    return builder.end()


def write_detached(writer, data, start, end, indices):
    """Write a detached chunk into ``writer``'s file as mcap's own chunk close does.

    The same records in the same order as ``Writer.__finalize_chunk`` (mcap 1.6): the Chunk
    (zstd, crc of the uncompressed bytes), its MessageIndex records, the ChunkIndex kept
    for the summary (packed as bytes), and the stream flushed to the operating system.
    zstd only: the compression :class:`~rigidrot_ros.bag.writer.BagWriter` gives every
    file. The records are packed by ``struct`` and written straight to the stream (the
    compressed bytes are not copied into mcap's record builder), except where the writer
    keeps a crc of its data section (:func:`_write_detached_records`, mcap's own way).
    """
    if writer._Writer__enable_data_crcs:
        return _write_detached_records(writer, data, start, end, indices)
    compressed = _compress(data)
    crc = zlib.crc32(data) if writer._Writer__enable_crcs else 0
    stream = writer._Writer__stream
    writer._Writer__flush()                         # what the record builder holds
    offset = stream.tell()
    head = _CHUNK_HEAD.pack(Opcode.CHUNK, _CHUNK_HEAD.size - 9 + len(compressed), start, end,
                            len(data), crc, 4, b'zstd', len(compressed))
    stream.write(head)
    stream.write(compressed)
    chunk_length = len(head) + len(compressed)
    at = offset + chunk_length                      # the message indexes start here
    offsets, raws = [], []
    if writer._Writer__index_types & IndexType.MESSAGE:
        for cid, message_index in indices.items():
            raw = _index_bytes(message_index)
            offsets.append((cid, at))
            raws.append(raw)
            at += len(raw)
        stream.write(b''.join(raws))
    length = at - offset - chunk_length
    pairs = b''.join(struct.pack('<HQ', cid, off) for cid, off in offsets)
    record = (_INDEX_HEAD.pack(Opcode.CHUNK_INDEX, 0, start, end, offset, chunk_length,
                               len(pairs)) + pairs
              + _INDEX_TAIL.pack(length, 4, b'zstd', len(compressed), len(data)))
    record = record[:1] + struct.pack('<Q', len(record) - 9) + record[9:]
    chunk_list = writer._Writer__chunk_indices
    pack_indexes(chunk_list)
    chunk_list[0].data += record
    stream.flush()


def _write_detached_records(writer, data, start, end, indices):
    """:func:`write_detached` through mcap's records and record builder."""
    compressed = _compress(data)
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
    pack_indexes(chunk_list)
    stream.flush()
