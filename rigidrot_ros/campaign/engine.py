"""Run a campaign's runs on an engine, resumably, and write its outputs.

Engines: a local process pool (default, one worker per core), a Dask
``distributed.LocalCluster`` (``workers=N``) or a running Dask cluster
(``scheduler='tcp://host:port'``). Workers compute :func:`run.run_one` and return its
result; the client alone writes into the output directory:

- ``spec.json``: the validated spec (a rerun into the same directory must match it);
- ``runs/NNNNNN.json``: each run's row and series, written atomically (temp + rename) as
  it finishes; ``runs/NNNNNN.log`` for a failed run; ``runs/NNNNNN.time.json`` its wall
  time (kept apart: it is the only thing that differs between engines);
- once all runs are done: ``report.json``, ``runs.csv`` and the charts, computed from the
  run files in index order, so a campaign resumed after SIGINT or a crash ends with the
  same bytes as one that was never stopped.
"""

import concurrent.futures as cf
import csv
import io
import json
import multiprocessing
import os
import sys
import time

from rigidrot_ros.campaign.aggregate import aggregate, csv_rows
from rigidrot_ros.campaign.run import run_one
from rigidrot_ros.campaign.spec import SpecError

__all__ = ['run_campaign', 'DASK_MISSING', 'write_atomic']

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


def _pool(spec, todo, bag_root, workers):
    ctx = multiprocessing.get_context('spawn')
    ex = cf.ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1, mp_context=ctx)
    try:
        futs = [ex.submit(run_one, spec, i, bag_root) for i in todo]
        for f in cf.as_completed(futs):
            yield f.result()
    except BaseException:
        for f in futs:
            f.cancel()
        ex.shutdown(wait=False, cancel_futures=True)
        raise
    ex.shutdown(wait=True)


def _dask(spec, todo, bag_root, workers, scheduler):
    try:
        from distributed import as_completed, Client, LocalCluster
    except ImportError:
        raise SpecError(DASK_MISSING) from None
    cluster = None
    if scheduler:
        client = Client(scheduler, timeout='20s')
    else:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=':0', host='127.0.0.1')
        client = Client(cluster)
    try:
        futs = [client.submit(run_one, spec, i, bag_root, pure=False, key=f'run-{i}')
                for i in todo]
        for f in as_completed(futs):
            yield f.result()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_campaign(spec, out_dir, workers=None, scheduler=None, dask_local=False,
                 bag_root=None, progress=True):
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
    """
    done = prepare_dir(spec, out_dir)
    todo = [i for i in range(spec['runs']) if i not in done]
    bar = Progress(spec['runs'], len(done), progress)
    if todo:
        gen = _dask(spec, todo, bag_root, workers, scheduler) if (scheduler or dask_local) \
            else _pool(spec, todo, bag_root, workers)
        ok = False
        try:
            for result in gen:
                if result.get('fatal') and not ok:   # the estimator cannot start: stop
                    gen.close()
                    raise SpecError(result['fatal'])
                ok = ok or result['row']['status'] == 'ok'
                _save_run(out_dir, result)
                bar.add(result['row']['status'] != 'ok')
        finally:
            bar.close()
    else:
        bar.close()
    return finish(spec, out_dir)


def finish(spec, out_dir):
    """Aggregate the run files into report.json, runs.csv and the charts."""
    results = []
    for i in range(spec['runs']):
        with open(_run_path(out_dir, i), encoding='utf-8') as fh:
            results.append(json.load(fh))
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
        write_charts(report, out_dir)
    except ImportError:
        print('rigidrot_campaign: no charts: pip install matplotlib', file=sys.stderr)
    return report
