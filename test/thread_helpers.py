"""Helpers for tests of threads and the interpreter's asynchronous-exception flag."""

import sys
import threading


def profiled_calls(n=2000):
    """Start a thread that makes ``n`` Python calls under a profile function; its end event.

    With the interpreter's flag of a pending asynchronous exception left up, such a thread
    spins at its first call (:mod:`rigidrot_ros.runtime.interrupt`) and never ends.
    """
    done = threading.Event()

    def call():
        return None

    def body():
        sys.setprofile(lambda frame, event, arg: None)
        try:
            for _ in range(n):
                call()
        finally:
            sys.setprofile(None)
        done.set()
    threading.Thread(target=body, daemon=True).start()
    return done
