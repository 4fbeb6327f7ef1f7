"""Helpers for the viewer's tests: bags, free ports, pixels, .rrd read-back."""

import socket
import subprocess
import time

import numpy as np

from ros_helpers import script


def free_ports(n):
    """Return ``n`` distinct TCP ports free on this machine now."""
    socks, ports = [], []
    for _ in range(n):
        s = socket.socket()
        s.bind(('', 0))
        socks.append(s)
        ports.append(s.getsockname()[1])
    for s in socks:
        s.close()
    return ports


def generate(out, duration, *overrides):
    """Write a bag with ``rigidrot_generate`` (imu and star tracker on) and return its path."""
    cmd = [script('rigidrot_generate'), '-o', str(out), '--duration', str(duration),
           '--quiet', '-p', 'imu.enable:=true', '-p', 'star_tracker.enable:=true']
    for o in overrides:
        cmd += ['-p', o]
    subprocess.run(cmd, check=True, timeout=120)
    return str(out)


def without_run(src, dst):
    """Copy a bag without its run description (no ``~/run`` topic, no metadata record)."""
    from rigidrot_ros.bag import BagWriter, read_bag
    bag = read_bag(src)
    w = BagWriter(None, 'norun', path=str(dst), split_seconds=0.0)
    for topic, (type_name, qos, schema) in bag.topics.items():
        if not topic.endswith('/run'):
            w.add_topic(topic, type_name, qos=qos, schema=schema)
    for topic, _, log_ns, _, data in bag.messages:
        if not topic.endswith('/run'):
            w.write(topic, data, log_ns)
    w.close()
    return str(dst)


def rrd_columns(path, entity, column):
    """Return ``(time_ns, values)`` of an entity's non-static column in a saved .rrd.

    Read with rerun's own reader (:class:`rerun.chunk.RrdReader`); rows in time order.
    """
    from rerun.chunk import RrdReader
    times, values = [], []
    for chunk in RrdReader(path).stream().to_chunks():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        rb = chunk.to_record_batch()
        if column not in rb.schema.names:
            continue
        times.extend(rb.column('time').cast('int64').to_pylist())
        values.extend(rb.column(column).to_pylist())
    order = np.argsort(times, kind='stable')
    return np.asarray(times, dtype=np.int64)[order], [values[i] for i in order]


def rrd_entities(path):
    """Return ``{entity: rows}`` of the non-static rows of a saved .rrd."""
    from rerun.chunk import RrdReader
    out = {}
    for chunk in RrdReader(path).stream().to_chunks():
        if not chunk.is_static:
            out[chunk.entity_path] = out.get(chunk.entity_path, 0) + chunk.num_rows
    return out


def rrd_static_text(path, entity):
    """Return the text of a static TextDocument in a saved .rrd."""
    from rerun.chunk import RrdReader
    for chunk in RrdReader(path).stream().to_chunks():
        if chunk.entity_path == entity and chunk.is_static:
            rb = chunk.to_record_batch()
            if 'TextDocument:text' in rb.schema.names:
                return rb.column('TextDocument:text').to_pylist()[-1][0]
    return None


def colour_mask(img, rgb, tol):
    """Pixels within ``tol`` (max over channels) of ``rgb``: a boolean (H, W) mask."""
    d = np.abs(img[..., :3].astype(int) - np.asarray(rgb)[None, None, :])
    return d.max(axis=2) <= tol


def columns_with(mask):
    """Return the fraction of a mask's columns that hold at least one pixel."""
    return float(mask.any(axis=0).mean()) if mask.size else 0.0


def region(img, x0, x1, y0, y1):
    """Return the part of ``img`` between the fractions x0..x1 of its width, y0..y1 of height."""
    h, w = img.shape[:2]
    return img[int(y0 * h):int(y1 * h), int(x0 * w):int(x1 * w)]


def wait_line(proc, text, timeout=60.0):
    """Read ``proc``'s stderr lines until one holds ``text``; return the lines read."""
    lines = []
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stderr.readline()
        if not line:
            if proc.poll() is not None:
                break
            continue
        lines.append(line)
        if text in line:
            return lines
    raise AssertionError(f'no {text!r} from the viewer: {"".join(lines)[-2000:]}')
