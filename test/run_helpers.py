"""Shared helpers for tests of the run model: a run's outputs one sample at a time, bags."""

import json
from pathlib import Path

from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores

from rigidrot_ros.run import table
from rigidrot_ros.run.scheduler import Track

_STORE = get_typestore(Stores.ROS2_JAZZY)


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


def canonical(raw, msgtype):
    """CDR bytes re-serialized by rosbags: the same values, padding bytes zero.

    rclpy's serializer (Fast CDR) leaves the alignment padding after a string
    uninitialized, so two serializations of one message may differ there; every value
    byte is kept.
    """
    return bytes(_STORE.serialize_cdr(_STORE.deserialize_cdr(raw, msgtype), msgtype))


def payloads(bag):
    """``{topic: {stamp_ns: raw CDR bytes}}`` and the ``~/run`` JSON, read by rosbags.

    The topics' types are left in ``payloads.types`` (``{topic: pkg/msg/Type}``).
    """
    out, run = {}, None
    types = payloads.types = {}
    with AnyReader([Path(bag)]) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            types[conn.topic] = conn.msgtype
            if conn.topic.endswith('/run'):
                run = json.loads(msg.data)
                out.setdefault(conn.topic, {})[0] = bytes(raw)
                continue
            ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            assert ns not in out.setdefault(conn.topic, {}), (conn.topic, ns)
            out[conn.topic][ns] = bytes(raw)
    return out, run
