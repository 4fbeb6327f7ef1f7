"""Benchmark part ``campaign_inproc``: the in-process MEKF campaign, runs a minute, old and new.

``python -m rigidrot_ros.bench.campaign_inproc [--inproc-runs M] [--inproc-baseline REF]
[--inproc-rounds N]`` (or ``rigidrot_bench --only campaign_inproc``) runs
``doc/campaigns/mekf_tuned.yaml`` (the MEKF demo: M runs of 30 s, default the spec's 100,
20 with ``--quick``) as the command ``rigidrot_campaign SPEC -o DIR --quiet`` in a child
process on the default pool (one worker per core), start-up included (the interpreter,
the imports, the check of the draws, the pool, the runs, report.json and the charts), two
ways in one run, alternated N times (default 3) so that both see the same machine:

- **before**: the code of commit ``REF`` (default :data:`BASELINE`, the last commit
  before the in-memory path: every run's estimates bagged, read back and scored; the
  workers spawned), taken from the checkout's git history into a temporary directory;
- **now**: this checkout (:mod:`rigidrot_ros.campaign.inproc`: the MEKF fed the run as
  arrays, scored from memory, workers forked from the warmed client).

For each: the wall time, runs a minute, the CPU time of the command and its workers (user
+ system), the load average before and after, and the SHA-256 of ``report.json``: both
ways must give the same bytes (:func:`failed`). Then the median phases of a run of the
new path from its ``runs/NNNNNN.time.json`` (generation and filter, scoring, whole run).
On a shared machine the wall time depends on the other load; the CPU time does not as
much, so the table also says what the CPU time alone allows on the machine's cores.
:func:`render_md` writes ``OUT/campaign_inproc.md`` (``doc/bench/campaign_inproc.md``).
"""

import hashlib
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

from rigidrot_ros.bench import common

__all__ = ['NAME', 'NEEDS', 'run', 'main', 'render_md', 'add_arguments', 'failed', 'BASELINE']

NAME = 'campaign_inproc'
NEEDS = ('rclpy', 'yaml')
MEASURES = ('rigidrot_ros.campaign', 'rigidrot_ros.estimators.mekf',
            'rigidrot_ros.estimators.mekf_kernel', 'rigidrot_ros.estimators.mekf_jit',
            'rigidrot_ros.scoring', 'rigidrot_ros.run.feed')

ROOT = common.CHECKOUT
SPEC = os.path.join(ROOT, 'doc', 'campaigns', 'mekf_tuned.yaml')
#: The code before the in-memory path (main when it began): the "before" of the table.
BASELINE = '96aa0ffec3df339e660afe0fd6575c5639c96513'
#: The figure quoted for the quiet machine before this part existed (hand-timed,
#: doc/bench/history/campaign_timing.md, 2026-11-24): runs a minute.
QUOTED_BEFORE = 278.0


def _sha(path):
    with open(path, 'rb') as fh:
        return hashlib.sha256(fh.read()).hexdigest()


def _baseline_tree(ref, tmp):
    """Extract ``rigidrot_ros/`` of commit ``ref`` into ``tmp``; its path, or None."""
    dest = os.path.join(tmp, 'before')
    os.makedirs(dest)
    try:
        archive = subprocess.run(['git', 'archive', ref, 'rigidrot_ros'], cwd=ROOT,
                                 capture_output=True, timeout=120, check=True).stdout
        subprocess.run(['tar', '-x', '-C', dest], input=archive, check=True, timeout=120,
                       capture_output=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return dest


def _campaign(code, spec, out, runs):
    """Run ``rigidrot_campaign`` of ``code`` (a directory on PYTHONPATH) into ``out``.

    From the directory of ``out``: ``python -m`` puts its working directory first on the
    path, so run from a checkout it would import that checkout's code, whatever
    ``PYTHONPATH`` says.
    """
    env = dict(os.environ, PYTHONPATH=code + (os.pathsep + os.environ['PYTHONPATH']
                                              if os.environ.get('PYTHONPATH') else ''))
    shutil.rmtree(out, ignore_errors=True)
    where = subprocess.run([sys.executable, '-c',
                            'import rigidrot_ros; print(rigidrot_ros.__file__)'],
                           env=env, capture_output=True, text=True, cwd=os.path.dirname(out))
    if not os.path.realpath(where.stdout.strip()).startswith(os.path.realpath(code) + os.sep):
        raise RuntimeError(f'campaign_inproc: the way of {code} imports rigidrot_ros from '
                           f'{where.stdout.strip() or where.stderr.strip()[-200:]}')
    load0 = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, '-m', 'rigidrot_ros.tools.campaign', spec, '-o', out,
                           '--quiet'], env=env, capture_output=True, text=True,
                          cwd=os.path.dirname(out))
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f'campaign_inproc: rigidrot_campaign of {code} failed '
                           f'(status {proc.returncode}): {proc.stderr.strip()[-300:]}')
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {'wall_s': wall, 'cpu_s': cpu, 'runs_per_min': 60.0 * runs / wall,
            'load_average': [load0, os.getloadavg()[0]],
            'report_sha256': _sha(os.path.join(out, 'report.json'))}


def _phases(out, runs):
    keys = ('filter_s', 'score_s', 'wall_s')
    rows = []
    for i in range(runs):
        with open(os.path.join(out, 'runs', f'{i:06d}.time.json'), encoding='utf-8') as fh:
            rows.append(json.load(fh))
    return {k: statistics.median(r[k] for r in rows if k in r) for k in keys
            if any(k in r for r in rows)}


def run(quick=False, log=print, inproc_runs=None, inproc_baseline=None,
        inproc_rounds=None):
    """Measure and return the figures (JSON-serialisable); ``quick``: 20 runs, one round."""
    import yaml
    with open(SPEC, encoding='utf-8') as fh:
        doc = yaml.safe_load(fh)
    runs = int(inproc_runs or (20 if quick else doc['runs']))
    rounds = int(inproc_rounds or (1 if quick else 3))
    ref = inproc_baseline or BASELINE
    res = {'quick': bool(quick), 'cores': os.cpu_count(), 'runs': runs, 'rounds': rounds,
           'spec': os.path.relpath(SPEC, ROOT), 'baseline': ref, 'quoted_before': QUOTED_BEFORE,
           'before': [], 'now': []}
    with tempfile.TemporaryDirectory(prefix='rigidrot_bench_inproc_') as tmp:
        doc['runs'] = runs
        spec = os.path.join(tmp, 'mekf_tuned.yaml')
        with open(spec, 'w', encoding='utf-8') as fh:
            yaml.safe_dump(doc, fh)
        old = _baseline_tree(ref, tmp)
        if old is None:
            log(f'campaign_inproc: commit {ref} cannot be read from {ROOT} (not a git '
                f'checkout?): the new path only')
        res['baseline_commit'] = common._git('rev-parse', ref) if old else None
        for r in range(rounds):
            ways = ([('before', old)] if old else []) + [('now', ROOT)]
            for way, code in (ways if r % 2 == 0 else ways[::-1]):
                out = os.path.join(tmp, f'{way}_{r}')
                fig = _campaign(code, spec, out, runs)
                if way == 'now':
                    fig['phases'] = _phases(out, runs)
                res[way].append(fig)
                log(f'campaign_inproc: {way} (round {r + 1}): {runs} runs in '
                    f'{fig["wall_s"]:.1f} s = {fig["runs_per_min"]:.0f} runs/min, CPU '
                    f'{fig["cpu_s"]:.1f} s, load average {fig["load_average"][0]:.1f} -> '
                    f'{fig["load_average"][1]:.1f}, report.json {fig["report_sha256"][:12]}')
    shas = {f['report_sha256'] for w in ('before', 'now') for f in res[w]}
    res['same_report'] = len(shas) == 1
    if res['before']:
        res['ratio'] = (statistics.median(f['runs_per_min'] for f in res['now'])
                        / statistics.median(f['runs_per_min'] for f in res['before']))
        res['ratio_best'] = (max(f['runs_per_min'] for f in res['now'])
                             / max(f['runs_per_min'] for f in res['before']))
        log(f'campaign_inproc: now / before = {res["ratio"]:.2f}× in runs a minute (medians; '
            f'{res["ratio_best"]:.2f}× best against best); report.json '
            f'{"the same bytes" if res["same_report"] else "DIFFERS"}')
    return res


def add_arguments(ap):
    """Add ``--inproc-runs``, ``--inproc-baseline`` and ``--inproc-rounds``."""
    ap.add_argument('--inproc-runs', type=int, metavar='M',
                    help="campaign_inproc: runs a campaign (default: the spec's 100, 20 with "
                         '--quick)')
    ap.add_argument('--inproc-baseline', metavar='REF',
                    help=f'campaign_inproc: the commit measured as "before" (default '
                         f'{BASELINE})')
    ap.add_argument('--inproc-rounds', type=int, metavar='N',
                    help='campaign_inproc: times each way runs, alternated (default 3, 1 '
                         'with --quick)')


def failed(results):
    """Return why the run failed: the two ways' report.json differ."""
    res = results.get(NAME) or {}
    if res and not res.get('same_report', True):
        return ['campaign_inproc: report.json differs between the ways (or rounds)']
    return []


def _rpm(x):
    """Format runs a minute: whole runs from 100 up, else three significant digits."""
    return f'{x:.0f}' if x >= 100 else common.fmt(x)


def _median(figs, key):
    return statistics.median(f[key] for f in figs)


def render_md(results):
    """Return the part's table from merged results (``'campaign_inproc'``), or None."""
    res = results.get(NAME)
    if not res:
        return None
    fmt = common.fmt
    cores = res['cores']
    rows = [('before, quoted: hand-timed on the quiet machine (2026-11-24)', '100', '—',
             f'{fmt(res["quoted_before"])}', '—', '—', '—', '—')]
    what = ('estimates bagged, read back, scored; workers spawned'
            if res['baseline'] == BASELINE else 'the code of that commit')
    labels = {'before': f'before (commit {res.get("baseline_commit", res["baseline"])[:12]}): '
                        f'{what}',
              'now': 'now: the run in memory (arrays), the MEKF compiled, scored from '
                     'memory; workers forked'}
    for way in ('before', 'now'):
        figs = res[way]
        if not figs:
            continue
        loads = [x for f in figs for x in f['load_average']]
        cpu = _median(figs, 'cpu_s')
        rows.append((labels[way], str(res['runs']),
                     ' / '.join(f'{fmt(f["wall_s"])} s' for f in figs),
                     f'**{_rpm(_median(figs, "runs_per_min"))}**',
                     _rpm(max(f['runs_per_min'] for f in figs)), f'{fmt(cpu)} s',
                     _rpm(60.0 * res['runs'] / (cpu / cores)),
                     f'{min(loads):.1f}–{max(loads):.1f}'))
    table = common.md_table(
        ['way', 'runs', 'wall (each round)', 'runs/min (median)', 'runs/min (best)',
         'CPU (median)', f'runs/min the CPU time allows on {cores} cores', 'load average'],
        rows)
    notes = []
    if 'ratio' in res:
        best = (f'; {res["ratio_best"]:.2f}× best against best' if 'ratio_best' in res
                else '')
        notes.append(f'now / before, measured in the same run: **{res["ratio"]:.2f}×** runs a '
                     f'minute (medians{best})')
    notes.append('report.json: ' + ('the same bytes every way and round'
                                    if res['same_report'] else '**differs**'))
    ph = (res['now'][0].get('phases') if res['now'] else None) or {}
    if ph:
        notes.append(f'a run of the new path, medians: generation and filter '
                     f'{fmt(ph.get("filter_s"))} s, scoring {fmt(ph.get("score_s"))} s, the '
                     f'run {fmt(ph.get("wall_s"))} s')
    title = (f'The in-process MEKF campaign (`rigidrot_bench --only campaign_inproc`): '
             f'{res["spec"]} ({res["runs"]} runs of 30 s), `rigidrot_campaign` start to end '
             f'on the default pool, the ways alternated {res["rounds"]}× in one run on '
             f'{cores} cores')
    if res.get('quick'):
        title += '; quick run'
    return common.part_md(results, NAME, title, table + '\n' + common.md_bullets(notes))


def main(argv=None):
    """``python -m rigidrot_ros.bench.campaign_inproc``: this part alone, into ``--out``."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
