"""Which committed benchmark tables are older than the code they measure (``--stale``).

Every table a part writes (``<part>.md`` beside its ``results.json``) names in its caption
the commit its run measured (the footer's ``commit``, :func:`common.commit_text`). A part
says which code it measures in ``MEASURES``: module names (a package: all of its modules),
taken with every module of the package they import, at any level; a part without it
measures the whole package. A table is *stale* when a commit after its own changed one of
those files for real: its code, not only its docstrings and comments (compared as Python
tokens without comments and docstrings; a file moved counts as changed where its code
changed, its imports included); *unstamped* when its footer names no commit. Nothing is
run: this reads the results files and git's history.

``rigidrot_bench --stale`` (or ``python -m rigidrot_ros.bench.stamps``) prints one line
per table, with the commits since; ``--strict`` makes it exit 1 when one is stale or
unstamped (2: not a git checkout, or a results file that cannot be read).
"""

import ast
import io
import json
import os
import subprocess
import sys
import tokenize

from rigidrot_ros.bench import common, registry
from rigidrot_ros.tools.cli import OneLineParser

__all__ = ['FOLDERS', 'code_files', 'tables', 'stale', 'main']

PKG = 'rigidrot_ros'
#: The folders of committed results and their tables, relative to the checkout.
FOLDERS = ('doc/bench', 'doc/bench/ratios')
#: Commits listed per stale table at most (the count is always given).
SHOWN = 5


def _modules(root):
    """Return ``{dotted name: path relative to root}`` of every module of the package."""
    out = {}
    base = os.path.join(root, PKG)
    for folder, _, files in os.walk(base):
        for f in files:
            if f.endswith('.py'):
                rel = os.path.relpath(os.path.join(folder, f), root)
                parts = rel[:-3].split(os.sep)
                if parts[-1] == '__init__':
                    parts.pop()
                out['.'.join(parts)] = rel
    return out


def _imports(name, path, modules):
    """Return the package modules ``name`` (its file at ``path``) imports, at any level."""
    with open(path, encoding='utf-8') as fh:
        tree = ast.parse(fh.read())
    here = name if path.endswith('__init__.py') else name.rpartition('.')[0]
    found = set()
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                up = here.split('.')[:len(here.split('.')) - (node.level - 1)]
                base = '.'.join(up + ([base] if base else []))
            targets = [f'{base}.{a.name}' for a in node.names] + [base]
        for t in targets:
            while t and t not in modules:
                t = t.rpartition('.')[0]
            if t and t.split('.')[0] == PKG:
                found.add(t)
    return found


#: ``{root: {module: the package modules it imports}}``, filled as modules are read.
_GRAPHS = {}


def code_files(entries, root=common.CHECKOUT):
    """Return the files (relative to ``root``) of ``entries`` and all they import.

    ``entries``: dotted module names; a package stands for all of its modules. Each
    package a module is in counts too (its ``__init__`` runs first).
    """
    modules, graph = _modules(root), _GRAPHS.setdefault(root, {})
    todo = set()
    for entry in entries:
        todo |= {m for m in modules if m == entry or m.startswith(entry + '.')}
    seen = set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        parents = ['.'.join(name.split('.')[:i]) for i in range(1, name.count('.') + 1)]
        todo |= {p for p in parents if p in modules} - seen
        if name not in graph:
            graph[name] = _imports(name, os.path.join(root, modules[name]), modules)
        todo |= graph[name] - seen
    return sorted(modules[m] for m in seen)


def _code(text):
    """Return a Python file's tokens without comments and bare strings (docstrings), or None.

    A string that is a statement of its own (a docstring) does nothing, nor does a comment
    or a blank line: two texts with the same tokens otherwise are the same code.
    """
    out, line = [], []
    try:
        for tok in tokenize.generate_tokens(io.StringIO(text).readline):
            if tok.type in (tokenize.COMMENT, tokenize.NL):
                continue
            if tok.type == tokenize.NEWLINE:
                if not all(t[0] == tokenize.STRING for t in line):
                    out += line + [(tok.type, '')]
                line = []
            elif tok.type in (tokenize.INDENT, tokenize.DEDENT, tokenize.ENDMARKER):
                out += line + [(tok.type, '')]
                line = []
            else:
                line.append((tok.type, tok.string))
    except (tokenize.TokenError, SyntaxError):
        return None
    return out + line


class _History:
    """The package's history: each commit's touched files, and which it really changed.

    Cached; a handful of git processes serve every table.
    """

    def __init__(self, root):
        self.root = root
        self._changed = {}          # (commit, path) -> changed for real
        self.commits, self.touched = [], {}
        log = common._git('log', '--no-merges', '-M', '--name-status', '--format=%x00%H %s',
                          'HEAD', '--', PKG, cwd=root) or ''
        for block in log.split('\0')[1:]:
            head, _, body = block.partition('\n')
            full, _, subject = head.partition(' ')
            touched = {}
            for line in body.splitlines():
                fields = line.split('\t')
                if len(fields) >= 2 and (fields[-1].endswith('.py') or fields[1].endswith('.py')):
                    touched[fields[-1]] = (fields[0][0], fields[1])
            self.commits.append((full, subject))
            self.touched[full] = touched

    def since(self, commit):
        """Return the ``(hash, subject)`` of the commits after ``commit``, newest first."""
        later = set((common._git('rev-list', '--no-merges', f'{commit}..HEAD', '--', PKG,
                                 cwd=self.root) or '').split())
        return [(h, subject) for h, subject in self.commits if h in later]

    def _blobs(self, specs):
        """Return the texts of ``rev:path`` specs (None where absent), by one cat-file."""
        if not specs:
            return []
        out = subprocess.run(['git', 'cat-file', '--batch'], cwd=self.root,
                             input=''.join(f'{s}\n' for s in specs).encode(),
                             capture_output=True, timeout=120).stdout
        texts, pos = [], 0
        for _ in specs:
            end = out.index(b'\n', pos)
            head = out[pos:end].split()
            pos = end + 1
            if len(head) < 3 or head[1] != b'blob':
                texts.append(None)
                continue
            size = int(head[2])
            texts.append(out[pos:pos + size].decode('utf-8', 'replace'))
            pos += size + 1
        return texts

    def changes(self, commit, files):
        """Whether ``commit`` changed the code of one of ``files`` (not only docstrings)."""
        touched = self.touched.get(commit, {})
        mine = [f for f in sorted(files) if f in touched]
        if any(self._changed.get((commit, f)) for f in mine):
            return True
        todo = [f for f in mine if (commit, f) not in self._changed]
        for f in todo:
            if touched[f][0] in 'AD':
                self._changed[(commit, f)] = True
                return True
        specs = [s for f in todo for s in (f'{commit}^:{touched[f][1]}', f'{commit}:{f}')]
        texts = self._blobs(specs)
        for i, f in enumerate(todo):
            a, b = texts[2 * i], texts[2 * i + 1]
            real = a is None or b is None or (a != b and _code(a) != _code(b))
            self._changed[(commit, f)] = real
            if real:
                return True
        return False


def tables(folder):
    """Return ``[(part, footer)]`` of the tables committed in ``folder`` (an absolute path).

    A table is a ``<part>.md`` of a known part; its footer is the part's in the folder's
    ``results.json`` (raises OSError or ValueError if that cannot be read).
    """
    names = sorted(f[:-3] for f in os.listdir(folder)
                   if f.endswith('.md') and f[:-3] in registry.PARTS)
    if not names:
        return []
    with open(os.path.join(folder, 'results.json'), encoding='utf-8') as fh:
        results = json.load(fh)
    return [(name, common.part_footer(results, name)) for name in names]


def measures(name):
    """Return the modules a part measures: its ``MEASURES``, else the whole package."""
    try:
        mod = registry.load(name, needs=False)
    except registry.Unavailable:
        return (PKG,)
    return tuple(getattr(mod, 'MEASURES', (PKG,)))


def stale(root=common.CHECKOUT, folders=FOLDERS, measured=measures):
    """Return one dict per committed table: where, its commit, and the commits since.

    Keys: ``table`` (path relative to ``root``), ``date``, ``commit``, ``status``
    (``current``, ``stale``, ``unstamped`` or ``unknown commit``: not in this history)
    and ``since``, the ``(short hash, subject)`` of each later commit that touched the
    code the part measures (``measured(part)``: module names), newest first.
    """
    rows = []
    history = _History(root)
    for folder in folders:
        for name, foot in tables(os.path.join(root, folder)):
            row = {'table': os.path.join(folder, f'{name}.md'), 'date': foot.get('date', '?'),
                   'commit': foot.get('commit'), 'status': 'current', 'since': []}
            rows.append(row)
            if not row['commit']:
                row['status'] = 'unstamped'
                continue
            if common._git('cat-file', '-e', f'{row["commit"]}^{{commit}}', cwd=root) is None:
                row['status'] = 'unknown commit'
                continue
            files = set(code_files(measured(name), root))
            row['since'] = [(h[:7], subject) for h, subject in history.since(row['commit'])
                            if history.changes(h, files)]
            if row['since']:
                row['status'] = 'stale'
    return rows


def _line(row):
    head = f'{row["table"]}: measured {row["date"]}, '
    if row['status'] == 'unstamped':
        return head + 'no commit recorded'
    if row['status'] == 'unknown commit':
        return head + f'commit {row["commit"][:12]}, which this history does not hold'
    if row['status'] == 'current':
        return head + f'commit {row["commit"][:12]}: current'
    n = len(row['since'])
    lines = [head + f'commit {row["commit"][:12]}: older than {n} commit'
             f'{"s" if n > 1 else ""} to the code it measures']
    lines += [f'    {h} {subject[:90]}' for h, subject in row['since'][:SHOWN]]
    if n > SHOWN:
        lines.append(f'    ... and {n - SHOWN} more')
    return '\n'.join(lines)


def add_arguments(ap):
    """Add ``--results`` and ``--strict`` (shared with ``rigidrot_bench --stale``)."""
    ap.add_argument('--results', action='append', metavar='DIR',
                    help='a folder of results.json and its tables, relative to the checkout '
                         f'(repeatable; default: {", ".join(FOLDERS)})')
    ap.add_argument('--strict', action='store_true',
                    help='exit 1 when a table is stale or unstamped')


def run(opts, root=common.CHECKOUT, prog='rigidrot_bench --stale'):
    """Print the tables and their state; return the exit status (0, 1 with --strict, 2)."""
    if common._git('rev-parse', '--git-dir', cwd=root) is None:
        print(f"{prog}: {root} is not a git checkout: the tables' commits cannot be "
              "compared with the code's history", file=sys.stderr)
        return 2
    try:
        rows = stale(root, tuple(opts.results or FOLDERS))
    except (OSError, ValueError) as exc:
        print(f'{prog}: cannot read the results: {exc}', file=sys.stderr)
        return 2
    for row in rows:
        print(_line(row))
    old = [r for r in rows if r['status'] != 'current']
    print(f'{len(old)} of {len(rows)} tables older than the code they measure or not '
          'stamped' if old else f'all {len(rows)} tables are current')
    return 1 if old and opts.strict else 0


def main(argv=None):
    """``python -m rigidrot_ros.bench.stamps``: the same as ``rigidrot_bench --stale``."""
    ap = OneLineParser(prog='python -m rigidrot_ros.bench.stamps',
                       description=__doc__.splitlines()[0])
    add_arguments(ap)
    return run(ap.parse_args(argv), prog='python -m rigidrot_ros.bench.stamps')


if __name__ == '__main__':
    sys.exit(main())
