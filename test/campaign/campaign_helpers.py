"""Estimators for the campaign tests: one that crashes on some runs, one that is silent."""


from rigidrot_ros.estimators.mekf import MEKF


class Flaky(MEKF):
    """The MEKF, except that it raises on a run whose first star tracker w is below 0.5."""

    def receive(self, topic, msg):
        """Raise on the chosen runs, else filter."""
        if topic.endswith('star_tracker') and self.q is None and \
                abs(msg.pose.pose.orientation.w) < 0.5:
            raise RuntimeError('flaky estimator: this run is not for me')
        return super().receive(topic, msg)


class Silent:
    """Receives everything, publishes nothing."""

    def receive(self, topic, msg):
        """Nothing."""
        return []

    def finish(self):
        """Nothing."""
        return []


def flaky(params):
    """Make a :class:`Flaky`."""
    return Flaky(params)


def silent(params):
    """Make a :class:`Silent`."""
    return Silent()


def counted(params):
    """Make the MEKF, each call counted in the file ``params['counter']`` (a line a call).

    Inside a worker (Dask's, or a process pool's), the call numbered ``params['kill_at']``
    (counting only those made in workers) SIGKILLs its own worker process, as an OOM
    killer would, once the
    client has saved all runs but the two under way (``params['out']``: the output
    directory), so that no result is lost but those of the runs under way.
    """
    import fcntl
    import glob
    import os
    import re
    import signal
    import time
    params = dict(params)
    counter, kill_at = params.pop('counter'), params.pop('kill_at', None)
    out = params.pop('out', None)
    import multiprocessing
    try:
        from distributed import get_worker
        get_worker()
        where = 'worker'
    except (ImportError, ValueError):
        where = 'client' if multiprocessing.parent_process() is None else 'worker'
    with open(counter, 'a+') as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        fh.seek(0)
        calls = sum(1 for line in fh if line.startswith('worker')) + (where == 'worker')
        fh.write(f'{where} {os.getpid()}\n')
        fh.flush()
    if where == 'worker' and calls == kill_at:
        end = time.monotonic() + 30
        while time.monotonic() < end and sum(
                1 for p in glob.glob(os.path.join(out, 'runs', '*.json'))
                if re.search(r'/\d{6}\.json$', p)) < kill_at - 2:
            time.sleep(0.05)
        os.kill(os.getpid(), signal.SIGKILL)
    return MEKF(params)


SPEC = {
    'name': 'test', 'seed': 7, 'runs': 3, 'duration': 2.0, 'timeout': 120,
    'base': {'overrides': {'imu.enable': True, 'star_tracker.enable': True}},
    'dispersions': {'attitude0': 'uniform',
                    'omega0': {'mean': [0.3, -0.2, 0.5], 'sigma': 0.05},
                    'imu.gyro_bias': {'mean': [0, 0, 0], 'sigma': 2e-3}},
    'estimator': {'factory': 'rigidrot_ros.estimators.mekf:make',
                  'params': {'sigma_v': 1.7e-4, 'sigma_u': 2e-5, 'bias_sigma': 2e-3}},
}


def _write(tmp_path, doc, name='spec.yaml'):
    import yaml
    p = tmp_path / name
    p.write_text(yaml.safe_dump(doc))
    return str(p)


class _Misbehaving(Silent):
    """Receives everything; on the first gyro sample does what ``how`` says."""

    def __init__(self, how):
        self.how = how

    def receive(self, topic, msg):
        """Misbehave at the first gyro sample."""
        if not topic.endswith('/imu'):
            return []
        if self.how == 'wrong_type':
            from std_msgs.msg import String
            return [String(data='not an estimate')]
        if self.how == 'not_a_list':
            from nav_msgs.msg import Odometry
            return Odometry()
        if self.how == 'sleep':
            import time
            time.sleep(1e6)
        if self.how == 'busy':
            while True:
                pass
        return None


def misbehaving(params):
    """Make a :class:`_Misbehaving` (``params['how']``)."""
    return _Misbehaving(params['how'])


def no_receive(params):
    """Return an object that is not an estimator."""
    return object()


_CALLS = [0]


def fails_after_the_check(params):
    """Pass the spec check (the first call), then raise as a factory that cannot start."""
    _CALLS[0] += 1
    if _CALLS[0] > 1:
        raise OSError('no licence for this filter')
    return Silent()


class _BadArrays(MEKF):
    """The MEKF whose ``receive_arrays`` misbehaves as ``how`` says."""

    def __init__(self, params, how):
        super().__init__(params)
        self.how = how

    def receive_arrays(self, arrays, order):
        """Misbehave."""
        if self.how == 'raises':
            raise ValueError('no arrays today')
        if self.how == 'not_a_dict':
            return [1, 2]
        if self.how == 'wrong_type':
            return {'type': 'std_msgs/msg/String'}
        out = super().receive_arrays(arrays, order)
        if self.how == 'short':
            out['orientation'] = out['orientation'][:-1]
        if self.how == 'empty':
            out = {k: (v[:0] if hasattr(v, 'shape') else v) for k, v in out.items()}
        return out


def bad_arrays(params):
    """Make a :class:`_BadArrays` (``params['how']``; the rest are the MEKF's)."""
    params = dict(params)
    how = params.pop('how')
    return _BadArrays(params, how)
