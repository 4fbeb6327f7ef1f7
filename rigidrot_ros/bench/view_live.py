"""The live view's cost beside the node at 100 Hz truth and a 1 kHz gyro.

``attitude_node`` (truth at 100 Hz; gyro at 1 kHz; star tracker at 10 Hz), the reference
MEKF as a node (``rigidrot_mekf``, an estimate every 10th gyro sample: 100 Hz) and
``rigidrot_view --live`` on its estimate run as three processes in one ROS domain; after
a warm-up, each process's CPU time (``/proc/<pid>/stat`` utime + stime) is read over the
window and given as a share of one core. The view's own count of what it received (per
topic, against the publishing rate times the window) says whether it kept up; it is
measured with its default decimation (each topic shown at most 50 Hz) and without any
(``--max-rate 0``: every message deserialized, scored and logged). With ``--view-browser``
a headless Chromium shows the view meanwhile (its own CPU is given apart).
"""

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

from rigidrot_ros.bench import common

__all__ = ['run', 'NAME', 'NEEDS', 'main', 'measure']

NAME = 'view_live'
NEEDS = ('rerun',)
NODE = ['-p', 'publish_rate:=100.0', '-p', 'imu.enable:=true', '-p', 'imu.rate:=1000.0',
        '-p', 'star_tracker.enable:=true']
MEKF = ['--sigma-v', '1.7e-4', '--sigma-u', '2e-5', '--bias-sigma', '2e-3']
ESTIMATE = '/estimator/odom:nav_msgs/msg/Odometry'
RATES = {'/attitude': 100.0, '/imu': 1000.0, '/star_tracker': 10.0, '/estimator/odom': 100.0}


def add_arguments(ap):
    """Options of this part."""
    ap.add_argument('--view-seconds', type=float, default=None,
                    help='measuring window per configuration (default 30 s; --quick 8 s)')
    ap.add_argument('--view-browser', action='store_true',
                    help='a headless Chromium shows the view during the window')


def _cpu_s(pid):
    """User + system CPU seconds of a process (``/proc/<pid>/stat``)."""
    with open(f'/proc/{pid}/stat', encoding='utf-8') as fh:
        fields = fh.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _stat(pid):
    with open(f'/proc/{pid}/stat', encoding='utf-8') as fh:
        return fh.read().rsplit(')', 1)[1].split()


def _browser_cpu_s():
    """CPU seconds of the Chromium processes started under this one (all of them)."""
    me, total = os.getpid(), 0.0
    for d in (d for d in os.listdir('/proc') if d.isdigit()):
        try:
            with open(f'/proc/{d}/cmdline', 'rb') as fh:
                if b'chromium' not in fh.read().split(b'\0')[0]:
                    continue
            f = _stat(d)
            p = int(f[1])
            while p > 1 and p != me:
                p = int(_stat(p)[1])
        except (OSError, ValueError, IndexError):
            continue
        if p == me:
            total += (int(f[11]) + int(f[12])) / os.sysconf('SC_CLK_TCK')
    return total


def _free_port():
    with socket.socket() as s:
        s.bind(('', 0))
        return s.getsockname()[1]


def _env(domain):
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               FASTDDS_BUILTIN_TRANSPORTS='UDPv4', PYTHONUNBUFFERED='1')
    env.pop('ROS_LOCALHOST_ONLY', None)
    return env


def _wait_for(proc, text, timeout, sink):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stderr.readline()
        if not line and proc.poll() is not None:
            break
        sink.append(line)
        if text in line:
            return True
    return False


def measure(seconds, max_rate, domain, log, warmup=5.0, browser=False):
    """Run node, MEKF and view for ``warmup + seconds``; return the figures (a dict)."""
    env = _env(domain)
    web, grpc = _free_port(), _free_port()
    node_err = tempfile.TemporaryFile(mode='w+')
    procs = {
        'node': subprocess.Popen([common.script('attitude_node'), '--ros-args'] + NODE,
                                 env=env, stdout=subprocess.DEVNULL, stderr=node_err),
        'mekf': subprocess.Popen([common.script('rigidrot_mekf')] + MEKF, env=env,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL),
        'view': subprocess.Popen([common.script('rigidrot_view'), '--live', '--topic', ESTIMATE,
                                  '--max-rate', repr(max_rate), '--port', str(web),
                                  '--grpc-port', str(grpc)], env=env, text=True,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE),
    }
    lines, shot, drain = [], {}, None
    try:
        if not _wait_for(procs['view'], 'live: ', 120, lines):
            raise RuntimeError(f'rigidrot_view did not start: {"".join(lines)[-800:]}')
        url = next(ln.split('serving the view at ')[1].split(' (')[0] for ln in lines
                   if 'serving the view at' in ln)
        drain = threading.Thread(target=lambda: lines.extend(procs['view'].stderr),
                                 daemon=True)
        drain.start()
        if browser:
            shot['thread'] = threading.Thread(target=_browse, args=(url, warmup + seconds,
                                                                    shot), daemon=True)
            shot['thread'].start()
        time.sleep(warmup)
        _alive(procs, node_err)
        c0 = {k: _cpu_s(p.pid) for k, p in procs.items()}
        b0 = _browser_cpu_s() if browser else None
        t0 = time.monotonic()
        time.sleep(seconds)
        wall = time.monotonic() - t0
        _alive(procs, node_err)
        c1 = {k: _cpu_s(p.pid) for k, p in procs.items()}
        b1 = _browser_cpu_s() if browser else None
    finally:
        view = procs['view']
        if view.poll() is None:
            view.send_signal(signal.SIGINT)
        try:
            code = view.wait(60)
        except subprocess.TimeoutExpired:
            view.kill()
            code = view.wait()
        if drain is not None:
            drain.join(10)          # it reads the view's stderr to its end
        for k in ('mekf', 'node'):
            common.stop(procs[k], 60.0)
    if 'thread' in shot:
        shot['thread'].join(30)
    summary = next((json.loads(ln.split('live summary: ', 1)[1]) for ln in lines
                    if 'live summary: ' in ln), None)
    if summary is None:
        raise RuntimeError(f'rigidrot_view gave no summary (status {code}): '
                           f'{"".join(lines)[-800:]}')
    out = {'max_rate_hz': max_rate, 'window_s': wall,
           'cpu_share': {k: (c1[k] - c0[k]) / wall for k in procs},
           'browser_cpu_share': None if b0 is None else (b1 - b0) / wall,
           'topics': summary['topics'], 'flushes': summary['flushes'],
           'flush_cpu_ms_median': summary['flush_cpu_ms_median'],
           'flush_cpu_ms_max': summary['flush_cpu_ms_max']}
    return out


class NodeExited(RuntimeError):
    """The node or the MEKF ended during the measurement (its last words)."""


def _alive(procs, node_err):
    for k in ('node', 'mekf'):
        if procs[k].poll() is not None:
            node_err.seek(0)
            said = node_err.read().strip().splitlines()[-3:] if k == 'node' else []
            raise NodeExited(f'{k} exited with status {procs[k].returncode} during the '
                             f'measurement: {" / ".join(said)}')


def _browse(url, seconds, shot):
    """Keep a headless Chromium on the view for ``seconds``."""
    from playwright.sync_api import sync_playwright

    from rigidrot_ros.view.browser import CHROMIUM, CHROMIUM_ARGS
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        page = b.new_page(viewport={'width': 1280, 'height': 720})
        page.route('**/*', lambda r: r.continue_() if '127.0.0.1' in r.request.url
                   else r.abort())
        page.goto(url)
        time.sleep(seconds)
        b.close()


def _line(r, log):
    cpu = r['cpu_share']
    topics = r['topics']
    log(f'view_live max-rate {r["max_rate_hz"]:g} Hz: view {100 * cpu["view"]:.1f} % of a '
        f'core, node {100 * cpu["node"]:.1f} %, MEKF {100 * cpu["mekf"]:.1f} %'
        + ('' if r['browser_cpu_share'] is None else
           f', browser {100 * r["browser_cpu_share"]:.1f} %')
        + f' over {r["window_s"]:.1f} s; batch cost median {r["flush_cpu_ms_median"]:.2f} ms,'
        f' max {r["flush_cpu_ms_max"]:.1f} ms ({r["flushes"]} batches)')
    for t, v in topics.items():
        if t in RATES and v['received']:
            log(f'  {t}: {v["received"]} received at {v["rate_hz"] or 0:.4g} Hz (published '
                f'{RATES[t]:g} Hz), {v["shown"]} shown, {v["dropped_behind"]} dropped by '
                f'the view (behind)')


def run(quick=False, log=print, view_seconds=None, view_browser=False):
    """Measure the live view with its default decimation and without; the figures."""
    seconds = view_seconds or (8.0 if quick else 30.0)
    domain = int(os.environ.get('ROS_DOMAIN_ID', '0') or 0)
    log(f'view_live: attitude_node (truth 100 Hz, gyro 1 kHz, star tracker 10 Hz), '
        f'rigidrot_mekf (estimates 100 Hz) and rigidrot_view --live, {seconds:g} s each, '
        f'ROS_DOMAIN_ID={domain}')
    res = {'seconds': seconds, 'runs': [], 'footer': common.footer()}
    for max_rate in (50.0, 0.0):
        load0 = os.getloadavg()[0]
        for attempt in range(3):    # the node's start-up trial can fail on a loaded machine
            try:
                r = measure(seconds, max_rate, domain, log, browser=view_browser)
                break
            except NodeExited as exc:
                log(f'view_live: {exc}' + ('; again' if attempt < 2 else ''))
                if attempt == 2:
                    raise
        r['load_1min'] = [load0, os.getloadavg()[0]]
        _line(r, log)
        log(f'  machine load (1 min average) {load0:.1f} before, {r["load_1min"][1]:.1f} '
            f'after, on {os.cpu_count()} cores')
        res['runs'].append(r)
    return res


def main(argv=None):
    """``python -m rigidrot_ros.bench.view_live [--quick] [--view-seconds S]``: this part."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
