"""A generated run's blocks as MCAP records, cut into chunks as the bag writer cuts them.

The parts of a block (each topic's header stamps, log times and columns, from
:mod:`rigidrot_ros.run.generate`) become MCAP Message records, written straight into one
buffer in the order the node publishes them (:func:`placed`) or, where that cannot be
(the run description's span, no numba), built in arrays (:func:`records`) and merged in
that order (:func:`span_of`), cut
where :meth:`rigidrot_ros.bag.BagWriter.write_many` would close a chunk (:func:`pieces`)
and handed to :meth:`BagWriter.write_chunk` a chunk at a time (:func:`write_piece`,
:func:`write_block`): the file of the message-by-message writer, byte for byte.
"""

from typing import NamedTuple

import numpy as np

__all__ = ['Span', 'records', 'placed', 'span_of', 'pieces', 'write_piece', 'write_block']


class Span(NamedTuple):
    """A span's messages in the order the node publishes them, as slices of their records.

    Message i is ``sources[src[i]][off[i]:off[i] + size[i]]``, an MCAP Message record
    (head and CDR) of channel ``cid[i]`` logged at ``log[i]`` (ns, from the start);
    ``cont[i]``: its record follows message i - 1's in the same source; ``run_at``: the
    place of the run description (-1: none).
    """

    log: np.ndarray
    cid: np.ndarray
    src: np.ndarray
    off: np.ndarray
    size: np.ndarray
    cont: np.ndarray
    sources: list
    run_at: int


def records(run, parts, cids, seq):
    """Build the MCAP Message records of a span's parts: ``(sources, src, off, size)`` per part.

    The parts of one output share rows: where each topic's CDR is a fixed-size
    :class:`~rigidrot_ros.msgs.cdr.Batch`, a row's records lie back to back in one array
    (:func:`rigidrot_ros.bag.chunks.record_dtype`), so the records of a sample's topics
    and of consecutive samples are consecutive bytes. Other parts (the run description)
    are joined message by message. ``seq`` (topic -> next sequence number) counts on.
    """
    from rigidrot_ros.bag.chunks import fill_records, MESSAGE_HEAD, record_dtype
    from rigidrot_ros.msgs.cdr import Batch
    groups = {}
    for i, p in enumerate(parts):
        groups.setdefault(id(p.output), []).append(i)
    sources, where = [], [None] * len(parts)
    for idx in groups.values():
        raws = [parts[i].output.encode_batch(parts[i].name, parts[i].stamps, parts[i].cols,
                                             run.frames) for i in idx]
        n = len(parts[idx[0]].stamps)
        if all(isinstance(r, Batch) for r in raws):
            rows = np.empty(n, dtype=record_dtype([r.size for r in raws]))
            step = rows.dtype.itemsize
            for j, (i, r) in enumerate(zip(idx, raws)):
                p = parts[i]
                fill_records(rows, j, cids[p.topic], seq[p.topic], p.log, r.data)
                seq[p.topic] += n
                at = rows.dtype.fields[f'm{j}'][1]
                where[i] = (len(sources), np.arange(n, dtype=np.int64) * step + at,
                            np.full(n, 31 + r.size, dtype=np.int64))
            sources.append(memoryview(rows.view(np.uint8)) if n else b'')
            continue
        for i, r in zip(idx, raws):
            p = parts[i]
            datas = r.tolist() if isinstance(r, Batch) else list(r)
            heads = np.zeros(n, dtype=MESSAGE_HEAD)
            size = np.array([len(d) for d in datas], dtype=np.int64)
            heads['op'], heads['len'], heads['cid'] = 0x05, 22 + size, cids[p.topic]
            heads['seq'] = np.arange(seq[p.topic], seq[p.topic] + n)
            heads['log'] = heads['pub'] = p.log
            seq[p.topic] += n
            flat = heads.tobytes()
            sources.append(b''.join(b for k, d in enumerate(datas)
                                    for b in (flat[31 * k:31 * k + 31], d)))
            where[i] = (len(sources) - 1, np.concatenate([[0], np.cumsum(31 + size)[:-1]]),
                        31 + size)
    return sources, where


def placed(run, parts, cids, seq, order):
    """Return a span's :class:`Span` with its records in one buffer, in the merge ``order``.

    Where every part's CDR is a fixed-size :class:`~rigidrot_ros.msgs.cdr.Batch` and the
    compiled placing loop is at hand (:func:`rigidrot_ros.bag.chunks.can_place`): each
    message's offset is the sum of the record sizes before it in ``order``, and each part's
    records (head and CDR) are written there at once
    (:func:`~rigidrot_ros.bag.chunks.place_batch`: from each CDR batch's plan, whose
    ``(n, size)`` array is never built), so the span is one read-only buffer, its
    messages back to back: the bytes of :func:`span_of`'s records in its order, with two
    copies fewer and no join; a chunk is a slice of it. None otherwise (nothing counted
    in ``seq``).
    """
    from rigidrot_ros.bag.chunks import can_place, place_batch
    from rigidrot_ros.msgs.cdr import Batch
    which, rows = order
    if not len(which) or not can_place():
        return None
    raws = []
    for p in parts:
        r = p.output.encode_batch(p.name, p.stamps, p.cols, run.frames)
        if not isinstance(r, Batch):
            return None
        raws.append(r)
    size = np.array([31 + r.size for r in raws], dtype=np.int64)[which]
    off = np.zeros(len(which), dtype=np.int64)
    np.cumsum(size[:-1], out=off[1:])
    buf = np.empty(int(off[-1] + size[-1]), dtype=np.uint8)
    # each part's places in the order, grouped by part (a stable sort of small keys)
    by = np.argsort(which.astype(np.int16) if len(parts) < 1 << 15 else which, kind='stable')
    counts = np.array([len(p.stamps) for p in parts], dtype=np.int64)
    first = np.cumsum(counts) - counts          # each part's first place in ``by`` and ``log``
    for i, (p, r) in enumerate(zip(parts, raws)):
        n = len(p.stamps)
        mine = by[first[i]:first[i] + n]
        dst = np.empty(n, dtype=np.int64)
        dst[rows[mine]] = off[mine]
        place_batch(buf, dst, cids[p.topic], seq[p.topic], p.log, r)
        seq[p.topic] += n
    buf.flags.writeable = False                 # frozen: chunks are slices of it
    cid = np.array([cids[p.topic] for p in parts], dtype=np.int64)[which]
    log = np.concatenate([p.log for p in parts])[first[which] + rows] - run.start_ns
    cont = np.ones(len(which), dtype=bool)
    cont[0] = False
    return Span(log, cid, np.zeros(len(which), dtype=np.int64), off, size, cont,
                [memoryview(buf)], -1)


def span_of(run, parts, cids, seq, order):
    """Return a span's :class:`Span`: its parts' records, in the merge ``order``.

    ``order``: ``(part index, row)`` arrays, the order the node publishes the parts'
    messages in (:func:`rigidrot_ros.run.generate` merges them so). Where it can,
    :func:`placed` builds it.
    """
    if not any(p.topic == run.run_topic for p in parts):
        got = placed(run, parts, cids, seq, order)
        if got is not None:
            return got
    sources, where = records(run, parts, cids, seq)
    which, rows = order
    if not len(which):
        empty = np.empty(0, dtype=np.int64)
        return Span(empty, empty, empty, empty, empty, np.empty(0, dtype=bool), sources, -1)
    first = np.cumsum([0] + [len(p.stamps) for p in parts])[:-1]
    pick = first[which] + rows
    src = np.concatenate([np.full(len(p.stamps), w[0]) for p, w in zip(parts, where)])[pick]
    off = np.concatenate([w[1] for w in where])[pick]
    size = np.concatenate([w[2] for w in where])[pick]
    cid = np.concatenate([np.full(len(p.stamps), cids[p.topic]) for p in parts])[pick]
    log = np.concatenate([p.log for p in parts])[pick] - run.start_ns
    cont = np.zeros(len(pick), dtype=bool)
    cont[1:] = (src[1:] == src[:-1]) & (off[1:] == off[:-1] + size[:-1])
    at = np.flatnonzero(cid == cids.get(run.run_topic, -1))
    return Span(log, cid, src, off, size, cont, sources, int(at[0]) if len(at) else -1)


def pieces(span, a, b, limit, base=0):
    """Cut messages ``a:b`` of ``span`` into chunks as :meth:`BagWriter.write_many` does.

    A chunk is closed right after the record that takes it past ``limit`` bytes, the
    first counting ``base`` bytes already open (:attr:`BagWriter.open_bytes`); returns
    ``[(lo, hi, closed), ...]``, ``closed`` False for a last piece left open (``flush``
    closes it).
    """
    out = []
    while a < b:
        ends = base + np.cumsum(span.size[a:b])
        over = np.flatnonzero(ends > limit)
        c = a + int(over[0]) + 1 if len(over) else b
        out.append((a, c, bool(len(over))))
        a, base = c, 0
    return out


def write_piece(writer, span, a, b, start_ns):
    """Write messages ``a:b`` of ``span`` as one chunk (their records joined run by run)."""
    new = ~span.cont[a:b]
    new[0] = True                           # the chunk's first record starts a run
    starts = np.flatnonzero(new) + a
    last = np.append(starts[1:], b) - 1
    lo = span.off[starts].tolist()
    hi = (span.off[last] + span.size[last]).tolist()
    src = [span.sources[k] for k in span.src[starts].tolist()]
    if len(src) == 1:                       # one run: its bytes as they are, in place
        data = src[0][lo[0]:hi[0]] if isinstance(src[0], memoryview) else \
            memoryview(src[0])[lo[0]:hi[0]]
        offsets = span.off[a:b] - lo[0]
    else:
        data = b''.join([s[x:y] for s, x, y in zip(src, lo, hi)])
        offsets = np.concatenate([[0], np.cumsum(span.size[a:b - 1])])
    writer.write_chunk(data, span.cid[a:b], span.log[a:b] + start_ns, offsets)


def write_block(writer, run, span, lo, hi):
    """Write the records of ``span`` logged in [lo, hi) ns, the run description where it falls."""
    a, b = np.searchsorted(span.log, [lo, hi]).tolist()
    if a <= span.run_at < b:
        # as the node's recorder: a metadata record, written at once; the chunk still
        # open before the run description is closed after it
        before = pieces(span, a, span.run_at, writer.chunk_size, writer.open_bytes)
        for x, y, closed in before:
            if closed:
                write_piece(writer, span, x, y, run.start_ns)
        writer.add_run(run.description())
        for x, y, closed in before:
            if not closed:
                write_piece(writer, span, x, y, run.start_ns)
        a = span.run_at
    for x, y, _ in pieces(span, a, b, writer.chunk_size, writer.open_bytes):
        write_piece(writer, span, x, y, run.start_ns)
