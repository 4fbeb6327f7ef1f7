"""The benchmark parts, by name: what ``rigidrot_bench`` loops over.

Each entry names a module ``rigidrot_ros.bench.<name>`` (a *part*) that defines

- ``NAME`` (its entry here), ``NEEDS`` (importable module names it needs beyond the
  package's own dependencies, such as ``'scipy'``);
- ``run(quick=False, log=print) -> dict``: JSON-serialisable results; it prints its
  figures through ``log``. A keyword ``results`` receives the results merged so far (for a
  part that works on another's, as the cross-check does), and a keyword named like an
  option the part adds (``add_arguments``) receives that option's value;
- ``main(argv=None)``, so that ``python -m rigidrot_ros.bench.<name>`` runs it alone.

and may define (the command does without each):

- ``KEYS``: the top-level keys of ``results.json`` its ``run`` returns (else the whole
  dict is stored under ``NAME``);
- ``MEASURES``: the modules whose code its tables measure (``rigidrot_bench --stale``;
  else the whole package);
- ``DEFAULT = True``: run without ``--only``; ``SHARED_FOOTER = True``: its charts carry
  the shared ``footer`` (else the run's footer is kept as ``footer_<NAME>_run``);
- ``add_arguments(parser)``: its own command options;
- ``write(res, out, foot, log)``: its data files (CSV, charts of its own run);
- ``draw(results, out) -> paths``: charts from merged results (also ``--charts-from``);
- ``render_md(results) -> str or None``: its Markdown table, written as ``<NAME>.md``;
- ``failed(results) -> lines``: what makes the command exit 1.

To add a part: write the module, and add its name to :data:`PARTS` (one line). An entry
whose module is not there (yet) or lacks a dependency is listed by ``rigidrot_bench
--list`` as unavailable and refused by ``--only`` with the reason; it breaks nothing else.
"""

import importlib

#: The parts in the order the command runs them (the cross-check after the stability map).
PARTS = (
    'wp',
    'horizon',
    'stability',
    'crosscheck',
    'ratios',
    'envelope',
    'soak',
    'triaxial',
    'node_tick',
    'random_access',
    'generate',
    'node_khz',
    'view_live',
    'leaderboard',
    'campaign_ros',
    'campaign_inproc',
)


class Unavailable(ImportError):
    """A part that cannot be imported: ``missing`` names the module that is absent."""

    def __init__(self, name, missing, reason):
        super().__init__(f'part {name}: {reason}')
        self.part, self.missing = name, missing


def load(name, needs=True):
    """Import part ``name``; raise :class:`Unavailable` naming what is missing.

    With ``needs``, a module that imports but misses ``NEEDS`` is refused the same way, so
    a part never half-runs without its dependencies (drawing from results needs none).
    """
    if name not in PARTS:
        raise KeyError(f'no benchmark part {name!r} (parts: {", ".join(PARTS)})')
    try:
        mod = importlib.import_module(f'rigidrot_ros.bench.{name}')
    except ImportError as exc:
        missing = exc.name or str(exc)
        if missing == f'rigidrot_ros.bench.{name}':
            raise Unavailable(name, None, 'its module is not installed') from exc
        raise Unavailable(name, missing, f'needs {missing}') from exc
    if getattr(mod, 'NAME', name) != name or not callable(getattr(mod, 'run', None)):
        raise Unavailable(name, None, 'its module defines no NAME = '
                          f'{name!r} and run(quick, log)')
    for dep in getattr(mod, 'NEEDS', ()) if needs else ():
        try:
            importlib.import_module(dep)
        except ImportError as exc:
            raise Unavailable(name, dep, f'needs {dep}') from exc
    return mod


def available(needs=True):
    """Return ``{name: module or Unavailable}`` for every part, in order."""
    out = {}
    for name in PARTS:
        try:
            out[name] = load(name, needs)
        except Unavailable as exc:
            out[name] = exc
    return out


def summary(mod):
    """Return the first line of a part's docstring."""
    return ((mod.__doc__ or '').strip().splitlines() or [''])[0]
