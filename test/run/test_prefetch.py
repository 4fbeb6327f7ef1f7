"""run.prefetch: an iterator made one ahead on a worker thread, as if iterated in place."""

import threading
import time

import pytest

from rigidrot_ros.run.prefetch import prefetch


def _alive():
    return [t for t in threading.enumerate() if t.name == 'probe_prefetch']


def test_items_in_order_each_made_once_on_one_thread():
    made = []

    def items():
        for i in range(50):
            made.append((i, threading.current_thread().name))
            yield i
    assert list(prefetch(items(), depth=2, name='probe_prefetch')) == list(range(50))
    assert [i for i, _ in made] == list(range(50))
    assert {name for _, name in made} == {'probe_prefetch'}
    assert not _alive()


def test_made_ahead_of_the_caller():
    made = []

    def items():
        for i in range(5):
            made.append(i)
            yield i
    got = prefetch(items(), depth=1, name='probe_prefetch')
    assert next(got) == 0
    deadline = time.monotonic() + 5
    while len(made) < 3 and time.monotonic() < deadline:   # 1 queued, 1 waiting to be
        time.sleep(0.01)
    assert len(made) == 3                                  # no further than that
    got.close()
    assert not _alive()


def test_an_error_is_raised_where_its_item_is_asked_for():
    def items():
        yield 1
        yield 2
        raise KeyError('third')
    got = prefetch(items(), name='probe_prefetch')
    assert next(got) == 1 and next(got) == 2
    with pytest.raises(KeyError, match='third'):
        next(got)
    assert not _alive()


def test_leaving_early_stops_the_worker():
    stopped = []

    def items():
        try:
            for i in range(10 ** 6):
                yield i
        finally:
            stopped.append(True)
    for i in prefetch(items(), name='probe_prefetch'):
        if i == 3:
            break
    # the generator is closed when dropped (CPython: at once); the worker then ends
    deadline = time.monotonic() + 5
    while _alive() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not _alive() and stopped == [True]         # and the iterator closed
    with pytest.raises(ValueError, match='depth'):
        next(prefetch(iter(()), depth=0))
