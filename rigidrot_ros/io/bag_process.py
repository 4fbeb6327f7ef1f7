"""A :class:`~rigidrot_ros.io.bag.BagWriter` in a child process: the caller only hands bytes over.

:class:`ProcessBagWriter` has the writing interface of ``BagWriter`` (``add_topic``,
``write``, ``write_many``, ``add_run``, ``add_metadata``, ``maybe_flush``, ``flush``,
``close``, ``has_topic``, ``counts``, ``closed``, ``path``). Each call is pickled into one
length-prefixed frame and written to the stdin pipe of a child process
(``python -m rigidrot_ros.io.bag_process``), which makes the very same ``BagWriter`` calls
in the same order: MCAP records, chunking, zstd compression and file writes happen there,
outside the caller's interpreter (no GIL shared with the publishing thread).

What it guarantees:

- Same bag: the child calls the same methods with the same arguments in the same order,
  so the files are the bytes an in-process ``BagWriter`` writes (chunks closed by the
  time-driven ``maybe_flush`` close at the child's clock, as they would at the caller's).
- Nothing lost or reordered when the child falls behind: the pipe is a FIFO and a write
  to a full pipe *blocks* the caller until the child has read. Memory is bounded by the
  pipe's buffer (raised to :data:`PIPE_BYTES`, 1 MiB, where Linux allows; 64 KiB
  otherwise) plus one frame in the child.
- Shutdown: :meth:`close` sends ``close``, closes the pipe and waits for the child, which
  writes everything before it and finishes the bag (summary, metadata.yaml). If the caller
  dies without closing, the child reads end-of-file and finishes the bag all the same.
- The child runs in a process group of its own and ignores SIGINT (a terminal's Ctrl-C
  goes to the caller's group; the caller stops the child by closing the pipe).
- A child that dies (killed, disk full): the next call raises :class:`OSError` naming the
  process and its exit status (a recorder then stops recording with one error); the bag
  keeps every chunk flushed before (``rigidrot_bag reindex`` finishes a killed one).
"""

import fcntl
import os
import pickle
import signal
import struct
import subprocess
import sys

from rigidrot_ros.io.bag import _exact_dir, _unique_dir, BagWriter

__all__ = ['ProcessBagWriter', 'PIPE_BYTES']

#: Bytes the pipe to the child may hold before a write blocks (Linux F_SETPIPE_SZ).
PIPE_BYTES = 1 << 20
_HEAD = struct.Struct('<I')
_F_SETPIPE_SZ = getattr(fcntl, 'F_SETPIPE_SZ', 1031)
_CALLS = frozenset({'add_topic', 'write', 'write_many', 'add_run', 'add_metadata',
                    'maybe_flush', 'flush', 'close'})


class ProcessBagWriter:
    """A bag writer whose writing happens in a child process (same arguments as BagWriter).

    Parameters
    ----------
    root, name, flush_period, path, split_seconds
        As :class:`rigidrot_ros.io.bag.BagWriter`; the bag directory is made here (so
        :attr:`path` is known at once and a bad path fails in the caller).
    timeout : float
        Seconds :meth:`close` waits for the child to finish the bag before killing it.
    """

    #: A recorder hands each call's messages over with one :meth:`write_many` (one frame).
    BATCHED = True

    def __init__(self, root, name, flush_period=0.5, path=None, split_seconds=3600.0,
                 timeout=60.0):
        if path is not None:
            self.path = _exact_dir(os.path.abspath(path))
        else:
            os.makedirs(root, exist_ok=True)
            self.path = _unique_dir(root, name.strip('/').replace('/', '_') or 'bag')
        self._timeout = float(timeout)
        self._topics = set()
        self._counts = {}
        self._closed = False
        self._dead = None
        self._proc = subprocess.Popen(
            [sys.executable, '-m', 'rigidrot_ros.io.bag_process', self.path,
             repr(float(flush_period)), repr(float(split_seconds))],
            stdin=subprocess.PIPE, process_group=0, close_fds=True)
        self._fd = self._proc.stdin.fileno()
        try:
            fcntl.fcntl(self._fd, _F_SETPIPE_SZ, PIPE_BYTES)
        except OSError:
            pass                                # a smaller limit: the default 64 KiB

    @property
    def pid(self):
        """Process id of the child."""
        return self._proc.pid

    def _send(self, name, *args):
        if self._dead is not None:
            raise OSError(self._dead)
        body = pickle.dumps((name, args), protocol=pickle.HIGHEST_PROTOCOL)
        data = memoryview(_HEAD.pack(len(body)) + body)
        try:
            while data:
                data = data[os.write(self._fd, data):]     # blocks while the pipe is full
        except OSError:
            self._dead = self._death()
            raise OSError(self._dead) from None

    def _death(self):
        try:
            code = self._proc.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            code = None
        how = (f'was killed by signal {-code}' if code is not None and code < 0
               else f'exited with status {code}')
        return f'the bag writer process (pid {self._proc.pid}) {how}'

    # -- BagWriter's interface -----------------------------------------------------------
    def add_topic(self, topic, type_name, qos=None, schema=None, metadata=None):
        """Register ``topic`` (see :meth:`BagWriter.add_topic`); returns None."""
        if topic not in self._topics:
            self._send('add_topic', topic, type_name, qos, schema, metadata)
            self._topics.add(topic)
            self._counts.setdefault(topic, 0)

    def has_topic(self, topic):
        """Whether ``topic`` has been registered."""
        return topic in self._topics

    def write(self, topic, data, log_time_ns, publish_time_ns=None):
        """Hand one serialized message over (see :meth:`BagWriter.write`)."""
        if topic not in self._topics:
            raise KeyError(topic)
        self._send('write', topic, bytes(data), int(log_time_ns), publish_time_ns)
        self._counts[topic] += 1

    def write_many(self, topics, datas, log_times_ns):
        """Hand serialized messages over in one frame (see :meth:`BagWriter.write_many`)."""
        topics = list(topics)
        if not (len(topics) == len(datas) == len(log_times_ns)):
            raise ValueError('write_many needs one topic, one payload and one stamp per '
                             'message')
        if not topics:
            return
        for topic in set(topics):
            if topic not in self._topics:
                raise KeyError(topic)
        self._send('write_many', topics, [bytes(d) for d in datas],
                   [int(t) for t in log_times_ns])
        for topic in topics:
            self._counts[topic] += 1

    def add_run(self, info):
        """Write a ``rigidrot_run`` metadata record (see :meth:`BagWriter.add_run`)."""
        self._send('add_run', dict(info))

    def add_metadata(self, name, data):
        """Write an MCAP metadata record (see :meth:`BagWriter.add_metadata`)."""
        self._send('add_metadata', name, dict(data))

    def maybe_flush(self):
        """Let the child flush if its flush period has passed."""
        self._send('maybe_flush')

    def flush(self):
        """Let the child close the open chunk and push it to the file."""
        self._send('flush')

    @property
    def counts(self):
        """Messages handed over per topic."""
        return dict(self._counts)

    @property
    def closed(self):
        """Whether :meth:`close` has run (or the child died)."""
        return self._closed

    def close(self):
        """Have the child write everything sent and finish the bag; wait for it.

        Raises :class:`OSError` if the child had died or did not finish cleanly (the bag
        then holds what the child flushed). Safe to call twice.
        """
        if self._closed:
            return
        self._closed = True
        error = self._dead
        if error is None:
            try:
                self._send('close')
            except OSError as exc:
                error = str(exc)
        try:
            self._proc.stdin.close()
        except OSError:
            pass
        try:
            code = self._proc.wait(timeout=self._timeout)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            code = self._proc.wait()
            error = error or (f'the bag writer process (pid {self._proc.pid}) did not '
                              f'finish the bag in {self._timeout:g} s: killed')
        if error is None and code != 0:
            error = self._death()
        if error is not None:
            raise OSError(error)


def _read_exact(stream, n):
    buf = stream.read(n)
    return buf if buf is not None and len(buf) == n else None


def serve(path, flush_period, split_seconds, stream):
    """Run the calls framed on ``stream`` against a new ``BagWriter`` at ``path``; 0 on success.

    On end-of-file (the caller closed the pipe or died) the bag is finished.
    """
    writer = BagWriter(None, '', flush_period=flush_period, path=path,
                       split_seconds=split_seconds)
    try:
        while True:
            head = _read_exact(stream, _HEAD.size)
            if head is None:
                break
            body = _read_exact(stream, _HEAD.unpack(head)[0])
            if body is None:
                break
            name, args = pickle.loads(body)
            if name not in _CALLS:
                raise ValueError(f'unknown call {name!r}')
            getattr(writer, name)(*args)
            if name == 'close':
                break
    finally:
        writer.close()
    return 0


def main(argv=None):
    """``python -m rigidrot_ros.io.bag_process PATH FLUSH_PERIOD SPLIT_SECONDS`` (frames on stdin)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)    # the parent stops us (closes the pipe)
    argv = sys.argv[1:] if argv is None else argv
    path, flush_period, split_seconds = argv[0], float(argv[1]), float(argv[2])
    try:
        return serve(path, flush_period, split_seconds, sys.stdin.buffer)
    except Exception as exc:  # noqa: B902 - one line naming the problem, then exit 1
        print(f'rigidrot bag writer ({path}): {type(exc).__name__}: {exc}', file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
