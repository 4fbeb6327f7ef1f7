"""Serialized messages published at their due times by a thread without the interpreter (no rclpy).

At 2 and 4 kHz the node's publishing shared the interpreter with everything else the node
does: the look-ahead worker, the recorder, the executor, the collector. Whatever held the
interpreter when a call fell due made the call late, and the messages with it (a quiet
machine: 4.5 % of the gyro samples more than a period late at 2 kHz, 16 % at 4 kHz, where a
bare publishing loop is at 0 % and 0.03 %).

A :class:`Pacer` takes that wait out of the interpreter. The node's scheduler runs its calls
a lead ahead (:data:`LEAD_S`) and hands each call's messages here, with the call's due time;
a native loop (LLVM IR, :data:`LOOP_IR`, built once and loaded as machine code by
:mod:`rigidrot_ros.runtime.native`) sleeps until that time on ``CLOCK_REALTIME`` (the ROS
system clock; the last :attr:`Pacer.spin_ns` before it, it reads the clock instead) and
publishes the bytes with rcl's ``rcl_publish_serialized_message``, without ever taking the
interpreter lock. It notes each message's publication time (its clock reading at the
wake-up, as the node's recorder logs it) and rcl's return code; the node reads those back
(:meth:`Pacer.harvest`) to record, count and report. With the ring empty it looks again
every :data:`IDLE_NS`.

**The queue** is a ring of :data:`CAPACITY` entries (due time, publisher, offset and length
of the bytes, publication time, status) and a byte arena, in numpy arrays. The
interpreter side is the only writer of entries and of ``WRITE``, the loop the only writer
of ``READ`` and of the results; x86-64 keeps stores in order, and the loop reads ``WRITE``
with acquire and writes ``READ`` with release semantics. Entries are taken in order: one
due in the future holds those behind it. :meth:`Pacer.cut` drops every entry not yet
published (a reset); :meth:`Pacer.stop` ends the loop after its current message.

The publishers are rcl's (``rclpy``'s ``Publisher.handle.pointer``); the caller gives
rcl's function's address and keeps each publisher alive while entries for it are queued
(it cuts first).
"""

import atexit
import ctypes
import os
import threading
import time

import numpy as np

from rigidrot_ros.runtime import native

__all__ = ['Pacer', 'PacerError', 'LEAD_S', 'CAPACITY', 'ARENA', 'STATUS_PENDING',
           'pacer_available']

#: How far ahead of its due time the node's scheduler call runs: the interpreter's
#: lateness up to this much does not reach the publication.
LEAD_S = 20e-3
#: Entries in the ring (messages queued at most).
CAPACITY = 1 << 13
#: Bytes of the arena (the queued messages' bytes).
ARENA = 1 << 22
#: The loop's sleep when the ring is empty, and its longest sleep before looking at the
#: control words again (a cut, a stop), ns.
IDLE_NS, MAX_WAIT_NS = 1_000_000, 2_000_000
#: An entry's status before the loop has published it (rcl's return codes are >= 0).
STATUS_PENDING = -1

# control words (int64)
_WRITE, _READ, _STOP, _CUT, _CAP, _IDLE, _MAXW, _SENT, _FAILED, _SPIN = range(10)
# entry fields (int64)
_DUE, _PUB, _OFF, _LEN, _AT, _STATUS = range(6)

LOOP_IR = native.CLOCK_IR + r'''
define i64 @rr_pace(ptr %ctl, ptr %ent, ptr %arena, ptr %pubs, ptr %publish) {
entry:
  %ts = alloca [2 x i64], align 8
  %msg = alloca [8 x i64], align 8
  call void @llvm.memset.p0.i64(ptr %msg, i8 0, i64 64, i1 false)
  %pwrite = getelementptr i64, ptr %ctl, i64 0
  %pread = getelementptr i64, ptr %ctl, i64 1
  %pstop = getelementptr i64, ptr %ctl, i64 2
  %pcut = getelementptr i64, ptr %ctl, i64 3
  %pcap = getelementptr i64, ptr %ctl, i64 4
  %pidle = getelementptr i64, ptr %ctl, i64 5
  %pmaxw = getelementptr i64, ptr %ctl, i64 6
  %psent = getelementptr i64, ptr %ctl, i64 7
  %pfail = getelementptr i64, ptr %ctl, i64 8
  %cap = load i64, ptr %pcap
  %mbuf = getelementptr i64, ptr %msg, i64 0
  %mlen = getelementptr i64, ptr %msg, i64 1
  %mcap = getelementptr i64, ptr %msg, i64 2
  br label %loop

loop:
  %stop = load atomic i64, ptr %pstop acquire, align 8
  %stopped = icmp ne i64 %stop, 0
  br i1 %stopped, label %done, label %checkcut

checkcut:
  %cut = load atomic i64, ptr %pcut acquire, align 8
  %cutting = icmp ne i64 %cut, 0
  br i1 %cutting, label %docut, label %peek

docut:
  %wc = load atomic i64, ptr %pwrite acquire, align 8
  store atomic i64 %wc, ptr %pread release, align 8
  store atomic i64 0, ptr %pcut release, align 8
  br label %loop

peek:
  %r = load atomic i64, ptr %pread monotonic, align 8
  %w = load atomic i64, ptr %pwrite acquire, align 8
  %empty = icmp sge i64 %r, %w
  %t0 = call i64 @now(ptr %ts)
  br i1 %empty, label %idle, label %head

idle:
  %idle_ns = load i64, ptr %pidle
  %tidle = add i64 %t0, %idle_ns
  call void @sleep_until(ptr %ts, i64 %tidle)
  br label %loop

head:
  %slot = urem i64 %r, %cap
  %row = mul i64 %slot, 6
  %pdue = getelementptr i64, ptr %ent, i64 %row
  %due = load i64, ptr %pdue
  %future = icmp sgt i64 %due, %t0
  br i1 %future, label %wait, label %publish_loop

wait:
  %maxw = load i64, ptr %pmaxw
  %limit = add i64 %t0, %maxw
  %early = icmp slt i64 %due, %limit
  br i1 %early, label %wait_due, label %wait_long

wait_long:
  call void @sleep_until(ptr %ts, i64 %limit)
  br label %loop

wait_due:
  %pspin = getelementptr i64, ptr %ctl, i64 9
  %spin = load i64, ptr %pspin
  %wake = sub i64 %due, %spin
  %sleeps = icmp sgt i64 %wake, %t0
  br i1 %sleeps, label %nap, label %spinning

nap:
  call void @sleep_until(ptr %ts, i64 %wake)
  br label %spinning

spinning:
  %ts_ = call i64 @now(ptr %ts)
  %yet = icmp slt i64 %ts_, %due
  br i1 %yet, label %spinning, label %loop

publish_loop:
  %i = phi i64 [ %r, %head ], [ %i1, %next_due ]
  %s2 = urem i64 %i, %cap
  %row2 = mul i64 %s2, 6
  %e = getelementptr i64, ptr %ent, i64 %row2
  %ppub = getelementptr i64, ptr %e, i64 1
  %poff = getelementptr i64, ptr %e, i64 2
  %plen = getelementptr i64, ptr %e, i64 3
  %pat = getelementptr i64, ptr %e, i64 4
  %pstatus = getelementptr i64, ptr %e, i64 5
  %pubi = load i64, ptr %ppub
  %off = load i64, ptr %poff
  %len = load i64, ptr %plen
  %buf = getelementptr i8, ptr %arena, i64 %off
  store ptr %buf, ptr %mbuf
  store i64 %len, ptr %mlen
  store i64 %len, ptr %mcap
  %pp = getelementptr ptr, ptr %pubs, i64 %pubi
  %pub = load ptr, ptr %pp
  %ret = call i32 %publish(ptr %pub, ptr %msg, ptr null)
  %ret64 = sext i32 %ret to i64
  store i64 %t0, ptr %pat
  store i64 %ret64, ptr %pstatus
  %ok = icmp eq i32 %ret, 0
  %pcount = select i1 %ok, ptr %psent, ptr %pfail
  %count = load i64, ptr %pcount
  %count1 = add i64 %count, 1
  store i64 %count1, ptr %pcount
  %i1 = add i64 %i, 1
  store atomic i64 %i1, ptr %pread release, align 8
  %more = icmp slt i64 %i1, %w
  br i1 %more, label %next_due, label %loop

next_due:
  %s3 = urem i64 %i1, %cap
  %row3 = mul i64 %s3, 6
  %pdue3 = getelementptr i64, ptr %ent, i64 %row3
  %due3 = load i64, ptr %pdue3
  %now_due = icmp sle i64 %due3, %t0
  br i1 %now_due, label %publish_loop, label %loop

done:
  ret i64 0
}

declare void @llvm.memset.p0.i64(ptr, i8, i64, i1)
'''

_LOOP = {}
_LOCK = threading.Lock()


class PacerError(RuntimeError):
    """The pacer cannot be had here (no object code loader, a build failure): one line why."""


def _loop_address():
    """Return the native loop's address (built once per machine, then loaded from the cache)."""
    with _LOCK:
        if 'addr' not in _LOOP:
            try:
                _LOOP['addr'] = native.load_ir(__file__, 'pacer', LOOP_IR, 'rr_pace')
            except native.NativeError as exc:
                _LOOP['addr'] = None
                _LOOP['why'] = str(exc)
        if _LOOP['addr'] is None:
            raise PacerError(_LOOP['why'])
        return _LOOP['addr']


def pacer_available():
    """Return ``(True, '')`` if the native loop loads here, else ``(False, why)``."""
    try:
        _loop_address()
    except PacerError as exc:
        return False, str(exc)
    return True, ''


class Pacer:
    """A native thread that publishes queued serialized messages at their due times.

    Parameters
    ----------
    publish : int
        The address of ``rcl_ret_t rcl_publish_serialized_message(const rcl_publisher_t *,
        const rcl_serialized_message_t *, rmw_publisher_allocation_t *)`` or of a function
        of that signature.
    capacity, arena : int
        Entries of the ring, bytes of the arena.
    priority : int or None
        With the caller on ``SCHED_FIFO``: the loop's thread asks for this priority
        (default: the caller's plus one, so that it preempts the process's own threads).

    Raises :class:`PacerError` where the loop cannot be had.
    """

    def __init__(self, publish, capacity=CAPACITY, arena=ARENA, priority=None,
                 name='rigidrot-pacer'):
        addr = _loop_address()
        self._fn = ctypes.CFUNCTYPE(ctypes.c_int64, *[ctypes.c_void_p] * 5)(addr)
        self.capacity = int(capacity)
        self.ctl = np.zeros(16, dtype=np.int64)
        self.ctl[_CAP], self.ctl[_IDLE], self.ctl[_MAXW] = self.capacity, IDLE_NS, MAX_WAIT_NS
        self.ent = np.zeros((self.capacity, 6), dtype=np.int64)
        self.arena = np.zeros(int(arena), dtype=np.uint8)
        self._pubs = np.zeros(64, dtype=np.uint64)
        self._slots = {}            # publisher pointer -> index in _pubs
        self._publish = int(publish)
        self._written = 0           # entries written (mirrors ctl[WRITE])
        self._harvested = 0         # entries handed back by harvest()
        self._head = 0              # the arena's next free byte
        self._priority = priority
        self._ended = threading.Event()
        self.error = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()
        # the loop never takes the interpreter, so interpreter exit would not stop it: it
        # would go on publishing through what the exit frees
        atexit.register(self.stop)

    def _run(self):
        try:
            if hasattr(os, 'sched_getscheduler') and \
                    os.sched_getscheduler(0) == getattr(os, 'SCHED_FIFO', -1):
                prio = self._priority
                if prio is None:
                    prio = min(os.sched_getparam(0).sched_priority + 1, 99)
                try:
                    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
                except OSError:
                    pass
            self._fn(self.ctl.ctypes.data, self.ent.ctypes.data, self.arena.ctypes.data,
                     self._pubs.ctypes.data, self._publish)
        except Exception as exc:  # noqa: B902 - reported through alive/error
            self.error = exc
        finally:
            self._ended.set()

    @property
    def alive(self):
        """Whether the loop runs."""
        return not self._ended.is_set()

    def slot(self, pointer):
        """Return the index of the publisher ``pointer`` (an ``rcl_publisher_t *``)."""
        pointer = int(pointer)
        i = self._slots.get(pointer)
        if i is None:
            i = len(self._slots)
            if i >= len(self._pubs):
                raise PacerError(f'more than {len(self._pubs)} publishers')
            self._pubs[i] = pointer
            self._slots[pointer] = i
        return i

    def forget_slots(self):
        """Forget every publisher's index (nothing may be queued: after a :meth:`cut`)."""
        if self._written != int(self.ctl[_READ]):
            raise PacerError('publishers forgotten while messages are queued')
        self._slots.clear()
        self._pubs[:] = 0

    def queued(self):
        """Return the entries written and not yet published (nor cut)."""
        return self._written - int(self.ctl[_READ])

    def push(self, due_ns, entries):
        """Queue ``entries`` (``(publisher slot, bytes)``), all due at ``due_ns``.

        Returns the index of the first entry (:meth:`harvest` reports them by index), or
        None when the ring or the arena has no room (the loop has stopped, or lags by
        thousands of messages, or the published entries wait for :meth:`harvest`): nothing
        is queued then.
        """
        return self.push_many([due_ns] * len(entries), [p for p, _ in entries],
                              [d for _, d in entries])

    def push_many(self, dues, pubs, datas):
        """Queue messages: ``datas[i]`` (bytes) to publisher slot ``pubs[i]`` at ``dues[i]``.

        The due times must not decrease (the loop takes entries in order). One set of
        array writes for them all; the first index, or None (nothing queued) as :meth:`push`.
        """
        n = len(datas)
        read = int(self.ctl[_READ])
        # an entry's row is free once harvested (its time and status handed back), not
        # once published: a push past that would overwrite what harvest has yet to read
        if n == 0 or not self.alive or self._written + n - self._harvested > self.capacity:
            return None
        sizes = np.fromiter(map(len, datas), dtype=np.int64, count=n)
        total = int(sizes.sum())
        head = self._place(total, read)
        if head is None:
            return None
        first = self._written
        self.arena[head:head + total] = np.frombuffer(b''.join(datas), dtype=np.uint8)
        block = np.empty((n, 6), dtype=np.int64)
        block[:, _DUE], block[:, _PUB] = dues, pubs
        block[:, _OFF] = np.cumsum(sizes) - sizes + head
        block[:, _LEN] = sizes
        block[:, _AT], block[:, _STATUS] = 0, STATUS_PENDING
        lo = first % self.capacity
        if lo + n <= self.capacity:
            self.ent[lo:lo + n] = block
        else:
            k = self.capacity - lo
            self.ent[lo:], self.ent[:n - k] = block[:k], block[k:]
        self._head = head + total
        self._written = first + n
        self.ctl[_WRITE] = self._written        # after the entries: x86 keeps the order
        return first

    def _place(self, total, read):
        """Return where ``total`` bytes go in the arena, or None where they do not fit.

        The bytes in use run from the oldest queued entry's (``read``) to :attr:`_head`,
        maybe wrapped round; a message's bytes are never split.
        """
        cur, size = self._head, len(self.arena)
        if read >= self._written:                   # nothing queued: all free
            return cur if cur + total <= size else (0 if total <= size else None)
        lo = int(self.ent[read % self.capacity, _OFF])
        if cur >= lo:               # in use [lo, cur): free [cur, size) and [0, lo)
            if cur + total <= size:
                return cur
            return 0 if total < lo else None
        return cur if cur + total < lo else None    # in use [lo, size) and [0, cur)

    def harvest(self):
        """Return ``(first, at_ns, status)`` of the entries finished since the last harvest.

        ``at_ns`` and ``status`` are int64 arrays, one item per entry from index ``first``:
        the loop's clock reading when it published the entry and rcl's return code (0:
        published), or :data:`STATUS_PENDING` for an entry cut before it was published.
        """
        first, done = self._harvested, int(self.ctl[_READ])
        idx = np.arange(first, done) % self.capacity
        self._harvested = done
        return first, self.ent[idx, _AT].copy(), self.ent[idx, _STATUS].copy()

    def cut(self, timeout=1.0):
        """Drop every entry not yet published; True once the loop has (or is not running)."""
        if not self.alive:
            self.ctl[_READ] = self._written
            return True
        self.ctl[_CUT] = 1
        end = time.monotonic() + timeout
        while self.ctl[_CUT] and self.alive and time.monotonic() < end:
            time.sleep(1e-4)
        if not self.alive:
            self.ctl[_READ] = self._written
            return True
        return not self.ctl[_CUT]

    def stop(self, timeout=1.0):
        """End the loop (after the message it is publishing); True once it has. Idempotent."""
        self.ctl[_STOP] = 1
        atexit.unregister(self.stop)
        return self._ended.wait(timeout)

    @property
    def spin_ns(self):
        """How long before a due time the loop stops sleeping and reads the clock instead (ns)."""
        return int(self.ctl[_SPIN])

    @spin_ns.setter
    def spin_ns(self, ns):
        self.ctl[_SPIN] = max(0, int(ns))

    def counts(self):
        """Return ``(published, failed)``: the loop's totals."""
        return int(self.ctl[_SENT]), int(self.ctl[_FAILED])
