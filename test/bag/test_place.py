"""chunks.place_batch / place_records: MCAP Message records written at their offsets.

The reference is :func:`rigidrot_ros.bag.chunks.fill_records`, the records the bulk
writer builds row by row from a batch's ``(n, size)`` bytes: the compiled loops must
put the same bytes at each offset, from the batch's plan or from its bytes, and touch
nothing else of the buffer.
"""

import numpy as np
import pytest

from rigidrot_ros.bag import chunks
from rigidrot_ros.msgs import cdr

pytestmark = pytest.mark.skipif(not chunks.can_place(), reason='numba is not importable')


def _batches(n, rng):
    """A batch of every planned builder (frames of odd lengths: padding on every side)."""
    stamps = np.sort(rng.integers(-2 ** 60, 2 ** 60, n))    # int32 seconds
    stamps[0] = -1                               # sec = -1, nsec = 999999999
    q, w, f = rng.standard_normal((n, 4)), rng.standard_normal((n, 3)), rng.random((n, 3))
    var, cov = rng.random(n), rng.random((n, 3, 3))
    w[1] = [np.nan, -0.0, np.inf]                # bits, not values: kept as they are
    return [cdr.imu(stamps, w, var, 'body'),
            cdr.imu(stamps, w, var, 'b', linear_acceleration=f, accel_variance=var),
            cdr.vector(stamps, w, 'body_frame'), cdr.attitude(stamps, q, 'n'),
            cdr.star_tracker(stamps, q, cov, 'inertial'),
            cdr.transform(stamps, q, 'inertial', 'body7'),
            cdr.odometry(stamps, q, w, var, var, 'odom', 'base_link'),
            cdr.magnetic_field(stamps, f, cov, 'mag')]


def _reference(batch, cid, seq0, log):
    """The records of fill_records, one (31 + size) row each."""
    rows = np.empty(len(batch), dtype=chunks.record_dtype([batch.size]))
    chunks.fill_records(rows, 0, cid, seq0, log, batch.data)
    return rows.view(np.uint8).reshape(len(batch), -1)


@pytest.mark.parametrize('seed', [0, 1])
def test_placed_records_are_the_filled_records(seed):
    rng = np.random.default_rng(seed)
    n = 37
    for batch in _batches(n, rng):
        assert batch.planned
        cid, seq0 = int(rng.integers(1, 60000)), int(rng.integers(0, 2 ** 31))
        log = np.sort(rng.integers(0, 2 ** 63 - 1, n))
        want = _reference(batch, cid, seq0, log)
        width = want.shape[1]
        gaps = rng.integers(0, 5, n)                    # records apart, in shuffled order
        order = rng.permutation(n)
        dst = np.empty(n, dtype=np.int64)
        dst[order] = np.cumsum(width + gaps) - width    # slot k holds record order[k]
        for place, arg in ((chunks.place_batch, batch), (chunks.place_records, batch.data)):
            buf = np.full(int(dst.max()) + width + 3, 0xA5, dtype=np.uint8)
            place(buf, dst, cid, seq0, log, arg)
            got = np.stack([buf[d:d + width] for d in dst.tolist()])
            assert np.array_equal(got, want)
            mask = np.ones(len(buf), dtype=bool)
            for d in dst.tolist():
                mask[d:d + width] = False
            assert np.all(buf[mask] == 0xA5)            # nothing else written


def test_a_batch_from_its_plan_is_its_bytes():
    """``data`` built from the plan once; ``len``, ``size`` and rows agree with it."""
    rng = np.random.default_rng(3)
    for batch in _batches(5, rng):
        n, size = len(batch), batch.size
        data = batch.data
        assert data.shape == (n, size) and batch.data is data
        assert batch.tolist() == [bytes(r) for r in data] and batch[2] == bytes(data[2])
        plain = cdr.Batch(data.copy())
        assert not plain.planned and len(plain) == n and plain.size == size
