"""One contract for every model: the base class, the registry, no import circle in core."""

import ast
import os

import numpy as np
import pytest

from rigidrot_ros.core import BaseSolution, MODELS, RateEnvelope, Scene, SOLUTIONS, solve
from rigidrot_ros.core.classify import NoExactSolution
from rigidrot_ros.sensors.increments import RateBound

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CORE = os.path.join(ROOT, 'rigidrot_ros', 'core')

#: One scene per model name (the registry must cover each, and only these).
SCENES = {
    'fixed-axis': Scene(inertia=(1, 2, 3), torque=(0, 0.1, 0), omega0=(0, 0.7, 0)),
    'torque-free-sphere': Scene(omega0=(0.1, 0.2, 0.3)),
    'torque-free-axisymmetric': Scene(inertia=(2, 2, 1), omega0=(0.3, -0.2, 1.5)),
    'sphere': Scene(inertia=(1.5,) * 3, torque=(0.05, -0.03, 0.04), omega0=(0.4, 0.1, -0.3)),
    'axial-torque': Scene(inertia=(2, 2, 1), torque=(0, 0, 0.05), omega0=(0.3, -0.2, 0.5)),
    'transverse-virtual': Scene(inertia=(2, 2, 1), torque=(0.04, 0, 0), torque_frame='virtual',
                                omega0=(0.3, -0.2, 0.5)),
    'transverse-body': Scene(inertia=(2, 2, 3), torque=(0.04, 0, 0), omega0=(0.3, -0.2, 0)),
    'oblique-virtual': Scene(inertia=(2, 2, 1), torque=(0.03, 0, 0.05),
                             torque_frame='virtual', omega0=(0.3, -0.2, 0.5)),
    'torque-free-triaxial': Scene(inertia=(1, 2, 3), omega0=(0.02, 1.0, 0.03)),
}
LINEAR = {'fixed-axis', 'torque-free-sphere', 'sphere'}


def _core_imports():
    """Map each core module to the core modules it imports, and where (module or function)."""
    graph, nested = {}, []
    for name in sorted(os.listdir(CORE)):
        if not name.endswith('.py'):
            continue
        mod = name[:-3]
        with open(os.path.join(CORE, name), encoding='utf-8') as fh:
            tree = ast.parse(fh.read())
        deps = set()
        top = set(id(n) for n in tree.body)
        for node in ast.walk(tree):
            targets = []
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                targets = [node.module] if node.module else [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and (node.module or '').startswith(
                    'rigidrot_ros.core'):
                targets = [(node.module.split('.') + [''])[2] or a.name for a in node.names]
            for t in targets:
                deps.add(t)
                if id(node) not in top:
                    nested.append((mod, t))
        graph[mod] = deps
    return graph, nested


def test_no_import_circle_and_no_function_level_core_imports():
    graph, nested = _core_imports()
    assert not nested, f'function-level imports of core modules: {nested}'
    state = {}

    def visit(m, path):
        if state.get(m) == 'done':
            return
        assert state.get(m) != 'open', f'import circle: {" -> ".join(path + [m])}'
        state[m] = 'open'
        for d in graph.get(m, ()):
            if d in graph:
                visit(d, path + [m])
        state[m] = 'done'
    for m in graph:
        visit(m, [])
    # the two models share the base, not each other's module
    assert 'models' not in graph['triaxial']
    assert 'solution' in graph['triaxial'] and 'solution' in graph['models']


def test_registry_covers_every_model_with_a_base_solution():
    assert set(SOLUTIONS) == set(MODELS) == set(SCENES)
    for name, cls in SOLUTIONS.items():
        assert issubclass(cls, BaseSolution)
        assert name in cls.MODELS and MODELS[name] == cls.MODELS[name]
        # the scalar/array dispatch is written once, in the base
        for meth in ('at', 'omega_at', 'omega_dot_at', 'torque_body_at'):
            assert meth not in vars(cls), (cls, meth)


@pytest.mark.parametrize('name', sorted(SCENES))
def test_every_solution_keeps_the_contract(name):
    sol = solve(SCENES[name], tol=1e-12)
    assert isinstance(sol, SOLUTIONS[name]) and sol.model == name
    assert sol.tol == 1e-12 and sol.scene is SCENES[name]
    assert isinstance(sol.method, str) and sol.reference == MODELS[name]
    t = np.array([0.0, 0.5, -2.0, 7.25])
    s = sol.at(t)
    assert s.quaternion.shape == (4, 4) and s.omega.shape == (4, 3) and s.error_bound.shape == (4,)
    one = sol.at(0.5)
    assert one.quaternion.shape == (4,) and one.omega.shape == (3,) and one.error_bound.shape == ()
    for f in (sol.omega_at, sol.omega_dot_at, sol.torque_body_at):
        assert f(t).shape == (4, 3) and f(0.5).shape == (3,)
    for f in (sol.at, sol.omega_at, sol.omega_dot_at, sol.torque_body_at):
        with pytest.raises(ValueError, match='1-D'):
            f(np.zeros((2, 2)))
        with pytest.raises(ValueError, match='finite'):
            f([0.0, np.inf])
    env = sol.rate_envelope()
    assert isinstance(env, RateEnvelope)
    if SCENES[name].torque_frame == 'body' or name in LINEAR:
        assert RateBound(sol).kind == env.kind
    assert env.kind == ('linear' if name in LINEAR else
                        'majorant' if name == 'torque-free-triaxial' else 'closed-form')


def test_rate_envelope_bounds_the_rate():
    rng = np.random.default_rng(3)
    for name, scene in SCENES.items():
        sol = solve(scene)
        env = sol.rate_envelope()
        if env.kind != 'closed-form':
            continue
        t = rng.uniform(-50.0, 50.0, 200)
        w = sol.omega_at(t)
        k = sol._axis
        tr = [(k + 1) % 3, (k + 2) % 3]
        at = np.abs(t)
        assert np.all(np.abs(w[:, k]) <= env.r0 + env.rdot * at + 1e-12)
        assert np.all(np.hypot(w[:, tr[0]], w[:, tr[1]]) <= env.w_t + env.m_t * at + 1e-12)


def test_outside_the_registry_says_why():
    with pytest.raises(NoExactSolution, match='three different moments'):
        solve(Scene(inertia=(1, 2, 3), torque=(0.1, 0.0, 0.0), omega0=(0.1, 0.2, 0.3)))
