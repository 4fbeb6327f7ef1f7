"""Run settings without ROS: parameter values -> a validated, tried run (:func:`prepare_run`).

Each parameter's own rule comes from the table :mod:`rigidrot_ros.run.params`; this module adds
the rules across parameters (the scene must be solvable, a sensor rate of 0 means
``publish_rate``, the imu needs ``time_scale > 0``) and the trial of a run's first samples.
The node (at start-up, on a parameter change, on ``~/reset``) and the offline generator
set a run up through :func:`prepare_run`, so a scene is validated by one
piece of code wherever it comes from. :func:`load_defaults` reads a params file.
"""

from dataclasses import dataclass, field
import math
import os
import sys
import time
from typing import Optional, Tuple

import numpy as np

from rigidrot_ros.core import NoExactSolution, PrecisionError, Scene, solve
from rigidrot_ros.run import rclyaml, table
from rigidrot_ros.run.params import BY_NAME, check_values
from rigidrot_ros.sensors import (
    Accelerometer, AttitudeNoise, Gyro, ImuNoise, load_kalibr_imu, Magnetometer, StarTracker,
)
from rigidrot_ros.sensors.accel import check_gravity, check_lever_arm
from rigidrot_ros.sensors.kalibr import KALIBR_SOURCES

__all__ = ['PACKAGE', 'SCENE_KEYS', 'OUTPUT_KEYS', 'find_config', 'load_defaults',
           'scene_from_params', 'solver_options', 'sensor_settings', 'SensorSettings',
           'build_solution', 'trial', 'check_run', 'TrialError', 'RunSetup', 'prepare_run',
           'TRIAL_LIMIT_S', 'SAMPLE_BUDGET_S', 'apply_kalibr', 'IMU_TERMS']

PACKAGE = 'rigidrot_ros'
SCENE_KEYS = ('inertia', 'torque', 'torque_frame', 'omega0', 'attitude0')
#: Output switches (read only).
OUTPUT_KEYS = ('imu.enable', 'star_tracker.enable', 'odom.enable', 'transform.enable',
               'markers.enable', 'accel.enable', 'mag.enable')
#: The error terms of :class:`rigidrot_ros.sensors.ImuNoise`, by their parameter suffix.
IMU_TERMS = ('noise_density', 'random_walk', 'bias', 'bias_stddev', 'bias_instability',
             'bias_correlation_time', 'scale_factor', 'misalignment', 'quantum',
             'increment_quantum')
#: A new scene is refused when one of its trial samples takes longer than this, s.
TRIAL_LIMIT_S = 1.0
#: Work one sensor callback may do before it leaves due samples to the next one, s; also
#: the most one gyro sample's quadrature may take (past it the sample fails, reported).
SAMPLE_BUDGET_S = 0.02


def _share_dirs():
    """Candidate share/<pkg> directories: ament prefixes, this environment, the checkout."""
    dirs = []
    prefixes = os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) + [sys.prefix]
    for prefix in prefixes:
        if prefix:
            dirs.append(os.path.join(prefix, 'share', PACKAGE))
    # an editable (pip -e) install runs from the source checkout
    dirs.append(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    return dirs


def find_config(name='default.yaml'):
    """Return the path of an installed config file (share/rigidrot_ros/config/<name>)."""
    for d in _share_dirs():
        path = os.path.join(d, 'config', name)
        if os.path.isfile(path):
            return path
    raise FileNotFoundError(f'config/{name} of {PACKAGE} not found in {_share_dirs()}')


def load_defaults(path=None):
    """Read the ``ros__parameters`` of a params YAML (first node entry) as a dict.

    Values are typed as rcl types them (:func:`rigidrot_ros.run.rclyaml.load`: ``2e-4`` is
    a double, a list of mixed types is refused), so the file means what it means to the node.
    """
    path = path or find_config()
    with open(path, encoding='utf-8') as fh:
        doc = rclyaml.load(fh)
    if not isinstance(doc, dict) or not doc:
        raise ValueError(f'{path}: not a ROS 2 params file')
    for entry in doc.values():
        if isinstance(entry, dict) and isinstance(entry.get('ros__parameters'), dict):
            return _flatten(entry['ros__parameters'])
    raise ValueError(f'{path}: no ros__parameters section')


def _flatten(tree, prefix=''):
    """Nested YAML mappings -> dotted parameter names, as ROS 2 reads a params file."""
    out = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            out.update(_flatten(value, name + '.'))
        else:
            out[name] = value
    return out


def _check(name, params):
    try:
        return BY_NAME[name].check(params[name])
    except KeyError:
        raise ValueError(f'parameter {name} is missing') from None


def apply_kalibr(params):
    """Merge the Kalibr file named by ``imu.kalibr_yaml`` over checked parameter values.

    Precedence: a parameter at its table default takes the file's value; a parameter set to
    anything else (by ``-p``, a params file or at run time) must equal the file's value, or
    the pair is refused naming both (a value equal to the default cannot be told from an
    unset one: the file wins then). Returns a new dict (``params`` itself when no file).

    Raises
    ------
    ValueError
        Naming ``imu.kalibr_yaml`` (unreadable file, missing or bad key) or the parameter
        and the Kalibr key that disagree.
    """
    path = params.get('imu.kalibr_yaml', '')
    if not path:
        return params
    try:
        found, _topic = load_kalibr_imu(path)
    except ValueError as exc:
        raise ValueError(f'parameter imu.kalibr_yaml: {exc}') from None
    out = dict(params)
    for name, value in found.items():
        value = BY_NAME[name].check(value)
        current, default = params[name], BY_NAME[name].check(BY_NAME[name].default)
        if current == default or current == value:
            out[name] = value
        else:
            raise ValueError(f'parameter {name} = {current!r} contradicts imu.kalibr_yaml '
                             f'({path}: {KALIBR_SOURCES[name]} = {value!r}); set it one '
                             'way only')
    return out


def scene_from_params(params):
    """Build a :class:`Scene` from parameter values; ValueError names the parameter."""
    try:
        return Scene(**{name: _check(name, params) for name in SCENE_KEYS})
    except ValueError as exc:
        msg = str(exc)
        raise ValueError(msg if msg.startswith('parameter') else f'parameter {msg}') from None


def solver_options(params):
    """Return ``(tol, backend)`` for :func:`solve`, validated, backend None for 'auto'."""
    tol = BY_NAME['tol'].check(params.get('tol', BY_NAME['tol'].default))
    backend = BY_NAME['backend'].check(params.get('backend', BY_NAME['backend'].default))
    return tol, (None if backend == 'auto' else backend)


class SensorSettings:
    """Validated sensor and output settings of the node.

    Attributes
    ----------
    imu, star_tracker, odom, transform, markers, accel, mag : bool
        Which outputs are on (``accel``: the accelerometer inside ``imu``).
    imu_rate, star_tracker_rate, mag_rate : float
        Sample rates, Hz of clock time (0 in the parameter means ``publish_rate``).
    gyro : ImuNoise
        The gyro's error model (a new, freshly seeded instance); with every term of issue
        19 zero its stream is the former ``GyroNoise``'s, bit for bit.
    accel_noise : ImuNoise
        The accelerometer's error model, ``kind='accel'`` (fresh).
    lever_arm, gravity : ndarray (3,)
        The IMU's position in B (m) and gravity in N (m/s^2).
    mag_options : dict
        Keyword arguments of :class:`rigidrot_ros.sensors.Magnetometer` (validated).
    attitude_noise : AttitudeNoise
        The star tracker's error model (a new, freshly seeded instance).
    """

    def __init__(self, params):
        p = {name: _check(name, params) for name in OUTPUT_KEYS}
        self.imu, self.star_tracker = p['imu.enable'], p['star_tracker.enable']
        self.odom, self.transform = p['odom.enable'], p['transform.enable']
        self.markers = p['markers.enable']
        self.accel, self.mag = p['accel.enable'], p['mag.enable']
        publish_rate = params.get('publish_rate', BY_NAME['publish_rate'].default)
        self.imu_rate = _check('imu.rate', params) or float(publish_rate)
        self.star_tracker_rate = _check('star_tracker.rate', params) or float(publish_rate)
        self.mag_rate = _check('mag.rate', params) or float(publish_rate)
        self.gyro = _named(lambda: ImuNoise(
            seed=params['imu.seed'], kind='gyro',
            **{t: params['imu.gyro_' + t] for t in IMU_TERMS}))
        self.accel_noise = _named(lambda: ImuNoise(
            seed=params['imu.seed'], kind='accel',
            **{t: params['accel.' + t] for t in IMU_TERMS}))
        self.lever_arm = _named(lambda: check_lever_arm(params['accel.lever_arm']))
        self.gravity = _named(lambda: check_gravity(params['accel.gravity']))
        self.mag_options = dict(field=params['mag.field'], soft_iron=params['mag.soft_iron'],
                                hard_iron=params['mag.hard_iron'],
                                noise_density=params['mag.noise_density'],
                                seed=params['mag.seed'])
        _named(lambda: Magnetometer(None, **self.mag_options))
        try:
            self.attitude_noise = AttitudeNoise(
                params['star_tracker.cross_boresight_arcsec'],
                params['star_tracker.about_boresight_arcsec'], params['star_tracker.boresight'],
                params['star_tracker.seed'])
        except ValueError as exc:
            raise ValueError(f'parameter star_tracker.{exc}') from None
        if self.accel and not self.imu:
            raise ValueError('parameter accel.enable needs imu.enable: the accelerometer '
                             'rides in the imu message (set imu.enable true)')
        if (self.imu or self.mag) and params.get('time_scale', 1.0) == 0.0:
            raise ValueError('parameter time_scale = 0 freezes the scene: the imu and the '
                             'magnetometer need scene time to pass (set time_scale > 0 or '
                             'imu.enable and mag.enable false)')


def _named(make):
    """Run ``make()``; a ValueError from a sensor model gets the word 'parameter' in front."""
    try:
        return make()
    except ValueError as exc:
        msg = str(exc)
        raise ValueError(msg if msg.startswith('parameter') else f'parameter {msg}') from None


def sensor_settings(params):
    """Validate the sensor and output parameters: a :class:`SensorSettings`.

    Raises
    ------
    ValueError
        Naming the parameter and the rule it breaks.
    """
    try:
        return SensorSettings(params)
    except KeyError as exc:
        raise ValueError(f'parameter {exc.args[0]} is missing') from None


def build_solution(values):
    """Return the core solution of checked parameter ``values`` (ValueError if none)."""
    scene = scene_from_params(values)
    tol, backend = solver_options(values)
    try:
        return solve(scene, tol=tol, backend=backend)
    except NoExactSolution as exc:
        raise ValueError(f'no exact solution for this scene: {exc}') from None
    except PrecisionError as exc:
        raise ValueError(f'the scene cannot be evaluated to tol: {exc}') from None
    except Exception as exc:        # whatever else the core raises: refuse the scene
        raise ValueError(f'the scene cannot be solved: {type(exc).__name__}: {exc} (inertia '
                         f'{list(scene.inertia)}, torque {list(scene.torque)}, omega0 '
                         f'{list(scene.omega0)})') from None


def _trial_sample(fn, fails, slow, hint, limit=True):
    """Run one trial sample ``fn()``: ``(result, None)``, or ``(None, why it is refused)``.

    ``fails`` says what could not be evaluated, ``slow`` what took too long (formatted
    with ``cost``, s), ``hint`` what to try (appended to both); ``limit`` False: no bound
    on the time it takes.
    """
    c0 = time.perf_counter()
    try:
        result = fn()
    except Exception as exc:        # PrecisionError, ValueError, or anything else
        return None, f'{fails}: {type(exc).__name__}: {exc}{hint}'
    cost = time.perf_counter() - c0
    if limit and cost > TRIAL_LIMIT_S:
        return None, (slow.format(cost=cost) +
                      f", beyond the node's limit of {TRIAL_LIMIT_S:g} s{hint}")
    return result, None


class TrialError(ValueError):
    """A run's first samples cannot be evaluated in time (:func:`trial`'s reason)."""


def trial(sol, values, cfg=None, timed=True):
    """Evaluate the first samples of a candidate run; return None or why it fails (str).

    A scene whose first tick (t = 0) or second (one period in, scaled by ``time_scale``)
    cannot be evaluated, or costs more than :data:`TRIAL_LIMIT_S`, would leave the node
    publishing nothing, or blocking its services; it is refused instead. With the sensor
    settings ``cfg`` (:func:`sensor_settings`), the first gyro sample (one interval,
    ``time_scale / imu_rate`` s of scene time, its quadrature within :data:`SAMPLE_BUDGET_S`
    as in the node) and the first star tracker sample are tried the same way, and a gyro
    sample whose increment bound is not finite refuses the scene too.

    ``timed`` False (offline generation, which has no deadline): the same samples are
    evaluated and judged, but neither :data:`TRIAL_LIMIT_S` nor :data:`SAMPLE_BUDGET_S`
    applies, so the answer does not depend on how fast or loaded the machine is.
    """
    time_scale = float(values['time_scale'])
    t1 = time_scale / float(values['publish_rate'])
    for t in (0.0, t1):
        _, reason = _trial_sample(
            lambda: sol.at(t), f'the scene cannot be evaluated at t = {t:g} s (the first '
            'ticks)', f'one sample of this scene takes {{cost:.3g}} s to evaluate ({sol.model}, '
            f'{sol.method})', "; try backend 'auto' or a larger tol", limit=timed)
        if reason:
            return reason
    if cfg is None:
        return None
    checks = [(cfg.imu, _trial_gyro), (cfg.imu and cfg.accel, _trial_accel),
              (cfg.mag, _trial_mag), (cfg.star_tracker, _trial_star)]
    for wanted, check in checks:
        reason = check(sol, cfg, time_scale, timed) if wanted else None
        if reason:
            return reason
    return None


def _trial_gyro(sol, cfg, time_scale, timed):
    dt = time_scale / cfg.imu_rate

    def gyro():                 # an ideal gyro: the run's own noise stream stays fresh
        with np.errstate(over='ignore', invalid='ignore'):  # judged below, not warned
            return Gyro(sol).read(0.0, dt, budget=SAMPLE_BUDGET_S if timed else None)
    r, reason = _trial_sample(
        gyro, f'the first gyro sample (imu.rate {cfg.imu_rate:g} Hz, time_scale '
        f'{time_scale:g}: {dt:g} s of scene time) cannot be evaluated',
        f'the first gyro sample ({dt:g} s of scene time) takes {{cost:.3g}} s',
        '; lower time_scale or raise imu.rate', limit=timed)
    if reason:
        return reason
    bound = float(max(r.delta_angle_bound, r.delta_rotation_bound))
    if not math.isfinite(bound):
        return (f'the gyro increments of this scene have no finite error bound '
                f'({bound!r} rad over the first {dt:g} s; omega0 or torque too large '
                'for float64); turn imu.enable off or choose a smaller scene')
    return None


def _trial_accel(sol, cfg, time_scale, timed):
    dt = time_scale / cfg.imu_rate

    def accel():
        with np.errstate(over='ignore', invalid='ignore'):
            return Accelerometer(sol, lever_arm=cfg.lever_arm, gravity=cfg.gravity) \
                .read(0.0, dt, budget=SAMPLE_BUDGET_S if timed else None)
    r, reason = _trial_sample(
        accel, f'the first accelerometer sample (imu.rate {cfg.imu_rate:g} Hz: {dt:g} s '
        'of scene time) cannot be evaluated',
        f'the first accelerometer sample ({dt:g} s of scene time) takes {{cost:.3g}} s',
        '; check accel.lever_arm and accel.gravity, lower time_scale or raise imu.rate',
        limit=timed)
    if reason:
        return reason
    if not (math.isfinite(r.delta_velocity_bound) and np.all(np.isfinite(r.specific_force))):
        return (f'the accelerometer of this scene has no finite value or error bound '
                f'({r.delta_velocity_bound!r} m/s over the first {dt:g} s); check '
                'accel.lever_arm and accel.gravity, or choose a smaller scene')
    return None


def _trial_mag(sol, cfg, time_scale, timed):
    dt = time_scale / cfg.mag_rate
    r, reason = _trial_sample(
        lambda: Magnetometer(sol, **cfg.mag_options).read(0.0, dt),
        'the first magnetometer sample (t = 0) cannot be evaluated',
        'the first magnetometer sample takes {cost:.3g} s', '', limit=timed)
    if reason:
        return reason
    if not np.all(np.isfinite(r.field)):
        return 'the first magnetometer sample is not finite; check mag.field and mag.soft_iron'
    return None


def _trial_star(sol, cfg, time_scale, timed):
    t = time_scale / cfg.star_tracker_rate
    _, reason = _trial_sample(
        lambda: StarTracker(sol).read(t),
        f'the first star tracker sample (t = {t:g} s) cannot be evaluated',
        'the first star tracker sample takes {cost:.3g} s', '', limit=timed)
    return reason


@dataclass(frozen=True)
class RunSetup:
    """Everything a run needs, validated and tried (see :func:`prepare_run`).

    Attributes
    ----------
    values : dict
        The checked parameter values by name (every parameter of the table).
    solution : Solution or TriaxialSolution
        The core's exact solution of the scene.
    sensors : SensorSettings
        Which outputs are on, the sensor rates (Hz, 0 resolved) and error models.
    gyro, star_tracker : Gyro or None, StarTracker or None
        The run's sensor models with fresh noise streams (None where off).
    accel, mag : Accelerometer or None, Magnetometer or None
        The accelerometer (read with the gyro, into the same ``imu`` message) and the
        magnetometer of the run, fresh (None where off).
    time_scale : float
        Scene seconds per clock second.
    publish_rate : float
        Truth rate, Hz.
    frames : tuple of str
        ``(frame_id, body_frame_id)``: the frames N and B of the messages.
    kalibr : dict
        The values the Kalibr file of ``imu.kalibr_yaml`` supplied, by parameter name
        (empty without one); ``values`` holds them too.
    outputs : tuple
        The kinds of output of :data:`rigidrot_ros.run.table.OUTPUTS` that the values
        switch on, in rank order.
    """

    values: dict
    solution: object
    sensors: SensorSettings
    gyro: Optional[Gyro]
    star_tracker: Optional[StarTracker]
    time_scale: float
    publish_rate: float
    frames: Tuple[str, str]
    accel: Optional[Accelerometer] = None
    mag: Optional[Magnetometer] = None
    kalibr: dict = field(default_factory=dict)
    outputs: tuple = ()


def _kalibr_supplied(values):
    """Return ``{name: value}`` that the Kalibr file of checked ``values`` supplies (or {})."""
    path = values.get('imu.kalibr_yaml', '')
    if not path:
        return {}
    try:
        found, _topic = load_kalibr_imu(path)
    except ValueError:              # read by apply_kalibr a moment ago: changed since
        return {}
    return {name: values[name] for name in found if name in values}


def check_run(values):
    """Validate parameter ``values`` without solving: the checked values (ValueError else).

    Each value by its table entry, then the scene, the solver options and the sensor
    settings; what :func:`prepare_run` checks before it solves. For a change that the
    running scene does not depend on (frames, rates of what is running).
    """
    p = apply_kalibr(check_values(values))
    scene_from_params(p)
    solver_options(p)
    sensor_settings(p)
    return p


def prepare_run(values, try_samples=True, timed=True):
    """Validate parameter ``values`` and set a run up: a :class:`RunSetup`.

    Each value is checked by its entry of :data:`rigidrot_ros.run.params.PARAMS`, the scene is
    solved, the sensor settings validated, and (``try_samples``) the first samples tried
    (:func:`trial`). The node calls this at start-up, for a parameter change and on
    ``~/reset``; the offline generator calls it for its run, with ``timed`` False.

    Parameters
    ----------
    values : dict
        Every parameter of the table by its dotted name (e.g. ``params.defaults()`` updated
        with overrides).
    try_samples : bool
        Try the first samples (:func:`trial`).
    timed : bool
        Bound the trial's wall time, as the node must (:data:`TRIAL_LIMIT_S`); False for
        offline generation, whose answer must not depend on the machine's speed.

    Raises
    ------
    TrialError
        The first samples cannot be evaluated in time (the reason, without the scene).
    ValueError
        Naming the parameter and the rule it breaks.
    """
    p = apply_kalibr(check_values(values))
    solution = build_solution(p)
    sensors = sensor_settings(p)
    if try_samples:
        reason = trial(solution, p, sensors, timed=timed)
        if reason is not None:
            raise TrialError(reason)
    return RunSetup(
        values=p, solution=solution, sensors=sensors, kalibr=_kalibr_supplied(p),
        gyro=Gyro(solution, sensors.gyro) if sensors.imu else None,
        star_tracker=(StarTracker(solution, sensors.attitude_noise) if sensors.star_tracker
                      else None),
        time_scale=p['time_scale'], publish_rate=p['publish_rate'],
        frames=(p['frame_id'], p['body_frame_id']),
        accel=(Accelerometer(solution, sensors.accel_noise, sensors.lever_arm, sensors.gravity)
               if sensors.imu and sensors.accel else None),
        mag=Magnetometer(solution, **sensors.mag_options) if sensors.mag else None,
        outputs=table.kinds_on(p))
