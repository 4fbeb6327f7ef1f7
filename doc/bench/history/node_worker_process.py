"""Prototype (issue 26): is the look-ahead's lateness the shared interpreter? thread vs process.

Run from a checkout: ``PYTHONPATH=. ROS_DOMAIN_ID=<id> python
doc/bench/history/node_worker_process.py MODE RATE SECONDS [CHILD_PRIORITY]`` (root or
CAP_SYS_NICE: the loop runs on SCHED_FIFO 10); ``PROTO_GC=0`` turns the loop's collector
off (as in the runs quoted in node_worker_process.md), ``PROTO_SWITCH`` sets the
interpreter's switch interval (s) in the thread and node modes. Not part of the package.

One publishing loop (SCHED_FIFO 10, like the node), truth + gyro at RATE Hz, every sample's
bytes published with rclpy (raw CDR) at its grid time. The bytes come from the real
evaluation code (TruthAhead / Sensor batches of 256, built = serialized), produced:

- pre:     all evaluated before the loop starts (no concurrent work: the floor);
- thread:  by a producer thread of the same interpreter (switch interval 1e-4, as the node);
- process: by a child process (spawned) into a shared-memory ring; the loop unpickles
           the ready batches and publishes their bytes;
- node:    the node's own path: Schedule.collect/refill/open_gate with a BatchWorker+gate.

Prints: samples per stream, late (> one period after stamp at publication), p99 delay.
"""

from collections import deque
import multiprocessing as mp
from multiprocessing import shared_memory
import os
import pickle
import struct
import sys
import threading
import time

BATCH = 256
RING = 32 << 20


def setup_for(rate):
    from rigidrot_ros.run import params, settings
    values = params.defaults()
    values.update({'imu.enable': True, 'publish_rate': float(rate), 'imu.rate': float(rate)})
    return values, settings.prepare_run(values)


def make_schedule(setup, g0, rate, worker=None):
    from rigidrot_ros.run.schedule import Schedule
    from rigidrot_ros.runtime import diagnostics
    counters = diagnostics.Counters()
    sch = Schedule(setup, counters, lambda: ('world', 'body'), worker)
    sch.retime(rate)
    return sch, counters


def producer_batches(values, rate, g0, seconds, emit, full=lambda: False):
    """Evaluate truth and sensor batches on the grid from g0 and ``emit`` each batch.

    A batch is a list of (stamp_ns, rank, [(topic, bytes), ...]).
    """
    from rigidrot_ros.run import settings
    from rigidrot_ros.run.sensor_ahead import Sensor
    setup = settings.prepare_run(values)
    sch, counters = make_schedule(setup, g0, rate)
    sch.t_start_ns = g0
    sch.truth.anchor(g0, g0)
    sensors = [Sensor(o, g0, setup, counters, sch.frames) for o in sch.streams]
    n_total = int(seconds * rate) + BATCH
    nxt = {id(s): s.output.first for s in sensors}
    k = 0
    while k < n_total:
        while full():
            time.sleep(0.002)
        a = sch.truth.ahead
        samples, data = a._batch(k, BATCH)
        built = a.build(k, data)
        out = [(sch.truth.stamp_ns(j), 0, b) for j, b in zip(range(k, k + BATCH), built)]
        for s in sensors:
            st = nxt[id(s)]
            smp, blk = s.ahead._batch(st, BATCH)
            bl = s.ahead.build(st, blk)
            out += [(x[1], s.rank, b) for x, b in zip(smp, bl) if b is not None]
            nxt[id(s)] = st + BATCH
        emit(out)
        k += BATCH


class Ring:
    """SPSC byte ring in shared memory: [w u64][r u64][data]."""

    def __init__(self, name=None):
        if name is None:
            self.shm = shared_memory.SharedMemory(create=True, size=RING + 16)
            struct.pack_into('QQ', self.shm.buf, 0, 0, 0)
        else:
            self.shm = shared_memory.SharedMemory(name=name)
        self.buf = self.shm.buf

    def used(self):
        w, r = struct.unpack_from('QQ', self.buf, 0)
        return w - r

    def put(self, data):
        n = len(data) + 8
        while RING - self.used() < n:
            time.sleep(0.001)
        w = struct.unpack_from('Q', self.buf, 0)[0]
        rec = struct.pack('Q', len(data)) + data
        pos = w % RING
        first = min(n, RING - pos)
        self.buf[16 + pos:16 + pos + first] = rec[:first]
        if first < n:
            self.buf[16:16 + n - first] = rec[first:]
        struct.pack_into('Q', self.buf, 0, w + n)

    def get(self):
        w, r = struct.unpack_from('QQ', self.buf, 0)
        if w == r:
            return None
        pos = r % RING

        def read(p, m):
            p %= RING
            first = min(m, RING - p)
            out = bytes(self.buf[16 + p:16 + p + first])
            if first < m:
                out += bytes(self.buf[16:16 + m - first])
            return out
        ln = struct.unpack('Q', read(pos, 8))[0]
        data = read(pos + 8, ln)
        struct.pack_into('Q', self.buf, 8, r + 8 + ln)
        return data


def child_main(values, rate, g0, seconds, ring_name, prio):
    if prio is not None:
        if prio:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
        else:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    ring = Ring(ring_name)
    producer_batches(values, rate, g0, seconds, lambda b: ring.put(
        pickle.dumps(b, protocol=5)), full=lambda: ring.used() > RING // 2)
    ring.buf.release()
    ring.shm.close()


def main():
    mode, rate, seconds = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
    prio = int(sys.argv[4]) if len(sys.argv) > 4 else None
    import rclpy
    from rigidrot_ros.ros.recorder import msg_class
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
    import gc
    if os.environ.get('PROTO_GC') == '0':
        gc.disable()
    values, setup = setup_for(rate)
    period = int(1e9 / rate)
    rclpy.init(domain_id=int(os.environ.get('ROS_DOMAIN_ID', '200')))
    node = rclpy.create_node('proto_pub')
    pubs = {}
    for kind in setup.outputs:
        for t in kind.topics_on(setup.values):
            pubs[t.name] = node.create_publisher(msg_class(t.type), t.name, 100)
    warm = 2.0
    import subprocess
    probe_out = f'/tmp/rigidrot_proto_stalls_{os.getpid()}.json'
    probe = subprocess.Popen([sys.executable, '-m', 'rigidrot_ros.bench.stalls', probe_out])
    g0 = (time.time_ns() // period + int(3.0 * rate)) * period     # 3 s to get ready
    ready = deque()
    child = None
    if mode == 'pre':
        producer_batches(values, rate, g0, seconds + warm + 1, ready.append)
    elif mode == 'thread':
        sys.setswitchinterval(float(os.environ.get('PROTO_SWITCH', '1e-4')))
        th = threading.Thread(target=producer_batches, args=(
            values, rate, g0, seconds + warm + 1, ready.append,
            lambda: len(ready) > 8), daemon=True)
        th.start()
    elif mode == 'process':
        ring = Ring()
        ctx = mp.get_context('spawn')
        child = ctx.Process(target=child_main, args=(values, rate, g0, seconds + warm + 1,
                                                     ring.shm.name, prio), daemon=True)
        child.start()
    elif mode == 'node':
        from rigidrot_ros.runtime.worker import BatchWorker
        if os.environ.get('PROTO_SWITCH'):
            sys.setswitchinterval(float(os.environ['PROTO_SWITCH']))
        worker = BatchWorker()
        sch, counters = make_schedule(setup, g0, rate, worker)
    delays = {}
    wakes, durs = [], []
    heap = []           # (stamp, rank, items) sorted
    end = g0 + int((warm + seconds) * 1e9)
    due = g0
    calls = 0
    while True:
        now = time.time_ns()
        if now < due:
            time.sleep((due - now) / 1e9)
            now = time.time_ns()
        if now >= end:
            break
        calls += 1
        c0 = time.perf_counter_ns()
        wakes.append(now - due)
        if mode == 'node':
            call = sch.collect(now, lambda: max(due + period - time.time_ns(), 0),
                               lambda t, e: None)
            groups = sorted(call.groups, key=lambda g: (g[0], g[1]))
            for st, rank, items in groups:
                for topic, raw in items:
                    pubs[topic].publish(raw)
                if st >= g0 + warm * 1e9:
                    delays.setdefault(rank, []).append((st, now - st))
            sch.published(now)
            sch.refill()
            c_end = time.perf_counter_ns()
            sch.open_gate(c_end - (time.time_ns() - now), now, c_end)
        else:
            if mode == 'process':
                while len(heap) < 4 * BATCH:
                    data = ring.get()
                    if data is None:
                        break
                    heap.extend(pickle.loads(data))
                    heap.sort(key=lambda g: (g[0], g[1]))
            else:
                while ready and len(heap) < 4 * BATCH:
                    heap.extend(ready.popleft())
                    heap.sort(key=lambda g: (g[0], g[1]))
            i = 0
            while i < len(heap) and heap[i][0] <= now:
                st, rank, items = heap[i]
                for topic, raw in items:
                    pubs[topic].publish(raw)
                if st >= g0 + warm * 1e9:
                    delays.setdefault(rank, []).append((st, now - st))
                i += 1
            del heap[:i]
        durs.append(time.perf_counter_ns() - c0)
        due += period
        if due < time.time_ns() - period:      # behind: next wake is now
            due = time.time_ns()
    import json
    import numpy as np
    from rigidrot_ros.bench import stalls as stl
    probe.terminate()
    probe.wait()
    rec = json.load(open(probe_out))
    lo = g0 + int(warm * 1e9)
    span = [(d, lt) for d, lt in rec['stalls'] if lt >= period // 2 and d >= lo]
    load = os.getloadavg()
    n_w = len(wakes) // 6                # the warm-up's calls left out (about 2 of 12 s)
    w, c = np.array(wakes[n_w:]) / 1e3, np.array(durs[n_w:]) / 1e3
    print(f'{mode} {rate:g} Hz calls: wake p50 {np.percentile(w, 50):.0f} p99 '
          f'{np.percentile(w, 99):.0f} us; call p50 {np.percentile(c, 50):.0f} p99 '
          f'{np.percentile(c, 99):.0f} p99.9 {np.percentile(c, 99.9):.0f} us; '
          f'calls over {period / 2e3:.0f} us {int((c > period / 2e3).sum())}', flush=True)
    for rank, d in sorted(delays.items()):
        a = np.array(d, dtype=np.int64)
        st, d = a[:, 0], a[:, 1]
        late = d > period
        inst = stl.overlapping(span, st[late], st[late] + d[late])
        print(f'{mode} {rate:g} Hz rank {rank}: n={len(d)} late {int(late.sum())} '
              f'({100 * late.mean():.3f} %), outside stalls {int((~inst).sum())} '
              f'({100 * (~inst).sum() / len(d):.3f} %); p99 {np.percentile(d, 99) / 1e3:.0f} us,'
              f' max {d.max() / 1e3:.0f} us; stalls {len(span)} (max '
              f'{max([x[1] for x in span], default=0) / 1e3:.0f} us); calls {calls}; '
              f'load {load[0]:.2f}', flush=True)
    if child is not None:
        child.terminate()
        child.join()
        ring.buf.release()
        ring.shm.close()
        ring.shm.unlink()
    node.destroy_node()
    rclpy.try_shutdown()
    os._exit(0)


if __name__ == '__main__':
    main()
