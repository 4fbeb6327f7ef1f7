"""The paced ROS path of a campaign: an estimator program, its ROS domain, and its feed.

For ``estimator.command`` without ``rate:`` (worker side). The campaign worker itself
plays the run and takes the estimator's answers, in a ROS context of its own on a domain
claimed for the run (no replay or recorder process):

1. the run's sensor messages and description are generated, serialized as the bag would
   hold them (:func:`rigidrot_ros.run.generate.iter_serialized`);
2. the command starts, with ``ROS_DOMAIN_ID`` set to a free domain (one lock file per id,
   held by the worker and inherited by the command, so a leftover process keeps its
   domain to itself), ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and Fast DDS on UDP;
3. once its subscriptions to ``inputs`` (default: every sensor topic of the run) have
   matched, and its output topics (``topics``) have a publisher (1 s more at most),
   and 0.3 s more (:data:`~rigidrot_ros.ros.paced.MATCH_SETTLE_S`: the command's
   publishers match the worker's answer subscriptions on their own time), the run
   description goes out on ``/attitude_node/run`` (transient local) and the sensor
   messages in log-time order, with ``/clock`` stepped with them, paced by its answers
   (:class:`rigidrot_ros.ros.paced.PacedPlayer`); at the end every message must be
   acknowledged by its subscriptions, or the run fails;
4. once no answer has come for ``settle`` seconds (0.2 by default), it gets SIGINT and
   must exit (5 s at most); its answers, with the run description, make the bag that is
   scored.

**Long-lived estimator** (``reset: SERVICE``): the command starts once per worker and
serves every run that worker is given. After each run's answers have settled, the worker
calls ``SERVICE`` (``std_srvs/srv/Trigger``); the estimator publishes what it still holds,
forgets the run and answers ``success: true``. The next run's stamps and ``/clock`` start
again from that run's start (they go back in time). A run that fails ends the process;
the next run starts a new one, on a new domain. The process ends with the worker
(SIGINT at exit; SIGTERM by ``setpriv --pdeathsig`` where available if the worker dies).

The worker's Fast DDS profile (:func:`rigidrot_ros.ros.paced.fast_dds`) is set around its
first ROS context only, but Fast DDS reads a profile file once per process: later
participants of the worker process keep it (quicker announcements and heartbeats).

What fails a run, with its reason: the command exits, never subscribes (30 s, at most
the run's ``timeout``), offers an incompatible QoS, publishes a type the campaign does not
score, publishes nothing, leaves messages unacknowledged, hangs past ``timeout``, does
not exit within 5 s of SIGINT, exits with an error status, or refuses or ignores the
reset.
"""

import atexit
import os
import shutil
import signal
import subprocess
import tempfile
import time

from rigidrot_ros.campaign.failure import RunFailed
from rigidrot_ros.campaign.spec import command_path
from rigidrot_ros.campaign.workdir import claim_domain

__all__ = ['run_paced', 'Session', 'SENSORS', 'SCORED_TYPES', 'feed_topics', 'claim_domain',
           'STARTUP_S']

#: The run's topics an estimator is given, by the last component of their names: the
#: sensors (``/attitude``, ``/odom``, ``/delta_angle``... are the truth, never given).
SENSORS = ('imu', 'star_tracker', 'mag')
#: The types scored with NEES (an orientation with its covariance).
SCORED_TYPES = ('nav_msgs/msg/Odometry', 'geometry_msgs/msg/PoseWithCovarianceStamped',
                'sensor_msgs/msg/Imu')
#: Seconds (at most the run's timeout) the command has to subscribe to its inputs.
STARTUP_S = 30.0
#: Seconds after its inputs matched for its output topics to show a publisher.
OUTPUT_GRACE_S = 1.0
#: Seconds to exit after SIGINT.
STOP_S = 5.0
#: Seconds for the reset service to answer.
RESET_S = 10.0
#: Default quiet time after the last message before the estimator is stopped (or reset).
SETTLE_S = 0.2


def feed_topics(topics):
    """Return the topics of ``topics`` an estimator is given (:data:`SENSORS`), sorted."""
    return sorted(t for t in topics if t.rsplit('/', 1)[-1] in SENSORS)


def _last_line(path):
    try:
        with open(path, 'rb') as fh:
            fh.seek(max(0, os.path.getsize(path) - 4096))
            lines = [ln.strip() for ln in fh.read().decode('utf-8', 'replace').splitlines()]
    except OSError:
        return ''
    lines = [ln for ln in lines if ln]
    return ' '.join(lines[-1].split())[:200] if lines else ''


def _cpu_s(pid):
    """Return the CPU seconds (user + system) process ``pid`` has used, or None."""
    try:
        with open(f'/proc/{pid}/stat', encoding='ascii') as fh:
            fields = fh.read().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, ValueError, IndexError):
        return None


def _tail(path, count=40):
    try:
        with open(path, encoding='utf-8', errors='replace') as fh:
            return ''.join(fh.readlines()[-count:])
    except OSError:
        return ''


class Session:
    """One estimator process in a claimed ROS domain, and the worker's node that feeds it.

    Parameters
    ----------
    est : dict
        The spec's ``estimator`` (a command).
    log_dir : str
        Where the estimator's output goes (``estimator.log``).

    Notes
    -----
    :meth:`spawn` starts the command, :meth:`connect` opens the worker's side and waits
    until the command listens: a run is generated in between, while the command starts.
    """

    def __init__(self, est, log_dir):
        self.est = est
        self.inputs = None
        self.key = _key(est)
        self.log_path = os.path.join(log_dir, 'estimator.log')
        self.proc = self.lock = self.context = self.node = self.executor = None
        self.player = self.run_pub = self.reset_client = None
        self.domain = None
        self._log = None
        self.runs = 0
        self.timing = {}

    # -- life --------------------------------------------------------------------------
    def spawn(self):
        """Claim a domain and start the command; RunFailed if it cannot be started."""
        self._t0 = time.perf_counter()
        self.domain, self.lock = claim_domain(self.est['domain_base'],
                                              self.est['domain_span'])
        env = self._environment()
        cmd = list(self.est['command'])
        if shutil.which('setpriv'):
            cmd = ['setpriv', '--pdeathsig', 'TERM', '--'] + cmd
        self._log = open(self.log_path, 'ab')
        try:
            self.proc = subprocess.Popen(cmd, env=env, stdout=self._log,
                                         stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                         pass_fds=(self.lock.fileno(),))
        except OSError as exc:
            raise RunFailed(f'the estimator command {self.est["command"][0]} did not start: '
                            f'{exc.strerror or exc}', startup=True) from None
        self._env = env

    def connect(self, inputs, deadline):
        """Open the worker's node for ``inputs`` (topic -> type); wait until it listens."""
        self.inputs = dict(inputs)
        self._open_ros(self._env)
        self.timing['process_start_s'] = time.perf_counter() - self._t0
        startup = time.monotonic() + STARTUP_S
        self._wait_ready(min(deadline, startup), f'within {STARTUP_S:g} s' if startup < deadline
                         else "before the run's timeout")
        self.timing['ready_s'] = time.perf_counter() - self._t0

    @property
    def connected(self):
        """Whether :meth:`connect` has been done."""
        return self.context is not None

    def _environment(self):
        from rigidrot_ros.ros.paced import fast_dds
        env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain), PYTHONUNBUFFERED='1',
                   PATH=command_path(), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                   FASTDDS_BUILTIN_TRANSPORTS='UDPv4')
        env.pop('ROS_LOCALHOST_ONLY', None)
        fast_dds(env)
        return env

    def _open_ros(self, env):
        """Open this worker's ROS context on the domain (the environment set around init)."""
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions
        from std_msgs.msg import String

        from rigidrot_ros.ros.paced import CLOCK_STEP, PacedPlayer
        from rigidrot_ros.ros.recorder import msg_class
        from rigidrot_ros.run.generate import RUN_TOPIC
        keys = ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'FASTDDS_BUILTIN_TRANSPORTS',
                'FASTRTPS_DEFAULT_PROFILES_FILE', 'ROS_LOCALHOST_ONLY')
        saved = {k: os.environ.get(k) for k in keys}
        try:
            for k in keys:
                if env.get(k) is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = env[k]
            self.context = Context()
            rclpy.init(args=['rigidrot_campaign'], context=self.context,
                       domain_id=self.domain, signal_handler_options=SignalHandlerOptions.NO)
            self.node = rclpy.create_node('rigidrot_campaign_feed', context=self.context,
                                          start_parameter_services=False,
                                          enable_rosout=False)
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.player = PacedPlayer(self.node, self.executor,
                                  {t: msg_class(n) for t, n in self.inputs.items()},
                                  self.est['topics'], clock=True, window=self.est.get('window'),
                                  clock_step=(CLOCK_STEP if self.est.get('clock_step') is None
                                              else self.est['clock_step']))
        self.run_pub = self.node.create_publisher(
            String, RUN_TOPIC, QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                          durability=DurabilityPolicy.TRANSIENT_LOCAL))
        if self.est.get('reset'):
            from std_srvs.srv import Trigger
            self.reset_client = self.node.create_client(Trigger, self.est['reset'])

    def _check(self, when='during the run', startup=False):
        """Raise RunFailed if the estimator's process has exited."""
        code = self.proc.poll() if self.proc is not None else None
        if code is not None:
            said = _last_line(self.log_path)
            raise RunFailed(f'the estimator exited with status {code} {when}'
                            + (f': {said}' if said else ''), _tail(self.log_path),
                            startup=startup)

    def _wait_ready(self, limit, within):
        player = self.player
        need = self.est.get('inputs') or list(self.inputs)
        unknown = [t for t in need if t not in self.inputs]
        if unknown:
            raise RunFailed(f'estimator.inputs {", ".join(unknown)}: not a sensor topic of '
                            f'the run (it has {", ".join(sorted(self.inputs))})', startup=True)
        matched_at = None
        while True:
            self._check('before subscribing to its inputs', startup=True)
            if player.problems:
                raise RunFailed(f'the estimator: {player.problems[0]}')
            missing = player.missing(need)
            player.poll_outputs()
            self._check_types()
            now = time.monotonic()
            unmatched = player.unmatched() if not missing else []
            if not missing and not unmatched:
                matched_at = matched_at or now
                outputs = player.outputs_matched() or now - matched_at > OUTPUT_GRACE_S
                service = self.reset_client is None or self.reset_client.service_is_ready()
                if outputs and service:
                    player.settle_match(
                        limit, lambda: self._check('before the run', startup=True))
                    return
            if now > limit:
                if missing:
                    raise RunFailed(f'the estimator did not subscribe to {", ".join(missing)} '
                                    f'{within}', _tail(self.log_path))
                if unmatched:
                    raise RunFailed(f'a subscription to {", ".join(unmatched)} is listed but '
                                    f'not matched {within}', _tail(self.log_path))
                raise RunFailed(f'the estimator offers no reset service {self.est["reset"]} '
                                f'(std_srvs/srv/Trigger) {within}', _tail(self.log_path))
            player.spin(0.02)

    def _check_types(self):
        topic = self.player.output_topics[0]
        type_name = self.player.output_types.get(topic)
        if type_name is not None and type_name not in SCORED_TYPES:
            raise RunFailed(f'the estimator publishes {type_name} on {topic}: the campaign '
                            f'scores {", ".join(SCORED_TYPES)} (an orientation with its '
                            f'covariance)')

    def alive(self):
        """Return whether the process runs (and the context is open, once connected)."""
        return self.proc is not None and self.proc.poll() is None

    # -- one run -----------------------------------------------------------------------
    def feed(self, run_data, messages, deadline):
        """Play one run; return the answers ``[(topic, cdr bytes, stamp or None), ...]``."""
        from rigidrot_ros.ros.paced import PlayError
        player = self.player
        settle = self.est.get('settle')
        settle = SETTLE_S if settle is None else settle
        player.clear()
        cpu0, own0 = _cpu_s(self.proc.pid), time.process_time()
        t0 = time.perf_counter()
        try:
            self.run_pub.publish(bytes(run_data))
            player.play(messages, deadline, check=self._check)
            t1 = time.perf_counter()
            player.confirm(max(0.5, min(5.0, deadline - time.monotonic())))
            t2 = time.perf_counter()
            player.settle(settle, deadline, check=self._check)
        except PlayError as exc:
            raise RunFailed(str(exc), _tail(self.log_path)) from None
        t3 = time.perf_counter()
        cpu1 = _cpu_s(self.proc.pid)
        if cpu0 is not None and cpu1 is not None:
            self.timing['estimator_cpu_s'] = cpu1 - cpu0
        self.timing['feeder_cpu_s'] = time.process_time() - own0
        self.timing.update(play_s=t1 - t0, confirm_s=t2 - t1, settle_s=t3 - t2,
                           sent=sum(player.sent.values()), stalls=player.stalls,
                           clocks=player.clocks,
                           window=player.used_window)
        if player.unconfirmed:
            self.timing['unconfirmed'] = list(player.unconfirmed)
        if self.reset_client is not None:
            self._reset(deadline)
        else:
            self._stop()
        self.timing['end_s'] = time.perf_counter() - t3
        self._check_types()
        self.runs += 1
        return list(player.answers)

    def _reset(self, deadline):
        from std_srvs.srv import Trigger
        fut = self.reset_client.call_async(Trigger.Request())
        end = min(deadline, time.monotonic() + RESET_S)
        while not fut.done():
            self._check('before answering its reset')
            if time.monotonic() > end:
                raise RunFailed(f'the estimator did not answer its reset service '
                                f'{self.est["reset"]} within {RESET_S:g} s', _tail(self.log_path))
            self.player.spin(0.01)
        res = fut.result()
        if not res.success:
            raise RunFailed(f'the estimator refused the reset: {" ".join(res.message.split())}'
                            [:300], _tail(self.log_path))
        self.player.settle(0.05)

    def _stop(self):
        """SIGINT the estimator; take its last answers; RunFailed on a bad exit."""
        self._check('during the run')
        self.proc.send_signal(signal.SIGINT)
        end = time.monotonic() + STOP_S
        while self.proc.poll() is None and time.monotonic() < end:
            self.player.spin(0.01)
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
            raise RunFailed(f'the estimator did not exit within {STOP_S:g} s of SIGINT '
                            f'(killed)', _tail(self.log_path))
        end = time.monotonic() + 1.0                 # its answers still on their way
        while self.player.output_publishers() and time.monotonic() < end:
            self.player.spin(0.01)
        self.player.settle(0.02)
        code = self.proc.returncode
        if code not in (0, -signal.SIGINT, 128 + signal.SIGINT):
            said = _last_line(self.log_path)
            raise RunFailed(f'the estimator exited with status {code} when stopped'
                            + (f': {said}' if said else ''), _tail(self.log_path))

    def close(self):
        """Stop the process if it runs, close the context, free the domain."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(STOP_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.context is not None:
            import rclpy
            try:
                self.executor.shutdown(0)
                self.node.destroy_node()
            finally:
                rclpy.try_shutdown(context=self.context)
                self.context = None
        if self._log is not None:
            self._log.close()
            self._log = None
        if self.lock is not None:
            self.lock.close()
            self.lock = None


#: The long-lived session of this worker process (``reset:``), kept across runs.
_LIVE = {}


def _close_live():
    session = _LIVE.pop('session', None)
    if session is not None:
        try:
            session.close()
        finally:
            shutil.rmtree(_LIVE.pop('dir', ''), ignore_errors=True)


atexit.register(_close_live)


def _key(est):
    return (tuple(est['command']), tuple(est['topics']), tuple(est.get('inputs') or ()),
            est.get('reset'), est['domain_base'], est['domain_span'])


def _live_session(est):
    """Return this worker's session for ``est``: running, or spawned now."""
    session = _LIVE.get('session')
    if session is not None and (session.key != _key(est) or not session.alive()):
        _close_live()
        session = None
    if session is not None:
        session.timing = {}
        return session
    _LIVE['dir'] = tempfile.mkdtemp(prefix='rigidrot_estimator_')
    session = Session(est, _LIVE['dir'])
    _LIVE['session'] = session
    try:
        session.spawn()
    except BaseException:
        _close_live()
        raise
    return session


def run_paced(spec, values, work, timing, bag=None):
    """Generate run ``values``, feed it to the command, return ``(answers bag, runs)``.

    ``bag``, the run's bag when it is generated already (several estimators on one run),
    is read instead of generating the messages again.

    ``timing`` receives the phases' wall times (seconds): ``generate_s``, the session's
    ``process_start_s``/``ready_s`` (when a process started for this run), ``play_s``,
    ``confirm_s``, ``settle_s``, ``end_s`` (stop or reset), ``write_s``; and ``sent``,
    ``stalls``, ``window``.
    """
    from rigidrot_ros.bag import run_from_string
    from rigidrot_ros.ros.paced import write_answers
    from rigidrot_ros.run.generate import iter_serialized, RUN_TOPIC
    est = spec['estimator']
    deadline = time.monotonic() + spec['timeout']
    live = bool(est.get('reset'))
    session = _live_session(est) if live else Session(est, work)
    try:
        if not live:
            session.spawn()                       # it starts while the run is generated
        t0 = time.perf_counter()
        if bag is None:
            messages = list(iter_serialized(values, spec['duration'], SENSORS + ('run',)))
        else:
            from rigidrot_ros.bag import read_bag
            messages = [(t, log_ns, bytes(data))
                        for t, _, log_ns, _, data in read_bag(bag).messages
                        if t.rsplit('/', 1)[-1] in SENSORS + ('run',)]
        run_data = next(data for t, _, data in messages if t == RUN_TOPIC)
        messages = [m for m in messages if m[0] != RUN_TOPIC]
        run = run_from_string(run_data)
        inputs = {t: run['topics'][t] for t in feed_topics({m[0] for m in messages})}
        timing['generate_s'] = time.perf_counter() - t0
        if session.connected and session.inputs != inputs:
            raise RunFailed(f'the run has other sensors ({", ".join(sorted(inputs))}) than '
                            f'the one before it on this estimator '
                            f'({", ".join(sorted(session.inputs))})')
        if not session.connected:
            session.connect(inputs, deadline)
        answers = session.feed(run_data, messages, deadline)
        types = dict(session.player.output_types)
    except BaseException:
        if live:
            _close_live()
        raise
    finally:
        if not live:
            session.close()
    timing.update(session.timing)
    t1 = time.perf_counter()
    path = write_answers(os.path.join(work, 'estimate'), answers, types, [run],
                         {RUN_TOPIC: run_data})
    timing['write_s'] = time.perf_counter() - t1
    return path, [run]
