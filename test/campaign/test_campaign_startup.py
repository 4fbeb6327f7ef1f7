"""What the campaign's client does once for its workers changes no result.

- The set-up :func:`~rigidrot_ros.campaign.spec.check_draws` prepared for a run, kept
  and taken by the run, gives the row and series of a run prepared afresh.
- An estimator's ``warm()`` is called by the client before the pool forks.
- Estimates scored against the generator's own solution of the run score as against the
  solution the scorer makes from the run description.
- The charts drawn in two processes are the files drawn in one, byte for byte.
- Results saved in threads: a save that fails stops the campaign with its error once the
  others are saved, and the same command continues it to the report of one never stopped.
"""

import os
import threading

import numpy as np

from rigidrot_ros.campaign import charts, engine, spec as spec_mod
from rigidrot_ros.campaign.run import run_one
from rigidrot_ros.campaign.spec import draw_run, load_spec, run_values, take_prepared
from rigidrot_ros.tools.campaign import main

from campaign_helpers import _write, Silent, SPEC  # noqa: I100, I201 - a helper module beside it

WARMED = []


class _Warm(Silent):
    """An estimator that publishes nothing and counts its ``warm()`` calls."""

    def warm(self):
        """Count the call."""
        WARMED.append(os.getpid())


def warm_factory(params):
    """Make a :class:`_Warm`."""
    return _Warm()


def test_a_kept_setup_gives_the_run_of_a_fresh_one(tmp_path):
    path = _write(tmp_path, dict(SPEC, runs=2, duration=1.5))
    spec_mod.forget_prepared()
    try:
        spec = load_spec(path, keep=True)
        assert len(spec_mod._PREPARED) == 2
        values = run_values(spec, draw_run(spec, 1)[0])
        kept = run_one(spec, 1)                             # takes the kept set-up
        assert take_prepared(values) is None and len(spec_mod._PREPARED) == 1
        fresh = run_one(spec, 1)                            # prepares it again
    finally:
        spec_mod._PREPARED.clear()
    assert kept['row']['status'] == 'ok'
    assert (kept['row'], kept['series']) == (fresh['row'], fresh['series'])
    assert load_spec(path) and not spec_mod._PREPARED      # kept only when asked


def test_a_ros_estimator_keeps_no_setup(tmp_path):
    est = {'command': 'rigidrot_mekf --ros-args -p use_sim_time:=true',
           'topics': ['/estimator/odom']}
    spec_mod.forget_prepared()
    try:
        load_spec(_write(tmp_path, dict(SPEC, runs=2, estimator=est)), keep=True)
        assert not spec_mod._PREPARED
    finally:
        spec_mod._PREPARED.clear()


def test_the_client_warms_each_estimator_before_the_pool_forks(tmp_path):
    WARMED.clear()
    doc = dict(SPEC, runs=1, estimator={'factory': 'test_campaign_startup:warm_factory'})
    spec = load_spec(_write(tmp_path, doc))
    engine._warm(spec)
    assert WARMED == [os.getpid()]


def _report(steps=299):
    rng = np.random.default_rng(3)
    t = [0.1 * (k + 1) for k in range(steps)]
    nees = list(3.0 + 0.2 * rng.standard_normal(steps))
    return {'name': 'two ways', 'runs_ok': 100, 'steps': steps,
            'mc_nees': {'band_95': [2.54, 3.50], 't_s': t, 'nees': nees,
                        'fraction_inside': 0.97},
            'anees': {'value': float(np.mean(nees))},
            'rms_error': {'t_s': t, 'rad': list(1e-4 + 1e-5 * rng.random(steps))},
            'per_run_anees': {'values': list(np.linspace(2.6, 3.4, 100)),
                              'bounds_95': [2.73, 3.28], 'fraction_inside': 0.87}}


def test_charts_drawn_in_two_processes_are_the_same_files(tmp_path, monkeypatch):
    one, two = tmp_path / 'one', tmp_path / 'two'
    one.mkdir()
    two.mkdir()
    paths = charts.write_charts(_report(), str(one), jobs=1)
    forked, real = [], charts._forked
    monkeypatch.setattr(charts, '_forked', lambda *a: forked.append(1) or real(*a))
    alone = threading.active_count() == 1          # else it draws them here (no fork)
    assert charts.write_charts(_report(), str(two), jobs=2) == \
        [str(two / os.path.basename(p)) for p in paths]
    assert forked == ([1] if alone else [])
    assert sorted(os.listdir(one)) == sorted(os.listdir(two)) == sorted(
        f'{n}.{e}' for n in ('nees', 'rms_error', 'anees_hist') for e in ('png', 'svg'))
    for name in os.listdir(one):
        assert (one / name).read_bytes() == (two / name).read_bytes(), name


def test_the_command_keeps_no_setup_after_it(tmp_path):
    spec_mod.forget_prepared()
    path = _write(tmp_path, dict(SPEC, runs=2, duration=1.0))
    assert main([path, '-o', str(tmp_path / 'out'), '--quiet', '--processes', '1']) == 0
    assert not spec_mod._PREPARED


def test_a_failed_save_stops_the_campaign_and_a_rerun_continues(tmp_path, monkeypatch):
    spec = load_spec(_write(tmp_path, dict(SPEC, runs=3, duration=0.5)))
    real = engine._save_run

    def save(out_dir, result):
        if result['row']['run'] == 1:
            raise OSError(28, 'No space left on device')
        real(out_dir, result)

    monkeypatch.setattr(engine, '_save_run', save)
    out = tmp_path / 'out'
    try:
        engine.run_campaign(spec, str(out), workers=1, progress=False)
    except OSError as exc:
        assert exc.errno == 28
    else:
        raise AssertionError('the failed save was not raised')
    saved = sorted(n for n in os.listdir(out / 'runs') if n.endswith('.time.json'))
    assert '000001.time.json' not in saved and '000000.time.json' in saved
    monkeypatch.setattr(engine, '_save_run', real)
    report = engine.run_campaign(spec, str(out), workers=1, progress=False)
    whole = engine.run_campaign(spec, str(tmp_path / 'whole'), workers=1, progress=False)
    assert report == whole and report['runs_ok'] == 3
    assert (out / 'report.json').read_bytes() == (tmp_path / 'whole' / 'report.json').read_bytes()


def test_the_generators_solution_scores_as_the_descriptions(tmp_path):
    from rigidrot_ros.campaign.inproc import run_inproc
    from rigidrot_ros.campaign.run import score_estimates
    spec = load_spec(_write(tmp_path, dict(SPEC, runs=1, duration=2.0)))
    est = run_inproc(spec, run_values(spec, draw_run(spec, 0)[0]), None, {})
    assert len(est.solutions) == 1
    own = score_estimates(est)
    est.solutions = None
    assert own == score_estimates(est)
    assert own[0]['nees_count'] > 10
