"""The truth ticks reuse the gyro's attitudes at its interval ends: the bits of solution.at.

A truth tick on a gyro end takes that sample's rows (``Gyro.last_ends``); the others
are evaluated. Whatever the rates (a tick on every 10th end, on every 3rd, on the grids'
common seconds only) and a gyro latency (blocks shifted), each block's columns must be
the bits :func:`read_truth` gives at the same times.
"""

import numpy as np
import pytest

from rigidrot_ros.run import generate as gen
from rigidrot_ros.run.truth_outputs import read_truth


def _bits(cols):
    return {k: np.ascontiguousarray(v, dtype=float).view(np.uint8).tobytes()
            for k, v in cols.items()}


@pytest.mark.parametrize('values, reused', [
    ({'imu.enable': True, 'imu.rate': 1000.0, 'publish_rate': 100.0}, 'all'),
    ({'imu.enable': True, 'imu.rate': 300.0, 'publish_rate': 100.0,
      'imu.latency': 0.0123}, 'some'),
    ({'imu.enable': True, 'imu.rate': 200.0, 'publish_rate': 7.0}, 'some'),
    ({'publish_rate': 50.0}, 'none'),
])
def test_truth_columns_are_read_truth_bits(monkeypatch, values, reused):
    run = gen._Run(values, 5.5, 1_000_000_123)
    own = gen._Run._truth
    counts = {'ticks': 0, 'taken': 0}

    def checked(self, times):
        cols = own(self, times)
        assert _bits(cols) == _bits(read_truth(self.sol, times))
        got = [getattr(o, 'model', None) for o, _, _ in self.sensors]
        ends = got[0].last_ends[0] if got and got[0].last_ends else np.empty(0)
        assert isinstance(self.known, gen._KnownAt) == bool(got)
        counts['ticks'] += len(times)
        counts['taken'] += int(np.isin(times, ends).sum())
        return cols
    monkeypatch.setattr(gen._Run, '_truth', checked)
    for _ in run.blocks(2):
        pass
    assert counts['ticks'] > 0
    if reused == 'all':
        assert counts['taken'] >= counts['ticks'] - 3      # a block's first end is kept
    elif reused == 'some':
        assert 0 < counts['taken'] < counts['ticks']
    else:
        assert counts['taken'] == 0
