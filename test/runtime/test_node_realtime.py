"""The node's scheduling policy (node.realtime) and its frozen heap (node.collector)."""

import gc
import json
import os
import subprocess
import sys
import textwrap

import pytest

from rigidrot_ros.runtime import collector, realtime
from ros_helpers import next_domain_id, ros_env, script


@pytest.mark.parametrize('text, want', [('', realtime.PRIORITY), (' 0 ', 0), ('1', 1),
                                        ('99', 99)])
def test_the_priority_comes_from_the_environment(text, want):
    assert realtime.priority_from_env({'RIGIDROT_RT_PRIORITY': text}) == want
    assert realtime.priority_from_env({}) == realtime.PRIORITY


@pytest.mark.parametrize('text', ['100', '-1', 'high', '1.5'])
def test_a_bad_priority_is_named(text):
    with pytest.raises(ValueError, match=r'RIGIDROT_RT_PRIORITY .*0 \(off\) to 99.*'
                       + repr(text).replace('.', r'\.')):
        realtime.priority_from_env({'RIGIDROT_RT_PRIORITY': text})


def test_off_leaves_the_policy_and_a_refusal_is_one_line(monkeypatch):
    before = realtime.describe()
    assert realtime.request(0) == (False, 'ordinary scheduling (RIGIDROT_RT_PRIORITY=0)')

    def refuse(*args):
        raise PermissionError(1, 'Operation not permitted')
    monkeypatch.setattr(os, 'sched_setscheduler', refuse)
    ok, text = realtime.request(10)
    assert not ok and 'SCHED_FIFO 10 not permitted (Operation not permitted)' in text
    assert '\n' not in text and realtime.describe() == before


_CHILD = textwrap.dedent('''
    import json, os, threading
    from rigidrot_ros.runtime import realtime
    ok, text = realtime.request(7)
    seen = {}
    t = threading.Thread(target=lambda: seen.update(thread=realtime.describe()))
    t.start(); t.join()
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.write(w, realtime.describe().encode()); os._exit(0)
    os.waitpid(pid, 0)
    child = os.read(r, 100).decode()
    print(json.dumps({'ok': ok, 'text': text, 'main': realtime.describe(),
                      'thread': seen['thread'], 'child': child}))
''')


def test_the_policy_holds_for_later_threads_and_children():
    """In a process of its own: SCHED_FIFO where permitted, else the ordinary policy."""
    out = subprocess.run([sys.executable, '-c', _CHILD], capture_output=True, text=True,
                         timeout=60, check=True)
    got = json.loads(out.stdout)
    if got['ok']:
        assert got['text'] == 'real-time scheduling: SCHED_FIFO priority 7'
        assert got['main'] == got['thread'] == 'SCHED_FIFO 7'
    else:
        assert 'not permitted' in got['text']
        assert got['main'] == got['thread'] == 'SCHED_OTHER'
    assert got['child'] == got['main']


def test_the_node_refuses_a_bad_priority_in_one_line():
    env = dict(ros_env(next_domain_id()), RIGIDROT_RT_PRIORITY='fast')
    proc = subprocess.run([script('attitude_node')], env=env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip() == ('attitude_node: RIGIDROT_RT_PRIORITY must be an integer '
                                   "from 0 (off) to 99, got 'fast'")


def _frozen(obj):
    return not any(o is obj for o in gc.get_objects())


@pytest.fixture
def unfreeze():
    yield
    gc.unfreeze()


def test_the_freezer_freezes_at_start_and_once_into_the_first_run(unfreeze):
    now = [100.0]
    fr = collector.Freezer(on=True, clock=lambda: now[0])
    early = []
    early.append(early)                 # a container the collector tracks
    fr.start()
    assert _frozen(early) and fr.freezes == 1
    later = []
    later.append(later)
    assert not fr.poll()                # not armed
    fr.arm()
    now[0] += collector.FREEZE_AFTER_S - 0.01
    assert not fr.poll() and not _frozen(later)
    now[0] += 0.02
    assert fr.poll() and _frozen(later) and fr.freezes == 2
    assert not fr.poll()                # once per arm
    # a second run (a ~/reset): its garbage must stay collectable, so no freeze
    again = []
    again.append(again)
    fr.arm()
    now[0] += 2 * collector.FREEZE_AFTER_S
    assert not fr.poll() and not _frozen(again) and fr.freezes == 2


def test_the_freezer_off_does_nothing(unfreeze, monkeypatch):
    monkeypatch.setenv('RIGIDROT_GC_FREEZE', '0')
    fr = collector.Freezer()
    obj = []
    obj.append(obj)
    fr.start()
    fr.arm()
    assert not fr.poll() and not _frozen(obj) and fr.freezes == 0
    monkeypatch.setenv('RIGIDROT_GC_FREEZE', '1')
    assert collector.Freezer().on


@pytest.fixture
def thresholds():
    saved = gc.get_threshold()
    yield saved
    gc.set_threshold(*saved)


class _Cycle:
    """A container in a reference cycle (only the collector frees it)."""

    def __init__(self):
        self.me = self


def test_passes_take_generation_0_over_and_give_it_back(thresholds, monkeypatch):
    gc.set_threshold(700, 10, 10)
    ps = collector.Passes(on=True)
    ps.start()
    ps.start()                                          # idempotent
    assert gc.get_threshold() == (collector.SAFETY_THRESHOLD, 10, 10) and ps.active
    ps.stop()
    ps.stop()
    assert gc.get_threshold() == (700, 10, 10) and not ps.active
    assert ps.poll() is None                            # stopped: never collects
    monkeypatch.setenv('RIGIDROT_GC_SCHEDULE', '0')
    off = collector.Passes()
    off.start()
    assert not off.on and gc.get_threshold() == (700, 10, 10) and off.poll() is None
    monkeypatch.delenv('RIGIDROT_GC_SCHEDULE')
    assert collector.Passes().on


def test_a_poll_runs_the_pass_that_is_due_and_frees_the_cycles(thresholds):
    """Cyclic garbage outlives 700 allocations (no automatic pass) until a poll collects it."""
    import weakref
    gc.set_threshold(700, 10, 10)
    gc.collect()
    ps = collector.Passes(on=True)
    ps.start()
    try:
        dead = weakref.ref(_Cycle())                    # garbage, kept alive by its cycle
        keep = [[] for _ in range(3 * collector.STEP)]  # allocations past the default
        assert dead() is not None                       # threshold: no automatic pass
        assert gc.get_count()[0] >= collector.STEP
        assert ps.poll() is not None and dead() is None and gc.get_count()[0] < collector.STEP
        assert ps.poll() is None                        # nothing pending: no pass
        keep.extend([[] for _ in range(2 * collector.STEP)])
        assert ps.poll(early=False) is None             # a call with no room: not yet
        keep.extend([[] for _ in range(collector.LATE_STEP)])
        assert ps.poll(early=False) is not None         # overdue: at the end of any call
        keep.clear()
        refs = []
        for i in range(300):                            # the interpreter's mix of passes
            refs.append(weakref.ref(_Cycle()))
            keep.clear()                                # freed first: its count goes
            keep.extend([[] for _ in range(2 * collector.STEP)])
            assert ps.poll() is not None
        assert len(keep) == 2 * collector.STEP and ps.passes[0] > ps.passes[1] > ps.passes[2] > 0
        assert sum(r() is not None for r in refs) <= 1  # memory bounded: all but the last
    finally:
        ps.stop()
