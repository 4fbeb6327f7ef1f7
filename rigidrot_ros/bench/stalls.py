"""The machine's own stalls, seen by a real-time probe on each processor beside the node (no ROS).

A late sample has two possible causes: the node (its calls, its worker, its collector) or
the machine, which stops a processor for a while (the hypervisor of a virtual machine, the
kernel). The probe tells them apart. It runs in a process of its own, with one thread
pinned to each processor the process may use, on ``SCHED_FIFO`` at :data:`PRIORITY` (above
the node's 10 and its pacer's 11, :mod:`rigidrot_ros.runtime.realtime`) where the system
allows it. Each thread sleeps to an absolute grid of :data:`PERIOD_S` on ``CLOCK_REALTIME``
(the clock of the node's stamps) and notes each wake-up more than :data:`THRESHOLD_S` after
its due time: nothing of the node can hold it back, so such a wait is the machine's.

The threads run a loop in native code (:data:`LOOP_IR`, built once per machine by
:mod:`rigidrot_ros.runtime.native`, called without the interpreter lock), so the probe costs
a few microseconds per wake-up and sees a stall on the processor where it happens. Stop 32's
probe was one Python thread, on whichever processor was free: it missed the stalls of the
other one. Traced on the 2-core VM at 1 kHz (quiet, 62 s; the pacer's own publication
times beside two pinned probes): all three late events were the pacer's processor stopped
for 0.7 to 3.3 ms, one of them in the middle of an rcl publish, and the Python probe had
seen none of them. Where the loop cannot be built, one Python thread per processor does the
same, more coarsely (``probe: python``).

``python -m rigidrot_ros.bench.stalls OUT.json [--seconds S]`` probes for ``S`` seconds
(default: until SIGINT or SIGTERM) and writes ``{'policy', 'probe', 'cpus', 'period_s',
'threshold_s', 'wakes', 'stalls': [[due wall-clock ns, delay ns, cpu], ...]}``, stalls in
order of due time. :func:`overlapping` says which waits (e.g. a late sample's, from its stamp
to its publication) a stall covers.
"""

import argparse
import ctypes
import json
import os
import signal
import sys
import threading
import time

import numpy as np

from rigidrot_ros.runtime import native

__all__ = ['probe', 'overlapping', 'PRIORITY', 'PERIOD_S', 'THRESHOLD_S', 'LOOP_IR', 'main']

#: The probe's SCHED_FIFO priority (the node's is 10, its pacer's 11).
PRIORITY = 20
#: The probe's grid, s: a stall longer than this is always seen, to within this.
PERIOD_S = 2.5e-4
#: Wake-ups later than this are noted, s.
THRESHOLD_S = 2e-4
#: Stalls kept per processor (the earliest).
CAPACITY = 1 << 16

# control words (int64): grid, threshold, end (0: none), stop, capacity, stalls, wakes
_PER, _THR, _END, _STOP, _CAP, _COUNT, _WAKES = range(7)

LOOP_IR = native.CLOCK_IR + r'''
define i64 @rr_stalls(ptr %ctl, ptr %out) {
entry:
  %ts = alloca [2 x i64], align 8
  %pper = getelementptr i64, ptr %ctl, i64 0
  %pthr = getelementptr i64, ptr %ctl, i64 1
  %pend = getelementptr i64, ptr %ctl, i64 2
  %pstop = getelementptr i64, ptr %ctl, i64 3
  %pcap = getelementptr i64, ptr %ctl, i64 4
  %pcount = getelementptr i64, ptr %ctl, i64 5
  %pwakes = getelementptr i64, ptr %ctl, i64 6
  %per = load i64, ptr %pper
  %thr = load i64, ptr %pthr
  %end = load i64, ptr %pend
  %cap = load i64, ptr %pcap
  %t0 = call i64 @now(ptr %ts)
  %k0 = sdiv i64 %t0, %per
  %k1 = add i64 %k0, 1
  %due0 = mul i64 %k1, %per
  br label %loop

loop:
  %due = phi i64 [ %due0, %entry ], [ %due2, %next ]
  %stop = load atomic i64, ptr %pstop acquire, align 8
  %stopped = icmp ne i64 %stop, 0
  %bounded = icmp ne i64 %end, 0
  %past = icmp sge i64 %due, %end
  %over = and i1 %bounded, %past
  %quit = or i1 %stopped, %over
  br i1 %quit, label %done, label %sleep

sleep:
  call void @sleep_until(ptr %ts, i64 %due)
  %t = call i64 @now(ptr %ts)
  %late = sub i64 %t, %due
  %w = load i64, ptr %pwakes
  %w1 = add i64 %w, 1
  store atomic i64 %w1, ptr %pwakes release, align 8
  %stall = icmp sgt i64 %late, %thr
  %c = load i64, ptr %pcount
  %room = icmp slt i64 %c, %cap
  %keep = and i1 %stall, %room
  br i1 %keep, label %note, label %next

note:
  %i = mul i64 %c, 2
  %pd = getelementptr i64, ptr %out, i64 %i
  store i64 %due, ptr %pd
  %i1 = add i64 %i, 1
  %pl = getelementptr i64, ptr %out, i64 %i1
  store i64 %late, ptr %pl
  %c1 = add i64 %c, 1
  store atomic i64 %c1, ptr %pcount release, align 8
  br label %next

next:
  %d1 = add i64 %due, %per
  %long = icmp sgt i64 %late, %per
  %skip = sdiv i64 %late, %per
  %skipns = mul i64 %skip, %per
  %d2 = add i64 %d1, %skipns
  %due2 = select i1 %long, i64 %d2, i64 %d1
  br label %loop

done:
  ret i64 0
}
'''


def _policy(priority):
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return f'SCHED_FIFO {priority}'
    except (OSError, AttributeError):
        return 'SCHED_OTHER'


def _native_loop():
    """Return the native loop as a ctypes function, or None where it cannot be had."""
    try:
        addr = native.load_ir(__file__, 'stalls', LOOP_IR, 'rr_stalls')
    except native.NativeError:
        return None
    return ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p)(addr)


def _python_loop(ctl, out, stop):
    """Do the native loop's work in Python (coarser: the interpreter's own wake-up costs)."""
    import gc
    per, thr, end, cap = (int(ctl[i]) for i in (_PER, _THR, _END, _CAP))
    due = (time.time_ns() // per + 1) * per
    gc.disable()
    try:
        while not stop.is_set() and not (end and due >= end):
            left = due - time.time_ns()
            if left > 0:
                time.sleep(left / 1e9)
            late = time.time_ns() - due
            ctl[_WAKES] += 1
            c = int(ctl[_COUNT])
            if late > thr and c < cap:
                out[c] = due, late
                ctl[_COUNT] = c + 1
            due += per
            if late > per:              # a long stall: on to the next slot still ahead
                due += (late // per) * per
    finally:
        gc.enable()


def probe(seconds=None, period_s=PERIOD_S, threshold_s=THRESHOLD_S, priority=PRIORITY,
          stop=None, cpus=None, native=True):
    """Probe every processor for ``seconds`` (None: until ``stop()`` returns True).

    ``cpus``: the processors to probe (default: every one this process may use);
    ``native``: False runs the Python loop even where the native one loads. Returns the
    record :func:`main` writes.
    """
    cpus = sorted(os.sched_getaffinity(0) if cpus is None else cpus)
    fn = _native_loop() if native else None
    end = 0 if seconds is None else time.time_ns() + int(seconds * 1e9)
    ctls, outs, policies = [], [], []
    halt = threading.Event()

    def run(cpu, ctl, out):
        try:
            os.sched_setaffinity(0, {cpu})
        except OSError:
            pass
        policies.append(_policy(priority))
        if fn is not None:
            fn(ctl.ctypes.data, out.ctypes.data)
        else:
            _python_loop(ctl, out, halt)
    threads = []
    for cpu in cpus:
        ctl = np.zeros(8, dtype=np.int64)
        ctl[_PER], ctl[_THR] = int(round(period_s * 1e9)), int(round(threshold_s * 1e9))
        ctl[_END], ctl[_CAP] = end, CAPACITY
        out = np.zeros((CAPACITY, 2), dtype=np.int64)
        ctls.append(ctl)
        outs.append(out)
        threads.append(threading.Thread(target=run, args=(cpu, ctl, out), daemon=True))
    for t in threads:
        t.start()
    while any(t.is_alive() for t in threads):
        if stop is not None and stop():
            halt.set()
            for ctl in ctls:
                ctl[_STOP] = 1
        for t in threads:
            t.join(0.05)
    stalls = [[int(d), int(late), cpu] for cpu, ctl, out in zip(cpus, ctls, outs)
              for d, late in out[:int(ctl[_COUNT])]]
    stalls.sort()
    policy = sorted(set(policies))
    return {'policy': policy[0] if len(policy) == 1 else ', '.join(policy),
            'probe': 'native' if fn is not None else 'python', 'cpus': cpus,
            'period_s': period_s, 'threshold_s': threshold_s,
            'wakes': int(sum(int(ctl[_WAKES]) for ctl in ctls)), 'stalls': stalls}


def overlapping(stalls, starts_ns, ends_ns, min_ns=0):
    """Return a bool per wait ``[starts_ns[i], ends_ns[i]]``: a stall covers part of it.

    Only stalls of at least ``min_ns`` count; a stall is ``(due, delay)`` or ``(due,
    delay, cpu)``, on any processor.

    A stall ``[due, due + delay]`` (the probe's wait past its due time) overlaps a wait
    if the two intervals share a point.
    """
    starts = np.asarray(starts_ns, dtype=np.int64)
    ends = np.asarray(ends_ns, dtype=np.int64)
    out = np.zeros(len(starts), dtype=bool)
    for due, delay, *_ in stalls:
        if delay >= min_ns:
            out |= (starts <= due + delay) & (ends >= due)
    return out


def main(argv=None):
    """``python -m rigidrot_ros.bench.stalls OUT.json [--seconds S]``."""
    ap = argparse.ArgumentParser(prog='python -m rigidrot_ros.bench.stalls',
                                 description="Note the machine's stalls: wake-ups of a "
                                 'real-time 0.25 ms sleep loop on each processor past '
                                 '0.2 ms.')
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
