"""A :class:`~rigidrot_ros.bag.BagWriter` in a child process: the caller only hands bytes over.

:class:`ProcessBagWriter` has the writing interface of ``BagWriter`` (``add_topic``,
``write``, ``write_many``, ``add_run``, ``add_metadata``, ``maybe_flush``, ``flush``,
``close``, ``has_topic``, ``counts``, ``closed``, ``path``). Each call is pickled into one
length-prefixed frame and copied into a ring buffer shared with a child process
(``python -m rigidrot_ros.bag.process``, a ``memfd`` mapped by both), which makes the
very same ``BagWriter`` calls in the same order: MCAP records, chunking, zstd compression
and file writes happen there, outside the caller's interpreter.

Why a shared ring and not a pipe: handing a frame over must not release the caller's
interpreter lock. Every blocking system call does (a pipe ``write`` included), and the
node's publishing thread that releases it must get it back from the look-ahead worker
thread, which runs niced: when the OS has descheduled the worker while it holds the lock,
the publishing thread waits for it. Measured with a pipe, the node's record phase reached
3.9-5.0 ms and late gyro samples rose (doc/recording.md). Copying into the ring is a
memory copy; the child drains the ring every :data:`DRAIN_S` (50 ms), niced by 10
(``RIGIDROT_RECORD_NICE``) so that the OS runs the node's threads first.

What it guarantees:

- Same bag: the child calls the same methods with the same arguments in the same order,
  so the files are the bytes an in-process ``BagWriter`` writes (chunks closed by the
  time-driven ``maybe_flush`` close at the child's clock, as they would at the caller's).
- Nothing lost or reordered when the child falls behind: the ring is a FIFO and a frame
  that does not fit *blocks* the caller (1 ms sleeps) until the child has read. Memory is
  bounded by the ring (``ring_bytes``, default :data:`RING_BYTES`, 4 MiB, about 10 s of
  the node at 4 kHz) plus one frame in the child.
- Shutdown: :meth:`close` sends ``close``, closes the child's stdin and waits for the
  child, which writes everything before it and finishes the bag (summary, metadata.yaml).
  If the caller dies without closing, the child sees end-of-file on its stdin, writes what
  the ring holds and finishes the bag all the same.
- The child runs in a process group of its own and ignores SIGINT (a terminal's Ctrl-C
  goes to the caller's group; the caller stops the child by closing its stdin).
- A child that dies (killed, disk full): :meth:`maybe_flush` (the recorder's flush timer)
  notices when the child's heartbeat has stood still since the last call and the process
  has ended, and raises :class:`OSError` naming the process and its exit status (a
  recorder then stops recording with one error); so does a call that finds the ring full.
  The bag keeps every chunk flushed before (``rigidrot_reindex`` finishes a killed one).
"""

import mmap
import os
import pickle
import select
import signal
import struct
import subprocess
import sys
import time

from rigidrot_ros.bag.writer import _exact_dir, _unique_dir, BagWriter

__all__ = ['ProcessBagWriter', 'RING_BYTES']

#: Bytes of the shared ring the caller writes frames into; a full ring blocks the caller.
RING_BYTES = 4 << 20
#: Seconds the child sleeps between drains of the ring (fewer wake-ups, bigger batches).
DRAIN_S = 0.05
_HEAD = struct.Struct('<I')
_DATA = 64                          # header: write index, read index, heartbeat (u64 each)
_CALLS = frozenset({'add_topic', 'write', 'write_many', 'add_run', 'add_metadata',
                    'maybe_flush', 'flush', 'close'})


class ProcessBagWriter:
    """A bag writer whose writing happens in a child process (same arguments as BagWriter).

    Parameters
    ----------
    root, name, flush_period, path, split_seconds
        As :class:`rigidrot_ros.bag.BagWriter`; the bag directory is made here (so
        :attr:`path` is known at once and a bad path fails in the caller).
    timeout : float
        Seconds :meth:`close` waits for the child to finish the bag before killing it.
    ring_bytes : int
        Size of the shared ring (default :data:`RING_BYTES`, 4 MiB): the most memory
        messages wait in when the child falls behind.
    """

    #: A recorder hands each call's messages over with one :meth:`write_many` (one frame).
    BATCHED = True

    def __init__(self, root, name, flush_period=0.5, path=None, split_seconds=3600.0,
                 timeout=60.0, ring_bytes=RING_BYTES):
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
        self._size = int(ring_bytes)
        fd = os.memfd_create('rigidrot-bag-ring', 0)
        try:
            os.ftruncate(fd, _DATA + self._size)
            self._map = mmap.mmap(fd, _DATA + self._size)
            self._proc = subprocess.Popen(
                [sys.executable, '-m', 'rigidrot_ros.bag.process', self.path,
                 repr(float(flush_period)), repr(float(split_seconds)), str(fd),
                 str(self._size)],
                stdin=subprocess.PIPE, process_group=0, pass_fds=(fd,))
        finally:
            os.close(fd)
        self._head = memoryview(self._map)[:_DATA].cast('Q')
        self._written = 0
        self._beat = -1

    @property
    def pid(self):
        """Process id of the child."""
        return self._proc.pid

    def _send(self, name, *args):
        """Copy one frame into the ring (no system call: the GIL is never released)."""
        if self._dead is not None:
            raise OSError(self._dead)
        body = pickle.dumps((name, args), protocol=pickle.HIGHEST_PROTOCOL)
        data = memoryview(_HEAD.pack(len(body)) + body)
        size, ring = self._size, self._map
        while data:
            free = size - (self._written - self._head[1])
            if free == 0:                       # the child is behind: wait for it
                if self._proc.poll() is not None:
                    self._dead = self._death()
                    raise OSError(self._dead)
                time.sleep(0.001)
                continue
            at = self._written % size
            n = min(len(data), free, size - at)
            ring[_DATA + at:_DATA + at + n] = data[:n]
            data = data[n:]
            self._written += n
            self._head[0] = self._written       # one aligned 8-byte store, after the bytes

    def _check(self):
        """Raise OSError if the child has died (looked at when its heartbeat stood still)."""
        beat = self._head[2]
        if beat == self._beat and self._dead is None and self._proc.poll() is not None:
            self._dead = self._death()
        self._beat = beat
        if self._dead is not None:
            raise OSError(self._dead)

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
        """Let the child flush if its flush period has passed; OSError if it has died."""
        self._check()
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
            self._proc.stdin.close()            # end-of-file: the child ends after the ring
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
        self._head.release()
        self._map.close()
        if error is not None:
            raise OSError(error)


class _Ring:
    """The child's end of the ring: bytes in order, then end-of-file when the caller closes."""

    def __init__(self, fd, size, alive):
        self._map = mmap.mmap(fd, _DATA + size)
        os.close(fd)
        self._head = memoryview(self._map)[:_DATA].cast('Q')
        self._size, self._alive, self._buf, self._eof = size, alive, bytearray(), False

    def _take(self):
        written, read = self._head[0], self._head[1]
        if written == read:
            return False
        size = self._size
        at, n = read % size, written - read
        first = min(n, size - at)
        self._buf += self._map[_DATA + at:_DATA + at + first]
        if n > first:
            self._buf += self._map[_DATA:_DATA + n - first]
        self._head[1] = written                 # the caller may reuse those bytes now
        return True

    def frames(self):
        """Return the calls come since the last drain (waiting for one); None at end-of-file.

        Every call first sleeps one drain period (:data:`DRAIN_S`): the child wakes 20
        times a second, not at every frame, and writes what came meanwhile in one go.
        """
        if not self._eof:
            self._wait()
        while True:
            self._head[2] += 1                  # heartbeat
            self._take()
            out = []
            at = 0
            while len(self._buf) - at >= _HEAD.size:
                n = _HEAD.unpack_from(self._buf, at)[0]
                if len(self._buf) - at - _HEAD.size < n:
                    break
                out.append(pickle.loads(self._buf[at + _HEAD.size:at + _HEAD.size + n]))
                at += _HEAD.size + n
            del self._buf[:at]
            if out:
                return out
            if self._eof:
                return None
            self._wait()

    def _wait(self):
        """Sleep one drain period, or until the caller closes (end-of-file on stdin)."""
        ready, _, _ = select.select([self._alive], [], [], DRAIN_S)
        if ready and not os.read(self._alive, 4096):
            self._eof = True                    # one more look: bytes sent before the close


def serve(path, flush_period, split_seconds, stream):
    """Run the calls from ``stream`` against a new ``BagWriter`` at ``path``; 0 on success.

    ``stream.frames()`` returns the ``(name, args)`` calls available (waiting for one), or
    None at end-of-file, where the bag is finished. Consecutive ``write_many`` calls are
    made as one (the bytes :meth:`BagWriter.write` one by one writes, fewer numpy passes).
    """
    writer = BagWriter(None, '', flush_period=flush_period, path=path,
                       split_seconds=split_seconds)
    msgs = ([], [], [])
    try:
        while True:
            calls = stream.frames()
            if calls is None:
                break
            for name, args in calls:
                if name == 'write_many':
                    for lst, more in zip(msgs, args):
                        lst.extend(more)
                    continue
                if msgs[0]:
                    writer.write_many(*msgs)
                    for lst in msgs:
                        lst.clear()
                if name not in _CALLS:
                    raise ValueError(f'unknown call {name!r}')
                getattr(writer, name)(*args)
                if name == 'close':
                    return 0
            if msgs[0]:
                writer.write_many(*msgs)
                for lst in msgs:
                    lst.clear()
    finally:
        writer.close()
    return 0


def main(argv=None):
    """``python -m rigidrot_ros.bag.process PATH FLUSH_S SPLIT_S RING_FD RING_BYTES``.

    Frames come through the shared ring ``RING_FD``; stdin only tells when the caller
    has closed (end-of-file).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)    # the parent stops us (closes stdin)
    try:
        os.nice(int(os.environ.get('RIGIDROT_RECORD_NICE', '10')))  # the node's threads first
    except (OSError, ValueError):
        pass
    argv = sys.argv[1:] if argv is None else argv
    path, flush_period, split_seconds = argv[0], float(argv[1]), float(argv[2])
    try:
        ring = _Ring(int(argv[3]), int(argv[4]), sys.stdin.fileno())
        return serve(path, flush_period, split_seconds, ring)
    except Exception as exc:  # noqa: B902 - one line naming the problem, then exit 1
        print(f'rigidrot bag writer ({path}): {type(exc).__name__}: {exc}', file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
