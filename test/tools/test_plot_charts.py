"""Charts as drawn: rigidrot_compare --plot's axes and colours, the campaign charts' ticks.

The figures are drawn by the project's own code, caught before they are closed, and read
back through matplotlib's artists (axis limits, line colours, tick label texts).
"""

import numpy as np
import pytest

pytest.importorskip('matplotlib')

from rigidrot_ros.campaign import charts  # noqa: E402
from rigidrot_ros.tools import compare  # noqa: E402


class _Catch:
    """pyplot, except that the figures it closes are kept (drawn) for the test."""

    def __init__(self):
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
        self.plt, self.figures = plt, []

    def __getattr__(self, name):
        return getattr(self.plt, name)

    def close(self, fig=None):
        fig.canvas.draw()
        self.figures.append(fig)


def _result(topic, field, unit, t, error, covariance=False):
    r = {'topic': topic, 'field': field, 'unit': unit, 'label': topic if field ==
         'orientation' else f'{topic} [{field}]', 'type': 'nav_msgs/msg/Odometry',
         't': list(t), 'error': list(error), 'count': len(t), 'max': max(error),
         'rms': 0.0, 'p95': 0.0}
    if covariance:
        rng = np.random.default_rng(3)
        r.update(components=(rng.standard_normal((len(t), 3)) * 1e-3).tolist(),
                 sigma=np.full((len(t), 3), 1e-3).tolist(), anees=3.0,
                 anees_bounds_95=[2.7, 3.3], nees_count=len(t))
    return r


def test_compare_plot_keeps_colours_and_a_useful_log_axis(tmp_path):
    t = np.arange(200) * 0.1
    rng = np.random.default_rng(1)
    est = 10.0 ** rng.uniform(-4, -2, t.size)
    est[0] = 1e-17                              # started at the truth: exact at t = 0
    star = 10.0 ** rng.uniform(-5, -4, t.size)
    results = [_result('/star_tracker', 'orientation', 'rad', t, star),
               _result('/estimator/odom', 'orientation', 'rad', t, est, covariance=True),
               _result('/estimator/odom', 'angular_velocity', 'rad/s', t,
                       10.0 ** rng.uniform(-4, -3, t.size))]
    catch = _Catch()
    compare._plot(catch, results, str(tmp_path / 'p.png'), 'title', 'log')
    assert (tmp_path / 'p.png').stat().st_size > 0
    angle_ax, rate_ax = catch.figures[0].axes[:2]
    colors = {}
    for ax in (angle_ax, rate_ax):
        for line in ax.get_lines():
            topic = line.get_label().split(' ')[0]
            colors.setdefault(topic, set()).add(line.get_color())
    assert all(len(c) == 1 for c in colors.values()), colors     # one colour per topic
    assert colors['/estimator/odom'] != colors['/star_tracker']
    # the 1e-17 at t = 0 does not stretch the axis: it starts a decade below the bulk,
    # the sample is drawn on it and counted in the legend
    bottom = angle_ax.get_ylim()[0]
    assert 1e-6 <= bottom <= 1e-5, bottom
    label = [ln.get_label() for ln in angle_ax.get_lines()
             if ln.get_label().startswith('/estimator/odom')][0]
    assert '1 below 1e-05, drawn on the axis bottom' in label, label
    assert min(angle_ax.get_lines()[1].get_ydata()) == bottom


def _report(name, nees):
    steps = len(nees)
    t = [0.1 * (k + 1) for k in range(steps)]
    return {'name': name, 'runs_ok': 100, 'steps': steps,
            'mc_nees': {'band_95': [2.54, 3.50], 't_s': t, 'nees': list(nees),
                        'fraction_inside': 0.97},
            'anees': {'value': float(np.mean(nees))},
            'rms_error': {'t_s': t, 'rad': [1e-4] * steps},
            'per_run_anees': {'values': list(np.linspace(2.6, 3.4, 100)),
                              'bounds_95': [2.73, 3.28], 'fraction_inside': 0.87}}


def test_campaign_charts_label_log_ticks_plainly(tmp_path, monkeypatch):
    drawn = []
    real = charts._save

    def save(fig, prefix):
        fig.canvas.draw()
        drawn.append([t.get_text() for ax in fig.axes
                      for t in ax.get_yticklabels(minor=False) + ax.get_yticklabels(minor=True)
                      if ax.get_yscale() == 'log' and t.get_text()])
        return real(fig, prefix)

    monkeypatch.setattr(charts, '_save', save)
    rng = np.random.default_rng(2)
    tuned = _report('tuned', 3.0 + 0.2 * rng.standard_normal(299))
    charts.write_charts(tuned, str(tmp_path))
    charts.compare_chart([tuned, _report('mistuned', 50 + 5 * rng.standard_normal(299))],
                         str(tmp_path / 'both'))
    labels = [lab for chart in drawn for lab in chart]
    assert drawn[0] and drawn[-1], drawn
    for lab in labels:
        assert 'times' not in lab and '×' not in lab and '^' not in lab, labels
        float(lab)                                              # a plain number
    assert '3' in drawn[0]
