"""Shared test helpers: seeded scenes per model, an independent DOP853 reference, a ROS domain."""

import contextlib
import faulthandler
import math
import os
import signal
import sys
import tempfile

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import Scene
from ros_helpers import next_domain_id, ros_env

# A hung test must not hold the run. pytest-timeout (setup.cfg: 600 s) fails it by name,
# but its timer is Python code (a thread stuck in C holding the interpreter lock stops it
# too) and, in a test process of ``-n``, what it prints is captured and lost with the
# process. faulthandler's timer is neither: in a test process of ``-n`` it fires 30 s
# before pytest-timeout's, alone, 60 s after it; it writes every thread's stack and ends
# the process (xdist reports the test as crashed). A test given more time
# (``@pytest.mark.timeout(s)``) gets it here too. A test process sent SIGTERM writes its
# stacks first. Both go to a file of the worker's, which the controlling process prints
# when the worker goes down.
TIMEOUT_S = 600.0


def _last_words_path(uid, worker):
    return os.path.join(tempfile.gettempdir(), f'rigidrot-tests-{uid}-{worker}.txt')


if os.environ.get('PYTEST_XDIST_WORKER'):
    _LAST_WORDS = open(_last_words_path(os.environ.get('PYTEST_XDIST_TESTRUNUID', 'run'),
                                        os.environ['PYTEST_XDIST_WORKER']), 'w')
else:
    _LAST_WORDS = sys.__stderr__
faulthandler.register(signal.SIGTERM, file=_LAST_WORDS, all_threads=True, chain=True)

# A suite started in the background by a shell without job control inherits SIGINT
# ignored, and so would every program a test starts: Python then installs no
# KeyboardInterrupt, and a test's Ctrl-C would find a program that cannot hear it. A
# handler here (reset to the default action at exec) gives the programs what a terminal
# gives them.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


# The process controlling ``-n`` adopts what a test process leaves running when it dies
# (a node, a probe): the kernel reparents such orphans to it rather than to init, and it
# ends them when the run ends, so that none holds the run's output open after it.
_PR_SET_CHILD_SUBREAPER = 36                    # <linux/prctl.h>


def _controls_workers(config):
    return (not os.environ.get('PYTEST_XDIST_WORKER')
            and bool(getattr(config.option, 'numprocesses', None)))


def _compile_once():
    """Byte-compile the package and the tests once, where Python writes no bytecode itself.

    With ``PYTHONDONTWRITEBYTECODE`` set, every program a test starts (some 450 in a run)
    would compile the package's modules from source at each start, about 0.1 s of CPU
    each; ``compileall`` writes their ``__pycache__`` once, which Python still reads. A
    tree that cannot be written is left as it is.
    """
    if not sys.dont_write_bytecode:
        return
    import compileall
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for name in ('rigidrot_ros', 'test'):
        with contextlib.suppress(OSError):
            compileall.compile_dir(os.path.join(root, name), quiet=2, workers=1)


def pytest_configure(config):
    """Make the controlling process of ``-n`` the reaper of its test processes' orphans.

    The controlling process (or a run without ``-n``) also byte-compiles the package once
    (:func:`_compile_once`).
    """
    if not os.environ.get('PYTEST_XDIST_WORKER'):
        _compile_once()
    if _controls_workers(config) and sys.platform.startswith('linux'):
        import ctypes
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)


def _children(pid):
    """List the children of ``pid`` from /proc: (name, pid, state) triples (Z: a zombie)."""
    out = []
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        try:
            with open(f'/proc/{entry}/stat', encoding='utf-8', errors='replace') as fh:
                stat = fh.read()
        except OSError:
            continue
        name, rest = stat[stat.index('(') + 1:stat.rindex(')')], stat[stat.rindex(')') + 2:]
        if int(rest.split()[1]) == pid:
            out.append((name, int(entry), rest.split()[0]))
    return out


def _cmdline(pid):
    """Return process ``pid``'s command line (its first 200 characters), or ''."""
    try:
        with open(f'/proc/{pid}/cmdline', 'rb') as fh:
            return fh.read().replace(b'\0', b' ').decode('utf-8', 'replace').strip()[:200]
    except OSError:
        return ''


def pytest_unconfigure(config):
    """End the orphans adopted (controller); remove this worker's file of last words."""
    if _controls_workers(config) and os.path.isdir('/proc'):
        adopted = _children(os.getpid())
        left = [(pid, _cmdline(pid) or name) for name, pid, state in adopted if state != 'Z']
        for _, pid, _ in adopted:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
            with contextlib.suppress(OSError):
                os.waitpid(pid, 0)          # the ended ones too: no zombie outlives the run
        if left:
            sys.__stderr__.write(f'ended {len(left)} processes left running by test processes: '
                                 f'{"; ".join(sorted(cmd for _, cmd in left))}\n')
    if _LAST_WORDS is not sys.__stderr__:
        faulthandler.unregister(signal.SIGTERM)
        _LAST_WORDS.close()
        with contextlib.suppress(OSError):
            os.unlink(_LAST_WORDS.name)


#: The modules holding the longest tests (10 to 40 s each: browsers, campaigns, several
#: processes, linters), longest first. They run first: under ``-n`` each test process is
#: sent a first batch of consecutive tests, then more as it runs low, so when the long ones
#: come early the run ends on short tests and the processes finish together, instead of
#: one waiting out another's last long test (the collection's own order puts view/, with
#: the browser test, last). The order of the tests within a module, and of the rest, is
#: kept. A scheduling hint only: a module missing here or renamed is run in its place.
LONG_MODULES = (
    'view/test_view.py', 'campaign/test_campaign_ros.py', 'bench/test_bench.py',
    'tools/test_node_accel_ahrs.py', 'core/test_core_fuzz.py', 'project/test_flake8.py',
    'campaign/test_campaign.py', 'project/test_docs.py', 'tools/test_estimator_loop.py',
    'tools/test_cli.py', 'campaign/test_campaign_multi.py', 'bench/test_bench_figures.py',
    'tools/test_record.py', 'core/test_core_triaxial.py', 'project/test_colcon.py',
)


def pytest_collection_modifyitems(config, items):
    """Run the modules of :data:`LONG_MODULES` first, in that order (a stable sort)."""
    here = os.path.dirname(os.path.abspath(__file__))
    rank = {os.path.join(here, *m.split('/')): k for k, m in enumerate(LONG_MODULES)}
    items.sort(key=lambda item: rank.get(str(item.path), len(rank)))


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    """Say how a crashed xdist worker ended: its exit status and its last words."""
    if not error:
        return
    popen = getattr(getattr(getattr(node, 'gateway', None), '_io', None), 'popen', None)
    status = None
    if popen is not None:
        try:
            status = popen.wait(timeout=5)
        except Exception:   # noqa: B902 - a report only
            status = popen.poll()
    info = getattr(node, 'workerinput', {})
    path = _last_words_path(info.get('testrunuid', 'run'), info.get('workerid', '?'))
    try:
        with open(path, encoding='utf-8', errors='replace') as fh:
            words = fh.read()
        os.unlink(path)
    except OSError:
        words = ''
    sys.__stderr__.write(f'\n[{info.get("workerid", "?")}] worker process ended with status '
                         f'{status} (negative: the signal)\n{words}')


@pytest.fixture(autouse=True)
def _hard_timeout(request):
    mark = request.node.get_closest_marker('timeout')
    limit = float(mark.args[0]) if mark is not None and mark.args else TIMEOUT_S
    hard = limit - 30 if _LAST_WORDS is not sys.__stderr__ else limit + 60
    faulthandler.dump_traceback_later(hard, exit=True, file=_LAST_WORDS)
    yield
    faulthandler.cancel_dump_traceback_later()


def _sym_axis(inertia):
    for k in range(3):
        if inertia[(k + 1) % 3] == inertia[(k + 2) % 3]:
            return k
    return None


def read_in_blocks(sensor, times, sizes, fields, cell=lambda v: v):
    """Read the intervals of ``times`` in blocks of the given sizes (0: one ``read``).

    Returns one row a interval, ``{field: cell(value)}`` (a block's ``None`` field stays
    None), from ``sensor.read`` or row k of ``sensor.read_many``; the sizes repeat.
    """
    rows, i, j = [], 0, 0
    while i < len(times) - 1:
        size = sizes[j % len(sizes)]
        j += 1
        if size == 0:
            r = sensor.read(times[i], times[i + 1])
            rows.append({f: cell(getattr(r, f)) for f in fields})
            i += 1
            continue
        b = sensor.read_many(times[i:i + size + 1])
        for k in range(len(b)):
            rows.append({f: None if getattr(b, f) is None else cell(getattr(b, f)[k])
                         for f in fields})
        i += len(b)
    return rows


def integrate(scene, t_eval, rtol=1e-13, atol=1e-13):
    """Euler's equations (Eq. 3) + quaternion kinematics, DOP853; returns (omega, q).

    Shares no formula with the core: it integrates I dw/dt = m_B - w x I w and
    dq/dt = q ⊗ (w, 0) / 2 directly. For torque_frame='virtual' the torque in B turns
    about the symmetry axis k by -f, with df/dt = ((I - I3) / I) r (the scene's definition).
    """
    inertia = np.array(scene.inertia)
    m = np.array(scene.torque)
    k = _sym_axis(scene.inertia) if scene.torque_frame == 'virtual' else None

    def rhs(t, y):
        w, q = y[:3], y[3:7]
        m_b = m
        if k is not None:
            f = y[7]
            c, s = np.cos(f), np.sin(f)
            i1, i2 = (k + 1) % 3, (k + 2) % 3
            m_b = m.copy()
            m_b[i1] = c * m[i1] + s * m[i2]
            m_b[i2] = -s * m[i1] + c * m[i2]
        dw = (m_b - np.cross(w, inertia * w)) / inertia
        dq = 0.5 * quat.multiply(q, np.append(w, 0.0))
        out = np.concatenate([dw, dq])
        if k is not None:
            ip, i3 = inertia[(k + 1) % 3], inertia[k]
            out = np.append(out, (ip - i3) / ip * w[k])
        return out

    y0 = np.concatenate([scene.omega0, scene.attitude0] + ([[0.0]] if k is not None else []))
    t_eval = np.asarray(t_eval, dtype=float)
    r = solve_ivp(rhs, (0.0, float(t_eval[-1])), y0, method='DOP853', rtol=rtol, atol=atol,
                  t_eval=t_eval)
    assert r.success, r.message
    return r.y[:3].T, r.y[3:7].T


#: The attitude accuracy the package claims at its default tol, rad.
CLAIM = 1e-12
#: DOP853's tightest tolerances here (scipy takes rtol down to 100 eps) and the looser pair
#: whose distance to it estimates its own error.
TIGHT, LOOSE = 2.5e-14, 1e-13


def reference(scene, t_eval):
    """DOP853 at rtol = atol = 2.5e-14 and an estimate of its own error, per sample.

    Returns ``(omega, q, q_err, omega_err)``: the tight integration (:func:`integrate`, no
    formula shared with the core) and its distance to the same integration at 1e-13 (angle,
    rad; rate difference norm, rad/s). DOP853's error grows about as tol^(8/9), so that
    distance is the looser run's error within about 30 %, some three times the tight run's:
    a test asks ``error <= claim + q_err``, the claim plus the reference's own error.
    """
    w_t, q_t = _integrate_lean(scene, t_eval, TIGHT)
    w_l, q_l = _integrate_lean(scene, t_eval, LOOSE)
    return (w_t, q_t, quat.angle_between(q_l, q_t),
            np.linalg.norm(w_l - w_t, axis=-1))


def _integrate_lean(scene, t_eval, tol):
    """:func:`integrate`'s equations in plain floats (no small numpy arrays): faster."""
    i0, i1, i2 = (float(v) for v in scene.inertia)
    m = [float(v) for v in scene.torque]
    k = _sym_axis(scene.inertia) if scene.torque_frame == 'virtual' else None
    a, b = ((k + 1) % 3, (k + 2) % 3) if k is not None else (0, 0)
    rate = (scene.inertia[a] - scene.inertia[k]) / scene.inertia[a] if k is not None else 0.0

    def rhs(t, y):
        p, q, r, x, yy, z, s = y[:7]
        mb = list(m)
        if k is not None:               # the torque in B turns about k by -f
            c, sn = math.cos(y[7]), math.sin(y[7])
            mb[a] = c * m[a] + sn * m[b]
            mb[b] = -sn * m[a] + c * m[b]
        out = [(mb[0] - (q * i2 * r - r * i1 * q)) / i0,
               (mb[1] - (r * i0 * p - p * i2 * r)) / i1,
               (mb[2] - (p * i1 * q - q * i0 * p)) / i2,
               0.5 * (s * p + yy * r - z * q), 0.5 * (s * q + z * p - x * r),
               0.5 * (s * r + x * q - yy * p), -0.5 * (x * p + yy * q + z * r)]
        if k is not None:
            out.append(rate * (p, q, r)[k])
        return out

    y0 = list(scene.omega0) + list(scene.attitude0) + ([0.0] if k is not None else [])
    t_eval = np.asarray(t_eval, dtype=float)
    r = solve_ivp(rhs, (0.0, float(t_eval[-1])), y0, method='DOP853', rtol=tol, atol=tol,
                  t_eval=t_eval)
    assert r.success, r.message
    return r.y[:3].T, r.y[3:7].T


def rate_claim(omega):
    """Return the rate accuracy the package states, rad/s: 32 eps |omega| (odometry's 1-sigma).

    ``|omega|`` at its largest over the samples: a rate that passes through zero keeps the
    rounding of the terms that cancel there.
    """
    return 32.0 * np.finfo(float).eps * float(np.linalg.norm(omega, axis=-1).max())


def random_scene(model, rng):
    """Draw a seeded random scene that the core should classify as ``model``."""
    ip = rng.uniform(1.0, 3.0)
    i3 = ip * rng.uniform(0.3, 1.7)
    w = rng.uniform(-1.0, 1.0, 3)
    att = rng.normal(size=4)
    mag = ip * rng.uniform(0.05, 0.5)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    k = int(rng.integers(3))           # the symmetry axis, any principal axis
    i1, i2 = (k + 1) % 3, (k + 2) % 3
    inertia = np.empty(3)
    inertia[[i1, i2]] = ip
    inertia[k] = i3
    torque = np.zeros(3)
    frame = 'body'
    if model == 'sphere':
        inertia[:] = ip
        torque = mag * d
    elif model == 'torque-free-sphere':
        inertia[:] = ip
    elif model == 'torque-free-axisymmetric':
        pass
    elif model == 'axial-torque':
        torque[k] = mag * rng.choice([-1.0, 1.0])
    elif model == 'transverse-virtual':
        torque[[i1, i2]] = mag * d[:2] / np.linalg.norm(d[:2])
        frame = 'virtual'
    elif model == 'transverse-body':
        torque[[i1, i2]] = mag * d[:2] / np.linalg.norm(d[:2])
        w[k] = 0.0
    elif model == 'oblique-virtual':
        torque = mag * d
        frame = 'virtual'
    elif model == 'fixed-axis':
        inertia = np.array([ip, ip * 1.3, ip * 1.7])
        w[[i1, i2]] = 0.0
        torque[k] = mag
    else:
        raise ValueError(model)
    return Scene(inertia=tuple(inertia), torque=tuple(torque), torque_frame=frame,
                 omega0=tuple(w), attitude0=tuple(att))


ALL_MODELS = ['fixed-axis', 'torque-free-sphere', 'torque-free-axisymmetric', 'sphere',
              'axial-torque', 'transverse-virtual', 'transverse-body', 'oblique-virtual']
HYPER_MODELS = ['sphere', 'axial-torque', 'transverse-virtual', 'transverse-body',
                'oblique-virtual']


@pytest.fixture
def rng(request):
    """Return a generator seeded from the test's name, so each test is repeatable."""
    seed = sum(ord(c) for c in request.node.name)
    return np.random.default_rng(seed)


@pytest.fixture
def ros_context(monkeypatch):
    """Each test gets its own domain, on this machine only.

    Used by the in-process node tests through ``pytest.mark.usefixtures('ros_context')``;
    rclpy is imported here, not above, so that the pure tests never load it.
    """
    import rclpy
    domain = next_domain_id()
    for k, v in ros_env(domain).items():
        if k.startswith(('ROS_', 'FASTDDS_')):
            monkeypatch.setenv(k, v)
    rclpy.init(domain_id=domain)
    yield
    rclpy.try_shutdown()
