"""What a bag directory is: its rosbag2 ``metadata.yaml``, its file list and its run records.

A bag is a directory holding ``<dir>_0.mcap`` (and ``_1``, ... when split) and a rosbag2
``metadata.yaml`` (version 9), so ``ros2 bag info`` and ``ros2 bag play`` accept it. Runs of
the node are described twice: by MCAP metadata records named ``rigidrot_run`` (written by
the node's own recorder) and by ``std_msgs/msg/String`` messages whose JSON carries
``"rigidrot_run": 1`` (the node's transient-local ``~/run`` topic, which any recorder keeps).
A new bag's directory is made by :func:`new_bag_dir` or :func:`exact_bag_dir`, never over
another's.
"""

import datetime
import json
import os
import re
import struct
import threading

import yaml


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


def uninterrupted(fn, *args, **kwargs):
    """Return ``fn(*args, **kwargs)``, run to its end whatever signal arrives meanwhile.

    Python runs signal handlers in the main thread only, between two bytecodes, so a
    KeyboardInterrupt (a second Ctrl-C) can stop a write half way. Called from the main
    thread, ``fn`` runs in a thread of its own while the main thread waits for it; an
    exception a signal handler raises in the wait is raised once ``fn`` has finished (its
    own exception first). From any other thread ``fn`` is simply called.
    """
    if threading.current_thread() is not threading.main_thread():
        return fn(*args, **kwargs)
    result, error = [], []
    claim, done = threading.Lock(), threading.Event()

    def body():
        if not claim.acquire(blocking=False):
            return                      # started twice (a signal inside Thread.start)
        try:
            result.append(fn(*args, **kwargs))
        except BaseException as exc:    # noqa: B902 - handed to the caller's thread
            error.append(exc)
        finally:
            done.set()
    started, signalled = False, None
    while not done.is_set():
        try:
            if not started:             # a signal may stop start() before or after the
                threading.Thread(target=body, name='uninterrupted').start()   # thread runs
                started = True
            done.wait()
        except BaseException as exc:    # noqa: B902 - a signal handler's: after the write
            signalled = signalled or exc
    if error:
        raise error[0]
    if signalled is not None:
        raise signalled
    return result[0]


def new_bag_dir(root, name):
    """Create and return a new directory ``<root>/<name>_<UTC time>`` (never one that exists).

    Another writer's directory of the same microsecond gets ``_1``, ``_2``, ... appended:
    nothing is overwritten.
    """
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


def exact_bag_dir(path):
    """Create and return the directory ``path``; raise FileExistsError if it holds anything."""
    if os.path.exists(path) and (not os.path.isdir(path) or os.listdir(path)):
        raise FileExistsError(f'{path} exists and is not an empty directory; nothing is '
                              f'overwritten: choose another output directory')
    os.makedirs(path, exist_ok=True)
    return path


def write_metadata_yaml(path, files, topics, counts, first, last, per_file=None):
    """Write a rosbag2 (v9) ``metadata.yaml`` into bag directory ``path`` atomically.

    ``topics`` maps topic -> (type, offered_qos_profiles YAML); ``counts`` topic -> count;
    ``per_file`` optionally maps file name -> (first_ns, last_ns, count). The text goes to
    ``metadata.yaml.tmp`` and is renamed over ``metadata.yaml``, in
    :func:`uninterrupted`: a reader finds the former file or the whole new one, never a
    part, and no signal (a second Ctrl-C) stops the write half way.
    """
    uninterrupted(_write_metadata_yaml, path, files, topics, counts, first, last, per_file)


def _write_metadata_yaml(path, files, topics, counts, first, last, per_file):
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
    text = yaml.safe_dump({'rosbag2_bagfile_information': info}, sort_keys=False)
    tmp = os.path.join(path, 'metadata.yaml.tmp')
    with open(tmp, 'w', encoding='utf-8') as fh:
        fh.write(text)
    os.replace(tmp, os.path.join(path, 'metadata.yaml'))


def file_index(name):
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
    present = sorted((f for f in os.listdir(path) if f.endswith('.mcap')), key=file_index)
    meta_path = os.path.join(path, 'metadata.yaml')
    if os.path.exists(meta_path):
        listed = listed_files(meta_path)
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
        inner = bags_below(path)
        if inner:
            raise BagError(f'{path}: a directory with no .mcap file is not a bag; the bags '
                           f'sit one level down: {", ".join(inner)} (give one of them)')
        raise BagError(f'{path}: a directory with no .mcap file is not a bag')
    return [os.path.join(path, f) for f in files]


def bags_below(path):
    """Return the bag directories one level below ``path`` (those holding a .mcap), sorted.

    A run directory of the README's estimator loop holds the recorder's bag and the
    node's, side by side.
    """
    def has_mcap(d):
        try:
            return os.path.isdir(d) and any(f.endswith('.mcap') for f in os.listdir(d))
        except OSError:
            return False
    try:
        names = sorted(os.listdir(path))
    except OSError:
        return []
    return [os.path.join(path, n) for n in names if has_mcap(os.path.join(path, n))]


def listed_files(meta_path):
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


def decode_run(data):
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
