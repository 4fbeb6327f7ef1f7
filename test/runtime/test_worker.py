"""The look-ahead worker thread, without ROS: its calls, their errors, its shutdown."""

from rigidrot_ros.runtime.worker import BatchWorker


def test_a_call_in_the_worker_reports_its_error_and_the_worker_goes_on():
    worker = BatchWorker()
    try:
        errors, done = [], []
        worker.call(lambda: 1 / 0, errors.append)
        worker.call(lambda: done.append(True))
        assert worker.drain(timeout=30.0)
        assert [type(e) for e in errors] == [ZeroDivisionError] and done == [True]
    finally:
        worker.stop()


def test_a_second_ctrl_c_while_the_worker_stops_does_not_end_the_shutdown():
    """stop() waits the running batch out even when a KeyboardInterrupt hits its wait."""
    import signal
    import threading
    gate, ran = threading.Event(), []
    worker = BatchWorker()
    worker.call(lambda: (gate.wait(10), ran.append(1)))

    def interrupt():
        pause = threading.Event()
        pause.wait(0.2)                             # main is in stop()'s wait by then
        signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)
        pause.wait(0.2)
        gate.set()
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        threading.Thread(target=interrupt, daemon=True).start()
        worker.stop()                               # no KeyboardInterrupt out of here
    finally:
        signal.signal(signal.SIGINT, old)
    assert ran == [1] and not worker.alive


# -- the slack gate: the worker runs only where the publishing thread leaves it room ------
def test_a_call_that_evaluates_nothing_does_not_wait_for_the_evaluation_lock():
    """A chunk of the bag written in the worker never holds up the node's own evaluations."""
    import threading
    worker = BatchWorker()
    try:
        free, locked = threading.Event(), threading.Event()
        with worker.locked():                       # the publishing thread evaluates
            worker.call(free.set, evaluates=False)
            assert free.wait(30.0)
            worker.call(locked.set)
            assert not locked.wait(0.2)             # this one waits for the lock
        assert locked.wait(30.0)
    finally:
        worker.stop()
