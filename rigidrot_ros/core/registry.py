"""Model selection: :func:`solve` and the registry :data:`SOLUTIONS` of solution classes.

:func:`solve` checks its arguments, classifies the scene (:func:`~.classify.classify`) and
builds the solution class registered for its model: :class:`~.models.Solution` for
Romano's spherical and axisymmetric bodies, :class:`~.triaxial.TriaxialSolution` for the
torque-free triaxial body. Both keep the contract of :class:`~.solution.BaseSolution`.
"""

import math
import reprlib

from .classify import classify
from .kernel import available_backends
from .models import Solution
from .scene import Scene
from .solution import FLOAT_FLOOR
from .triaxial import TriaxialSolution

__all__ = ['solve', 'SOLUTIONS', 'MODELS', 'MIN_TOL', 'MAX_PREC']

#: The smallest tol accepted, rad: twice the float64 floor.
MIN_TOL = 2 * FLOAT_FLOOR

#: The highest precision ceiling ``solve`` accepts, bits: Arb's 1F1 at 65536 bits takes
#: seconds to minutes a value; beyond that a request would effectively hang.
MAX_PREC = 65536

#: The solution class of every model (as scipy's ``integrate._ivp`` METHODS): :func:`solve`
#: classifies the scene and builds ``SOLUTIONS[model]``. Every class is a
#: :class:`~.solution.BaseSolution` and lists its models in its ``MODELS``.
SOLUTIONS = {**{name: Solution for name in Solution.MODELS},
             **{name: TriaxialSolution for name in TriaxialSolution.MODELS}}
#: Model names and the paper's results they evaluate.
MODELS = {name: cls.MODELS[name] for name, cls in SOLUTIONS.items()}


def solve(scene, tol=1e-12, backend=None, max_prec=4096):
    """Choose the cheapest exact model for ``scene`` and prepare its constants.

    Parameters
    ----------
    scene : Scene
    tol : float
        Attitude accuracy asked, rad (>= ``MIN_TOL`` = 2e-14, twice the float64 floor).
    backend : {None, 'flint', 'mpmath'}
        Special-function backend; None picks the fastest installed (flint, else mpmath).
    max_prec : int
        Ceiling on the working precision of the special functions, bits (64 to
        ``MAX_PREC`` = 65536).

    Returns
    -------
    Solution

    Raises
    ------
    NoExactSolution
        The scene is outside the exact models; the message says why and what would fix it.
    PrecisionError
        The per-scene constants cannot be evaluated to ``tol`` within ``max_prec`` bits.

    References
    ----------
    Romano, M., "Exact analytic solutions for the rotation of an axially symmetric
    rigid body subjected to a constant torque", Celest. Mech. Dyn. Astr. 101 (2008).
    """
    if not isinstance(scene, Scene):
        raise TypeError(f'scene must be a rigidrot_ros.core.Scene, got {type(scene).__name__}')
    try:
        tol_f = float(tol) if isinstance(tol, (int, float)) else math.nan
    except OverflowError:                                       # int(10**400)
        tol_f = math.inf
    if isinstance(tol, bool) or not math.isfinite(tol_f):
        raise ValueError(f'tol must be a finite number of radians, got {reprlib.repr(tol)}')
    if tol < MIN_TOL:
        raise ValueError(f'tol = {tol!r} rad is below {MIN_TOL} rad, twice the float64 '
                         f'floor of the returned samples')
    if backend is None:
        backend = available_backends()[0]
    if backend not in ('flint', 'mpmath'):
        raise ValueError(f"backend must be None, 'flint' or 'mpmath', got {backend!r}")
    if isinstance(max_prec, bool) or not isinstance(max_prec, int) or \
            not 64 <= max_prec <= MAX_PREC:
        raise ValueError(f'max_prec must be an integer from 64 to {MAX_PREC} bits (a higher '
                         f'ceiling could run for hours), got {max_prec!r}')
    return SOLUTIONS[classify(scene)[0]](scene, tol_f, backend, max_prec)
