"""The node's scheduler calls published by the native pacer at >= 1 kHz (rclpy glue).

Where the node's scheduler period is at most :data:`PACE_PERIOD_NS` and its clock is the
system clock, each call runs :data:`~rigidrot_ros.runtime.pacer.LEAD_S` ahead of the time
it serves and hands its messages to a :class:`~rigidrot_ros.runtime.pacer.Pacer`, whose
native thread publishes them at that time without the interpreter lock
(:class:`PacedCalls`). What a call published, when, and whether rcl took it, comes back
through :meth:`PacedCalls.harvest`; the node then records, counts and announces as it did
for a call it published itself.
"""

import collections
import ctypes
import os

from rigidrot_ros.runtime.pacer import Pacer, PacerError, STATUS_PENDING

__all__ = ['PacedCalls', 'PacerError', 'PACE_PERIOD_NS', 'PACED_CALL_NS', 'SPIN_NS',
           'STATUS_PENDING', 'rcl_publish_address']

#: The node paces its calls where its scheduler period is at most this (1 kHz and up):
#: there a call's lateness in the interpreter made samples late (doc/node.md).
PACE_PERIOD_NS = 1_000_000
#: Paced, the scheduler calls come this often (each serves every slot of the lead).
PACED_CALL_NS = 1_000_000
#: The pacer stops sleeping this long before a due time and reads the clock until it
#: (at most a quarter of the grid's period): a processor left idle in a virtual machine
#: wakes late (doc/node.md, the pacer).
SPIN_NS = 50_000


def _loaded(name):
    """Return the path of the loaded shared library ``name`` (``/proc/self/maps``), or None."""
    try:
        with open('/proc/self/maps', encoding='utf-8', errors='replace') as fh:
            for line in fh:
                path = line.rstrip('\n').split(maxsplit=5)[-1]
                if os.path.basename(path).split('.so')[0] == name.split('.so')[0] and \
                        '.so' in path:
                    return path
    except OSError:
        pass
    return None


def rcl_publish_address():
    """Return the address of rcl's ``rcl_publish_serialized_message`` in this process.

    rcl is loaded by rclpy (imported before this is called); it is looked up, never loaded
    again. Raises :class:`PacerError` where it is not found.
    """
    mode = getattr(os, 'RTLD_NOLOAD', 4)
    for name in ('librcl.so', _loaded('librcl.so')):
        if not name:
            continue
        try:
            lib = ctypes.CDLL(name, mode=mode)
            return ctypes.cast(lib.rcl_publish_serialized_message, ctypes.c_void_p).value
        except (OSError, AttributeError):
            continue
    raise PacerError('rcl (librcl.so) is not loaded in this process')


class PacedCalls:
    """The node's calls queued on a :class:`Pacer`, in order, until they are published.

    Each call is ``items`` (``(publisher, message class, bytes)`` in publishing order),
    the :class:`~rigidrot_ros.run.schedule.Call` and the stamps its latencies wait for
    (:meth:`~rigidrot_ros.run.schedule.Schedule.note_published`). Raises
    :class:`PacerError` where the pacer cannot run here.
    """

    def __init__(self, pacer=None):
        self.pacer = pacer if pacer is not None else Pacer(rcl_publish_address())
        self._calls = collections.deque()    # (first entry, items, call, pending)
        #: The due time of the last call queued and not cut (ns), or None
        self.last_due = None
        self._slots = {}                     # publisher -> the pacer's index of it
        self._at, self._status, self._base = [], [], 0   # finished entries from _base

    def push_many(self, calls):
        """Queue several calls ``(due_ns, items, call, pending)``, due times in order.

        All or nothing: False (nothing queued) without room for them all.
        """
        self._absorb()                       # the rows the pacer has finished are free
        dues, pubs, datas = [], [], []
        for due_ns, items, _, _ in calls:
            for pub, _, raw in items:
                dues.append(due_ns)
                pubs.append(self._slot(pub))
                datas.append(raw)
        first = self.pacer.push_many(dues, pubs, datas)
        if first is None:
            return False
        for due_ns, items, call, pending in calls:
            self._calls.append((first, items, call, pending))
            first += len(items)
        self.last_due = calls[-1][0]
        return True

    def _slot(self, pub):
        slot = self._slots.get(pub)
        if slot is None:
            slot = self._slots[pub] = self.pacer.slot(pub.handle.pointer)
        return slot

    def __len__(self):
        return len(self._calls)

    def _absorb(self):
        """Take the publication times and codes of the entries the pacer has finished."""
        _, at, status = self.pacer.harvest()
        if len(at):
            self._at += at.tolist()
            self._status += status.tolist()

    def harvest(self):
        """Return the calls finished since the last harvest, oldest first.

        Each as ``(items, call, pending, sent, at_ns, statuses)``: ``sent`` the leading
        items rcl took (the rest failed, or were cut), ``at_ns`` the pacer's clock at
        their publication, ``statuses`` rcl's codes of the items not sent (or
        :data:`STATUS_PENDING`: cut before publication).
        """
        self._absorb()
        out = []
        while self._calls:
            start, items, call, pending = self._calls[0]
            end = start + len(items) - self._base
            if end > len(self._at):
                break
            self._calls.popleft()
            lo = start - self._base
            st = self._status[lo:end]
            sent = next((i for i, s in enumerate(st) if s != 0), len(st))
            out.append((items, call, pending, sent, self._at[lo], st[sent:]))
        done = (self._calls[0][0] - self._base) if self._calls else len(self._at)
        if done:
            del self._at[:done], self._status[:done]
            self._base += done
        return out

    def cut(self):
        """Drop what is queued and not yet published; the calls finished (:meth:`harvest`)."""
        self.pacer.cut()
        self.last_due = None
        out = self.harvest()
        # the publishers may be destroyed now (a reset's topics that go): their indexes too
        self._slots.clear()
        self.pacer.forget_slots()
        return out

    def stop(self):
        """Stop the pacer; return every call left, finished or not (:meth:`harvest`'s form).

        A call the pacer did not get to is returned with ``sent`` 0.
        """
        self.pacer.stop()
        out = self.harvest()
        while self._calls:
            _, items, call, pending = self._calls.popleft()
            out.append((items, call, pending, 0, None, [STATUS_PENDING] * len(items)))
        return out
