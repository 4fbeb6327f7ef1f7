"""Soak: run ``attitude_node`` for minutes at a high rate, recording, and fit its RSS slope.

The node runs as users run it: the installed ``attitude_node`` console script in its own
process, ``publish_rate`` 200 Hz, ``record:=true`` into a temporary directory, and one
subscriber process (``rigidrot_echo``, output discarded) so the DDS path is exercised.
Its resident set size (``VmRSS`` from ``/proc/<pid>/status``) is sampled every few seconds;
after a warm-up (the first fifth of the run, at most two minutes) a least-squares line
gives the growth in MB per minute. SIGINT ends it; the node must then exit 0 and finish
its bag.
"""

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

from rigidrot_ros.bench import common

__all__ = ['soak', 'rss_mb', 'slope_mb_per_min', 'run']

NAME = 'soak'
NEEDS = ()
#: The code this part measures (``rigidrot_bench --stale``): modules, with what they import.
MEASURES = ('rigidrot_ros.ros.cli', 'rigidrot_ros.ros.attitude_node')
KEYS = ('soak',)


def add_arguments(ap):
    """Add ``--soak-minutes`` to the parser ``ap``."""
    ap.add_argument('--soak-minutes', type=common.positive_number, default=10.0, metavar='MIN',
                    help='length of the soak part (--only soak), minutes (default 10)')


def rss_mb(pid):
    """Return the resident set size of process ``pid`` in MB (``VmRSS``), or None."""
    try:
        with open(f'/proc/{pid}/status', encoding='ascii') as fh:
            for line in fh:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError):
        return None
    return None


def slope_mb_per_min(samples, warmup_s):
    """Least-squares slope (MB/min) of ``(t_s, rss_mb)`` samples after ``warmup_s``.

    Returns ``(slope, half_width)``: the slope and a 95 % half-width from the residual
    scatter (normal approximation), so a flat line reads as ``0.00 +- 0.01``.
    """
    pts = np.array([(t, m) for t, m in samples if t >= warmup_s], dtype=float)
    if len(pts) < 3:
        return float('nan'), float('nan')
    t, m = pts[:, 0] / 60.0, pts[:, 1]
    a = np.vstack([t, np.ones_like(t)]).T
    coef, *_ = np.linalg.lstsq(a, m, rcond=None)
    resid = m - a @ coef
    dof = max(len(t) - 2, 1)
    s2 = float(resid @ resid) / dof
    var_slope = s2 / max(float(((t - t.mean()) ** 2).sum()), 1e-300)
    return float(coef[0]), 1.96 * float(np.sqrt(var_slope))


def soak(minutes, log, rate=200.0, sample_s=5.0, record=True, subscriber=True):
    """Run the node for ``minutes`` and return a dict with RSS samples and the slope.

    Parameters
    ----------
    minutes : float
        Length of the run, minutes (the issue's soak: 10).
    log : callable
        Receives progress lines.
    rate : float
        ``publish_rate`` of the node, Hz.
    sample_s : float
        Seconds between RSS samples.
    record, subscriber : bool
        Record to an MCAP bag; run a subscriber process.

    Returns
    -------
    dict
        ``minutes``, ``rate_hz``, ``rss_start_mb``, ``rss_end_mb``, ``slope_mb_per_min``,
        ``slope_ci95_mb_per_min``, ``warmup_s``, ``samples`` ([t_s, rss_mb] pairs),
        ``exit_code``, ``bag_bytes``, ``stderr_tail``.
    """
    env = dict(os.environ)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env.setdefault('FASTDDS_BUILTIN_TRANSPORTS', 'UDPv4')
    tmp = tempfile.mkdtemp(prefix='rigidrot_soak_')
    cmd = [common.script('attitude_node'), '--ros-args', '-p', f'publish_rate:={float(rate)}',
           '-p', f'record:={"true" if record else "false"}', '-p', f'record_path:={tmp}']
    duration = 60.0 * float(minutes)
    warmup = min(120.0, duration / 5.0)
    samples = []
    sub = None
    errf = tempfile.TemporaryFile(mode='w+')
    node = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=errf)
    try:
        if subscriber:
            sub = subprocess.Popen([common.script('rigidrot_echo')], env=env,
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _sample_rss(node, samples, minutes, duration, warmup, sample_s, log)
    finally:
        _stop(node, sub)
        errf.seek(0)
        stderr_tail = errf.read()[-2000:]
        errf.close()
        bag_bytes = sum(os.path.getsize(os.path.join(d, f))
                        for d, _, files in os.walk(tmp) for f in files)
        shutil.rmtree(tmp, ignore_errors=True)
    slope, hw = slope_mb_per_min(samples, warmup)
    settled = [m for t, m in samples if t >= warmup]
    out = {
        'minutes': float(minutes), 'rate_hz': float(rate), 'record': bool(record),
        'rss_start_mb': settled[0] if settled else float('nan'),
        'rss_end_mb': samples[-1][1] if samples else float('nan'),
        'slope_mb_per_min': slope, 'slope_ci95_mb_per_min': hw, 'warmup_s': warmup,
        'samples': [[round(t, 2), round(m, 3)] for t, m in samples],
        'exit_code': node.returncode, 'bag_bytes': bag_bytes, 'stderr_tail': stderr_tail,
    }
    log(f'soak: {minutes:g} min at {rate:g} Hz, recording {record}: RSS after warm-up '
        f'{out["rss_start_mb"]:.1f} -> {out["rss_end_mb"]:.1f} MB, slope after '
        f'{warmup:.0f} s warm-up {slope:+.4f} +- {hw:.4f} MB/min '
        f'({slope * 60 * 24:+.1f} MB/day); node exit {node.returncode}, bag '
        f'{bag_bytes / 1e6:.1f} MB')
    return out


def _sample_rss(node, samples, minutes, duration, warmup, sample_s, log):
    """Append ``(t_s, rss_mb)`` of ``node`` to ``samples`` every ``sample_s`` for ``duration``.

    Logs the slope so far once a minute; stops early if the node exits.
    """
    t0 = time.monotonic()
    next_log = 0.0
    while True:
        el = time.monotonic() - t0
        if node.poll() is not None:
            log(f'soak: attitude_node exited early with status {node.returncode}')
            break
        m = rss_mb(node.pid)
        if m is not None:
            samples.append((el, m))
        if el >= next_log:
            slope, hw = slope_mb_per_min(samples, warmup)
            log(f'soak {el / 60:5.1f}/{minutes:g} min  RSS {m or 0:7.1f} MB  slope so far '
                f'{slope:+.3f} +- {hw:.3f} MB/min')
            next_log += 60.0
        if el >= duration:
            break
        time.sleep(min(sample_s, max(duration - el, 0.05)))


def _stop(node, sub):
    """Stop the subscriber (SIGINT) and the node (:func:`common.stop`), and reap both."""
    if sub is not None:
        sub.send_signal(signal.SIGINT)
    common.stop(node, 60)
    if sub is not None:
        try:
            sub.wait(timeout=30)
        except subprocess.TimeoutExpired:
            sub.kill()
            sub.wait()


def run(quick=False, log=print, soak_minutes=10.0):
    """Soak for ``soak_minutes``; return ``{'soak': result of soak()}``."""
    return {'soak': soak(soak_minutes, log)}


def write(res, out, foot, log):
    """Write ``soak.csv``: the RSS samples."""
    common.write_csv(os.path.join(out, 'soak.csv'),
                     [{'t_s': t, 'rss_mb': m} for t, m in res['soak']['samples']], foot)


def failed(results):
    """Return a line where the node exited with a non-zero status, else none."""
    res = results.get('soak')
    if not res or res['exit_code'] == 0:
        return []
    return [f'SOAK: attitude_node exited with status {res["exit_code"]}: '
            f'{res["stderr_tail"][-500:]}']


def render_md(results):
    """Render the soak's RSS and slope as a table; None where the results hold no soak."""
    res = results.get('soak')
    if not res:
        return None
    row = [common.fmt(res['minutes']), common.fmt(res['rate_hz']),
           'yes' if res['record'] else 'no', common.fmt(res['warmup_s']),
           f'{common.fmt(res["rss_start_mb"], 4)} → {common.fmt(res["rss_end_mb"], 4)}',
           f'{res["slope_mb_per_min"]:+.3f} ± {res["slope_ci95_mb_per_min"]:.3f}',
           str(res['exit_code']), common.fmt(res['bag_bytes'] / 1e6)]
    return common.md_fragment(
        'Soak: the installed attitude_node with a subscriber, RSS from /proc',
        common.part_footer(results, NAME),
        common.md_table(['minutes', 'rate [Hz]', 'recording', 'warm-up [s]',
                         'RSS after warm-up [MB]', 'slope [MB/min] (95 %)', 'node exit',
                         'bag [MB]'], [row]))


def main(argv=None):
    """``python -m rigidrot_ros.bench.soak [--soak-minutes MIN]``: this part alone."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
