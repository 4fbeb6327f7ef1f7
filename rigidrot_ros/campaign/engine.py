"""Run a campaign's runs on an engine, resumably, and write its outputs.

Engines: a local process pool (default, one worker per core), a Dask
``distributed.LocalCluster`` (``workers=N``; on 127.0.0.1, with TLS on temporary
certificates where ``cryptography`` is installed) or a running Dask cluster
(``scheduler='tls://host:port'`` with a ``distributed.security.Security``, or
``tcp://``). Workers compute :func:`run.run_one` and return its result; the client
alone writes into the output directory:

- ``spec.json``: the validated spec (a rerun into the same directory must match it);
- ``runs/NNNNNN.json``: each run's row and series, written atomically (temp + rename) as
  it finishes; ``runs/NNNNNN.log`` for a failed run; ``runs/NNNNNN.time.json`` its wall
  time (kept apart: it is the only thing that differs between engines);
- once all runs are done: ``report.json``, ``runs.csv`` and the charts, computed from the
  run files in index order, so a campaign resumed after SIGINT or a crash ends with the
  same bytes as one that was never stopped.

At most a few runs per worker are submitted at a time (:data:`WINDOW_PER_WORKER`), and
the client drops each run's future once its result is saved: a million-run campaign does
not hold a million futures, and a Dask worker that dies does not make the scheduler
recompute results the client already has. Pool workers end when the client process
dies, even by SIGKILL (:func:`_orphan_guard`).
"""

import collections
import concurrent.futures as cf
import csv
import ctypes
import gc
import io
import json
import multiprocessing
import os
import signal
import sys
import threading
import time

from rigidrot_ros.campaign.aggregate import aggregate, csv_rows
from rigidrot_ros.campaign.run import run_one
from rigidrot_ros.campaign.spec import forget_prepared, SpecError
from rigidrot_ros.campaign.workdir import sweep_work_dirs

__all__ = ['run_campaign', 'DASK_MISSING', 'write_atomic', 'WINDOW_PER_WORKER',
           'CONNECT_TIMEOUT', 'CampaignStopped', 'dask_security']

#: Runs submitted ahead per worker (thread): enough to keep every worker busy.
WINDOW_PER_WORKER = 4
#: Threads of the client that save results (their fsyncs overlap), and the results that
#: may wait to be saved.
SAVE_THREADS = 4
SAVE_WINDOW = 64
#: How long the client tries to reach a Dask scheduler.
CONNECT_TIMEOUT = '20s'
_PR_SET_PDEATHSIG = 1                       # <linux/prctl.h>


class CampaignStopped(RuntimeError):
    """The engine failed under the campaign (a worker killed, the cluster lost); one line.

    The runs saved so far are kept: the same command continues.
    """


DASK_MISSING = ('--workers/--scheduler need Dask: pip install "dask[distributed]" '
                '(or pip install "rigidrot_ros[campaign]")')


def write_atomic(path, data):
    """Write ``data`` (str or bytes) to ``path`` through a temporary file and a rename."""
    tmp = f'{path}.tmp{os.getpid()}'
    with open(tmp, 'wb') as fh:
        fh.write(data.encode('utf-8') if isinstance(data, str) else data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _dumps(obj):
    return json.dumps(obj, sort_keys=True, indent=1) + '\n'


def _run_path(out_dir, i, suffix='.json'):
    return os.path.join(out_dir, 'runs', f'{i:06d}{suffix}')


def prepare_dir(spec, out_dir):
    """Create the output directory or check it holds this spec; the runs already done."""
    if not out_dir:
        raise SpecError('-o: the output directory must be named (got an empty path)')
    try:
        return _prepare_dir(spec, out_dir)
    except OSError as exc:
        where = f' ({exc.filename})' if exc.filename not in (None, out_dir) else ''
        raise SpecError(f'-o {out_dir}: cannot create or use it{where}: '
                        f'{exc.strerror or exc}') from None


def _prepare_dir(spec, out_dir):
    text = _dumps(spec)
    spec_path = os.path.join(out_dir, 'spec.json')
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise SpecError(f'-o {out_dir}: exists and is not a directory')
    if os.path.isfile(spec_path):
        with open(spec_path, encoding='utf-8') as fh:
            if fh.read() != text:
                raise SpecError(f'-o {out_dir}: holds a campaign of another spec (its '
                                f'spec.json differs); choose another directory')
    elif os.path.isdir(out_dir) and os.listdir(out_dir):
        raise SpecError(f'-o {out_dir}: exists, is not empty and holds no campaign')
    os.makedirs(os.path.join(out_dir, 'runs'), exist_ok=True)
    if not os.path.isfile(spec_path):
        write_atomic(spec_path, text)
    return {i for i in range(spec['runs']) if os.path.isfile(_run_path(out_dir, i))}


class Progress:
    """One line on stderr: runs done, failed, rate and time left."""

    def __init__(self, total, done, enabled=True):
        self.total, self.done, self.failed = total, done, 0
        self.start_done = done
        self.t0 = time.monotonic()
        self.enabled = enabled
        self.show()

    def add(self, failed):
        """Count one finished run."""
        self.done += 1
        self.failed += bool(failed)
        self.show()

    def show(self):
        """Redraw the line."""
        if not self.enabled:
            return
        n = self.done - self.start_done
        dt = time.monotonic() - self.t0
        left = '' if not n else f', ~{_hms((self.total - self.done) * dt / n)} left'
        rate = '' if not n else f', {60 * n / dt:.1f} runs/min'
        width = 24
        fill = int(width * self.done / max(self.total, 1))
        print(f'\r[campaign] [{"#" * fill}{"." * (width - fill)}] {self.done}/{self.total} '
              f'runs, {self.failed} failed{rate}{left}   ', end='', file=sys.stderr, flush=True)

    def close(self):
        """End the line."""
        if self.enabled:
            print(file=sys.stderr, flush=True)


def _hms(s):
    s = int(round(s))
    return f'{s // 3600}h{s % 3600 // 60:02d}m' if s >= 3600 else f'{s // 60}m{s % 60:02d}s'


def _save_run(out_dir, result):
    i = result['row']['run']
    if result.get('log'):
        write_atomic(_run_path(out_dir, i, '.log'), result['log'])
    write_atomic(_run_path(out_dir, i, '.time.json'), _dumps(result['timing']))
    write_atomic(_run_path(out_dir, i), _dumps({'row': result['row'],
                                                'series': result['series']}))


class _ParentGone(BaseException):
    """Raised in a pool worker whose client died, to unwind its run (temp files, children)."""


_IN_RUN = []


def _parent_gone(signum, frame):
    if _IN_RUN:
        raise _ParentGone()
    os._exit(1)


def _orphan_guard(parent):
    """Initialise a pool worker: it ends when the client process ``parent`` dies.

    The kernel sends the worker SIGTERM when the process that started it dies (Linux
    ``prctl(PR_SET_PDEATHSIG)``; the pool starts its workers from the thread that
    submits, the campaign's own), even by SIGKILL; elsewhere a thread polls the parent's
    pid. On that signal a worker between runs exits at once; one inside a run unwinds it
    first (its temporary directory removed, a ROS run's processes stopped). The resource
    tracker of the pool ends by itself once the client and every worker are gone.
    """
    signal.signal(signal.SIGTERM, _parent_gone)
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), 'prctl')
    except (OSError, AttributeError):
        threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()
    if os.getppid() != parent:                  # it died before the guard was set
        os._exit(1)


def _watch_parent(parent):
    while os.getppid() == parent:
        time.sleep(0.5)
    os.kill(os.getpid(), signal.SIGTERM)


def _pool_run(spec, index, bag_root):
    """Run one campaign run in a pool worker (see :func:`_orphan_guard`)."""
    _IN_RUN.append(index)
    try:
        return _job(spec)(spec, index, bag_root)
    except _ParentGone:
        os._exit(1)
    finally:
        _IN_RUN.clear()


def _job(spec):
    """Return the worker's function: one estimator's run, or several on the same run."""
    if 'estimators' in spec:
        from rigidrot_ros.campaign.multi import run_one_multi
        return run_one_multi
    return run_one


def _estimators(spec):
    return spec['estimators'] if 'estimators' in spec else [spec['estimator']]


def start_method(spec):
    """Return how the pool starts its workers: ``fork`` for in-process estimators, else spawn.

    Forked from the client, a worker starts with the modules the client has loaded and
    warmed (the generator, the scorer, the estimator's module: :func:`_warm`), instead of
    importing them again: most of a short campaign's start-up. Only where it is safe:
    Linux, every estimator in process (a ROS estimator's worker opens ROS contexts of its
    own: those start clean, by spawn), and a client without other threads (a fork copies
    no thread, but it copies the locks they hold).
    """
    if not sys.platform.startswith('linux') or threading.active_count() != 1 or \
            any(e['kind'] != 'inproc' for e in _estimators(spec)):
        return 'spawn'
    return 'fork'


def _warm(spec):
    """Load what an in-process run uses, once, in the client, before the pool forks.

    The modules, and what each estimator's ``warm()`` loads, if its object has one (the
    reference MEKF's compiled filter): the workers start with it instead of each loading
    it at its first run. A factory or ``warm()`` that fails here is left to the runs,
    which report it.
    """
    import rigidrot_ros.campaign.inproc  # noqa: F401
    import rigidrot_ros.campaign.session  # noqa: F401
    import rigidrot_ros.run.feed  # noqa: F401
    import rigidrot_ros.run.generate  # noqa: F401
    import rigidrot_ros.scoring.score  # noqa: F401
    from rigidrot_ros.campaign.spec import load_factory
    for est in _estimators(spec):
        try:
            warm = getattr(load_factory(est['factory'])(dict(est['params'])), 'warm', None)
            if callable(warm):
                warm()
        except Exception:  # noqa: B902 - the runs make it again and report its failure
            pass


def _pool(spec, todo, bag_root, workers):
    method = start_method(spec)
    frozen = method == 'fork'
    if frozen:
        _warm(spec)
        sys.stdout.flush()          # nothing buffered is written again by a worker
        sys.stderr.flush()
        gc.freeze()                 # the client's objects: no worker's collector walks them
    ctx = multiprocessing.get_context(method)
    n = workers or os.cpu_count() or 1
    ex = cf.ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=_orphan_guard,
                                initargs=(os.getpid(),))
    queue, pending = collections.deque(todo), set()
    try:
        while queue or pending:
            while queue and len(pending) < WINDOW_PER_WORKER * n:
                pending.add(ex.submit(_pool_run, spec, queue.popleft(), bag_root))
            if frozen:              # the workers are forked at the first submit
                gc.unfreeze()
                frozen = False
            done, pending = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
            for f in done:
                try:
                    result = f.result()
                except cf.process.BrokenProcessPool:
                    raise CampaignStopped('a worker of the process pool died in a run (killed, '
                                          'or out of memory?)') from None
                yield result
    except BaseException:
        if frozen:
            gc.unfreeze()
        for f in pending:
            f.cancel()
        ex.shutdown(wait=False, cancel_futures=True)
        raise
    ex.shutdown(wait=True)


def dask_security(ca_file=None, cert=None, key=None):
    """Return the ``distributed.security.Security`` of a client, TLS files checked.

    With ``ca_file`` and ``cert`` (``key`` if the certificate file holds no key): mutual
    TLS with these files, encryption required. Without them: Dask's configuration
    (``distributed.comm.tls.ca-file``, ``distributed.comm.tls.client.cert`` and
    ``.key``, ``distributed.comm.require-encryption``), which is plain TCP unless it
    says otherwise. SpecError (one line) for a missing or unreadable file.
    """
    try:
        from distributed.security import Security
    except ImportError:
        raise SpecError(DASK_MISSING) from None
    given = {'--tls-ca-file': ca_file, '--tls-cert': cert, '--tls-key': key}
    if not any(given.values()):
        return Security()
    for opt in ('--tls-ca-file', '--tls-cert'):
        if not given[opt]:
            with_ = ' and '.join(k for k, v in given.items() if v)
            raise SpecError(f'{opt} is needed with {with_} (mutual TLS: the CA that signed '
                            "the scheduler's certificate, and this client's certificate "
                            'signed by a CA the scheduler trusts)')
    for opt, path in given.items():
        if path:
            try:
                with open(path, 'rb') as fh:
                    fh.read(1)
            except OSError as exc:
                raise SpecError(f'{opt} {path}: {exc.strerror or exc}') from None
    return Security(tls_ca_file=ca_file, tls_client_cert=cert, tls_client_key=key,
                    require_encryption=True)


def _local_security():
    """TLS with temporary certificates for a LocalCluster, where ``cryptography`` is installed.

    Without it the cluster listens in plain TCP on 127.0.0.1, which other users of the
    machine can reach.
    """
    from distributed.security import Security
    try:
        return Security.temporary()
    except ImportError:
        return None


def _connect(scheduler, security):
    from distributed import Client
    if scheduler.startswith('tls://') and not security.get_tls_config_for_role('client').get(
            'cert'):
        raise SpecError(f'--scheduler {scheduler}: a TLS scheduler needs --tls-ca-file and '
                        "--tls-cert (and --tls-key), or Dask's configuration "
                        'distributed.comm.tls.ca-file and distributed.comm.tls.client.cert')
    if security.require_encryption and not scheduler.startswith('tls://'):
        raise SpecError(f'--scheduler {scheduler}: the TLS options need a tls:// address')
    try:
        return Client(scheduler, timeout=CONNECT_TIMEOUT, security=security)
    except Exception as exc:  # noqa: B902 - Dask raises OSError, TimeoutError, ssl errors
        raise SpecError(f'--scheduler {scheduler}: cannot connect ({type(exc).__name__}: '
                        f'{" ".join(str(exc).split()) or "no reason given"}); is the '
                        "scheduler running, and does it trust this client's certificate?") \
            from None


def _dask(spec, todo, bag_root, workers, client=None):
    """Run ``todo`` on ``client``'s cluster, or on a new LocalCluster; closes both."""
    try:
        from distributed import as_completed, LocalCluster
    except ImportError:
        raise SpecError(DASK_MISSING) from None
    cluster = None
    if client is None:
        from distributed import Client
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=':0', host='127.0.0.1',
                               security=_local_security())
        client = Client(cluster)
    try:
        threads = max(1, sum(client.nthreads().values()))
        queue = collections.deque(todo)
        flow = as_completed()
        submitted = 0

        def top_up():
            nonlocal submitted
            while queue and submitted < WINDOW_PER_WORKER * threads:
                i = queue.popleft()
                flow.add(client.submit(_job(spec), spec, i, bag_root, pure=False,
                                       key=f'run-{i}'))
                submitted += 1

        top_up()
        while not flow.is_empty():
            f = next(flow)
            try:
                result = f.result()
            except SpecError:
                raise
            except Exception as exc:  # noqa: B902 - KilledWorker, a lost scheduler, ...
                raise CampaignStopped(f'Dask gave no result for {f.key} '
                                      f'({type(exc).__name__}: '
                                      f'{" ".join(str(exc).split())[:200]})') from None
            f.release()                # the client has it: the cluster may forget it now
            del f
            yield result               # and the caller saves it before asking again
            submitted -= 1
            threads = max(1, sum(client.nthreads().values())) if queue else threads
            top_up()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_campaign(spec, out_dir, workers=None, scheduler=None, dask_local=False,
                 bag_root=None, progress=True, security=None):
    """Run (or continue) the campaign into ``out_dir``; return the report dict.

    Parameters
    ----------
    spec : dict
        From :func:`rigidrot_ros.campaign.spec.load_spec`.
    out_dir : str
        Output directory (a rerun with the same one continues).
    workers : int, optional
        Process-pool size, or the LocalCluster's worker count with ``dask_local``.
    scheduler : str, optional
        Address of a running Dask scheduler.
    dask_local : bool
        Start a ``distributed.LocalCluster`` of ``workers`` workers.
    bag_root : str, optional
        Keep each run's bags under this (shared) directory.
    progress : bool
        Show the progress bar on stderr.
    security : distributed.security.Security, optional
        The client's security with ``scheduler`` (:func:`dask_security`); default: Dask's
        configuration.
    """
    client = None
    if scheduler:                   # reached before anything is written
        if security is None:
            security = dask_security()
        client = _connect(scheduler, security)
    try:
        done = prepare_dir(spec, out_dir)
    except BaseException:
        if client is not None:
            client.close()
        raise
    todo = [i for i in range(spec['runs']) if i not in done]
    bar = Progress(spec['runs'], len(done), progress)
    if not todo and client is not None:
        client.close()
    if todo:
        gen = _dask(spec, todo, bag_root, workers, client) \
            if (scheduler or dask_local) else _pool(spec, todo, bag_root, workers)
        ok = False
        charts = saver = None
        try:
            for result in gen:
                if charts is None:      # the workers are running (forked): start the threads
                    charts = _preload_charts()
                    saver = _Saver(out_dir, bar)
                    forget_prepared()   # the workers have their copies
                if result.get('fatal') and not ok:   # the estimator cannot start: stop
                    gen.close()
                    raise SpecError(result['fatal'])
                ok = ok or result['row']['status'] == 'ok'
                saver.put(result)
        finally:
            try:
                if saver is not None:
                    saver.close()       # every result received is saved, even on an error
            finally:
                bar.close()
                gen.close()
                sweep_work_dirs()       # those of workers killed on this machine
                forget_prepared()
                if charts is not None:
                    charts.join()
    else:
        bar.close()
    return finish(spec, out_dir)


class _Saver:
    """Save results (:func:`_save_run`) in :data:`SAVE_THREADS` threads: their fsyncs overlap.

    On a disk busy with other writes an fsync can take 10 ms or more, longer than a short
    run of the pool takes: one after the other, they held up the client between results,
    and with it the submission of new runs. A save's error (a full disk) is raised by the
    next :meth:`put` or by :meth:`close`; at most :data:`SAVE_WINDOW` results wait to be
    saved.
    """

    def __init__(self, out_dir, bar):
        self.out_dir, self.bar = out_dir, bar
        self.ex = cf.ThreadPoolExecutor(max_workers=SAVE_THREADS,
                                        thread_name_prefix='rigidrot-campaign-save')
        self.pending = collections.deque()

    def put(self, result):
        """Save ``result`` in a thread; count the saves done."""
        self.pending.append((self.ex.submit(_save_run, self.out_dir, result),
                             result['row']['status'] != 'ok'))
        self._reap(len(self.pending) > SAVE_WINDOW)

    def _reap(self, wait):
        while self.pending and (wait or self.pending[0][0].done()):
            f, failed = self.pending.popleft()
            f.result()              # a save's error
            self.bar.add(failed)
            wait = False

    def close(self):
        """Wait for every save; then raise the first save's error, if any."""
        first = None
        try:
            while self.pending:
                f, failed = self.pending.popleft()
                try:
                    f.result()
                except Exception as exc:  # noqa: B902 - the others are saved first
                    first = first or exc
                    continue
                self.bar.add(failed)
        finally:
            self.ex.shutdown(wait=True)
        if first is not None:
            raise first


def _preload_charts():
    """Import the charts' library in a thread (the report's last step): the thread.

    Started once the runs go, it takes the client's idle time instead of adding to the
    end; the client's own work (saving results) goes on beside it.
    """
    def load():
        try:
            from rigidrot_ros.campaign.charts import preload
            preload()
        except Exception:  # noqa: B902 - the charts say it themselves when drawn
            pass
    thread = threading.Thread(target=load, name='rigidrot-campaign-charts', daemon=True)
    thread.start()
    return thread


def finish(spec, out_dir):
    """Aggregate the run files into report.json, runs.csv and the charts."""
    results = []
    for i in range(spec['runs']):
        with open(_run_path(out_dir, i), encoding='utf-8') as fh:
            results.append(json.load(fh))
    if 'estimators' in spec:                # several on the same runs
        from rigidrot_ros.campaign.multi import finish_multi
        return finish_multi(spec, out_dir, results, write_atomic, _dumps)
    report = aggregate(results, spec)
    write_atomic(os.path.join(out_dir, 'report.json'), _dumps(report))
    header, rows = csv_rows(results)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator='\n')
    w.writerow(header)
    w.writerows(rows)
    write_atomic(os.path.join(out_dir, 'runs.csv'), buf.getvalue())
    try:
        from rigidrot_ros.campaign.charts import write_charts
        write_charts(report, out_dir, jobs=min(2, os.cpu_count() or 1))
    except ImportError:
        print('rigidrot_campaign: no charts: pip install matplotlib', file=sys.stderr)
    return report
