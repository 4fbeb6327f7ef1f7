"""An iterator's next item made on a thread of its own while the caller uses the current one.

:func:`prefetch` runs an iterator on a worker thread, ``depth`` items ahead of its
caller (offline generation evaluates the next span of samples while the current one is
packed and written). The items arrive in their order, each made once, by the one worker
thread (the iterator's own state, e.g. a sensor's noise stream, is never touched by two
threads). An exception of the iterator is raised on the caller's thread where it asks
for the item that failed; closing the returned generator (or leaving it) stops the worker
after the item it is making, and waits for it.
"""

import queue
import threading

__all__ = ['prefetch']

_END = object()
#: Seconds between the worker's checks for a stop while its queue is full.
_POLL_S = 0.05


def prefetch(items, depth=1, name='rigidrot_prefetch'):
    """Yield the items of ``items`` in order, made up to ``depth`` ahead on a worker thread.

    Parameters
    ----------
    items : iterable
        Iterated on the worker thread only (started at the first ``next``).
    depth : int
        Items made and not yet taken, at most (memory: that many items more).
    name : str
        The worker thread's name.
    """
    if depth < 1:
        raise ValueError(f'prefetch depth must be at least 1, got {depth!r}')
    box = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def hand(entry):
        while not stop.is_set():
            try:
                box.put(entry, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def work():
        try:
            for item in items:
                if not hand((item, None)):
                    return
            hand((_END, None))
        except BaseException as exc:    # noqa: B902 - raised on the caller's thread
            hand((_END, exc))

    worker = threading.Thread(target=work, name=name, daemon=True)
    worker.start()
    try:
        while True:
            item, exc = box.get()
            if exc is not None:
                raise exc
            if item is _END:
                return
            yield item
    finally:
        stop.set()
        worker.join()
