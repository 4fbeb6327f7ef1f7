"""Which exact model covers a scene: :func:`classify`, or :class:`NoExactSolution` and why.

A body whose omega0 and torque lie along one principal axis turns about it
('fixed-axis'); otherwise a spherical body ('torque-free-sphere', 'sphere'), an
axisymmetric one (Romano's models, by where its torque points and the frame it is fixed
in) or a torque-free triaxial one (Euler-Poinsot). Every refusal says why and what would
make the scene exact.
"""

__all__ = ['classify', 'NoExactSolution']


class NoExactSolution(ValueError):
    """The scene is outside every exact solution this package evaluates."""


def classify(scene):
    """Return (model, symmetry axis index) or raise NoExactSolution.

    The model is a key of :data:`~.registry.SOLUTIONS`; the axis is the symmetry axis of
    an axisymmetric body, the axis that carries the motion for 'fixed-axis', 2 for a
    sphere and None for the torque-free triaxial body.
    """
    inertia = scene.inertia
    w0, m = scene.omega0, scene.torque
    triaxial = len(set(inertia)) == 3
    if triaxial and scene.torque_frame == 'virtual':
        raise NoExactSolution(
            f"torque_frame='virtual' needs an axisymmetric body (two equal moments); "
            f"inertia {inertia} has three different moments. Use torque_frame='body'.")
    # one principal axis carries all of omega0 and of the torque (any body)
    for k in range(3):
        others = [j for j in range(3) if j != k]
        if all(w0[j] == 0.0 and m[j] == 0.0 for j in others):
            return 'fixed-axis', k
    if len(set(inertia)) == 1:
        return ('torque-free-sphere' if not any(m) else 'sphere'), 2
    sym = [k for k in range(3) if inertia[(k + 1) % 3] == inertia[(k + 2) % 3]]
    if not sym and not any(m):
        return 'torque-free-triaxial', None            # evaluated by core/triaxial.py
    if not sym:
        raise NoExactSolution(
            f'inertia {inertia} has three different moments; with a torque such a body has '
            f'no exact solution here (Romano treats spherical and axisymmetric bodies; the '
            f'torque-free triaxial body is exact). Make two moments equal, remove the '
            f'torque, or put omega0 and the torque along one principal axis.')
    k = sym[0]
    names = 'xyz'
    m_ax = m[k]
    m_tr = [m[j] for j in range(3) if j != k]
    r0 = w0[k]
    if not any(m):
        return 'torque-free-axisymmetric', k
    if not any(m_tr):
        return 'axial-torque', k
    if scene.torque_frame == 'virtual':
        return ('transverse-virtual' if m_ax == 0.0 else 'oblique-virtual'), k
    if m_ax != 0.0:
        raise NoExactSolution(
            f'a body-fixed torque {m} oblique to the symmetry axis ({names[k]}) of an '
            f'axisymmetric body has no exact solution (Theorems 2-4 need it along or '
            f'across the axis). Remove its axial or transverse part, or set '
            f"torque_frame='virtual' to hold it fixed in the virtual sphere instead.")
    if r0 != 0.0:
        raise NoExactSolution(
            f'a body-fixed torque across the symmetry axis ({names[k]}) has an exact '
            f'solution only with no spin about that axis (Theorem 4: r0 = 0), but '
            f'omega0[{k}] = {r0!r} rad/s. Set omega0[{k}] = 0, or set '
            f"torque_frame='virtual' so the torque turns at -omega_e (Theorem 3).")
    return 'transverse-body', k
