"""Scene validation and model selection: every bad input and every unsupported scene."""

import math

import pytest

from rigidrot_ros.core import NoExactSolution, Scene, solve


@pytest.mark.parametrize('kwargs, field', [
    ({'inertia': (1.0, math.nan, 1.0)}, r'inertia\[1\] must be finite'),
    ({'inertia': (1.0, 1.0, math.inf)}, r'inertia\[2\] must be finite'),
    ({'inertia': (1.0, -1.0, 1.0)}, r'inertia\[1\] must be positive'),
    ({'inertia': (0.0, 1.0, 1.0)}, r'inertia\[0\] must be positive'),
    ({'inertia': (1.0, 1.0, 2.5)}, r'triangle inequality.*I1 \+ I2'),
    ({'inertia': (1.0, 1.0)}, r'inertia must have 3 components'),
    ({'inertia': 'abc'}, r'inertia must be a sequence'),
    ({'inertia': (1.0, '1', 1.0)}, r'inertia\[1\] must be a real number'),
    ({'inertia': (1.0, True, 1.0)}, r'inertia\[1\] must be a real number'),
    ({'torque': (0.0, math.nan, 0.0)}, r'torque\[1\] must be finite'),
    ({'omega0': (0.0, 0.0, -math.inf)}, r'omega0\[2\] must be finite'),
    ({'omega0': 3.0}, r'omega0 must be a sequence'),
    ({'attitude0': (0.0, 0.0, 0.0, 0.0)}, r'attitude0 must be a nonzero quaternion'),
    ({'attitude0': (0.0, 0.0, 1.0)}, r'attitude0 must have 4 components'),
    ({'torque_frame': 'inertial'}, r"torque_frame must be one of \('body', 'virtual'\)"),
])
def test_bad_scene_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        Scene(**kwargs)


def test_attitude_is_normalised_and_scene_round_trips():
    s = Scene(attitude0=(0.0, 0.0, 2.0, 2.0))
    assert s.attitude0 == pytest.approx((0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)), abs=2.3e-16)
    assert Scene.from_dict(s.as_dict()) == s
    huge = Scene(attitude0=(1e308, 1e308, 0.0, 0.0))   # no overflow in the norm
    assert huge.attitude0 == pytest.approx((math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0))
    with pytest.raises(ValueError, match='unknown scene field'):
        Scene.from_dict({'q0': [0, 0, 0, 1]})


@pytest.mark.parametrize('scene, model', [
    (Scene(inertia=(1, 2, 3), omega0=(0, 0, 1), torque=(0, 0, 0.2)), 'fixed-axis'),
    (Scene(inertia=(1, 2, 3)), 'fixed-axis'),
    (Scene(inertia=(2, 2, 2), omega0=(1, 2, 3)), 'torque-free-sphere'),
    (Scene(inertia=(2, 2, 1), omega0=(1, 2, 3)), 'torque-free-axisymmetric'),
    (Scene(inertia=(2, 2, 2), omega0=(1, 2, 3), torque=(1, 1, 1)), 'sphere'),
    (Scene(inertia=(2, 2, 2), omega0=(1, 2, 3), torque=(1, 1, 1), torque_frame='virtual'),
     'sphere'),
    (Scene(inertia=(2, 2, 1), omega0=(1, 2, 3), torque=(0, 0, 1)), 'axial-torque'),
    (Scene(inertia=(1, 2, 2), omega0=(1, 2, 3), torque=(1, 0, 0)), 'axial-torque'),
    (Scene(inertia=(2, 1, 2), omega0=(1, 2, 3), torque=(0, -1, 0)), 'axial-torque'),
    (Scene(inertia=(2, 2, 1), omega0=(1, 2, 3), torque=(1, 0, 0), torque_frame='virtual'),
     'transverse-virtual'),
    (Scene(inertia=(2, 2, 1), omega0=(1, 2, 0), torque=(1, 1, 0)), 'transverse-body'),
    (Scene(inertia=(2, 2, 1), omega0=(1, 2, 3), torque=(1, 0, 1), torque_frame='virtual'),
     'oblique-virtual'),
    (Scene(inertia=(1, 2, 2.5), omega0=(1, 2, 3)), 'torque-free-triaxial'),
])
def test_cheapest_model_is_chosen(scene, model):
    assert solve(scene).model == model


@pytest.mark.parametrize('scene, reason', [
    (Scene(inertia=(1, 2, 2.5), omega0=(1, 2, 3), torque=(0, 0, 1)), 'three different'),
    (Scene(inertia=(2, 2, 1), omega0=(1, 2, 3), torque=(1, 0, 1)), 'oblique to the symmetry'),
    (Scene(inertia=(2, 2, 1), omega0=(1, 2, 3), torque=(1, 0, 0)), r'r0 = 0'),
    (Scene(inertia=(1, 2, 2.5), omega0=(1, 2, 3), torque=(1, 0, 0), torque_frame='virtual'),
     'needs an axisymmetric body'),
])
def test_unsupported_scene_says_why_and_how_to_fix(scene, reason):
    with pytest.raises(NoExactSolution, match=reason) as info:
        solve(scene)
    assert isinstance(info.value, ValueError)
    text = str(info.value)
    assert any(w in text for w in ('Set ', 'set ', 'Make ', 'Remove ', 'Use ')), text


@pytest.mark.parametrize('kwargs, match', [
    ({'tol': math.nan}, 'tol must be a finite'),
    ({'tol': 1e-16}, 'below'),
    ({'tol': 'small'}, 'tol must be a finite'),
    ({'backend': 'scipy'}, "backend must be None, 'flint' or 'mpmath'"),
    ({'max_prec': 10}, 'max_prec'),
])
def test_bad_solve_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        solve(Scene(), **kwargs)


def test_solve_wants_a_scene():
    with pytest.raises(TypeError, match='Scene'):
        solve({'inertia': (1, 1, 1)})


def test_bad_times_are_rejected():
    sol = solve(Scene(omega0=(0.0, 0.0, 1.0)))
    with pytest.raises(ValueError, match='finite'):
        sol.at([0.0, math.nan])
    with pytest.raises(ValueError, match='1-D'):
        sol.at([[0.0, 1.0]])
