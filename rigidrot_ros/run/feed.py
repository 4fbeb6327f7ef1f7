"""A run's sensor samples in memory, in the order the node publishes them (no rclpy).

:func:`sensor_feed` takes the arrays of :func:`rigidrot_ros.run.generate.run_arrays` and
says in which order their samples arrive: the order :func:`~rigidrot_ros.run.generate.iter_run`
yields their messages in, by log time (the true sample time plus the sensor's latency, from
the run description's ``sensor_timing``), then true sample time, then the table's rank of
the topic, then sample index. An estimator fed in memory gets the samples of a message
feed without a message being built.
"""

import numpy as np

from rigidrot_ros.run import table

__all__ = ['sensor_feed', 'sensor_types', 'FEED_NAMES']

#: The run's topics an estimator is given, by the last component of their names.
FEED_NAMES = ('imu', 'star_tracker', 'mag')


def _kinds():
    """Return ``{topic name: (rank, sensor kind name)}`` of the table's sensor topics."""
    return {t.name: (t.rank, kind.name) for kind in table.OUTPUTS if kind.grid == 'sensor'
            for t in kind.topics}


def sensor_feed(arrays, names=FEED_NAMES):
    """Return ``(feed, order)``: the sensor topics' arrays and their arrival order.

    Parameters
    ----------
    arrays : dict
        From :func:`rigidrot_ros.run.generate.run_arrays` (its ``'run'``, the run
        description, gives each sensor's latency).
    names : tuple of str
        The topics kept, by the last component of their names.

    Returns
    -------
    feed : dict
        ``{topic: columns}`` of the kept topics (the arrays themselves, not copies).
    order : list of (topic, row)
        Every kept sample in the order the node publishes it.
    """
    timing = (arrays.get('run') or {}).get('sensor_timing') or {}
    kinds = _kinds()
    feed = {t: cols for t, cols in arrays.items()
            if t != 'run' and t.rsplit('/', 1)[-1] in names}
    topics = sorted(feed)
    parts = {'which': [], 'row': [], 'rank': [], 'true': [], 'log': []}
    for i, topic in enumerate(topics):
        true = np.asarray(feed[topic]['true_ns'], dtype=np.int64)
        rank, kind = kinds.get(topic.rsplit('/', 1)[-1], (np.inf, None))
        latency = round(float((timing.get(kind) or {}).get('latency_s', 0.0)) * 1e9)
        n = len(true)
        parts['which'].append(np.full(n, i))
        parts['row'].append(np.arange(n))
        parts['rank'].append(np.full(n, rank, dtype=float))
        parts['true'].append(true)
        parts['log'].append(true + latency)
    if not topics:
        return feed, []
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    idx = np.lexsort((cat['row'], cat['rank'], cat['true'], cat['log']))
    which, rows = cat['which'][idx].tolist(), cat['row'][idx].tolist()
    return feed, [(topics[i], r) for i, r in zip(which, rows)]


def sensor_types(names=FEED_NAMES):
    """Return ``{topic name: pkg/msg/Type}`` of the table's sensor topics kept by ``names``.

    By the relative name a sensor kind gives its topic (``imu``, ``star_tracker``, ...):
    the type every run publishes it with.
    """
    return {t.name: t.type for kind in table.OUTPUTS if kind.grid == 'sensor'
            for t in kind.topics if t.name in names}
