"""node_khz's report of where the time went: the longest call's phases, gc passes, policy."""

from rigidrot_ros.bench import node_khz


def _diags(t0, phases_by_s):
    out = []
    for s, (call_us, phases, gc) in phases_by_s.items():
        out.append({'stamp_ns': t0 + s * 10**9, 'level': 0, 'message': '',
                    'values': {'ticks_published': str(1000 * s), 'ticks_missed': '0',
                               'call_max_us': call_us, 'call_max_phases': phases,
                               'gc_collections': gc, 'gc_max_us': '12.5',
                               'scheduling': 'SCHED_FIFO 10'}})
    return out


def test_the_worst_windows_phases_and_the_gc_passes_past_the_warm_up():
    t0 = 10**18
    diags = _diags(t0, {
        1: ('9000.0', 'wake 1.0, batch 8999.0 (imu 8)', '5/1/1'),    # in the warm-up
        3: ('1500.0', 'wake 1200.0, batch 300.0 (imu 64)', '3/0/0'),
        4: ('2500.0', 'wake 100.0, collect 2400.0 (truth 9 owed/0 now)', '2/1/0'),
        5: ('800.0', 'wake 800.0', '1/0/0'),
    })
    got = node_khz.diag_figures(diags, 1000.0, 2.0, 4.0, t0_ns=t0)
    assert got['call_max_us'] == {'median': 1500.0, 'worst': 2500.0}
    assert got['call_max_phases'] == 'wake 100.0, collect 2400.0 (truth 9 owed/0 now)'
    assert got['gc_collections'] == [6, 1, 0]
    assert got['scheduling'] == 'SCHED_FIFO 10'
    res = {'node_khz': {'seconds': 4.0, 'warmup_s': 2.0, 'rates': [node_khz.summarize(
        {'rate_hz': 1000.0, 'seconds': 4.0, 'warmup_s': 2.0, 'diags': diags, 'bag': None,
         'exit_code': 0, 'stderr_tail': ''})]}, 'footer': {}}
    md = node_khz.render_md(res)
    assert 'collect 2400.0 (truth 9 owed/0 now)' in md and '6/1/0 (gen 0/1/2)' in md
    assert '| SCHED_FIFO 10 |' in md


def test_a_node_without_the_keys_reads_na():
    t0 = 10**18
    diags = [{'stamp_ns': t0 + s * 10**9, 'level': 0, 'message': '',
              'values': {'ticks_published': str(1000 * s)}} for s in range(1, 8)]
    got = node_khz.diag_figures(diags, 1000.0, 2.0, 4.0, t0_ns=t0)
    assert got['call_max_us'] is None and got['call_max_phases'] is None
    assert got['gc_collections'] is None and got['scheduling'] is None
    lines = []
    node_khz._log_rate(node_khz.summarize(
        {'rate_hz': 1000.0, 'seconds': 4.0, 'warmup_s': 2.0, 'diags': diags, 'bag': None,
         'exit_code': 0, 'stderr_tail': ''}), lines.append)
    assert 'longest call median/worst n/a us (worst: n/a); gc passes n/a; scheduling n/a' \
        in lines[-1]
