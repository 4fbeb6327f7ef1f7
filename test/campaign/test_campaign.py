"""Campaigns: draws, aggregation statistics, bad input, resume, failures, and the engines.

Oracles: chi-square statistics of synthetic NEES drawn from scipy's chi2 (which shares no
code with the scorer's mpmath quantiles), SeedSequence.spawn as numpy defines it, the
bytes of report.json / runs.csv between engines and between an interrupted and an
uninterrupted campaign.
"""

import json
import os
from pathlib import Path
import shutil
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from scipy import stats

from campaign_helpers import _write, SPEC
from rigidrot_ros.campaign.aggregate import aggregate
from rigidrot_ros.campaign.engine import run_campaign
from rigidrot_ros.campaign.spec import check_spec, draw_run, load_spec, SpecError
from rigidrot_ros.tools.campaign import main

sys.path.insert(0, os.path.dirname(__file__))


def _bytes(d):
    return {n: (Path(d) / n).read_bytes() for n in ('report.json', 'runs.csv')}


# -- draws ---------------------------------------------------------------------------------
def test_draws_are_the_spawned_children_whatever_the_order():
    spec = check_spec(dict(SPEC, runs=5))
    kids = np.random.SeedSequence(7).spawn(5)
    for i in (4, 0, 2):
        draws, _ = draw_run(spec, i)
        rng = np.random.default_rng(kids[i].spawn(2)[0])
        q = rng.standard_normal(4)
        q /= np.linalg.norm(q)
        np.testing.assert_array_equal(draws['attitude0'], q if q[3] >= 0 else -q)
        np.testing.assert_array_equal(draws['omega0'], np.array([0.3, -0.2, 0.5])
                                      + 0.05 * rng.standard_normal(3))
    assert draw_run(spec, 3) == draw_run(spec, 3)
    assert draw_run(spec, 3)[0]['imu.seed'] != draw_run(spec, 2)[0]['imu.seed']


def test_triangle_redraws_and_impossible_box():
    doc = dict(SPEC, runs=40, dispersions={'inertia': {'low': [0.5, 0.5, 0.5],
                                                       'high': [1.0, 1.0, 2.0]}})
    doc['base'] = {'overrides': {'torque': [0.0, 0.0, 0.0]}}
    spec = check_spec(doc)
    redraws = 0
    for i in range(40):
        d, r = draw_run(spec, i)
        a, b, c = d['inertia']
        assert a + b >= c and b + c >= a and a + c >= b
        redraws += r
    assert redraws > 0
    doc['dispersions'] = {'inertia': {'low': [0.5, 0.5, 3.0], 'high': [1.0, 1.0, 4.0]}}
    with pytest.raises(SpecError, match='triangle'):
        check_spec(doc)


# -- aggregation -----------------------------------------------------------------------------
def _fake(nees, t_ns):
    out = []
    for i, row in enumerate(nees):
        out.append({'row': {'run': i, 'status': 'ok', 'reason': ''},
                    'series': {'t_ns': list(t_ns), 'nees': row.tolist(),
                               'error': np.sqrt(row).tolist()}})
    return out


def test_aggregate_on_chi_square_nees():
    spec = check_spec(SPEC)
    m, k = 50, 400
    rng = np.random.default_rng(1)
    good = stats.chi2.rvs(3, size=(m, k), random_state=rng)
    rep = aggregate(_fake(good, np.arange(k) * 10 ** 8), spec)
    lo, hi = stats.chi2.ppf([0.025, 0.975], 3 * m) / m
    np.testing.assert_allclose(rep['mc_nees']['band_95'], [lo, hi], rtol=1e-9)
    assert 0.92 <= rep['mc_nees']['fraction_inside'] <= 0.98
    a = rep['anees']
    np.testing.assert_allclose(a['bounds_95'], stats.chi2.ppf([0.025, 0.975], 3 * m * k)
                               / (m * k), rtol=1e-9)
    assert a['bounds_95'][0] <= a['value'] <= a['bounds_95'][1]
    assert 0.85 <= rep['per_run_anees']['fraction_inside'] <= 1.0
    np.testing.assert_allclose(rep['rms_error']['rad'], np.sqrt(good.mean(axis=0)))
    bad = aggregate(_fake(2.0 * good, np.arange(k) * 10 ** 8), spec)     # over-confident
    assert bad['mc_nees']['fraction_inside'] < 0.1
    assert bad['anees']['value'] > bad['anees']['bounds_95'][1]
    # a step one run lacks is dropped from all
    res = _fake(good[:3], np.arange(k) * 10 ** 8)
    for key in ('t_ns', 'nees', 'error'):
        res[1]['series'][key] = res[1]['series'][key][:-1]
    assert aggregate(res, spec)['steps'] == k - 1


# -- bad input -------------------------------------------------------------------------------
@pytest.mark.parametrize('change, word', [
    (lambda d: d.update(nope=1), 'nope'),
    (lambda d: d['dispersions']['omega0'].update(sigma=-0.1), 'sigma'),
    (lambda d: d['dispersions'].update(inertia={'low': [1, 1, 5], 'high': [1, 1, 6]}),
     'triangle'),
    (lambda d: d['dispersions'].update(torque={'low': [0.1, 0, 0], 'high': [0.2, 0, 0]}),
     'impossible dispersion'),
    (lambda d: d['estimator'].update(factory='no_such_module_xyz:make'), 'no_such_module'),
    (lambda d: d.update(estimator={'command': 'no_such_estimator_xyz --x'}),
     'no_such_estimator_xyz'),
    (lambda d: d.update(estimator={'command': sys.executable, 'inputs': [3]}),
     'estimator.inputs must be a list of topic names, got [3]'),
])
def test_bad_input_one_line_exit_2_nothing_written(tmp_path, capsys, change, word):
    doc = json.loads(json.dumps(SPEC))
    change(doc)
    out = tmp_path / 'out'
    assert main([_write(tmp_path, doc), '-o', str(out), '--quiet']) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and word in err and 'Traceback' not in err, err
    assert not out.exists()


# -- engines, resume, failures -------------------------------------------------------------
def test_resume_is_bit_identical_and_failures_are_recorded(tmp_path):
    spec = load_spec(_write(tmp_path, dict(SPEC, runs=4)))
    full = tmp_path / 'full'
    run_campaign(spec, str(full), workers=2, progress=False)
    part = tmp_path / 'part'
    shutil.copytree(full, part)
    for name in ('report.json', 'runs.csv', 'runs/000001.json', 'runs/000003.json'):
        os.remove(part / name)                  # as after a stop before runs 1 and 3 ended
    (part / 'runs' / '000003.json.tmp123').write_text('{"half')   # a torn temp file
    before = (part / 'runs' / '000000.json').stat().st_mtime_ns
    run_campaign(spec, str(part), workers=2, progress=False)
    assert _bytes(full) == _bytes(part)
    assert (part / 'runs' / '000000.json').stat().st_mtime_ns == before     # not redone
    rep = json.loads((full / 'report.json').read_text())
    assert rep['runs_ok'] == 4 and rep['steps'] > 10
    # another spec into the same directory is refused
    other = load_spec(_write(tmp_path, dict(SPEC, runs=4, seed=8), 'other.yaml'))
    with pytest.raises(SpecError, match='another spec'):
        run_campaign(other, str(part), progress=False)
    # a crashing estimator and a silent one: failed with reason and log; the others go on
    flaky = dict(SPEC, runs=6, estimator={'factory': 'campaign_helpers:flaky',
                                          'params': SPEC['estimator']['params']})
    rep = run_campaign(load_spec(_write(tmp_path, flaky, 'f.yaml')), str(tmp_path / 'f'),
                       workers=2, progress=False)
    assert 0 < rep['runs_failed'] < 6 and rep['runs_ok'] == 6 - rep['runs_failed']
    for f in rep['failed']:
        assert 'flaky estimator' in f['reason']
        log = (tmp_path / 'f' / 'runs' / f'{f["run"]:06d}.log').read_text()
        assert 'RuntimeError' in log
    silent = dict(SPEC, runs=2, estimator={'factory': 'campaign_helpers:silent'})
    rep = run_campaign(load_spec(_write(tmp_path, silent, 's.yaml')), str(tmp_path / 's'),
                       workers=1, progress=False)
    assert rep['runs_failed'] == 2 and 'published nothing' in rep['failed'][0]['reason']


def _free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _tls_files(d):
    """A temporary CA certificate, certificate and key (PEM files), made here."""
    from distributed.security import Security
    sec = Security.temporary()
    d.mkdir()
    for name, text in (('ca.pem', sec.tls_ca_file), ('cert.pem', sec.tls_client_cert),
                       ('key.pem', sec.tls_client_key)):
        (d / name).write_text(text)
    return [str(d / n) for n in ('ca.pem', 'cert.pem', 'key.pem')]


def test_dask_local_cluster_and_tls_scheduler_match_the_process_pool(
        tmp_path, capsys, monkeypatch):
    pytest.importorskip('distributed')
    pytest.importorskip('cryptography')
    spec_path = _write(tmp_path, SPEC)
    spec = load_spec(spec_path)
    run_campaign(spec, str(tmp_path / 'pool'), workers=2, progress=False)
    run_campaign(spec, str(tmp_path / 'local'), workers=2, dask_local=True, progress=False)
    assert _bytes(tmp_path / 'pool') == _bytes(tmp_path / 'local')
    # the documented cluster: a TLS scheduler and workers with certificates of one CA
    ca, cert, key = _tls_files(tmp_path / 'pki')
    tls = ['--tls-ca-file', ca, '--tls-cert', cert, '--tls-key', key]
    port = _free_port()
    bindir = os.path.dirname(sys.executable)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [os.path.dirname(__file__)] + os.environ.get('PYTHONPATH', '').split(os.pathsep)))
    addr = f'tls://127.0.0.1:{port}'
    procs = [subprocess.Popen([os.path.join(bindir, 'dask'), 'scheduler', '--host',
                               '127.0.0.1', '--port', str(port), '--protocol', 'tls',
                               '--no-dashboard'] + tls,
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        for _ in range(2):
            procs.append(subprocess.Popen(
                [os.path.join(bindir, 'dask'), 'worker', addr, '--nthreads', '1',
                 '--nworkers', '1', '--no-dashboard', '--host', '127.0.0.1'] + tls,
                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        from distributed import Client
        from rigidrot_ros.campaign import engine
        security = engine.dask_security(ca, cert, key)
        end = time.monotonic() + 60
        while True:
            try:
                with Client(addr, timeout='5s', security=security) as c:
                    c.wait_for_workers(2, timeout=60)
                    break
            except OSError:
                if time.monotonic() > end:
                    raise
                time.sleep(0.5)
        assert main([spec_path, '-o', str(tmp_path / 'cluster'), '--scheduler', addr,
                     '--quiet'] + tls) == 0
        capsys.readouterr()
        # a client without a certificate, or with one the cluster's CA did not sign, is
        # refused in one line, and writes nothing
        monkeypatch.setattr(engine, 'CONNECT_TIMEOUT', '2s')
        stranger = _tls_files(tmp_path / 'stranger')
        for extra, word in (([], 'a TLS scheduler needs --tls-ca-file'),
                            (['--tls-ca-file', ca, '--tls-cert', stranger[1], '--tls-key',
                              stranger[2]], 'cannot connect')):
            assert main([spec_path, '-o', str(tmp_path / 'refused'), '--scheduler', addr,
                         '--quiet'] + extra) == 2
            err = capsys.readouterr().err.strip()
            assert len(err.splitlines()) == 1 and word in err, err
            assert not (tmp_path / 'refused').exists()
    finally:
        for p in procs[::-1]:
            p.terminate()
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()
    assert _bytes(tmp_path / 'pool') == _bytes(tmp_path / 'cluster')


def test_a_ros_estimator_of_this_package_is_found_without_the_environment_activated(
        monkeypatch):
    """``.venv/bin/rigidrot_campaign`` run with a PATH that lacks ``.venv/bin`` (not activated)
    finds ``rigidrot_mekf`` beside the interpreter, checks and starts it from there; an
    unknown command is still refused by name."""
    from rigidrot_ros.campaign.spec import command_path
    here = os.path.dirname(sys.executable)
    bare = os.pathsep.join(p for p in os.environ.get('PATH', '').split(os.pathsep)
                           if p != here) or os.defpath
    monkeypatch.setenv('PATH', bare)
    assert shutil.which('rigidrot_mekf') is None or \
        os.path.dirname(shutil.which('rigidrot_mekf')) != here
    import yaml
    path = Path(__file__).resolve().parents[2] / 'doc' / 'campaigns' / 'mekf_ros.yaml'
    doc = yaml.safe_load(path.read_text())
    spec = check_spec(doc, str(path.parent))
    assert spec['estimator']['command'][0] == 'rigidrot_mekf'
    assert shutil.which('rigidrot_mekf', path=command_path()) == \
        os.path.join(here, 'rigidrot_mekf')
    doc['estimator']['command'] = 'rigidrot_no_such_filter --x'
    with pytest.raises(SpecError, match='rigidrot_no_such_filter: command not found'):
        check_spec(doc, str(path.parent))
