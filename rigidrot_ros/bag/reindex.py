"""Finish a torn bag (a killed writer) in place, like ``ros2 bag reindex``."""

import os
import re

from mcap.writer import CompressionType, Writer

from rigidrot_ros.bag.metadata import (bag_files, BagError, file_index, listed_files, MAGIC,
                                       write_metadata_yaml)
from rigidrot_ros.bag.reader import BagContents, read_indexed, read_stream, schemaless_note


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
        if not read_indexed(fpath, part):
            notes.append(f'{os.path.basename(fpath)}: ' + read_stream(fpath, part))
            _rewrite(fpath, part, backup)
            rewritten.append(fpath)
        if part.schemaless:
            notes.append(f'{os.path.basename(fpath)}: ' + schemaless_note(part.schemaless)
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
            listed_files(meta)
        except BagError as exc:
            notes.append(f'{exc}; rebuilt from the files named <dir>_<n>.mcap')
        else:
            return bag_files(path)
    base = os.path.basename(os.path.normpath(path))
    own = re.compile(re.escape(base) + r'_\d+\.mcap')
    present = sorted((f for f in os.listdir(path) if f.endswith('.mcap')), key=file_index)
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
    if not read_indexed(tmp, check) or len(check.messages) != len(part.messages):
        os.remove(tmp)
        raise BagError(f'{fpath}: the rewritten file did not read back whole; nothing changed')
    if backup:
        os.replace(fpath, fpath + '.orig')
    os.replace(tmp, fpath)
