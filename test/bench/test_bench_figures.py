"""Quoted figures and table stamps: the prose quotes its results files, tables name their commit.

The figures: every marked figure of README.md and doc/*.md is the text its results file
gives, every defined figure is quoted, and the checker names a drifted figure, an unknown
name and a missing results file, which ``--write`` fills. The stamps: a run's footer names
its commit; the staleness check, on a small git history made here, counts the commits that
changed the measured code (its imports included) and not those that changed docstrings
only; ``rigidrot_bench --stale`` runs on this checkout.
"""

import json
import os
from pathlib import Path
import shutil
import subprocess

import pytest

from rigidrot_ros.bench import common, figures, stamps
from ros_helpers import script

ROOT = Path(__file__).resolve().parents[2]


def test_every_quoted_figure_is_what_its_results_file_gives():
    quoted = figures.quoted(ROOT)
    assert len(quoted) >= 15 and {'README.md'} <= {q[0] for q in quoted}
    assert figures.check(ROOT) == [], 'python -m rigidrot_ros.bench.figures --write'


def test_every_figure_defined_is_quoted_somewhere():
    assert {q[2] for q in figures.quoted(ROOT)} == set(figures.FIGURES)


def test_numbers_are_written_as_the_prose_writes_them():
    xs = (0.0, 5.584e-15, 0.6924, 4.786, 67.81, 308.3, 999.7, 12_502.0, 1.3692e7, -2.5e-4, 1.0)
    assert [figures.number(x) for x in xs] == [
        '0', '5.58e-15', '0.692', '4.79', '67.8', '308', '1 000', '12 500', '1.37e7', '-2.5e-4',
        '1']
    assert figures.count(1228) == '1 228' and figures.count(60000) == '60 000'
    assert figures.span([4.786, 1.527, 2.0], ' ms') == '1.53–4.79 ms'
    assert figures.span([100.0, 100.0], ' %') == '100 %'


def test_the_check_names_drift_unknown_names_and_missing_files_and_write_fills(tmp_path):
    (tmp_path / 'doc' / 'bench' / 'ratios').mkdir(parents=True)
    shutil.copy(ROOT / figures.RATIOS, tmp_path / figures.RATIOS)
    good = figures.compute('ratios.stream_ms', ROOT)
    (tmp_path / 'README.md').write_text(
        f'a <!--fig ratios.stream_ms-->{good}<!--/fig--> b\n'
        'c <!--fig ratios.max_error-->3.0e-15 rad<!--/fig--> d\n'
        'e <!--fig ratios.nothing-->1 s<!--/fig-->\n', encoding='utf-8')
    (tmp_path / 'doc' / 'page.md').write_text(
        'f <!--fig generate.hour_s-->33 s<!--/fig-->\n', encoding='utf-8')
    problems = figures.check(tmp_path)
    assert len(problems) == 3, problems
    assert problems[0].startswith("README.md:2: ratios.max_error: quoted '3.0e-15 rad', "
                                  'the results say ')
    assert problems[1] == ('README.md:3: ratios.nothing: no such figure '
                           '(rigidrot_ros/bench/figures.py)')
    assert problems[2].startswith('doc/page.md:1: generate.hour_s: its results file '
                                  'doc/bench/results.json: ')
    assert figures.write(tmp_path) == ['README.md']
    text = (tmp_path / 'README.md').read_text(encoding='utf-8')
    assert figures.compute('ratios.max_error', ROOT) + '<!--/fig-->' in text
    assert '1 s<!--/fig-->' in text and 'a <!--fig ratios.stream_ms-->' in text
    assert len(figures.check(tmp_path)) == 2


def test_a_run_footer_names_the_commit_it_measured(tmp_path):
    got = common.measured_commit()
    if (ROOT / '.git').exists():
        assert len(got['commit']) == 40 and isinstance(got['changes'], bool)
        # a folder inside a checkout (an installed copy in a venv there) is not one
        assert common.measured_commit(str(ROOT / 'doc')) == {}
    assert common.measured_commit(str(tmp_path)) == {}
    assert common.commit_text({}) == 'commit not recorded'
    assert common.commit_text({'commit': 'a' * 40, 'changes': True}) == (
        'commit aaaaaaaaaaaa with uncommitted changes')
    assert common.commit_text({'commit': 'b' * 40, 'commit_backfilled': True}) == (
        'added at commit bbbbbbbbbbbb')


def _git(root, *args):
    env = dict(os.environ, GIT_AUTHOR_NAME='t', GIT_AUTHOR_EMAIL='t@example.org',
               GIT_COMMITTER_NAME='t', GIT_COMMITTER_EMAIL='t@example.org')
    out = subprocess.run(['git', *args], cwd=root, env=env, capture_output=True, text=True,
                         check=True)
    return out.stdout.strip()


def _commit(root, message, files):
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding='utf-8')
    _git(root, 'add', '-A')
    _git(root, 'commit', '-q', '-m', message)
    return _git(root, 'rev-parse', 'HEAD')


def test_a_table_is_stale_after_a_real_change_to_what_it_measures(tmp_path):
    """wp measures the core; node_khz a module of ros that imports the core."""
    _git(tmp_path, 'init', '-q')
    a = _commit(tmp_path, 'code', {
        'rigidrot_ros/__init__.py': '"""Pkg."""\n',
        'rigidrot_ros/core/__init__.py': '"""Core."""\nfrom .a import f\n',
        'rigidrot_ros/core/a.py': '"""A."""\n\n\ndef f():\n    """F."""\n    return 1\n',
        'rigidrot_ros/ros/__init__.py': '"""Ros."""\n',
        'rigidrot_ros/ros/n.py': 'from rigidrot_ros.core import a\nX = a.f()\n'})
    foot = {'date': 'd', 'commit': a}
    _commit(tmp_path, 'results', {
        'doc/bench/results.json': json.dumps({'footer_wp_run': foot,
                                              'footer_node_khz_run': foot,
                                              'footer_random_access_run': {'date': 'd'}}),
        'doc/bench/wp.md': 't', 'doc/bench/node_khz.md': 't', 'doc/bench/random_access.md': 't',
        'doc/bench/other.md': 'not a part: no table'})
    _commit(tmp_path, 'docstrings only', {
        'rigidrot_ros/core/a.py': '"""A, said better."""\n\n\ndef f():\n    """F, too."""\n'
                                  '    # and a comment\n    return 1\n'})
    _commit(tmp_path, 'ros code', {
        'rigidrot_ros/ros/n.py': 'from rigidrot_ros.core import a\nX = a.f() + 1\n'})
    _commit(tmp_path, 'core code', {
        'rigidrot_ros/core/a.py': '"""A."""\n\n\ndef f():\n    return 2\n'})
    measured = {'wp': ('rigidrot_ros.core',), 'node_khz': ('rigidrot_ros.ros.n',),
                'random_access': ('rigidrot_ros.core',)}.get
    assert stamps.code_files(('rigidrot_ros.ros.n',), str(tmp_path)) == [
        'rigidrot_ros/__init__.py', 'rigidrot_ros/core/__init__.py', 'rigidrot_ros/core/a.py',
        'rigidrot_ros/ros/__init__.py', 'rigidrot_ros/ros/n.py']
    rows = {r['table']: r for r in stamps.stale(str(tmp_path), ('doc/bench',), measured)}
    assert sorted(rows) == ['doc/bench/node_khz.md', 'doc/bench/random_access.md',
                            'doc/bench/wp.md']
    assert [s for _, s in rows['doc/bench/wp.md']['since']] == ['core code']
    assert [s for _, s in rows['doc/bench/node_khz.md']['since']] == ['core code', 'ros code']
    assert rows['doc/bench/wp.md']['status'] == 'stale'
    assert rows['doc/bench/random_access.md']['status'] == 'unstamped'
    _git(tmp_path, 'reset', '-q', '--hard', 'HEAD~2')        # before the two code changes
    rows = {r['table']: r for r in stamps.stale(str(tmp_path), ('doc/bench',), measured)}
    assert rows['doc/bench/wp.md']['status'] == rows['doc/bench/node_khz.md']['status'] == \
        'current'


def test_rigidrot_bench_stale_lists_every_committed_table():
    out = subprocess.run([script('rigidrot_bench'), '--stale', '--strict'],
                         capture_output=True, text=True, timeout=120)
    if not (ROOT / '.git').exists():
        assert out.returncode == 2 and 'not a git checkout' in out.stderr
        return
    tables = sorted(str(p.relative_to(ROOT)) for folder in stamps.FOLDERS
                    for p in (ROOT / folder).glob('*.md'))
    heads = sorted(line.split(':')[0] for line in out.stdout.splitlines()
                   if line.startswith('doc/'))
    assert heads == tables, out.stderr
    last = out.stdout.splitlines()[-1]
    assert last.endswith(('are current', 'or not stamped'))
    assert out.returncode == (0 if last.endswith('are current') else 1), out.stderr


@pytest.mark.parametrize('args, needs', [(['--strict'], '--stale'),
                                         (['--results', 'doc/bench'], '--stale'),
                                         (['--write'], '--figures')])
def test_the_check_options_need_their_check(args, needs):
    out = subprocess.run([script('rigidrot_bench'), *args], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 2 and out.stderr.count('\n') == 1
    assert needs in out.stderr and 'Traceback' not in out.stderr


def test_rigidrot_bench_figures_checks_this_checkout():
    out = subprocess.run([script('rigidrot_bench'), '--figures'], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.startswith('all ') and 'quoted figures are their results' in out.stdout
