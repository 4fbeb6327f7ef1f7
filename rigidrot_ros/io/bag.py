"""rosbag2-compatible MCAP bags: a durable writer and a reader that survives a torn file.

A bag is a directory ``<root>/<name>_<UTC timestamp>/`` holding ``<dir>_0.mcap`` and a
rosbag2 ``metadata.yaml`` (version 9), so ``ros2 bag info`` and ``ros2 bag play`` accept
it. The MCAP follows the ROS 2 profile: header profile ``ros2``, schemas ``pkg/msg/Type``
encoded ``ros2msg`` with their dependencies, messages ``cdr``, and every channel carries
the ``offered_qos_profiles`` metadata rosbag2 writes. Chunks are zstd-compressed and are
closed at least every ``flush_period`` seconds, so a killed writer loses at most that much.
Runs are described by MCAP metadata records named ``rigidrot_run``.
"""

from dataclasses import dataclass, field
import datetime
import json
import os
import struct
import time

from mcap.exceptions import McapError
from mcap.reader import make_reader, StreamReader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer
import yaml

from rigidrot_ros.io.msgdefs import schema_text

__all__ = ['BagWriter', 'BagError', 'read_bag', 'BagContents', 'qos_yaml', 'RUN_RECORD']

RUN_RECORD = 'rigidrot_run'
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


class BagWriter:
    """Write a rosbag2-compatible MCAP bag directory.

    Parameters
    ----------
    root : str
        Directory under which the bag directory is created (made if missing).
    name : str
        Prefix of the bag directory (the node name).
    flush_period : float
        Seconds between forced chunk flushes: the most a hard kill can lose.
    """

    def __init__(self, root, name, flush_period=0.5):
        os.makedirs(root, exist_ok=True)
        self.path = _unique_dir(root, name.strip('/').replace('/', '_') or 'bag')
        self.file_name = os.path.basename(self.path) + '_0.mcap'
        self._fh = open(os.path.join(self.path, self.file_name), 'xb')
        self._writer = Writer(self._fh, chunk_size=1 << 20, compression=CompressionType.ZSTD)
        self._writer.start(profile='ros2', library='rigidrot_ros')
        self._schemas = {}
        self._channels = {}
        self._topics = {}
        self._counts = {}
        self._first = None
        self._last = None
        self._flush_period = float(flush_period)
        self._last_flush = time.monotonic()
        self._closed = False
        self._write_metadata_yaml()

    def add_topic(self, topic, type_name, qos=None, schema=None):
        """Register ``topic`` of ``pkg/msg/Type``; returns its channel id."""
        if topic in self._channels:
            return self._channels[topic]
        if type_name not in self._schemas:
            text = schema if schema is not None else schema_text(type_name)
            self._schemas[type_name] = self._writer.register_schema(
                name=type_name, encoding='ros2msg', data=text.encode('utf-8'))
        cid = self._writer.register_channel(
            topic=topic, message_encoding='cdr', schema_id=self._schemas[type_name],
            metadata={'offered_qos_profiles': qos or qos_yaml(), 'topic_type_hash': ''})
        self._channels[topic] = cid
        self._topics[topic] = (type_name, qos or qos_yaml())
        self._counts[topic] = 0
        return cid

    def write(self, topic, data, log_time_ns, publish_time_ns=None):
        """Write one serialized (CDR) message."""
        cid = self._channels[topic]
        self._writer.add_message(channel_id=cid, log_time=int(log_time_ns), data=bytes(data),
                                 publish_time=int(publish_time_ns or log_time_ns),
                                 sequence=self._counts[topic])
        self._counts[topic] += 1
        self._first = log_time_ns if self._first is None else min(self._first, log_time_ns)
        self._last = log_time_ns if self._last is None else max(self._last, log_time_ns)
        self.maybe_flush()

    def add_run(self, info):
        """Record a run (scene, start stamp, ...) as a ``rigidrot_run`` metadata record."""
        self._writer.add_metadata(RUN_RECORD, {k: (v if isinstance(v, str) else json.dumps(v))
                                               for k, v in info.items()})
        self.flush()

    def maybe_flush(self):
        """Flush if ``flush_period`` has passed since the last flush."""
        if time.monotonic() - self._last_flush >= self._flush_period:
            self.flush()

    def flush(self):
        """Close the open chunk and push it to the operating system."""
        self._writer.flush()
        self._fh.flush()
        self._last_flush = time.monotonic()

    @property
    def counts(self):
        """Messages written per topic."""
        return dict(self._counts)

    def close(self):
        """Finish the MCAP (summary and index) and write the final metadata.yaml."""
        if self._closed:
            return
        self._closed = True
        self._writer.finish()
        self._fh.close()
        self._write_metadata_yaml()

    def _write_metadata_yaml(self):
        start = self._first or 0
        duration = (self._last - self._first) if self._first is not None else 0
        total = sum(self._counts.values())
        info = {
            'version': 9,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': int(duration)},
            'starting_time': {'nanoseconds_since_epoch': int(start)},
            'message_count': total,
            'topics_with_message_count': [
                {'topic_metadata': {'name': t, 'type': ty, 'serialization_format': 'cdr',
                                    'offered_qos_profiles': yaml.safe_load(q),
                                    'type_description_hash': ''},
                 'message_count': self._counts[t]}
                for t, (ty, q) in self._topics.items()],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [self.file_name],
            'files': [{'path': self.file_name,
                       'starting_time': {'nanoseconds_since_epoch': int(start)},
                       'duration': {'nanoseconds': int(duration)}, 'message_count': total}],
            'custom_data': None,
            'ros_distro': 'jazzy',
        }
        tmp = os.path.join(self.path, 'metadata.yaml.tmp')
        with open(tmp, 'w', encoding='utf-8') as fh:
            yaml.safe_dump({'rosbag2_bagfile_information': info}, fh, sort_keys=False)
        os.replace(tmp, os.path.join(self.path, 'metadata.yaml'))


@dataclass
class BagContents:
    """Everything read from one bag, in log-time order."""

    path: str
    messages: list = field(default_factory=list)    # (topic, type, log_ns, pub_ns, data)
    topics: dict = field(default_factory=dict)      # topic -> (type, qos yaml, schema text)
    runs: list = field(default_factory=list)        # dicts from rigidrot_run records
    truncated: bool = False
    note: str = ''


def _mcap_path(path):
    if os.path.isdir(path):
        files = sorted(f for f in os.listdir(path) if f.endswith('.mcap'))
        if not files:
            raise BagError(f'{path}: a directory with no .mcap file is not a bag')
        return os.path.join(path, files[0])
    if not os.path.exists(path):
        raise BagError(f'{path}: no such file or directory')
    return path


def _decode_run(data):
    out = {}
    for k, v in data.items():
        try:
            out[k] = json.loads(v)
        except ValueError:
            out[k] = v
    return out


def read_bag(path):
    """Read a bag directory or .mcap file; a torn file is read up to its last whole record.

    Raises
    ------
    BagError
        The path is missing, not MCAP, or holds no readable records.
    """
    fpath = _mcap_path(path)
    with open(fpath, 'rb') as fh:
        magic = fh.read(8)
    if magic != b'\x89MCAP0\r\n':
        raise BagError(f'{fpath}: not an MCAP file (bad magic {magic[:8]!r})')
    out = BagContents(path=fpath)
    schemas, channels = {}, {}
    try:
        with open(fpath, 'rb') as fh:
            reader = make_reader(fh)
            summary = reader.get_summary()
            if summary is None:
                raise McapError('no summary')
            for rec in reader.iter_metadata():
                if rec.name == RUN_RECORD:
                    out.runs.append(_decode_run(rec.metadata))
            for schema, channel, msg in reader.iter_messages(log_time_order=True):
                _note(out, schema, channel)
                out.messages.append((channel.topic, schema.name, msg.log_time,
                                     msg.publish_time, msg.data))
        return out
    except (McapError, struct.error, EOFError, ValueError, KeyError, OSError):
        pass
    # unfinished or damaged: stream records up to the tear
    out = BagContents(path=fpath, truncated=True)
    with open(fpath, 'rb') as fh:
        try:
            for rec in StreamReader(fh, skip_magic=False, emit_chunks=False).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
                elif isinstance(rec, Message):
                    ch = channels.get(rec.channel_id)
                    sc = schemas.get(ch.schema_id) if ch else None
                    if ch is None or sc is None:
                        continue
                    _note(out, sc, ch)
                    out.messages.append((ch.topic, sc.name, rec.log_time, rec.publish_time,
                                         rec.data))
                elif isinstance(rec, Metadata) and rec.name == RUN_RECORD:
                    out.runs.append(_decode_run(rec.metadata))
            out.truncated = False
            out.note = 'no summary section, but all records read'
        except Exception as exc:  # the tear: EndOfFile, struct.error, zstd errors...
            out.note = f'read up to the last complete record ({type(exc).__name__})'
    if not out.messages and not out.runs:
        raise BagError(f'{fpath}: MCAP file with no readable records ({out.note})')
    out.messages.sort(key=lambda m: m[2])
    return out


def _note(out, schema, channel):
    if channel.topic not in out.topics:
        out.topics[channel.topic] = (schema.name,
                                     channel.metadata.get('offered_qos_profiles', ''),
                                     schema.data.decode('utf-8', 'replace'))
