"""The machine's own stalls, seen by a real-time probe beside the node (no ROS).

A late sample has two possible causes: the node (its calls, its worker, its collector) or
the machine, which stops every process for a while (the hypervisor of a virtual machine,
the kernel). The probe tells them apart. It runs in a process of its own, on
``SCHED_FIFO`` at :data:`PRIORITY` (above the node's 10, :mod:`rigidrot_ros.runtime.realtime`)
where the system allows it, sleeps to an absolute grid of :data:`PERIOD_S` and notes each
wake-up more than :data:`THRESHOLD_S` after its due time: nothing of the node can hold it
back, so such a wait is the machine's. Measured on the 2-core VM with nothing else running:
39 wake-ups past 0.3 ms in 120 s, 8 of them past 1 ms, the longest 2.0 ms; in other runs
up to 4 ms.

``python -m rigidrot_ros.bench.stalls OUT.json [--seconds S]`` probes for ``S`` seconds
(default: until SIGINT or SIGTERM) and writes ``{'policy', 'period_s', 'wakes', 'stalls':
[[due wall-clock ns, delay ns], ...]}``. :func:`overlapping` says which waits (e.g. a late
sample's, from its stamp to its publication) a stall covers.
"""

import argparse
import json
import os
import signal
import sys
import time

import numpy as np

__all__ = ['probe', 'overlapping', 'PRIORITY', 'PERIOD_S', 'THRESHOLD_S', 'main']

#: The probe's SCHED_FIFO priority (the node's is 10).
PRIORITY = 20
#: The probe's grid, s.
PERIOD_S = 1e-3
#: Wake-ups later than this are noted, s.
THRESHOLD_S = 3e-4


def _policy(priority):
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return f'SCHED_FIFO {priority}'
    except (OSError, AttributeError):
        return 'SCHED_OTHER'


def probe(seconds=None, period_s=PERIOD_S, threshold_s=THRESHOLD_S, priority=PRIORITY,
          stop=None):
    """Probe for ``seconds`` (None: until ``stop()`` returns True); return the record.

    The garbage collector is off meanwhile (the probe allocates a tuple per stall only).
    """
    import gc
    policy = _policy(priority)
    gc.disable()
    per = int(round(period_s * 1e9))
    limit = int(round(threshold_s * 1e9))
    clock = time.CLOCK_MONOTONIC
    due = time.clock_gettime_ns(clock) + per
    end = None if seconds is None else due + int(seconds * 1e9)
    stalls, wakes = [], 0
    try:
        while (end is None or due < end) and not (stop is not None and stop()):
            left = due - time.clock_gettime_ns(clock)
            if left > 0:
                time.sleep(left / 1e9)
            late = time.clock_gettime_ns(clock) - due
            wakes += 1
            if late > limit:
                stalls.append((time.time_ns() - late, late))
            due += per
            if late > per:              # a long stall: on to the next slot still ahead
                due += (late // per) * per
    finally:
        gc.enable()
    return {'policy': policy, 'period_s': period_s, 'threshold_s': threshold_s,
            'wakes': wakes, 'stalls': [list(s) for s in stalls]}


def overlapping(stalls, starts_ns, ends_ns, min_ns=0):
    """Return a bool per wait ``[starts_ns[i], ends_ns[i]]``: a stall covers part of it.

    Only stalls of at least ``min_ns`` count.

    A stall ``[due, due + delay]`` (the probe's wait past its due time) overlaps a wait
    if the two intervals share a point.
    """
    starts = np.asarray(starts_ns, dtype=np.int64)
    ends = np.asarray(ends_ns, dtype=np.int64)
    out = np.zeros(len(starts), dtype=bool)
    for due, delay in stalls:
        if delay >= min_ns:
            out |= (starts <= due + delay) & (ends >= due)
    return out


def main(argv=None):
    """``python -m rigidrot_ros.bench.stalls OUT.json [--seconds S]``."""
    ap = argparse.ArgumentParser(prog='python -m rigidrot_ros.bench.stalls',
                                 description="Note the machine's stalls: wake-ups of a "
                                 'real-time 1 ms sleep loop past 0.3 ms.')
    ap.add_argument('out', help='JSON file to write at the end')
    ap.add_argument('--seconds', type=float, default=None,
                    help='how long (default: until SIGINT or SIGTERM)')
    args = ap.parse_args(argv)
    stopped = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stopped.append(True))
    rec = probe(args.seconds, stop=lambda: bool(stopped))
    with open(args.out, 'w') as fh:
        json.dump(rec, fh)
    return 0


if __name__ == '__main__':
    sys.exit(main())
