"""Campaign engines under stress: bad input, huge specs, killed clients and workers, TLS.

Oracles: the exit status and stderr of the CLI (one line, exit 2, nothing written), the
processes left in /proc after a SIGKILL, the directories left in the temporary
directory, a count of the estimator factory's calls, and the bytes of report.json /
runs.csv against the process pool's.
"""

import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

import pytest
import yaml

from rigidrot_ros.campaign import spec as spec_mod
from rigidrot_ros.campaign.engine import run_campaign
from rigidrot_ros.campaign.spec import load_spec
from rigidrot_ros.campaign.workdir import claim_work_dir, PREFIX, sweep_work_dirs
from rigidrot_ros.tools.campaign import main

sys.path.insert(0, os.path.dirname(__file__))
from campaign_helpers import SPEC  # noqa: E402,I100,I202 - a helper module beside it

HERE = os.path.dirname(os.path.abspath(__file__))


def _write(tmp_path, doc, name='spec.yaml'):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(doc))
    return str(p)


def _ros(**est):
    base = {'command': f'{sys.executable} -c pass'}
    base.update(est)
    return dict(SPEC, estimator=base)


def _listing(root):
    return sorted(str(p.relative_to(root)) for p in Path(root).rglob('*'))


# -- bad input: one line, exit 2, nothing written --------------------------------------------
@pytest.mark.parametrize('doc, extra, word', [
    (_ros(command='rigidrot_mekf --sigma-v "1e-4'), [], 'estimator.command'),
    (_ros(command="python -c 'unbalanced"), [], 'No closing quotation'),
    (_ros(topics=5), [], 'estimator.topics must be a list of topic names, got 5'),
    (_ros(topics={'a': 1}), [], 'estimator.topics must be a list'),
    (_ros(domain_base=232, domain_span=233), [], 'last ROS domain ID, 232'),
    (_ros(domain_base=200, domain_span=40), [], 'make domain_span at most 33'),
    (dict(SPEC, seed=10 ** 400), [], 'seed must lie in'),
    (dict(SPEC, base={'params_file': 'a\0b'}), [], 'base.params_file must be a file name'),
    (SPEC, ['--keep-bags', '/proc/no/bags'], '--keep-bags /proc/no/bags: cannot create it'),
    (SPEC, ['--bags', '/proc/no/bags'], '--keep-bags /proc/no/bags: cannot create it'),
    (SPEC, ['--tls-cert', 'c.pem'], '--tls-cert apply to --scheduler'),
    (SPEC, ['--scheduler', 'tls://127.0.0.1:1', '--tls-cert', 'c.pem'],
     '--tls-ca-file is needed with --tls-cert'),
    (SPEC, ['--scheduler', 'tls://127.0.0.1:1', '--tls-ca-file', 'none.pem', '--tls-cert',
            'none.pem'], '--tls-ca-file none.pem: No such file'),
])
def test_bad_input_one_line_exit_2(tmp_path, capsys, monkeypatch, doc, extra, word):
    monkeypatch.chdir(tmp_path)
    path = _write(tmp_path, doc)
    before = _listing(tmp_path)
    assert main([path, '-o', str(tmp_path / 'out'), '--quiet'] + extra) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and word in err and 'Traceback' not in err, err
    assert _listing(tmp_path) == before


def test_keep_bags_without_a_directory_is_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = _write(tmp_path, SPEC)
    with pytest.raises(SystemExit) as exc:
        main([path, '-o', str(tmp_path / 'out'), '--quiet', '--keep-bags'])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1, err
    assert 'argument --keep-bags/--bags: expected one argument' in err
    assert not (tmp_path / 'out').exists()


@pytest.mark.parametrize('out', ['/proc/rigidrot_out', '/dev/null/out', ''])
def test_an_output_that_cannot_be_made_is_one_line(tmp_path, capsys, monkeypatch, out):
    monkeypatch.chdir(tmp_path)
    path = _write(tmp_path, dict(SPEC, runs=1))
    before = _listing(tmp_path)
    assert main([path, '-o', out, '--quiet']) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith('rigidrot_campaign: -o'), err
    assert _listing(tmp_path) == before


def test_a_million_runs_are_checked_lazily_with_progress(tmp_path, monkeypatch):
    calls = []
    from rigidrot_ros.run import generate
    real = generate.prepare_run
    monkeypatch.setattr(generate, 'prepare_run', lambda v: calls.append(1) or real(v))
    monkeypatch.setattr(spec_mod, 'EAGER_DRAWS', 12)
    seen = []
    spec = load_spec(_write(tmp_path, dict(SPEC, runs=1_000_000)),
                     progress=lambda done, total: seen.append((done, total)))
    assert spec['runs'] == 1_000_000
    assert len(calls) == 1 + 12                 # the base, then the first 12 draws
    assert seen[0] == (0, 12) and seen[-1] == (12, 12)
    # the draws beyond are the runs' own: one the node refuses is a failed run
    bad = dict(SPEC, runs=30, dispersions={'torque': {'low': [0, 0, 0.0],
                                                      'high': [0.1, 0, 0.01]}})
    monkeypatch.setattr(spec_mod, 'EAGER_DRAWS', 0)
    spec = load_spec(_write(tmp_path, bad, 'bad.yaml'))
    from rigidrot_ros.campaign.run import run_one
    row = run_one(spec, 0)['row']
    assert row['status'] == 'failed' and 'torque' in row['reason'], row


def test_the_check_of_the_draws_says_how_far_it_is_once_it_takes_a_second(capsys):
    from rigidrot_ros.tools.campaign import _CheckProgress
    bar = _CheckProgress()
    bar(5, 1000)
    assert capsys.readouterr().err == ''          # quick checks say nothing
    bar.t0 -= 2.0
    bar.last -= 1.0
    bar(500, 1000)
    bar(1000, 1000)
    err = capsys.readouterr().err
    assert 'checking the draws as the node would: 500/1000, ~' in err and 's left' in err
    assert err.endswith('1000/1000   \n'), err


# -- work directories outlive no owner ------------------------------------------------------
def test_a_killed_owner_leaves_no_work_directory(tmp_path):
    code = ('import sys, time; sys.path.insert(0, sys.argv[1]); '
            'from rigidrot_ros.campaign.workdir import claim_work_dir; '
            'd = claim_work_dir(7, sys.argv[2]); print(d.path, flush=True); time.sleep(60)')
    child = subprocess.Popen([sys.executable, '-c', code, os.path.dirname(HERE), str(tmp_path)],
                             stdout=subprocess.PIPE, text=True)
    path = child.stdout.readline().strip()
    mine = claim_work_dir(8, str(tmp_path))
    (tmp_path / 'rigidrot_campaign_domains_0').mkdir()        # not a run directory
    assert os.path.basename(path).startswith(PREFIX + '7_') and os.path.isdir(path)
    assert sweep_work_dirs(str(tmp_path)) == 0                 # both owners live
    child.kill()
    child.wait()
    assert sweep_work_dirs(str(tmp_path)) == 1 and not os.path.exists(path)
    assert os.path.isdir(mine.path)
    mine.release()
    assert sorted(os.listdir(tmp_path)) == ['rigidrot_campaign_domains_0']


# -- a client killed: its pool workers end ---------------------------------------------------
def _children(pid):
    out = []
    for task in Path(f'/proc/{pid}/task').glob('*'):
        try:
            out += [int(c) for c in (task / 'children').read_text().split()]
        except OSError:
            pass
    return out


def _running(pid):
    """Whether process ``pid`` runs: it exists and is not a zombie (ended, not yet reaped).

    An orphan is reaped by whoever adopts it: init at once, or the test run's controlling
    process (a subreaper) only at the end of the run.
    """
    try:
        with open(f'/proc/{pid}/stat', encoding='ascii', errors='replace') as fh:
            return fh.read().rsplit(')', 1)[1].split()[0] not in ('Z', 'X')
    except (OSError, IndexError):
        return False


def test_pool_workers_end_when_the_client_is_killed(tmp_path):
    spec = _write(tmp_path, dict(SPEC, runs=40, duration=30.0))
    env = dict(os.environ, TMPDIR=str(tmp_path))
    client = subprocess.Popen([sys.executable, '-m', 'rigidrot_ros.tools.campaign', spec,
                               '-o', str(tmp_path / 'out'), '--processes', '2', '--quiet'],
                              env=env, stderr=subprocess.DEVNULL)
    try:
        end = time.monotonic() + 120
        # runs under way: a work directory, or (in memory, none) a first result saved
        while not list(tmp_path.glob(PREFIX + '*')) and \
                not list(tmp_path.glob('out/runs/*.json')):
            assert client.poll() is None and time.monotonic() < end
            time.sleep(0.1)
        kids = _children(client.pid)
        assert len(kids) >= 2                  # two workers (and the resource tracker)
    finally:
        client.kill()
        client.wait()
    # a worker inside a compiled call (numba's first compilation, an Arb evaluation) unwinds
    # when the call returns: seconds on a quiet machine, tens of them on a loaded one
    end = time.monotonic() + 90
    while any(_running(k) for k in kids) and time.monotonic() < end:
        time.sleep(0.1)
    alive = [k for k in kids if _running(k)]
    for k in alive:
        os.kill(k, signal.SIGKILL)
    assert not alive, 'orphans of the killed client were still running after 90 s'
    sweep_work_dirs(str(tmp_path))
    assert not list(tmp_path.glob(PREFIX + '*'))


# -- Dask: a worker killed --------------------------------------------------------------------
def test_a_killed_dask_worker_costs_one_run_and_leaves_nothing(tmp_path, monkeypatch):
    pytest.importorskip('distributed')
    scratch = tmp_path / 'tmp'
    scratch.mkdir()
    monkeypatch.setenv('TMPDIR', str(scratch))
    monkeypatch.setattr(tempfile, 'tempdir', None)
    monkeypatch.setenv('PYTHONPATH', os.pathsep.join(
        [HERE] + os.environ.get('PYTHONPATH', '').split(os.pathsep)))
    counter = tmp_path / 'calls.txt'
    runs = 16
    doc = dict(SPEC, runs=runs, duration=1.0, estimator={
        'factory': 'campaign_helpers:counted',
        'params': dict(SPEC['estimator']['params'], counter=str(counter), kill_at=10,
                       out=str(tmp_path / 'out'))})
    spec = load_spec(_write(tmp_path, doc))
    rep = run_campaign(spec, str(tmp_path / 'out'), workers=2, dask_local=True,
                       progress=False)
    assert rep['runs_ok'] == runs
    calls = counter.read_text().split('\n')
    in_workers = sum(1 for c in calls if c.startswith('worker'))
    # the run killed with its worker is run again, and at most the other one under way;
    # before, every result the dead worker had computed was computed again (51 for 40)
    assert runs + 1 <= in_workers <= runs + 2, in_workers
    assert not [n for n in os.listdir(scratch) if n.startswith('rigidrot_campaign')]


def test_a_killed_pool_worker_stops_the_campaign_in_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv('PYTHONPATH', os.pathsep.join(
        [HERE] + os.environ.get('PYTHONPATH', '').split(os.pathsep)))
    out = tmp_path / 'out'
    doc = dict(SPEC, runs=4, duration=1.0, estimator={
        'factory': 'campaign_helpers:counted',
        'params': dict(SPEC['estimator']['params'], counter=str(tmp_path / 'calls.txt'),
                       kill_at=2, out=str(out))})
    assert main([_write(tmp_path, doc), '-o', str(out), '--processes', '2', '--quiet']) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'a worker of the process pool died' in err \
        and 'run the same command again' in err, err


def test_in_process_workers_are_forked_from_a_client_without_threads():
    import threading

    from rigidrot_ros.campaign.engine import start_method
    inproc = {'estimator': {'kind': 'inproc'}}
    mixed = {'estimators': [{'kind': 'inproc'}, {'kind': 'ros'}]}
    alone = threading.active_count() == 1
    assert start_method(inproc) == ('fork' if alone and sys.platform.startswith('linux')
                                    else 'spawn')
    assert start_method({'estimator': {'kind': 'ros'}}) == start_method(mixed) == 'spawn'
    stop = threading.Event()
    th = threading.Thread(target=stop.wait)
    th.start()
    try:
        assert start_method(inproc) == 'spawn'       # a fork would copy its locks
    finally:
        stop.set()
        th.join()
