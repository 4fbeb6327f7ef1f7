"""The pacer's native loop: order, bytes, due times, the ring's wrap, cut, stop, rcl's codes.

The loop calls whatever function it is given with rcl's signature; here a ctypes callback
that notes each message (the node's glue passes rcl's own, tested in test/ros).
"""

import contextlib
import ctypes
import threading
import time

import numpy as np
import pytest

from rigidrot_ros.runtime import pacer as pacer_mod
from rigidrot_ros.runtime.pacer import Pacer, STATUS_PENDING

_PUBLISH = ctypes.CFUNCTYPE(ctypes.c_int32, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p)

ok, why = pacer_mod.pacer_available()
pytestmark = pytest.mark.skipif(not ok, reason=f'no native pacer here: {why}')


class _Sink:
    """A publish function: notes (publisher, bytes, clock ns) of each call; returns ``code``."""

    def __init__(self, code=0):
        self.got, self.code, self.lock = [], code, threading.Lock()
        self.fn = _PUBLISH(self._publish)
        self.address = ctypes.cast(self.fn, ctypes.c_void_p).value

    def _publish(self, pub, msg, alloc):
        words = ctypes.cast(msg, ctypes.POINTER(ctypes.c_uint64))
        data = ctypes.string_at(words[0], words[1])
        with self.lock:
            self.got.append((pub, data, time.time_ns(), words[1] == words[2], alloc))
        return self.code


@contextlib.contextmanager
def _pacer(**kwargs):
    """A :class:`Pacer` publishing into a :class:`_Sink`; stopped at the end."""
    sink = _Sink()
    p = Pacer(sink.address, **kwargs)
    try:
        yield sink, p
    finally:
        assert p.stop()


def _wait(pred, timeout=10.0):
    end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < end, 'timed out'
        time.sleep(0.002)


def test_messages_go_out_in_order_with_their_bytes_never_before_their_due_time():
    with _pacer() as (sink, p):
        a, b = p.slot(0x1000), p.slot(0x2000)
        assert (a, b, p.slot(0x1000)) == (0, 1, 0)
        t0 = time.time_ns() + 5_000_000
        sent = []
        for k in range(50):
            due = t0 + k * 400_000
            entries = [(a, f'truth {k}'.encode()), (b, bytes([k % 256]) * (k % 7 + 1))]
            assert p.push(due, entries) == 2 * k
            sent += [(0x1000 if s == a else 0x2000, d, due) for s, d in entries]
        _wait(lambda: len(sink.got) == 100)
        first, at, status = p.harvest()
        assert first == 0 and len(at) == 100 and np.all(status == 0)
        assert [(pub, data) for pub, data, *_ in sink.got] == [(pub, d) for pub, d, _ in sent]
        dues = np.array([due for *_, due in sent])
        assert np.all(at >= dues)                        # never early
        assert np.all(np.array([t for _, _, t, _, _ in sink.got]) >= dues)
        assert all(full and alloc is None for *_, full, alloc in sink.got)
        assert p.counts() == (100, 0)
        assert p.harvest()[1].size == 0                  # each entry handed back once


def test_the_ring_and_the_arena_wrap_and_refuse_rather_than_overwrite():
    with _pacer(capacity=8, arena=40) as (sink, p):
        s = p.slot(1)
        far = time.time_ns() + 3_600_000_000_000
        assert p.push(far, [(s, b'x' * 41)]) is None     # larger than the arena
        assert p.push(far, [(s, b'y' * 30)]) == 0        # held: due in an hour
        assert p.push(far, [(s, b'z' * 11)]) is None     # the arena is full (30 + 11 > 40)
        assert p.push(far, [(s, b'z' * 5)] * 2) == 1
        assert p.push(far, [(s, b'w')] * 6) is None      # the ring is full (3 + 6 > 8)
        assert p.queued() == 3
        assert p.cut()
        assert p.queued() == 0
        first, at, status = p.harvest()
        assert (first, list(status)) == (0, [STATUS_PENDING] * 3) and not sink.got
        # now many more messages than the ring holds, of sizes that wrap the arena; a row
        # is free again only once harvested, so the pushes wait for the harvests
        payloads = [bytes([k]) * (k % 13 + 1) for k in range(200)]
        now = time.time_ns()
        firsts, ats, statuses = [], [], []
        for k, data in enumerate(payloads):
            while p.push(now, [(s, data)]) is None:
                first, at, status = p.harvest()
                firsts.append(first)
                ats += at.tolist()
                statuses += status.tolist()
                time.sleep(0.001)
        _wait(lambda: len(sink.got) == 200)
        first, at, status = p.harvest()
        firsts.append(first)
        ats += at.tolist()
        statuses += status.tolist()
        assert [d for _, d, *_ in sink.got] == payloads
        assert firsts[0] == 3 and statuses == [0] * 200
        # each entry's own publication time, as the sink saw it (never before it)
        assert all(now <= a <= t for a, (*_, t, _, _) in zip(ats, sink.got))


def test_a_push_never_overwrites_a_published_entry_not_yet_harvested():
    with _pacer(capacity=8) as (sink, p):
        s = p.slot(1)
        now = time.time_ns()
        assert p.push(now, [(s, bytes([k])) for k in range(8)]) == 0
        _wait(lambda: len(sink.got) == 8 and p.queued() == 0)
        assert p.push(now, [(s, b'late')]) is None      # the 8 rows wait for harvest
        first, at, status = p.harvest()
        assert first == 0 and list(status) == [0] * 8 and np.all(at >= now)
        assert p.push(now, [(s, b'late')]) == 8
        _wait(lambda: len(sink.got) == 9)
        first, at, status = p.harvest()
        assert first == 8 and list(status) == [0]


def test_cut_drops_only_what_is_not_yet_published_and_the_loop_goes_on():
    with _pacer() as (sink, p):
        s = p.slot(7)
        now = time.time_ns()
        p.push(now, [(s, b'now')])
        _wait(lambda: len(sink.got) == 1)
        p.push(now + 3_600_000_000_000, [(s, b'later')] * 3)
        with pytest.raises(pacer_mod.PacerError):
            p.forget_slots()                # not while messages are queued
        assert p.cut()
        first, at, status = p.harvest()
        assert list(status) == [0] + [STATUS_PENDING] * 3
        p.forget_slots()
        assert p.slot(8) == 0 and p.slot(7) == 1        # indexes handed out afresh
        s = p.slot(7)
        p.push(time.time_ns(), [(s, b'after')])
        _wait(lambda: len(sink.got) == 2)
        assert [d for _, d, *_ in sink.got] == [b'now', b'after']


def test_rcl_codes_are_kept_and_a_stopped_pacer_takes_nothing():
    sink = _Sink(code=200)                  # RCL_RET_PUBLISHER_INVALID, say
    p = Pacer(sink.address)
    s = p.slot(3)
    p.push(time.time_ns(), [(s, b'a'), (s, b'b')])
    _wait(lambda: len(sink.got) == 2)
    _wait(lambda: p.queued() == 0)
    assert list(p.harvest()[2]) == [200, 200]
    assert p.counts() == (0, 2)
    assert p.stop() and p.stop()            # idempotent
    assert not p.alive
    assert p.push(time.time_ns(), [(s, b'c')]) is None
    assert p.cut()


def test_push_many_queues_several_due_times_at_once_across_the_rings_end():
    with _pacer(capacity=8, arena=64) as (sink, p):
        s = p.slot(5)
        now = time.time_ns()
        assert p.push_many([now] * 5, [s] * 5, [b'a%d' % k for k in range(5)]) == 0
        _wait(lambda: p.queued() == 0)
        first, at, status = p.harvest()                     # their rows are free again
        assert first == 0 and list(status) == [0] * 5 and np.all(at >= now)
        dues = [now + k * 2_000_000 for k in range(6)]
        datas = [bytes([65 + k]) * (k + 1) for k in range(6)]
        assert p.push_many(dues, [s] * 6, datas) == 5       # entries 5..10: slots 5..7, 0..2
        assert p.push_many([now], [s], [b'x' * 60]) is None  # no room in the arena now
        _wait(lambda: len(sink.got) == 11)
        assert [d for _, d, *_ in sink.got[5:]] == datas
        first, at, status = p.harvest()
        assert first == 5 and list(status) == [0] * 6 and np.all(at >= np.array(dues))
        assert p.push_many([], [], []) is None               # nothing to queue


def test_with_a_spin_before_the_due_time_nothing_goes_out_early_either():
    with _pacer() as (sink, p):
        p.spin_ns = 1_500_000               # read the clock for the last 1.5 ms
        assert p.spin_ns == 1_500_000
        s = p.slot(9)
        t0 = time.time_ns() + 2_000_000
        dues = [t0 + k * 700_000 for k in range(30)]
        for due in dues:
            p.push(due, [(s, b'm')])
        _wait(lambda: len(sink.got) == 30)
        _, at, status = p.harvest()
        assert np.all(status == 0) and np.all(at >= np.array(dues))
        assert all(t >= due for (_, _, t, _, _), due in zip(sink.got, dues))


def test_a_late_call_s_big_push_keeps_every_earlier_call_s_publication_record():
    """The node's case (ros.pacing.PacedCalls): calls queued and published, then one call,
    late by most of the ring, queues nearly a ring's worth before it harvests. Every call
    must come back whole from the harvest, each item published (status 0)."""
    from rigidrot_ros.ros.pacing import PacedCalls

    class Pub:                      # what PacedCalls reads of an rclpy publisher
        def __init__(self, pointer):
            self.handle = type('Handle', (), {'pointer': pointer})()
    with _pacer(capacity=16) as (sink, p):
        paced = PacedCalls(p)
        pubs = [Pub(0x100 + k) for k in range(2)]
        now = time.time_ns()

        def calls(first, n, due):
            return [(due, [(pub, None, b'%d' % (first + k)) for pub in pubs],
                     ('call', first + k), None) for k in range(n)]
        assert paced.push_many(calls(0, 3, now))               # 6 entries, published
        _wait(lambda: len(sink.got) == 6)
        # 14 more, due in an hour: 20 entries > 16 rows, so rows of the first calls are
        # reused, which is right only once their times and codes are taken
        assert paced.push_many(calls(3, 7, now + 3_600_000_000_000))
        out = paced.harvest()
        assert [c for _, c, _, _, _, _ in out] == [('call', k) for k in range(3)]
        assert all(sent == 2 and not statuses for _, _, _, sent, _, statuses in out)
        assert all(at >= now for *_, at, _ in out)
        assert len(paced) == 7 and p.cut()
