"""Run benchmark parts and write their results: what the command and each part's main share.

:func:`run_parts` runs parts of the registry (:mod:`rigidrot_ros.bench.registry`), merges
their results into ``OUT/results.json`` and writes each part's data files, charts and
Markdown table (``OUT/<part>.md``); :func:`redraw` writes the charts and tables from a
results file alone. Parts never import this module at module level (their ``main`` does,
when run alone), nor the command :mod:`rigidrot_ros.bench.run`.
"""

import inspect
import json
import os
import sys
import time

from rigidrot_ros.bench import common, registry
from rigidrot_ros.tools.cli import OneLineParser


def install_hint(missing):
    """Return the line that says which extra to install for the ``missing`` modules."""
    return (f'rigidrot_bench needs {" and ".join(missing)}, which a plain `pip install .` '
            "does not install: pip install -e '.[bench]' in the checkout (or pip install "
            f'{" ".join(missing)})')


def missing_modules(modules):
    """Return the names among ``modules`` that cannot be imported."""
    out = []
    for name in modules:
        try:
            __import__(name)
        except ImportError:
            out.append(name)
    return out


def _fail(message):
    print(f'rigidrot_bench: {message}', file=sys.stderr)
    return 2


def clock_log():
    """Return a ``log`` that prefixes each line with the seconds since it was made."""
    t0 = time.monotonic()

    def log(line):
        print(f'[{time.monotonic() - t0:7.1f} s] {line}', flush=True)
    return log


def add_part_arguments(ap, modules):
    """Add the options of every part module in ``modules`` that has ``add_arguments``."""
    for mod in modules:
        if hasattr(mod, 'add_arguments'):
            mod.add_arguments(ap)


def _kwargs(mod, opts, results):
    """Return the keywords of ``mod.run`` beyond quick and log: results, or options."""
    out = {}
    for name in list(inspect.signature(mod.run).parameters)[2:]:
        if name == 'results':
            out[name] = results
        elif hasattr(opts, name):
            out[name] = getattr(opts, name)
    return out


def write_outputs(modules, results, out, log):
    """Draw every chart and write every Markdown table ``results`` allows; the paths."""
    paths = []
    for name, mod in modules.items():
        if hasattr(mod, 'draw'):
            paths += mod.draw(results, out)
        md = mod.render_md(results) if hasattr(mod, 'render_md') else None
        if md is not None:
            path = os.path.join(out, f'{name}.md')
            with open(path, 'w', encoding='utf-8') as fh:
                fh.write(md)
            paths.append(path)
    for p in paths:
        log(f'wrote {p}')
    return paths


def _load_json(path, what):
    try:
        with open(path, encoding='utf-8') as fh:
            return json.load(fh), None
    except OSError as exc:
        return None, f'{what}: {exc.strerror or exc}'
    except ValueError as exc:
        return None, f'{what}: not JSON ({exc})'


def redraw(path, out, log):
    """Redraw every chart and table from a ``results.json`` into ``out``; the exit status."""
    results, err = _load_json(path, f'--charts-from {path}')
    if err:
        return _fail(err)
    if not isinstance(results, dict) or not isinstance(results.get('footer'), dict):
        return _fail(f'--charts-from {path}: not a rigidrot_bench results.json (no footer)')
    os.makedirs(out, exist_ok=True)
    modules = {n: m for n, m in registry.available(needs=False).items()
               if not isinstance(m, registry.Unavailable)}
    if not write_outputs(modules, results, out, log):
        return _fail(f'--charts-from {path}: no chartable results in it')
    return 0


def run_parts(names, opts, log):
    """Run the parts ``names`` (registry order) into ``opts.out``; return the exit status.

    ``opts`` carries ``out``, ``quick`` and the parts' own options. Results merge into an
    existing ``OUT/results.json``; the exit status is 2 for a missing dependency or input,
    1 where a part reports a failure (``failed``), else 0.
    """
    modules = {}
    for name in [n for n in registry.PARTS if n in names]:
        try:
            modules[name] = registry.load(name)
        except registry.Unavailable as exc:
            if exc.missing is None:
                return _fail(str(exc))
            modules[name] = exc
    missing = sorted({m.missing for m in modules.values()
                      if isinstance(m, registry.Unavailable)} |
                     set(missing_modules(['matplotlib'])))
    if missing:
        return _fail(install_hint(missing))
    try:
        os.makedirs(opts.out, exist_ok=True)
    except OSError as exc:
        return _fail(f'--out {opts.out}: {exc.strerror or exc}')
    foot = common.footer()
    merged = os.path.join(opts.out, 'results.json')
    results = {}
    if os.path.exists(merged):            # a partial run (--only) adds to an earlier one
        results, err = _load_json(merged, merged)
        if err:
            return _fail(f'{err}; move it away or choose another --out')
    # 'footer' dates the charts of the default parts; a part run on its own keeps its own
    # footer beside theirs
    shared = {n for n, m in modules.items() if getattr(m, 'SHARED_FOOTER', False)}
    if shared or 'footer' not in results:
        results['footer'] = foot
    for name in set(modules) - shared:
        results[f'footer_{name}_run'] = foot
    for name, mod in modules.items():
        try:
            res = mod.run(opts.quick, log, **_kwargs(mod, opts, results))
        except common.MissingInput as exc:
            return _fail(f'--only {name} needs {exc.what} in {merged} '
                         f'(run --only {exc.part} first)')
        res = res if hasattr(mod, 'KEYS') else {name: res}
        results.update(res)
        if hasattr(mod, 'write'):
            mod.write(res, opts.out, foot, log)
        common.write_json(merged, results)     # a later part that fails loses nothing
    every = {n: m for n, m in registry.available(needs=False).items()
             if not isinstance(m, registry.Unavailable)}
    write_outputs(every, results, opts.out, log)
    failures = [line for mod in modules.values() if hasattr(mod, 'failed')
                for line in mod.failed(results)]
    for line in failures:
        log(line)
    print(json.dumps(foot))
    return 1 if failures else 0


def part_main(name, argv=None):
    """``python -m rigidrot_ros.bench.<name>``: run that part alone into ``--out``."""
    mod = registry.load(name, needs=False)
    ap = OneLineParser(prog=f'python -m rigidrot_ros.bench.{name}',
                       description=registry.summary(mod))
    ap.add_argument('--out', default='bench_out', help='directory for charts and data '
                    '(results merge into OUT/results.json)')
    ap.add_argument('--quick', action='store_true', help='a smoke run')
    add_part_arguments(ap, [mod])
    return run_parts([name], ap.parse_args(argv), clock_log())
