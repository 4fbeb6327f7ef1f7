"""A bag reader that survives a torn file: every complete record, in log-time order.

:func:`read_bag` merges the run descriptions of metadata records and ``~/run`` messages
into :attr:`BagContents.runs`.
"""

from dataclasses import dataclass, field
import os
import struct

from mcap.exceptions import McapError
from mcap.reader import make_reader, StreamReader
from mcap.records import Channel, Message, Metadata, Schema

from rigidrot_ros.bag.metadata import (bag_files, BagError, decode_run, MAGIC,
                                       run_from_string, RUN_RECORD, STRING_TYPE)


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


def read_indexed(fpath, out):
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


def read_stream(fpath, out):
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
        if not read_indexed(fpath, out):
            notes.append((f'{os.path.basename(fpath)}: ' if len(files) > 1 else '')
                         + 'unfinished file, ' + read_stream(fpath, out))
    if notes:
        notes.append(f'rigidrot_reindex {path} finishes it in place (summary, index, '
                     'metadata.yaml), so that other tools read it too')
    if out.schemaless:
        notes.append(schemaless_note(out.schemaless))
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
            add(decode_run(data))
    for topic, type_name, _, _, data in bag.messages:
        if type_name == STRING_TYPE:
            run = run_from_string(data)
            if run is not None and 'start_ns' in run:
                add(run)
    return runs


def schemaless_note(topics):
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
