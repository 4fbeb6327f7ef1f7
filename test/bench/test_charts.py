"""Chart helpers without drawing: fixed styles, independent-check marks, representations."""

from rigidrot_ros.bench import charts
from rigidrot_ros.bench.crosscheck import representation, stability_scene


def test_each_method_keeps_one_style():
    assert charts._style('DOP853') == charts._style('DOP853')
    styles = {m: charts._style(m) for m in charts.MARKERS}
    assert len({c for c, _ in styles.values()}) == len(styles)      # distinct colours
    assert charts._style('a new method')[0] not in {c for c, _ in styles.values()}


def test_marks_prefer_dop853_then_a_second_representation():
    st = [{'axis': 'U', 'value': 1.0, 'T_s': t, 'method': 'DOP853, rtol 1e-13', 'status': s}
          for t, s in ((1.0, 'meets 1e-12'), (10.0, 'meets 1e-9'), (100.0, 'fail: time-out'),
                       (1e3, 'meets 1e-9'))]
    cross = [{'axis': 'U', 'value': 1.0, 'T_s': t, 'independent': ind,
              'flint_vs_mpmath_rad': err}
             for t, ind, err in ((1.0, True, 0.0), (10.0, True, 1e-15), (100.0, False, 0.0),
                                 (1e3, True, 1e-9))]
    marks = charts.independent_marks(st, cross)
    assert marks[('U', 1.0, 1.0)] == 'meets 1e-12'
    assert marks[('U', 1.0, 10.0)] == 'other representation'
    assert ('U', 1.0, 100.0) not in marks           # same representation: no mark
    assert marks[('U', 1.0, 1e3)] == 'meets 1e-9'   # the backends disagree beyond 1e-12


def test_representations_and_scenes():
    assert representation('hypergeometric-flint') == representation('hypergeometric-mpmath')
    assert not representation('taylor-series-flint') & representation('hypergeometric-mpmath')
    assert representation('hypergeometric-flint+taylor-series-flint') == \
        {'hypergeometric', 'taylor-series'}
    sc = stability_scene('U', 1e-4)
    assert sc.torque == (0.0, 0.0, 1e-4) and sc.omega0 == (0.3, -0.2, 0.5)
    assert stability_scene('r0', 10.0).omega0 == (0.3, -0.2, 10.0)
