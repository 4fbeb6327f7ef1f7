"""Measured figures quoted in the prose, each filled from the results file it comes from.

``README.md`` and the pages ``doc/*.md`` quote a measured figure only between two markers,
invisible once rendered::

    costs <!--fig ratios.stream_ms-->1.53–4.79 ms<!--/fig--> a stream

``ratios.stream_ms`` names an entry of :data:`FIGURES`: a results file (relative to the
checkout) and a function of its contents that gives the text. ``rigidrot_bench --figures``
(or ``python -m rigidrot_ros.bench.figures``) reads every marked figure, computes it from
its source and lists each one that differs, names no figure or has no results file (exit
1; 0 when all agree); with ``--write`` it first writes each computed text in place, so
after a benchmark run one command brings the prose to the new results. A test runs the
check: a quoted figure cannot drift from its results file.
"""

import json
import math
import os
import re
import sys

from rigidrot_ros.bench import common
from rigidrot_ros.tools.cli import OneLineParser

__all__ = ['FIGURES', 'MARKER', 'FILES', 'number', 'count', 'span', 'quoted', 'check', 'write',
           'main']

#: A marked figure: its name, then its text.
MARKER = re.compile(r'<!--fig ([A-Za-z0-9_.]+)-->(.*?)<!--/fig-->', re.S)
#: The prose that quotes figures (globs relative to the checkout).
FILES = ('README.md', 'doc/*.md')
RESULTS = 'doc/bench/results.json'
RATIOS = 'doc/bench/ratios/results.json'

#: ``{name: (results file, function of its contents -> text)}``.
FIGURES = {}


def figure(name, source):
    """Register the decorated function as figure ``name``, computed from ``source``."""
    def register(fn):
        FIGURES[name] = (source, fn)
        return fn
    return register


# -- how figures are written ----------------------------------------------------------------

def number(x, digits=3):
    """Write ``x`` as the prose does: ``digits`` significant digits, ``12 500``, ``5.58e-15``."""
    if x == 0:
        return '0'
    r = float(f'{x:.{digits}g}')            # rounded to its significant digits
    if 1e-3 <= abs(r) < 1e6:
        if abs(r) >= 10 ** (digits - 1) and r == int(r):
            return f'{int(r):,}'.replace(',', ' ')
        return f'{r:.{digits}g}'
    mant, exp = f'{x:.{digits - 1}e}'.split('e')
    mant = mant.rstrip('0').rstrip('.') if '.' in mant else mant
    return f'{mant}e{int(exp)}'


def count(n):
    """Write a count exactly, in groups of three digits: ``60 000``."""
    return f'{int(n):,}'.replace(',', ' ')


def span(values, unit='', digits=3):
    """Write ``'lo–hi unit'`` over ``values`` (``'v unit'`` where both ends read the same)."""
    lo, hi = number(min(values), digits), number(max(values), digits)
    text = lo if lo == hi else f'{lo}–{hi}'
    return f'{text}{unit}'


# -- the speed ratios (doc/bench/ratios) ----------------------------------------------------

def _timed(res, part=None):
    return [r for r in res['ratios'] if math.isfinite(r['exact_cpu_s'])
            and (part is None or r['part'] == part)]


@figure('ratios.stream_ms', RATIOS)
def _stream_ms(res):
    return span([1e3 * r['exact_cpu_s'] for r in _timed(res, 'stream 100 Hz')], ' ms')


@figure('ratios.stream_speedup', RATIOS)
def _stream_speedup(res):
    return span([r['speedup_vs_dop853'] for r in _timed(res, 'stream 100 Hz')], '×')


@figure('ratios.max_error', RATIOS)
def _max_error(res):
    return number(max(r['exact_error_rad'] for r in _timed(res))) + ' rad'


@figure('ratios.query_ms', RATIOS)
def _query_ms(res):
    return span([1e3 * r['exact_cpu_s'] for r in _timed(res, 'one query')], ' ms')


@figure('ratios.query_speedup', RATIOS)
def _query_speedup(res):
    return span([r['speedup_vs_dop853'] for r in _timed(res, 'one query')], '×')


#: The scenes of the ratios that are not the presets' axisymmetric and sphere bodies.
_NOT_AXISYMMETRIC = ('torque_free_triaxial', 'spacecraft')


@figure('ratios.tick_p50', RATIOS)
def _tick_p50(res):
    """Give the p50 of a 100 Hz tick in a tight loop on the axisymmetric and sphere presets."""
    return span([r['p50_us'] for r in res['ratios'] if r['part'] == 'tick 100 Hz tight loop'
                 and r['scene'] not in _NOT_AXISYMMETRIC], ' µs')


# -- the torque-free triaxial body ------------------------------------------------------------

def _cost(res, model):
    return next(r for r in res['triaxial']['cost'] if r['model'] == model)


_MODELS = (('triaxial', 'torque-free-triaxial'), ('axisymmetric', 'torque-free-axisymmetric'))

for _key, _model in _MODELS:
    for _field, _scale, _unit in (('scalar_us', 1.0, ' µs'), ('scalar_at_1e5_s_us', 1.0, ' µs'),
                                  ('batch_us_per_sample', 1.0, ' µs'), ('setup_s', 1e3, ' ms')):
        figure(f'triaxial.{_key}.{_field}', RESULTS)(
            lambda res, m=_model, f=_field, k=_scale, u=_unit: number(k * _cost(res, m)[f]) + u)


# -- across the envelope ----------------------------------------------------------------------

_PATHS = (('hypergeometric-flint', '₁F₁ path'), ('taylor-series-flint', 'Taylor path'),
          ('adiabatic-series', 'adiabatic series'))


def _us(x):
    return f'{number(x / 1e3)} ms' if x >= 1e3 else f'{number(x)} µs'


@figure('envelope.held', RESULTS)
def _env_held(res):
    """Give how many of the envelope's scenes held their tol, of how many."""
    ok = sum(r['status'] == 'ok' for r in res['envelope'])
    n = len(res['envelope'])
    return f'all {n}' if ok == n else f'{ok} of {n}'


@figure('envelope.worst_bound', RESULTS)
def _env_bound(res):
    return number(max(r['max_bound_rad'] for r in res['envelope'])) + ' rad'


def _both(res):
    return [r['vs_other_representation_rad'] for r in res['envelope']
            if math.isfinite(r['vs_other_representation_rad'])]


@figure('envelope.scenes', RESULTS)
def _env_scenes(res):
    return count(len(res['envelope']))


@figure('envelope.two_representations', RESULTS)
def _env_both(res):
    """Give how many scenes were built in two representations."""
    return f'{count(len(_both(res)))} scenes'


@figure('envelope.agreement', RESULTS)
def _env_agree(res):
    """Give the largest difference between two representations of one scene."""
    return f'{number(max(_both(res)))} rad'


@figure('envelope.cost', RESULTS)
def _env_cost(res):
    """Give the median p50 and the worst p99 of a tick on each path, and its scene count."""
    parts = []
    for i, (method, label) in enumerate(_PATHS):
        rows = [r for r in res['envelope'] if r['method'] == method]
        p50 = sorted(r['p50_us'] for r in rows)
        median = (p50[(len(p50) - 1) // 2] + p50[len(p50) // 2]) / 2
        n = f'{len(rows)} scenes' if i == 0 else f'{len(rows)}'
        parts.append(f'{label} ({n}) {_us(median)} / {_us(max(r["p99_us"] for r in rows))}')
    return ', '.join(parts)


@figure('envelope.first_query', RESULTS)
def _env_first(res):
    return f'{number(max(r["first_query_s"] for r in res["envelope"]))} s'


# -- random access ----------------------------------------------------------------------------

def _access(res, horizon):
    """Return the warm rows at ``horizon``: the prose quotes those (and says what is cold)."""
    return [r for r in res['random_access']['rows'] if r['horizon_s'] == horizon
            and r.get('process', 'warm') == 'warm']


@figure('random_access.p50', RESULTS)
def _access_p50(res):
    return span([r['p50_us'] for r in _access(res, 1e3)], ' µs')


@figure('random_access.p99_max', RESULTS)
def _access_p99(res):
    return number(max(r['p99_us'] for r in _access(res, 1e3))) + ' µs'


@figure('random_access.far_p50', RESULTS)
def _access_far(res):
    """Give the median far out where the dense output needs exact evaluations (anchors)."""
    return span([r['p50_us'] for r in _access(res, 1e5) if r['exact_anchors']], ' µs')


@figure('random_access.engine_load', RESULTS)
def _engine_load(res):
    """Give the time the random-access run took to load the dense output's engine."""
    return f'{number(res["random_access"]["engine"]["load_s"])} s'


@figure('random_access.memory', RESULTS)
def _access_memory(res):
    return number(res['random_access']['memory_bound_bytes'] / 1e6) + ' MB'


# -- the node at kHz rates ------------------------------------------------------------------

@figure('node_khz.table', RESULTS)
def _khz_table(res):
    rows = []
    for r in res['node_khz']['rates']:
        b, d = r['bag'], r['diagnostics']
        rows.append([f'{number(r["rate_hz"] / 1e3)} kHz',
                     f'{number(b["delivered_pct"], 4)} % ({count(b["ticks_missed"])} missed)',
                     f'{count(b["gyro_late"])} of {count(b["gyro_asked"])}',
                     _na_count(b.get('gyro_late_machine')),
                     f'{number(d["tick_p99_us"]["median"])} µs',
                     f'{number(d["latency_p99_us"]["median"])} µs'])
    # blank lines around the table: the markers' comment lines stay out of it
    return '\n\n' + common.md_table(['rate', 'ticks delivered',
                                     'late gyro samples (> 1 period)',
                                     'of them in machine stalls', 'whole-tick p99',
                                     'wake-up p99'], rows) + '\n'


def _na_count(n):
    return 'n/a' if n is None else count(n)


@figure('node_khz.seconds', RESULTS)
def _khz_seconds(res):
    return f'{number(res["node_khz"]["seconds"])} s'


@figure('node_khz.stalls', RESULTS)
def _khz_stalls(res):
    """Give the machine's stalls the probe saw beside the node, per rate, and the longest."""
    rates = res['node_khz']['rates']
    counts = [r['bag'].get('machine_stalls') for r in rates]
    longest = max((r['bag'].get('machine_stall_max_us') or 0.0) for r in rates)
    names = [f'{number(r["rate_hz"] / 1e3)} kHz' for r in rates]
    per = ', '.join(f'{count(c)} at {n}' for c, n in zip(counts, names))
    return f'{per}; the longest {number(longest)} µs'


# -- offline generation -----------------------------------------------------------------------

def _generation(res):
    return res['generate']['generation']


def _inproc(res, way, key):
    """Return the median of ``key`` over the rounds of ``way`` ('before', 'now')."""
    import statistics
    return statistics.median(r[key] for r in res['campaign_inproc'][way])


@figure('campaign_inproc.cpu', RESULTS)
def _inproc_cpu(res):
    return f'{number(_inproc(res, "now", "cpu_s"))} s'


@figure('campaign_inproc.cpu_before', RESULTS)
def _inproc_cpu_before(res):
    return f'{number(_inproc(res, "before", "cpu_s"))} s'


@figure('campaign_inproc.cpu_ratio', RESULTS)
def _inproc_cpu_ratio(res):
    return f'{number(_inproc(res, "before", "cpu_s") / _inproc(res, "now", "cpu_s"), 2)}×'


@figure('campaign_inproc.cpu_runs_min', RESULTS)
def _inproc_cpu_runs(res):
    c = res['campaign_inproc']
    return number(c['runs'] * 60.0 * c['cores'] / _inproc(res, 'now', 'cpu_s'))


@figure('campaign_inproc.runs_min', RESULTS)
def _inproc_runs(res):
    return number(_inproc(res, 'now', 'runs_per_min'))


@figure('campaign_inproc.runs_min_before', RESULTS)
def _inproc_runs_before(res):
    return number(_inproc(res, 'before', 'runs_per_min'))


@figure('campaign_inproc.ratio', RESULTS)
def _inproc_ratio(res):
    return f'{number(res["campaign_inproc"]["ratio"])}×'


@figure('campaign_inproc.load', RESULTS)
def _inproc_load(res):
    c = res['campaign_inproc']
    loads = [x for way in ('before', 'now') for r in c[way] for x in r['load_average']]
    return f'{min(loads):.1f}–{max(loads):.1f}'


@figure('generate.hour_s', RESULTS)
def _gen_wall(res):
    return f'{number(_generation(res)["wall_s"])} s'


@figure('generate.speedup', RESULTS)
def _gen_speedup(res):
    return f'{number(_generation(res)["speedup"])}×'


@figure('generate.peak_mb', RESULTS)
def _gen_rss(res):
    return f'{number(_generation(res)["peak_rss_mb"])} MB'


@figure('generate.load', RESULTS)
def _gen_load(res):
    return f'{_generation(res)["load_average"]:.1f}'


@figure('generate.vs_previous', RESULTS)
def _gen_vs_previous(res):
    gen = _generation(res)
    base = gen['baseline']
    return (f'{number(gen["speedup"] / base["speedup"])}× the speed of the previous code '
            f'(commit {base["commit"][:12]}, {number(base["speedup"])}× real time) run '
            f'alternately in the same run, {number(base["cpu_s"] / gen["cpu_s"])}× less CPU')


for _variant in ('replay_5x', 'paced_process', 'paced_long_lived'):
    figure(f'campaign_ros.{_variant}', RESULTS)(
        lambda res, v=_variant: number(res['campaign_ros']['variants'][v]['runs_per_min']))


@figure('campaign_ros.in_process', RESULTS)
def _ros_in_process(res):
    return number(res['campaign_ros']['in_process']['runs_per_min'])


for _sensor in ('gyro', 'accel'):
    for _how, _key in (('single', 'single_us'), ('block', 'block_us')):
        figure(f'generate.{_sensor}_{_how}_us', RESULTS)(
            lambda res, s=_sensor, k=_key: number(res['generate']['sensors'][
                {'gyro': 'gyro', 'accel': 'accelerometer'}[s]][k]) + ' µs')


# -- the Monte Carlo campaigns of doc/campaigns (their report.json) --------------------------

#: A campaign's results: the ``report.json`` of ``rigidrot_campaign doc/campaigns/<spec>.yaml``.
CAMPAIGN = 'doc/campaigns/reports/{}.json'


def _bounds(pair, fmt):
    return f'[{pair[0]:{fmt}}, {pair[1]:{fmt}}]'


#: ``(field, text of the report)``: every campaign quotes some of these.
_CAMPAIGN_FIGURES = (
    ('anees', lambda r: f'{r["anees"]["value"]:#.4g}'),
    ('anees_bounds', lambda r: _bounds(r['anees']['bounds_95'], '#.4g')),
    ('samples', lambda r: count(r['anees']['samples'])),
    ('steps', lambda r: count(r['steps'])),
    ('band', lambda r: _bounds(r['mc_nees']['band_95'], '.2f')),
    ('inside', lambda r: f'{100 * r["mc_nees"]["fraction_inside"]:.1f} %'),
    ('run_band', lambda r: _bounds(r['per_run_anees']['bounds_95'], '.2f')),
    ('runs_inside', lambda r: f'{100 * r["per_run_anees"]["fraction_inside"]:.0f} %'),
    ('rms_arcsec', lambda r: f'{number(math.degrees(r["rms_error"]["overall_rad"]) * 3600)}″'),
)

#: The campaigns quoted, and which of their figures.
_CAMPAIGNS = {
    'mekf_tuned': ('anees', 'anees_bounds', 'samples', 'steps', 'band', 'inside', 'run_band',
                   'runs_inside', 'rms_arcsec'),
    'mekf_mistuned': ('anees', 'anees_bounds', 'inside', 'runs_inside'),
}

for _name, _fields in _CAMPAIGNS.items():
    for _field, _fn in _CAMPAIGN_FIGURES:
        if _field in _fields:
            figure(f'campaign.{_name}.{_field}', CAMPAIGN.format(_name))(_fn)


# -- reading and checking the prose -----------------------------------------------------------

def _files(root):
    import glob
    out = []
    for pattern in FILES:
        out += sorted(glob.glob(os.path.join(root, pattern)))
    return out


def quoted(root=common.CHECKOUT):
    """Return ``[(path relative to root, line, name, text)]`` of every marked figure."""
    out = []
    for path in _files(root):
        with open(path, encoding='utf-8') as fh:
            text = fh.read()
        for m in MARKER.finditer(text):
            line = text.count('\n', 0, m.start()) + 1
            out.append((os.path.relpath(path, root), line, m.group(1), m.group(2)))
    return out


def compute(name, root=common.CHECKOUT, _cache=None):
    """Return figure ``name``'s text from its results file; raise KeyError, OSError, ValueError."""
    source, fn = FIGURES[name]
    cache = {} if _cache is None else _cache
    if source not in cache:
        with open(os.path.join(root, source), encoding='utf-8') as fh:
            cache[source] = json.load(fh)
    return fn(cache[source])


def check(root=common.CHECKOUT):
    """Return one line per marked figure that is not its results' text (none: all agree)."""
    problems, cache = [], {}
    for path, line, name, text in quoted(root):
        where = f'{path}:{line}: {name}'
        if name not in FIGURES:
            problems.append(f'{where}: no such figure (rigidrot_ros/bench/figures.py)')
            continue
        try:
            want = compute(name, root, cache)
        except OSError as exc:
            problems.append(f'{where}: its results file {FIGURES[name][0]}: '
                            f'{exc.strerror or exc}')
            continue
        except (KeyError, ValueError, TypeError) as exc:
            problems.append(f'{where}: not in {FIGURES[name][0]} ({type(exc).__name__}: {exc})')
            continue
        if text != want:
            problems.append(f'{where}: quoted {text.strip()!r}, the results say '
                            f'{want.strip()!r} ({FIGURES[name][0]})')
    return problems


def write(root=common.CHECKOUT):
    """Write every marked figure's text from its results file; return the files changed."""
    changed, cache = [], {}
    for path in _files(root):
        with open(path, encoding='utf-8') as fh:
            text = fh.read()

        def fill(m):
            try:
                return f'<!--fig {m.group(1)}-->{compute(m.group(1), root, cache)}<!--/fig-->'
            except (KeyError, OSError, ValueError, TypeError):
                return m.group(0)           # left as it is: check() names it
        new = MARKER.sub(fill, text)
        if new != text:
            with open(path, 'w', encoding='utf-8') as fh:
                fh.write(new)
            changed.append(os.path.relpath(path, root))
    return changed


def add_arguments(ap):
    """Add ``--write`` (shared with ``rigidrot_bench --figures``)."""
    ap.add_argument('--write', action='store_true',
                    help='first write every quoted figure from its results file')


def run(opts, root=common.CHECKOUT):
    """Check (and with ``--write`` first fill) the quoted figures; the exit status."""
    if opts.write:
        for path in write(root):
            print(f'wrote {path}')
    problems = check(root)
    for line in problems:
        print(line)
    n = len(quoted(root))
    print(f'{len(problems)} of {n} quoted figures differ from their results files' if problems
          else f'all {n} quoted figures are their results files\' ({", ".join(FILES)})')
    return 1 if problems else 0


def main(argv=None):
    """``python -m rigidrot_ros.bench.figures``: the same as ``rigidrot_bench --figures``."""
    ap = OneLineParser(prog='python -m rigidrot_ros.bench.figures',
                       description=__doc__.splitlines()[0])
    add_arguments(ap)
    return run(ap.parse_args(argv))


if __name__ == '__main__':
    sys.exit(main())
