"""Several estimators on the same runs: one campaign, every estimator fed the same run.

Oracles: each estimator's section of the report against a one-estimator campaign of that
estimator alone (the path that existed before), the paired statistics against numpy and
scipy.stats (Student t) on the run files, and scipy's t quantiles for the mpmath ones.
"""

import csv
import json
import math
import os
import sys

import numpy as np
import pytest
from scipy import stats

from rigidrot_ros.campaign.engine import run_campaign
from rigidrot_ros.campaign.multi import paired, t_ppf
from rigidrot_ros.campaign.spec import load_spec
from rigidrot_ros.tools.campaign import main

sys.path.insert(0, os.path.dirname(__file__))
MEKF = 'rigidrot_ros.estimators.mekf:make'
TUNED = {'sigma_v': 1.7e-4, 'sigma_u': 2e-5, 'bias_sigma': 2e-3}
BASE = {
    'name': 'two', 'seed': 11, 'runs': 2, 'duration': 2.0, 'timeout': 120,
    'base': {'overrides': {'imu.enable': True, 'star_tracker.enable': True}},
    'dispersions': {'attitude0': 'uniform',
                    'omega0': {'mean': [0.3, -0.2, 0.5], 'sigma': 0.05},
                    'imu.gyro_bias': {'mean': [0, 0, 0], 'sigma': 2e-3}},
}
TWO = dict(BASE, estimators=[
    {'label': 'tuned', 'factory': MEKF, 'params': TUNED},
    {'label': 'sigma_v/10', 'factory': MEKF, 'params': dict(TUNED, sigma_v=1.7e-5)}])


def _write(tmp_path, doc, name='spec.yaml'):
    import yaml
    p = tmp_path / name
    p.write_text(yaml.safe_dump(doc))
    return str(p)


def test_t_quantiles_match_scipy():
    for dof in (1, 2, 5, 30, 400):
        for p in (0.975, 0.9, 0.6, 0.025):
            assert t_ppf(p, dof) == pytest.approx(stats.t.ppf(p, dof), rel=1e-9, abs=1e-12)


def test_paired_statistics_against_numpy_and_scipy():
    rng = np.random.default_rng(3)
    a, b = rng.normal(1.0, 0.3, 40), rng.normal(1.2, 0.3, 40)
    a[5], b[7] = np.nan, np.nan                       # runs one of them did not score
    ok = np.isfinite(a) & np.isfinite(b)
    d = a[ok] - b[ok]
    p = paired(a, b)
    assert p['n'] == 38 and p['a_lower'] == int(np.sum(a[ok] < b[ok]))
    assert p['mean'] == pytest.approx(d.mean()) and p['sd'] == pytest.approx(d.std(ddof=1))
    lo, hi = stats.t.interval(0.95, len(d) - 1, loc=d.mean(), scale=stats.sem(d))
    assert p['ci95'] == pytest.approx([lo, hi], rel=1e-9)
    assert paired([1.0], [2.0])['ci95'] is None and paired([], [])['n'] == 0


def test_two_estimators_on_the_same_runs(tmp_path, capsys):
    out = tmp_path / 'two'
    assert main([_write(tmp_path, TWO), '-o', str(out), '--quiet', '--processes', '2']) == 0
    said = capsys.readouterr().out
    assert 'tuned: 2/2 runs ok' in said and 'sigma_v/10: 2/2 runs ok' in said
    rep = json.loads((out / 'report.json').read_text())
    assert rep['estimators'] == ['tuned', 'sigma_v/10'] and rep['runs_all_ok'] == 2
    # each estimator's section is the report of a campaign of that estimator alone
    for est in TWO['estimators']:
        one = dict(BASE, estimator={'factory': MEKF, 'params': est['params']},
                   name=est['label'])
        alone = run_campaign(load_spec(_write(tmp_path, one, 'one.yaml')),
                             str(tmp_path / f'alone_{est["params"]["sigma_v"]}'),
                             workers=1, progress=False)
        assert json.loads(json.dumps(alone)) == rep['per_estimator'][est['label']]
    # the paired differences, recomputed from the run files
    rows = [json.loads((out / 'runs' / f'{i:06d}.json').read_text())['row'] for i in range(2)]
    pair = rep['comparison']['paired'][0]
    assert (pair['a'], pair['b']) == ('tuned', 'sigma_v/10')
    for key in ('rms_rad', 'anees', 'p95_rad'):
        d = np.array([r['estimators']['tuned'][key] - r['estimators']['sigma_v/10'][key]
                      for r in rows])
        assert pair[key]['mean'] == pytest.approx(d.mean(), rel=1e-12)
        half = stats.t.ppf(0.975, 1) * d.std(ddof=1) / math.sqrt(2)
        assert pair[key]['ci95'] == pytest.approx([d.mean() - half, d.mean() + half])
    # the mistuned filter is over-confident on every run: ANEES lower for the tuned one
    assert pair['anees']['a_lower'] == 2
    with open(out / 'runs.csv', newline='') as fh:
        table = list(csv.DictReader(fh))
    assert [(r['run'], r['estimator']) for r in table] == [
        ('0', 'tuned'), ('0', 'sigma_v/10'), ('1', 'tuned'), ('1', 'sigma_v/10')]
    for name in ('compare_nees', 'compare_rms_error', 'compare_paired'):
        assert (out / f'{name}.png').stat().st_size > 1000
    assert (out / 'tuned' / 'nees.png').exists() and (out / 'sigma_v_10' / 'nees.png').exists()
    text = (out / 'comparison.md').read_text()
    assert '| tuned | sigma_v/10 | ANEES |' in text


def test_an_estimator_that_fails_fails_alone(tmp_path):
    doc = dict(BASE, runs=4, estimators=[
        {'label': 'flaky', 'factory': 'campaign_helpers:flaky', 'params': TUNED},
        {'label': 'mekf', 'factory': MEKF, 'params': TUNED}])
    rep = run_campaign(load_spec(_write(tmp_path, doc)), str(tmp_path / 'o'), workers=2,
                       progress=False)
    table = {e['label']: e for e in rep['comparison']['table']}
    assert table['mekf']['runs_ok'] == 4 and 0 < table['flaky']['runs_ok'] < 4
    run_rows = [json.loads((tmp_path / 'o' / 'runs' / f'{i:06d}.json').read_text())['row']
                for i in range(4)]
    assert {r['status'] for r in run_rows} == {'ok', 'partial'}
    assert all('flaky estimator' in r['reason'] for r in run_rows if r['status'] == 'partial')
    assert rep['comparison']['paired'][0]['rms_rad']['n'] == table['flaky']['runs_ok']


@pytest.mark.parametrize('change, word', [
    (lambda d: d['estimators'].append(dict(d['estimators'][0])), 'used twice'),
    (lambda d: d.update(estimator=d['estimators'][0]), 'not both'),
    (lambda d: d.update(estimators=[]), 'non-empty list'),
    (lambda d: d['estimators'][1].update(factory='no_such_module_xyz:make'),
     'estimators[1] (sigma_v/10): estimator.factory'),
    (lambda d: d['estimators'][0].update(rate=2.0), 'estimators[0] (tuned)'),
])
def test_bad_estimator_lists_one_line_exit_2(tmp_path, capsys, change, word):
    doc = json.loads(json.dumps(TWO))
    change(doc)
    out = tmp_path / 'out'
    assert main([_write(tmp_path, doc), '-o', str(out), '--quiet']) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and word in err and 'Traceback' not in err, err
    assert not out.exists()
