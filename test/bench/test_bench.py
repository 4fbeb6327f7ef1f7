"""The benchmark: the quick smoke run, and the peers' orders of convergence."""

import json
import subprocess

import numpy as np
import pytest

from rigidrot_ros.bench import peers
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import Scene, solve
from ros_helpers import script

SCENE = Scene(inertia=(2.0, 2.0, 1.0), torque=(0.1, 0.05, 0.02), torque_frame='virtual',
              omega0=(0.3, -0.2, 0.5), attitude0=(0.1, 0.2, 0.3, 0.9))


@pytest.mark.parametrize('method', ['RK4', 'RKMK4', 'Magnus4'])
def test_fixed_step_peers_are_fourth_order(method):
    sol = solve(SCENE, tol=2e-14)
    t = np.array([10.0])
    ref = sol.at(t).quaternion
    errs = []
    for h in (0.1, 0.05, 0.025):
        if method == 'RK4':
            q = peers.rk4(SCENE, t, h)
        elif method == 'RKMK4':
            q = peers.rkmk4(SCENE, t, h)
        else:
            q = peers.magnus4(SCENE, t, h, sol.omega_at)
        errs.append(quat.angle_between(q, ref)[0])
    ratios = [errs[0] / errs[1], errs[1] / errs[2]]
    assert all(12.0 < r < 20.0 for r in ratios), (errs, ratios)


def test_scipy_peer_meets_tight_tolerance_and_budget_stops_it():
    sol = solve(SCENE, tol=2e-14)
    t = np.array([5.0])
    q = peers.scipy_ivp(SCENE, t, 'DOP853', 1e-12)
    assert quat.angle_between(q, sol.at(t).quaternion)[0] < 1e-10
    with pytest.raises(peers.TimeBudget):
        peers.rk4(SCENE, np.array([1e4]), 1e-3, budget=0.05)


def test_quick_run_writes_charts_and_checked_results(tmp_path):
    out = subprocess.run([script('rigidrot_bench'), '--quick', '--out', str(tmp_path)],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    for name in ('work_precision_query', 'work_precision_stream', 'horizon', 'stability'):
        assert (tmp_path / f'{name}.png').stat().st_size > 10000
        assert (tmp_path / f'{name}.svg').exists()
    res = json.loads((tmp_path / 'results.json').read_text())
    assert {'cpu', 'date', 'numpy', 'scipy', 'python-flint'} <= set(res['footer'])
    wp = res['work_precision']
    exact = [r for r in wp if r['method'].startswith('exact') and r['status'] == 'ok']
    assert exact and all(r['error_rad'] <= r['value'] for r in exact)
    assert not [r for r in wp if r['status'] == 'claim violated']
    # the stability map shows failures rather than hiding them
    statuses = {c['status'] for c in res['stability']}
    assert 'meets 1e-12' in statuses
    assert any(s.startswith('fail') for s in statuses)
    assert (tmp_path / 'work_precision.csv').read_text().rstrip().splitlines()[-1] \
        .startswith('# {')


def test_quick_ratios_check_every_answer(tmp_path):
    """The ratios part runs, times both DOP853 forms and finds every exact bound held."""
    out = subprocess.run([script('rigidrot_bench'), '--quick', '--only', 'ratios', '--out',
                          str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    with open(tmp_path / 'results.json', encoding='utf-8') as fh:
        rows = json.load(fh)['ratios']
    parts = {r['part'] for r in rows}
    assert {'stream 100 Hz', 'one query', 'batch memory', 'scalar at(t) random',
            'tick 100 Hz tight loop'} <= parts
    timed = [r for r in rows if r['part'] in ('stream 100 Hz', 'one query')
             or r['part'].endswith('samples')]
    assert timed and all(r['bounds_hold'] for r in timed)
    assert all(r['exact_error_rad'] <= r['exact_max_bound_rad'] for r in timed)
    assert all(r['dop853_cpu_s'] > 0 and r['dop853_lean_cpu_s'] > 0 for r in timed)
    assert all(r['p50_us'] > 0 for r in rows if r['part'].startswith(('scalar', 'tick')))


def _rendered(results_json):
    from rigidrot_ros.bench import registry
    with open(results_json, encoding='utf-8') as fh:
        results = json.load(fh)
    out = {}
    for name, mod in registry.available(needs=False).items():
        md = getattr(mod, 'render_md', lambda r: None)(results)
        if md is not None:
            out[name] = md
    return out


@pytest.mark.parametrize('folder', ['doc/bench', 'doc/bench/ratios', 'doc/bench/leaderboard'])
def test_committed_tables_are_what_the_results_render(folder):
    """Each doc/bench/<part>.md is its part's render_md of the committed results JSON."""
    from pathlib import Path
    root = Path(__file__).resolve().parents[2] / folder
    rendered = _rendered(root / 'results.json')
    assert rendered, 'no part renders a table from the committed results'
    committed = {p.stem: p.read_text(encoding='utf-8') for p in root.glob('*.md')}
    assert committed == rendered, (
        f'regenerate: rigidrot_bench --charts-from {folder}/results.json --out {folder}')


def test_registry_parts_follow_the_convention():
    from rigidrot_ros.bench import registry
    for name, mod in registry.available(needs=False).items():
        assert not isinstance(mod, registry.Unavailable), mod
        assert mod.NAME == name and callable(mod.run) and callable(mod.main)
        assert isinstance(mod.NEEDS, tuple)
    with pytest.raises(KeyError):
        registry.load('no_such_part')


def _khz_bag(tmp_path, late_imu, missing_ticks):
    """A 1 kHz bag: /attitude on the grid but ``missing_ticks``, /imu logged on time but
    ``late_imu`` (logged 2.5 periods after their stamp)."""
    from rclpy.serialization import serialize_message

    from rigidrot_ros.msgs import messages as msgs
    from rigidrot_ros.bag import BagWriter
    w = BagWriter(str(tmp_path), 'khz')
    w.add_topic('/attitude', 'geometry_msgs/msg/QuaternionStamped')
    w.add_topic('/imu', 'sensor_msgs/msg/Imu')
    t0, period = 1_700_000_000 * 10**9, 10**6
    for k in range(400):
        ns = t0 + k * period
        if k not in missing_ticks:
            w.write('/attitude', serialize_message(
                msgs.attitude(msgs.stamp(ns), 'n', (0.0, 0.0, 0.0, 1.0))), ns + 1000)
        if k:
            log = ns + (5 * period // 2 if k in late_imu else 800_000)
            w.write('/imu', serialize_message(
                msgs.imu(msgs.stamp(ns), 'b', (0.0, 0.0, 0.1), 1e-6)), log)
    w.close()
    return w.path


def test_node_khz_counts_missed_ticks_and_late_gyro_from_a_bag(tmp_path):
    """Missed slots and late samples inside the span count; those in the warm-up do not."""
    from rigidrot_ros.bench import node_khz
    bag = _khz_bag(tmp_path, late_imu={50, 150, 151, 390}, missing_ticks={20, 120, 200, 201})
    got = node_khz.bag_figures(bag, 1000.0, warmup=0.1, seconds=0.25)
    assert got['ticks_asked'] == 250 and got['ticks_missed'] == 3      # 120, 200, 201
    assert got['ticks_delivered'] == 247 and got['delivered_pct'] == pytest.approx(98.8)
    assert got['gyro_late'] == 2 and got['gyro_absent'] == 0          # 150, 151
    assert got['gyro_log_delay_max_us'] == pytest.approx(2500.0)


def test_node_khz_diagnostics_without_keys_read_na():
    """Absent keys give None (printed n/a); a look-ahead that goes off is found and dated."""
    from rigidrot_ros.bench import node_khz
    t0 = 10**18
    diags = [{'stamp_ns': t0 + s * 10**9, 'level': 0, 'message': '',
              'values': {'ticks_published': str(1000 * s), 'ticks_missed': str(7 * s),
                         'lookahead': '8 samples a batch' if s < 4 else 'off: too slow',
                         'latency_imu_p99_us': str(100.0 + s)}} for s in range(1, 9)]
    got = node_khz.diag_figures(diags, 1000.0, 2.0, 4.0, t0_ns=t0)
    assert got['tick_p99_us'] is None and got['latency_p99_us'] is None
    assert got['sensor_latency_p99_us'] == {'imu': {'median': 105.0, 'worst': 107.0}}
    assert got['ticks_missed'] == 28 and got['span_s'] == 4.0
    assert got['lookahead'] == {'on_throughout': False, 'last': 'off: too slow',
                                'off_after_s': 4.0, 'off_reason': 'too slow'}
    res = {'node_khz': {'seconds': 4.0, 'warmup_s': 2.0, 'rates': [node_khz.summarize(
        {'rate_hz': 1000.0, 'seconds': 4.0, 'warmup_s': 2.0, 'diags': diags, 'bag': None,
         'exit_code': 0, 'stderr_tail': ''})]}, 'footer': {}}
    md = node_khz.render_md(res)
    assert '| 1000 | n/a |' in md and 'off after 4.0 s (too slow)' in md


def test_random_access_times_a_scene_cold_in_a_fresh_process():
    """The cold row: the same scene and times t in a fresh interpreter, labelled as such."""
    from rigidrot_ros.bench import common, random_access
    lines = []
    cold = random_access._cold('torque_free_triaxial', 1e3, 5, lines.append)
    warm = random_access._one('torque_free_triaxial', common.ratio_scenes()[
        'torque_free_triaxial'], 1e3, 5, lines.append)
    assert (cold['process'], warm['process']) == ('cold', 'warm')
    assert cold['max_error_rad'] == warm['max_error_rad'] and cold['bounds_hold']
    assert cold['calls'] == random_access.CALLS and cold['p50_us'] > 0
    assert any(' cold ' in ln for ln in lines) and any(' warm ' in ln for ln in lines)
    md = random_access.render_md({'random_access': {'rows': [warm, cold], 'tol': 1e-12,
                                                    'memory_bound_bytes': 1}, 'footer': {}})
    assert '| torque_free_triaxial | warm |' in md and '| torque_free_triaxial | cold |' in md
