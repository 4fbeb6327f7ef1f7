"""The scene: a rigid body, a constant torque, and its state at t = 0.

Frames: N inertial, B body (principal axes). ``omega0`` is the angular velocity of B
relative to N, in B, rad/s. ``attitude0`` is ``q_NB`` at t = 0 in (x, y, z, w) order: it
rotates body vectors into N (``v_N = R_NB @ v_B``).
"""

from dataclasses import dataclass
import math
import numbers
import reprlib

__all__ = ['Scene', 'TORQUE_FRAMES', 'float_vector']

TORQUE_FRAMES = ('body', 'virtual')


def float_vector(name, value, size, kind='sequence', finite=True):
    """Return ``value``, a sequence of ``size`` real numbers, as a tuple of floats.

    The one check of a list of numbers, for the scene and for the node's parameters; each
    refusal is one ``ValueError`` line that starts with ``name`` and names the problem.

    Parameters
    ----------
    name : str
        How the messages name the value: ``'omega0'``, or ``'parameter omega0'``.
    value : object
        What was given.
    size : int
        How many numbers it must hold.
    kind : str
        What the messages call the container: ``'sequence'`` (Python callers) or
        ``'list'`` (ROS parameters).
    finite : bool
        Refuse NaN and infinities too (else the caller's own rules judge them).

    Returns
    -------
    tuple of float

    Raises
    ------
    ValueError
        Not a sized sequence (a string, a mapping, a scalar), the wrong length, an element
        that is not a real number (bool included), beyond the float64 range, or not finite.

    Examples
    --------
    >>> float_vector('omega0', [1, 2.5, 0], 3)
    (1.0, 2.5, 0.0)
    """
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, '__len__'):
        raise ValueError(f'{name} must be a {kind} of {size} numbers, got {value!r}')
    try:
        count = len(value)
    except TypeError:
        raise ValueError(f'{name} must be a {kind} of {size} numbers, got {value!r}') from None
    if count != size:
        raise ValueError(f'{name} must have {size} components, got {count}')
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise ValueError(f'{name}[{i}] must be a real number, got {v!r}')
        try:
            v = float(v)
        except (OverflowError, ValueError, TypeError):      # e.g. int(10**400)
            raise ValueError(f'{name}[{i}] = {reprlib.repr(v)} is beyond the float64 range '
                             f'(|x| <= 1.8e308)') from None
        if finite and not math.isfinite(v):
            raise ValueError(f'{name}[{i}] must be finite, got {v!r}')
        out.append(v)
    return tuple(out)


@dataclass(frozen=True)
class Scene:
    """A rigid body under a constant torque.

    Parameters
    ----------
    inertia : 3 floats
        Principal moments (I1, I2, I3), kg m^2; positive and meeting the triangle
        inequality (I1 + I2 >= I3 and its permutations).
    torque : 3 floats
        Constant torque, N m, with components in ``torque_frame``.
    torque_frame : {'body', 'virtual'}
        'body': the torque is constant in B. 'virtual': constant in the paper's
        virtual-sphere frame S (Romano 2008, Sec. 4), which coincides with B at t = 0
        and turns relative to B about the symmetry axis; in B a transverse torque then
        turns at ``-omega_e`` (Theorem 3). 'virtual' needs an axially symmetric body.
    omega0 : 3 floats
        Angular velocity of B relative to N, in B, rad/s, at t = 0.
    attitude0 : 4 floats
        ``q_NB`` at t = 0, order (x, y, z, w); normalised on input.

    Raises
    ------
    ValueError
        Naming the field: non-finite or non-numeric values, numbers beyond the float64
        range (an int of 10**400), non-positive moments, moments that break the triangle
        inequality, a zero quaternion, an unknown torque_frame. Any finite float is
        accepted otherwise (5e-324 ... 1.8e308); :func:`solve` refuses what it cannot
        evaluate, with the reason.

    Examples
    --------
    >>> Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.1), omega0=(0.3, -0.2, 0.5))
    ... # doctest: +ELLIPSIS
    Scene(inertia=(2.0, 2.0, 1.0), ...)
    """

    inertia: tuple = (1.0, 1.0, 1.0)
    torque: tuple = (0.0, 0.0, 0.0)
    torque_frame: str = 'body'
    omega0: tuple = (0.0, 0.0, 0.0)
    attitude0: tuple = (0.0, 0.0, 0.0, 1.0)

    def __post_init__(self):
        inertia = float_vector('inertia', self.inertia, 3)
        for i, v in enumerate(inertia):
            if v <= 0.0:
                raise ValueError(f'inertia[{i}] must be positive (kg m^2), got {v!r}')
        for i in range(3):
            j, k = (i + 1) % 3, (i + 2) % 3
            if inertia[j] + inertia[k] < inertia[i]:
                raise ValueError(
                    f'inertia {inertia} breaks the triangle inequality: '
                    f'I{j + 1} + I{k + 1} = {inertia[j] + inertia[k]!r} < I{i + 1} = '
                    f'{inertia[i]!r}; no rigid body has these principal moments')
        torque = float_vector('torque', self.torque, 3)
        if not isinstance(self.torque_frame, str) or self.torque_frame not in TORQUE_FRAMES:
            raise ValueError(
                f'torque_frame must be one of {TORQUE_FRAMES}, got {self.torque_frame!r}')
        omega0 = float_vector('omega0', self.omega0, 3)
        att = float_vector('attitude0', self.attitude0, 4)
        big = max(abs(v) for v in att)
        if big == 0.0:
            raise ValueError(f'attitude0 must be a nonzero quaternion (x, y, z, w), got {att}')
        if not abs(math.hypot(*att) - 1.0) <= 4.5e-16:   # leave unit input bit-for-bit
            # scale by the largest component first: no overflow (1e308 ...) and no
            # denormal rounding (5e-324 ...) in the norm
            att = tuple(v / big for v in att)
            norm = math.hypot(*att)
            att = tuple(v / norm for v in att)
        object.__setattr__(self, 'inertia', inertia)
        object.__setattr__(self, 'torque', torque)
        object.__setattr__(self, 'omega0', omega0)
        object.__setattr__(self, 'attitude0', att)

    def as_dict(self):
        """Plain-dict form (lists of floats), e.g. for YAML or JSON metadata."""
        return {
            'inertia': list(self.inertia), 'torque': list(self.torque),
            'torque_frame': self.torque_frame, 'omega0': list(self.omega0),
            'attitude0': list(self.attitude0),
        }

    @classmethod
    def from_dict(cls, d):
        """Inverse of :meth:`as_dict`; unknown keys raise ValueError."""
        unknown = set(d) - {'inertia', 'torque', 'torque_frame', 'omega0', 'attitude0'}
        if unknown:
            raise ValueError(f'unknown scene field(s): {sorted(unknown)}')
        return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()})
