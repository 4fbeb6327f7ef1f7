"""One kind of output of a run, defined once: the base classes of the rows of the table.

Everything the node and the offline generator need of one thing a run publishes is said
by its kind (a row of :data:`rigidrot_ros.run.table.OUTPUTS`), as scipy's
``integrate/_ivp`` says a solver by a subclass of one base class:

- its topics (:class:`Topic`: relative name, ``pkg/msg/Type``, rank among the messages of
  one instant, and any further parameter a topic needs on: ``delta_velocity`` needs
  ``accel.enable``);
- the parameter that enables it (:attr:`Output.enable`, None: always on);
- the grid it samples on (:attr:`Output.grid`): the truth's ticks (``'truth'``: the
  attitude, its rate, odometry, transform, markers; all read by one ``solution.at`` a
  block), its own rate (``'sensor'``, a :class:`SensorOutput`, whose :meth:`read` reads a
  block of samples), or once at a run's start (``'start'``: the run description);
- how a block of samples is encoded to CDR (:meth:`Output.encode`, one call per topic) and
  to ROS messages (:meth:`Output.messages`).

A block's values are columns: ``cols`` maps a name to an array with one row per sample
(the truth's ``q`` (n, 4) q_NB (x, y, z, w), ``w`` (n, 3) omega_BN_B rad/s, ``e`` (n,)
its error bound, rad; each sensor its own). Sample k of a grid is stamped ``origin + k /
rate`` (:func:`rigidrot_ros.run.grid.stamps_ns`) and taken at scene time ``(stamp -
t_start) * time_scale`` (:func:`scene_time`); ``frames`` is ``(frame_id,
body_frame_id)``: the frames N and B.
"""

import abc
import importlib
from typing import NamedTuple

import numpy as np

from rigidrot_ros.run import grid

__all__ = ['Topic', 'Output', 'SensorOutput', 'Block', 'scene_time', 'is_on', 'columns',
           'header_stamps']


def scene_time(stamp_ns, t_start_ns, time_scale):
    """Return the scene time (s) of a stamp: ``(stamp - t_start) * time_scale``.

    An int64 array of stamps gives each element the bits of the scalar call (the same
    integer difference, converted to float64 once, and the same two products).
    """
    return (stamp_ns - t_start_ns) * 1e-9 * time_scale


class LazyModule:
    """A module imported when one of its attributes is first read.

    ROS's message classes (:mod:`rigidrot_ros.msgs.messages`) take a tenth of a second
    and about 13 MB to load; offline generation writes CDR and never builds one, so the
    kinds reach them through this (``msgs = LazyModule('rigidrot_ros.msgs.messages')``).
    """

    __slots__ = ('_name',)

    def __init__(self, name):
        self._name = name

    def __getattr__(self, attr):
        return getattr(importlib.import_module(self._name), attr)


#: :mod:`rigidrot_ros.msgs.messages`, loaded on first use.
msgs = LazyModule('rigidrot_ros.msgs.messages')


def header_stamps(stamps):
    """Return the ``builtin_interfaces/Time`` of each stamp (integer ns)."""
    return [msgs.stamp(ns) for ns in np.asarray(stamps).tolist()]


def is_on(value):
    """Whether a parameter value switches something on: true, or a number above 0."""
    return bool(value) and not (isinstance(value, (int, float)) and value <= 0)


class Topic(NamedTuple):
    """One topic of an output kind.

    Attributes
    ----------
    name : str
        Relative to the node (``'imu'``), or private (``'~/run'``).
    type : str
        ``pkg/msg/Type``.
    rank : float
        Order among the messages of one instant (the truth first): the node publishes and
        the generator writes a sample time's messages in increasing rank.
    needs : tuple of str
        Further parameters that must be on (:func:`is_on`) for this topic, beyond the
        kind's own switch.
    """

    name: str
    type: str
    rank: float
    needs: tuple = ()


class Output(abc.ABC):
    """One kind of output: a row of the table (subclass it, then add one row).

    An instance is that output in one run (:class:`rigidrot_ros.run.settings.RunSetup`):
    a sensor's holds the run's model, whose noise stream runs on as it is read.

    Attributes
    ----------
    name : str
        The kind's name (a sensor's: its parameters' prefix and its diagnostics key).
    topics : tuple of Topic
        Every topic it may publish, in rank order.
    enable : str or None
        The parameter that switches it on (None: always on).
    grid : str
        ``'truth'``, ``'sensor'`` or ``'start'`` (see the module text).
    latched : bool
        Published transient-local with depth 1 (a late subscriber still gets the last).
    """

    name = ''
    topics = ()
    enable = None
    grid = 'truth'
    latched = False

    def __init__(self, setup):
        self.setup = setup
        self.active = self.topics_on(setup.values)

    @classmethod
    def on(cls, values):
        """Whether parameter ``values`` switch this kind on."""
        return cls.enable is None or is_on(values[cls.enable])

    @classmethod
    def topics_on(cls, values):
        """Return the topics this kind publishes under parameter ``values`` (rank order)."""
        return tuple(t for t in cls.topics if all(is_on(values[p]) for p in t.needs))

    @property
    def rank(self):
        """The rank of its first topic: its place among the outputs of one instant."""
        return self.active[0].rank

    @abc.abstractmethod
    def encode(self, topic, stamps, cols, frames):
        """Return the CDR bytes of ``topic`` for each row of ``cols`` (a list)."""

    def encode_batch(self, topic, stamps, cols, frames):
        """Return the CDR of ``topic`` for each row: a :class:`rigidrot_ros.msgs.cdr.Batch`.

        One ``(n, size)`` byte array where the kind's messages have one size (the bulk
        writer takes it as is), else the list of :meth:`encode`.
        """
        return self.encode(topic, stamps, cols, frames)

    @abc.abstractmethod
    def messages(self, topic, stamps, cols, frames):
        """Return the ROS messages of ``topic`` for each row of ``cols`` (a list)."""

    def build(self, stamps, cols, frames):
        """Return each sample's ``[(topic, bytes), ...]`` over its topics (the node's batches)."""
        names = [t.name for t in self.active]
        raws = [self.encode(n, stamps, cols, frames) for n in names]
        return [list(zip(names, row)) for row in zip(*raws)]


class SensorOutput(Output):
    """A sensor: samples k = :attr:`first`, ... on its own grid ``t_start + k / rate``.

    Subclasses define :meth:`read`. With :attr:`interval` sample k covers the interval
    from sample k - 1 to k (an integrating sensor: the imu, k from 1).

    Attributes
    ----------
    rate : float
        Samples per second of clock time, Hz (:meth:`rate_of`).
    bound : float
        The largest error bound of this run's samples read so far (0.0 where none is
        stated).
    """

    grid = 'sensor'
    first = 0
    interval = False
    #: The parameter of its rate, Hz (0: ``publish_rate``).
    rate_param = ''

    def __init__(self, setup):
        super().__init__(setup)
        self.rate = self.rate_of(setup)
        self.bound = 0.0

    @classmethod
    def rate_of(cls, setup):
        """Return the sample rate (Hz) of this kind in ``setup`` (0 means ``publish_rate``)."""
        return float(setup.values[cls.rate_param]) or float(setup.publish_rate)

    @abc.abstractmethod
    def read(self, times, budget=None):
        """Read the samples at scene ``times`` (s, in order): ``(cols, errors)``.

        With :attr:`interval`, ``times`` are the m + 1 ends of m intervals. ``errors``
        lists per sample the exception that kept it from being read, else None (its row
        of ``cols`` is then meaningless). ``budget`` (s) bounds a read where the model
        takes one. The model's state (noise) runs on in sample order.
        """

    @staticmethod
    def read_each(times, one, width):
        """Read sample by sample: ``(cols, errors)`` as :meth:`read` returns them.

        ``one(t)`` returns one sample's values at scene time t (a float), in the order of
        ``width``, which maps each column's name to its row shape; a sample whose read
        raises keeps NaN and its exception.
        """
        n = len(times)
        cols = {k: np.full((n,) + tuple(shape), np.nan) for k, shape in width.items()}
        targets = list(cols.values())
        errors = []
        for i, t in enumerate(np.asarray(times, dtype=float).tolist()):
            try:
                row = one(t)
            except Exception as exc:    # noqa: B902 - reported when the sample is due
                errors.append(exc)
                continue
            for target, v in zip(targets, row):
                target[i] = v
            errors.append(None)
        return cols, errors

    def sample(self, track, ks, time_scale, budget=None):
        """Read the samples ``ks`` (a range) on ``track``'s grid, with its timing: a Block.

        ``track`` is the sensor's :class:`rigidrot_ros.run.scheduler.Track` (origin
        ``t_start``); its stamps and drops are drawn once per sample, in order, read or not.
        """
        true = grid.stamps_ns(track.origin_ns, track.rate, ks)
        if self.interval:
            ends = grid.stamps_ns(track.origin_ns, track.rate, range(ks.start - 1, ks.stop))
            times = scene_time(ends, track.origin_ns, time_scale)
        else:
            times = scene_time(true, track.origin_ns, time_scale)
        cols, errors = self.read(times, budget)
        stamps, keep = track.marks(ks)
        return Block(ks, true, stamps, keep, errors, cols)


class Block:
    """Samples ``ks`` of one sensor: their grid times, stamps, drops, errors and values.

    Attributes
    ----------
    ks : range
        The sample indices.
    true_ns, stamps_ns : ndarray of int64
        Grid (true sample) times, and the stamps their messages carry.
    keep : ndarray of bool
        False where the timing model drops the sample.
    errors : list
        Per sample the exception that kept it from being read, else None.
    cols : dict
        The values, one row per sample.
    """

    __slots__ = ('ks', 'true_ns', 'stamps_ns', 'keep', 'errors', 'cols')

    def __init__(self, ks, true_ns, stamps_ns, keep, errors, cols):
        self.ks, self.true_ns, self.stamps_ns = ks, true_ns, stamps_ns
        self.keep, self.errors, self.cols = keep, errors, cols

    def __len__(self):
        return len(self.true_ns)

    def published(self):
        """Return the indices (rows) of the samples that are read and not dropped."""
        return np.flatnonzero(self.keep & np.array([e is None for e in self.errors],
                                                   dtype=bool))

    def rows(self, idx):
        """Return ``(stamps_ns, cols)`` of the rows ``idx`` (an index array)."""
        return self.stamps_ns[idx], {k: v[idx] for k, v in self.cols.items()}


def columns(rows, errors, width):
    """Scatter the read rows into full columns: ``{name: array}``, NaN where not read.

    ``rows`` maps a name to the array of the rows read (in order); ``errors`` has one
    entry per sample (None where read); ``width`` maps a name to its row shape.
    """
    if errors.count(None) == len(errors):       # every row read (no per-row Python)
        return rows
    ok = np.array([e is None for e in errors], dtype=bool)
    out = {}
    for name, shape in width.items():
        full = np.full((len(errors),) + tuple(shape), np.nan)
        if ok.any():
            full[ok] = rows[name]
        out[name] = full
    return out
