"""Campaign specification: read, validate, and draw each run's parameters (no rclpy here).

A spec is a YAML mapping (every key is checked; an unknown one is an error)::

    name: mekf-tuned                 # optional label
    seed: 2024                       # the campaign seed (int >= 0)
    runs: 100                        # M
    duration: 60.0                   # scene seconds per run
    timeout: 600                     # wall seconds per run before it is failed
    base:
      params_file: scene.yaml        # optional, relative to the spec's directory
      overrides: {imu.enable: true, star_tracker.enable: true}
    dispersions:
      attitude0: uniform             # uniform on SO(3)
      omega0: {mean: [0.3, -0.2, 0.5], sigma: 0.05}        # normal, sigma per axis or one
      imu.gyro_bias: {mean: [0, 0, 0], sigma: 2.0e-3}      # the bias prior, rad/s
      inertia: {low: [1.9, 1.9, 0.9], high: [2.1, 2.1, 1.1]}   # uniform per axis
      torque: {low: [0, 0, 0.04], high: [0, 0, 0.06]}          # uniform per axis
    sensor_seeds: per_run            # or fixed (the base's imu.seed, star_tracker.seed)
    estimator:                       # in process ...
      factory: rigidrot_ros.estimators.mekf:make
      params: {sigma_v: 1.7e-4, sigma_u: 2.0e-5, bias_sigma: 2.0e-3}
    # estimator:                     # ... or as a ROS program
    #   command: rigidrot_mekf --sigma-v 1.7e-4 --ros-args -p use_sim_time:=true
    #   topics: [/estimator/odom]    # recorded; the first is scored
    #   inputs: [/imu, /star_tracker]  # replayed once these have subscribers (default:
    #                                # every sensor topic of the run)
    #   settle: 0.2                  # s without an answer before it is stopped
    #   window: 64                   # messages in flight at most (default: from its
    #                                # subscriptions' depth, at most 64)
    #   reset: /estimator/reset      # optional: one process per worker, reset between
    #                                # runs by this std_srvs/srv/Trigger service
    #   clock_step: 0.05             # s of sim time between two /clock (0: every message)
    #   rate: 5.0                    # optional: a replay at this multiple of real time
    #                                # instead (then settle: 1.0 after the replay)
    #   domain_base: 100             # each run claims a free ROS_DOMAIN_ID in
    #   domain_span: 100             # [base, base + span) on this machine

Draws: run ``i`` uses ``numpy.random.SeedSequence(seed, spawn_key=(i,))`` (the i-th child
of ``SeedSequence(seed).spawn(M)``), whose first child drives the dispersions in the fixed
order attitude0, omega0, imu.gyro_bias, inertia, torque, and whose second gives the sensor
seeds: the same run gets the same draws whatever the order, worker or engine.

Inertia draws that break the triangle inequality (``I_a + I_b < I_c``, no rigid body has
them) are drawn again from the same stream (rejection: the accepted draws are the box
conditioned on the inequality), up to :data:`MAX_REDRAWS` times; the count is in the
run's row. A box where no draw can satisfy it is refused when the spec is read.
"""

import importlib
import math
import os
import reprlib
import shlex
import shutil
import sys

import numpy as np
import yaml

__all__ = ['SpecError', 'command_path', 'load_spec', 'check_spec', 'draw_run', 'run_values',
           'MAX_REDRAWS', 'load_factory', 'DISPERSIONS', 'take_prepared',
           'forget_prepared']

MAX_REDRAWS = 1000
#: The last ROS domain ID (ROS 2's "Domain ID" guide: 0-232 on Linux, the highest whose DDS
#: ports fit under 65535).
MAX_DOMAIN_ID = 232
#: Draws checked before anything runs (:func:`check_draws`); a larger campaign's further
#: draws are checked by their own runs (a draw the node refuses is a failed run).
EAGER_DRAWS = 1000
TOP_KEYS = ('name', 'seed', 'runs', 'duration', 'timeout', 'base', 'dispersions',
            'sensor_seeds', 'estimator', 'estimators')
BASE_KEYS = ('params_file', 'overrides')
DISPERSIONS = ('attitude0', 'omega0', 'imu.gyro_bias', 'inertia', 'torque')
INPROC_KEYS = ('factory', 'params', 'topic')
ROS_KEYS = ('command', 'topics', 'inputs', 'rate', 'settle', 'domain_base', 'domain_span',
            'window', 'reset', 'clock_step')


class SpecError(ValueError):
    """A spec that cannot run: the message is one line naming the problem."""


def _num(where, v, lo=-math.inf, hi=math.inf, integer=False, strict_lo=False):
    ok_type = isinstance(v, int) if integer else isinstance(v, (int, float))
    if isinstance(v, bool) or not ok_type:
        raise SpecError(f'{where} must be {"an integer" if integer else "a number"}, '
                        f'got {_short(v)}')
    finite = isinstance(v, int) or math.isfinite(v)       # an int of 400 digits is finite
    if not finite or v < lo or v > hi or (strict_lo and v == lo):
        rng = f'{"(" if strict_lo else "["}{lo:g}, {hi:g}]'
        raise SpecError(f'{where} must lie in {rng}, got {_short(v)}')
    return v


_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxdict, _REPR.maxstring, _REPR.maxother = 3, 6, 4, 60, 60


def _short(v, limit=80):
    """Return ``repr(v)`` within ``limit`` characters, however big or nested ``v`` is.

    A refused value can be a whole file, or YAML aliases nested into a structure whose
    full repr would not fit in memory.
    """
    text = _REPR.repr(v)
    return text if len(text) <= limit else text[:limit - 3] + '...'


def _vec(where, v, size=3):
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        v = [v] * size
    if not isinstance(v, (list, tuple)) or len(v) != size:
        raise SpecError(f'{where} must be {size} numbers (or one), got {_short(v)}')
    return [float(_num(f'{where}[{i}]', x)) for i, x in enumerate(v)]


def _keys(where, d, allowed):
    if not isinstance(d, dict):
        raise SpecError(f'{where} must be a mapping, got {_short(d)}')
    unknown = sorted(str(k) for k in d if k not in allowed)
    if unknown:
        raise SpecError(f'{where}: unknown key(s) {", ".join(unknown)} '
                        f'(known: {", ".join(allowed)})')


def load_factory(text):
    """Import ``module:factory``; SpecError naming it if it does not import."""
    mod, sep, attr = str(text).partition(':')
    if not sep or not mod or not attr:
        raise SpecError(f'estimator.factory must be module:callable, got {_short(text)}')
    try:
        module = importlib.import_module(mod)
    except Exception as exc:  # noqa: B902 - any import failure is the user's to read
        raise SpecError(f'estimator.factory {text}: cannot import {mod} '
                        f'({type(exc).__name__}: {" ".join(str(exc).split())})') from None
    obj = module
    for part in attr.split('.'):
        obj = getattr(obj, part, None)
    if not callable(obj):
        raise SpecError(f'estimator.factory {text}: {mod} has no callable {attr}')
    return obj


def _dispersion(name, d):
    where = f'dispersions.{name}'
    if name == 'attitude0':
        if d != 'uniform':
            raise SpecError(f'{where} must be "uniform" (uniform on SO(3)), got {_short(d)}')
        return 'uniform'
    if name in ('omega0', 'imu.gyro_bias'):
        _keys(where, d, ('mean', 'sigma'))
        if 'sigma' not in d:
            raise SpecError(f'{where} needs sigma (normal about mean)')
        sigma = _vec(f'{where}.sigma', d['sigma'])
        if any(s < 0 for s in sigma):
            raise SpecError(f'{where}.sigma must be >= 0, got {_short(d["sigma"])}')
        return {'mean': _vec(f'{where}.mean', d.get('mean', 0.0)), 'sigma': sigma}
    _keys(where, d, ('low', 'high'))
    if 'low' not in d or 'high' not in d:
        raise SpecError(f'{where} needs low and high (uniform per axis)')
    low, high = _vec(f'{where}.low', d['low']), _vec(f'{where}.high', d['high'])
    bad = [i for i in range(3) if low[i] > high[i]]
    if bad:
        raise SpecError(f'{where}: low > high on axis {bad[0]} ({low[bad[0]]} > '
                        f'{high[bad[0]]})')
    if name == 'inertia':
        if min(low) <= 0:
            raise SpecError(f'{where}: moments of inertia must be > 0, low is {low}')
        for c in range(3):
            a, b = [i for i in range(3) if i != c]
            if high[a] + high[b] < low[c]:
                raise SpecError(f'{where}: impossible: every draw breaks the triangle '
                                f'inequality (I{a + 1} + I{b + 1} <= {high[a] + high[b]:g} < '
                                f'I{c + 1} >= {low[c]:g})')
    return {'low': low, 'high': high}


def check_spec(doc, base_dir='.'):
    """Validate a spec mapping; return it normalised (a plain dict). SpecError otherwise."""
    from rigidrot_ros.run.generate import GenerationError, load_values, prepare_run
    _keys('spec', doc, TOP_KEYS)
    for k in ('seed', 'runs', 'duration'):
        if k not in doc:
            raise SpecError(f'spec: missing key {k}')
    if ('estimator' in doc) == ('estimators' in doc):
        raise SpecError('spec: missing key estimator' if 'estimator' not in doc else
                        'spec: give estimator (one) or estimators (a list), not both')
    spec = {
        'name': str(doc.get('name', '')),
        'seed': _num('seed', doc['seed'], 0, 2 ** 63 - 1, integer=True),
        'runs': _num('runs', doc['runs'], 1, 1_000_000, integer=True),
        'duration': float(_num('duration', doc['duration'], 0, 1e6, strict_lo=True)),
        'timeout': float(_num('timeout', doc.get('timeout', 600), 0, 1e6, strict_lo=True)),
        'sensor_seeds': doc.get('sensor_seeds', 'per_run'),
    }
    if spec['sensor_seeds'] not in ('per_run', 'fixed'):
        raise SpecError(f'sensor_seeds must be per_run or fixed, got '
                        f'{_short(spec["sensor_seeds"])}')
    base = doc.get('base') or {}
    _keys('base', base, BASE_KEYS)
    pf = base.get('params_file')
    if pf is not None:
        if not isinstance(pf, str) or not pf or '\0' in pf:
            raise SpecError(f'base.params_file must be a file name, got {_short(pf)}')
        pf = os.path.normpath(os.path.join(base_dir, pf))
        if not os.path.isfile(pf):
            raise SpecError(f'base.params_file {pf}: no such file')
    overrides = base.get('overrides') or {}
    if not isinstance(overrides, dict):
        raise SpecError(f'base.overrides must be a mapping of parameter: value, got '
                        f'{_short(overrides)}')
    try:
        values = load_values(pf, overrides.items())
        prepare_run(values)
    except GenerationError as exc:
        raise SpecError(f'base: {exc}') from None
    except RecursionError:
        raise SpecError(f'base: {pf or "base.overrides"}: nested too deeply to read') from None
    spec['base'] = {'params_file': pf, 'values': values}
    disp = doc.get('dispersions') or {}
    _keys('dispersions', disp, DISPERSIONS)
    spec['dispersions'] = {k: _dispersion(k, disp[k]) for k in DISPERSIONS if k in disp}
    if 'estimators' in doc:                 # several on the same runs (campaign/multi.py)
        from rigidrot_ros.campaign.listing import check_estimators
        spec['estimators'] = check_estimators(doc['estimators'], _estimator, SpecError)
    else:
        spec['estimator'] = _estimator(doc['estimator'])
    return spec


def _estimator(est):
    _keys('estimator', est, INPROC_KEYS + ROS_KEYS)
    if ('factory' in est) == ('command' in est):
        raise SpecError('estimator needs exactly one of factory (in process) or command '
                        '(a ROS program)')
    if 'factory' in est:
        return _inproc_estimator(est)
    return _ros_estimator(est)


def _inproc_estimator(est):
    """Check an in-process estimator (``factory``): its parameters are tried now."""
    extra = sorted(k for k in est if k not in INPROC_KEYS)
    if extra:
        raise SpecError(f'estimator: {", ".join(extra)} apply to a command, not a factory')
    params = est.get('params') or {}
    if not isinstance(params, dict):
        raise SpecError(f'estimator.params must be a mapping, got {_short(params)}')
    factory = load_factory(est['factory'])
    try:
        factory(dict(params))                      # the parameters are checked now
    except Exception as exc:  # noqa: B902 - the estimator's own complaint
        raise SpecError(f'estimator {est["factory"]} refuses its params: '
                        f'{" ".join(str(exc).split())}') from None
    topic = str(est.get('topic', '/estimator/odom'))
    return {'kind': 'inproc', 'factory': str(est['factory']), 'params': dict(params),
            'topic': topic if topic.startswith('/') else '/' + topic}


def command_path():
    """Return the ``PATH`` an estimator's command is looked up in and started with.

    The environment's ``PATH``, then the directory of this interpreter's console scripts:
    ``rigidrot_mekf`` is found beside ``.venv/bin/rigidrot_campaign`` run without
    activating the environment.
    """
    here = os.path.dirname(sys.executable)
    path = os.environ.get('PATH', os.defpath)
    return path if here in path.split(os.pathsep) else path + os.pathsep + here


def _ros_estimator(est):
    """Check a ROS program's estimator (``command``): its command, topics and feed."""
    extra = sorted(k for k in est if k not in ROS_KEYS)
    if extra:
        raise SpecError(f'estimator: {", ".join(extra)} apply to a factory, not a command')
    cmd = est['command']
    if isinstance(cmd, str):
        try:
            cmd = shlex.split(cmd)
        except ValueError as exc:                    # an unbalanced quote
            raise SpecError(f'estimator.command {_short(cmd)}: cannot split it into words '
                            f'as a shell would ({exc})') from None
    if not isinstance(cmd, list) or not cmd or \
            not all(isinstance(c, str) and c and '\0' not in c for c in cmd):
        raise SpecError(f'estimator.command must be a command line, got '
                        f'{_short(est["command"])}')
    if shutil.which(cmd[0], path=command_path()) is None:
        raise SpecError(f'estimator.command: {cmd[0]}: command not found')
    topics = est.get('topics', ['/estimator/odom'])
    if isinstance(topics, str):
        topics = [topics]
    if not isinstance(topics, list) or not topics or \
            not all(isinstance(t, str) and t for t in topics):
        raise SpecError(f'estimator.topics must be a list of topic names, got '
                        f'{_short(topics)}')
    topics = [t if t.startswith('/') else '/' + t for t in topics]
    inputs = est.get('inputs')
    if inputs is not None:
        inputs = [inputs] if isinstance(inputs, str) else inputs
        if not isinstance(inputs, list) or not all(isinstance(t, str) and t for t in inputs):
            raise SpecError(f'estimator.inputs must be a list of topic names, got '
                            f'{_short(inputs)}')
        inputs = [t if t.startswith('/') else '/' + t for t in inputs]
    keys = ('rate', 'settle', 'window', 'reset', 'clock_step')
    rate, settle, window, reset, step = (est.get(k) for k in keys)
    for name, value in (('window', window), ('clock_step', step)):
        if value is not None and rate is not None:
            raise SpecError(f'estimator.{name} is for the feed paced by the answers: it does '
                            f'not go with rate: (a replay at a fixed speed)')
    if reset is not None:
        if not isinstance(reset, str) or not reset.strip('/') or rate is not None:
            raise SpecError(f'estimator.reset must be the name of a std_srvs/srv/Trigger '
                            f'service, without rate: (a replay), got {_short(reset)}')
        reset = reset if reset.startswith('/') else '/' + reset
    base = _num('estimator.domain_base', est.get('domain_base', 100), 0, MAX_DOMAIN_ID,
                integer=True)
    span = _num('estimator.domain_span', est.get('domain_span', 100), 1, MAX_DOMAIN_ID + 1,
                integer=True)
    if base + span - 1 > MAX_DOMAIN_ID:
        raise SpecError(f'estimator.domain_base + domain_span = {base} + {span}: the domains '
                        f'[{base}, {base + span - 1}] go past the last ROS domain ID, '
                        f'{MAX_DOMAIN_ID}; make domain_span at most {MAX_DOMAIN_ID + 1 - base}')
    return {'kind': 'ros', 'command': cmd, 'topics': topics, 'inputs': inputs,
            'rate': None if rate is None else float(_num('estimator.rate', rate, 0, 1e3,
                                                         strict_lo=True)),
            'settle': None if settle is None else float(_num('estimator.settle', settle, 0,
                                                             600)),
            'window': None if window is None else _num('estimator.window', window, 1,
                                                       1_000_000, integer=True),
            'reset': reset,
            'clock_step': None if step is None else float(_num('estimator.clock_step', step,
                                                               0, 10)),
            'domain_base': base, 'domain_span': span}


def load_spec(path, progress=None, keep=False):
    """Read and validate a spec file; SpecError (one line) if it cannot run.

    The runs' draws are made and validated too (:func:`check_draws`, the first
    :data:`EAGER_DRAWS` of them; ``progress`` is its callback, ``keep`` keeps what the
    check prepared for the runs of in-process estimators, :func:`take_prepared`), so an
    impossible dispersion is found before anything is written.
    """
    from rigidrot_ros.run import rclyaml
    try:
        with open(path, encoding='utf-8') as fh:
            doc = rclyaml.load(fh, spec=True)     # values typed as the node types them
    except OSError as exc:
        raise SpecError(f'{path}: {exc.strerror or exc}') from None
    except UnicodeDecodeError as exc:
        raise SpecError(f'{path}: not a YAML text file (byte {exc.start} is not UTF-8)') \
            from None
    except yaml.YAMLError as exc:
        raise SpecError(f'{path}: not YAML ({" ".join(str(exc).split())})') from None
    except rclyaml.ParameterValueError as exc:
        raise SpecError(f'{path}: {exc}') from None
    except RecursionError:
        raise SpecError(f'{path}: nested too deeply to read') from None
    spec = check_spec(doc, os.path.dirname(os.path.abspath(path)))
    inproc = all(e['kind'] == 'inproc' for e in spec.get('estimators') or [spec['estimator']])
    check_draws(spec, progress=progress, keep=keep and inproc)
    return spec


def _uniform_so3(rng):
    """Uniform random ``q_NB`` (x, y, z, w): a normalised 4-D normal, w >= 0."""
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    return q if q[3] >= 0 else -q


def _triangle_ok(i):
    return i[0] + i[1] >= i[2] and i[1] + i[2] >= i[0] and i[0] + i[2] >= i[1]


def draw_run(spec, index):
    """Draw the dispersed parameters of run ``index``: ``(draws, redraws)``.

    ``draws`` maps parameter names to plain values (lists, ints); ``redraws`` counts the
    inertia draws rejected for the triangle inequality.
    """
    child = np.random.SeedSequence(spec['seed'], spawn_key=(int(index),))
    disp_ss, seed_ss = child.spawn(2)
    rng = np.random.default_rng(disp_ss)
    d = spec['dispersions']
    out, redraws = {}, 0
    if 'attitude0' in d:
        out['attitude0'] = _uniform_so3(rng).tolist()
    for name in ('omega0', 'imu.gyro_bias'):
        if name in d:
            out[name] = (np.array(d[name]['mean'])
                         + np.array(d[name]['sigma']) * rng.standard_normal(3)).tolist()
    if 'inertia' in d:
        lo, hi = np.array(d['inertia']['low']), np.array(d['inertia']['high'])
        while True:
            inertia = rng.uniform(lo, hi)
            if _triangle_ok(inertia):
                break
            redraws += 1
            if redraws > MAX_REDRAWS:
                raise SpecError(f'dispersions.inertia: run {index}: {MAX_REDRAWS} draws in a '
                                f'row broke the triangle inequality; narrow the box')
        out['inertia'] = inertia.tolist()
    if 'torque' in d:
        out['torque'] = rng.uniform(d['torque']['low'], d['torque']['high']).tolist()
    if spec['sensor_seeds'] == 'per_run':
        s = seed_ss.generate_state(2, np.uint64) >> np.uint64(1)     # within [0, 2^63)
        out['imu.seed'], out['star_tracker.seed'] = int(s[0]), int(s[1])
    return out, redraws


def run_values(spec, draws):
    """Return the run's parameter values: the base, then its draws."""
    values = dict(spec['base']['values'])
    values.update(draws)
    return values


#: What :func:`check_draws` prepared for the runs, by their values (``keep=True``).
_PREPARED = {}


def _values_key(values):
    return repr(sorted(values.items()))


def take_prepared(values):
    """Return (and forget) the run set-up :func:`check_draws` kept for ``values``, or None.

    The ``prepare_run(values)`` of the check (:func:`rigidrot_ros.run.generate.run_arrays`
    takes it): a run whose draw was checked in the campaign's client is not prepared again
    by the worker forked from it.
    """
    return _PREPARED.pop(_values_key(values), None) if _PREPARED else None


def forget_prepared():
    """Drop the set-ups :func:`check_draws` kept (the workers forked have their copies)."""
    _PREPARED.clear()


def check_draws(spec, limit=None, progress=None, keep=False):
    """Validate the runs' parameters as the node would; SpecError names the first bad run.

    The node's checks (model constraints such as a torque along the symmetry axis, the
    start-up trial) are those of :func:`rigidrot_ros.run.generate.prepare_run`, about 5 ms
    a draw. The first ``limit`` runs (default :data:`EAGER_DRAWS`) are checked here, so
    an impossible dispersion is found before anything is written; the draws of a larger
    campaign's further runs are checked by the runs themselves (the generator runs the
    same checks), a draw the node refuses making a failed run with the node's reason,
    rather than hours of checking before the first run. ``progress(done, total)``, if
    given, is called after each draw. ``keep`` keeps each run's set-up for the run
    (:func:`take_prepared`; about 60 kB a run). Returns the number of runs checked.
    """
    from rigidrot_ros.run.generate import GenerationError, prepare_run
    if not spec['dispersions'].keys() - {'attitude0'} and spec['sensor_seeds'] == 'fixed':
        return 0
    total = min(spec['runs'], EAGER_DRAWS if limit is None else limit)
    for i in range(total):
        if progress is not None:
            progress(i, total)
        draws, _ = draw_run(spec, i)
        values = run_values(spec, draws)
        try:
            setup = prepare_run(values)
        except GenerationError as exc:
            shown = {k: v for k, v in draws.items() if not k.endswith('seed')}
            raise SpecError(f'impossible dispersion: run {i} draws {shown}, which the node '
                            f'refuses: {exc}') from None
        if keep:
            _PREPARED[_values_key(values)] = setup
    if progress is not None:
        progress(total, total)
    return total
