"""Shared helpers for tests of the run model: a run's outputs, one sample at a time."""

from rigidrot_ros.run import table
from rigidrot_ros.run.scheduler import Track


def sensors(setup):
    """Return the sensor outputs of a run set-up, in the table's order (fresh: new noise)."""
    return [o for o in table.make(setup) if o.grid == 'sensor']


def per_sample(output, k, t_start_ns, time_scale, frames):
    """Return ``[(topic, msg), ...]`` of sample k of a sensor output, read alone.

    The sample is read as a block of one (its model's state runs on) on the grid
    ``t_start + k / rate`` without a timing model, and built as ROS messages by the kind
    (:mod:`rigidrot_ros.msgs.messages`): the per-sample path the node's batches (read in
    blocks, encoded as CDR) must equal.
    """
    track = Track(output.name, t_start_ns, output.rate, output.first)
    b = output.sample(track, range(k, k + 1), time_scale)
    assert b.errors == [None], b.errors
    return [(t.name, output.messages(t.name, b.stamps_ns, b.cols, frames)[0])
            for t in output.active]
