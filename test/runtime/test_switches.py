"""The environment switches: read in one module, listed in one table, and nowhere else.

By ast over the package's source (standard library only): the names
``rigidrot_ros/runtime/switches.py`` reads are :data:`SWITCHES`'s and the table's in
``doc/development.md``; no other module names one in code or reads one from the
environment. And what each reader makes of a value.
"""

import ast
from pathlib import Path
import re

import pytest

from rigidrot_ros.runtime import switches

ROOT = Path(__file__).resolve().parents[2]
MODULE = ROOT / 'rigidrot_ros' / 'runtime' / 'switches.py'
_NAME = re.compile(r'RIGIDROT_[A-Z0-9_]+')


def _docstrings(tree):
    """The ids of the docstring nodes of a module, its classes and functions."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                out.add(id(body[0].value))
    return out


def names_in_code(source):
    """Return the ``RIGIDROT_*`` names a module's code holds as whole strings (not docs)."""
    tree = ast.parse(source)
    docs = _docstrings(tree)
    return {node.value for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str)
            and id(node) not in docs and _NAME.fullmatch(node.value)}


def environment_reads(source):
    """Return the source of every environment read of a ``RIGIDROT_*`` name in a module.

    A read is ``os.environ.get(...)``, ``os.getenv(...)``, ``environ[...]``,
    ``... in os.environ``, or ``.get``/``pop``/``setdefault`` on anything, whose name
    argument's source mentions ``RIGIDROT_`` (a constant, an f-string, a concatenation).
    """
    tree = ast.parse(source)
    out = []
    for node in ast.walk(tree):
        key = None
        if isinstance(node, ast.Call) and node.args:
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, 'id', '')
            if name in ('get', 'getenv', 'pop', 'setdefault', 'getenvb'):
                key = node.args[0]
        elif isinstance(node, ast.Subscript):
            key = node.slice
        elif isinstance(node, ast.Compare) and any(isinstance(o, (ast.In, ast.NotIn))
                                                   for o in node.ops):
            key = node.left
        if key is not None and 'RIGIDROT_' in ast.unparse(key):
            out.append(ast.unparse(node))
    return out


def table_names():
    """The first column of the table under "## Environment variables" in development.md."""
    text = (ROOT / 'doc' / 'development.md').read_text(encoding='utf-8')
    section = text.split('## Environment variables', 1)[1].split('\n## ', 1)[0]
    rows = [line for line in section.splitlines() if line.startswith('| `')]
    assert rows, 'no table under "## Environment variables"'
    return {re.match(r'\| `([^`]+)`', row).group(1) for row in rows}


def test_the_checkers_find_reads_and_names_and_skip_docstrings():
    src = ('"""RIGIDROT_DOC is documented here."""\n'
           'import os\n'
           'X = "RIGIDROT_A"\n'
           'def f():\n'
           '    """RIGIDROT_IN_DOC"""\n'
           '    a = os.environ.get("RIGIDROT_B", "1")\n'
           '    b = os.getenv(f"RIGIDROT_{a}")\n'
           '    c = os.environ["RIGIDROT_C"] + ("RIGIDROT_D" in os.environ)\n'
           '    raise ValueError(f"RIGIDROT_E must be {a}")\n')
    assert names_in_code(src) == {'RIGIDROT_A', 'RIGIDROT_B', 'RIGIDROT_C', 'RIGIDROT_D'}
    reads = environment_reads(src)
    assert len(reads) == 4 and all('RIGIDROT_' in r for r in reads)
    assert not environment_reads('import os\nx = os.environ.get("HOME")\n')


def test_the_module_reads_exactly_its_table_and_the_doc_lists_exactly_those():
    read = names_in_code(MODULE.read_text(encoding='utf-8'))
    assert read == set(switches.SWITCHES)
    assert table_names() == read, 'doc/development.md: the environment variables table'


def test_no_other_module_reads_a_switch():
    found = {}
    for path in sorted((ROOT / 'rigidrot_ros').rglob('*.py')):
        if path == MODULE:
            continue
        source = path.read_text(encoding='utf-8')
        bad = sorted(names_in_code(source)) + environment_reads(source)
        if bad:
            found[str(path.relative_to(ROOT))] = bad
    assert found == {}, f'read them through rigidrot_ros.runtime.switches: {found}'


@pytest.mark.parametrize('reader', [switches.lookahead_worker,
                                    switches.gc_freeze, switches.gc_schedule,
                                    switches.record_offload])
def test_a_switch_on_by_default_is_off_only_at_0(reader):
    name = next(n for n, f in switches.SWITCHES.items() if f is reader)
    assert reader({}) is True
    for text in ('', '1', 'yes', ' 2 '):
        assert reader({name: text}) is True
    assert reader({name: '0'}) is False and reader({name: ' 0 '}) is False


def test_the_worker_gate_is_on_only_when_set_to_anything_but_0():
    assert switches.worker_gate({}) is False
    assert switches.worker_gate({'RIGIDROT_WORKER_GATE': ''}) is False
    assert switches.worker_gate({'RIGIDROT_WORKER_GATE': '0'}) is False
    assert switches.worker_gate({'RIGIDROT_WORKER_GATE': '1'}) is True


def test_no_jit_is_on_when_set_to_anything_but_0():
    assert switches.no_jit({}) is False
    assert switches.no_jit({'RIGIDROT_NO_JIT': ''}) is False
    assert switches.no_jit({'RIGIDROT_NO_JIT': '0'}) is False
    assert switches.no_jit({'RIGIDROT_NO_JIT': '1'}) is True
    assert switches.no_jit({'RIGIDROT_NO_JIT': 'yes'}) is True


def test_worker_batch_keeps_0_clips_the_rest_and_ignores_what_is_no_integer():
    def read(text):
        return switches.worker_batch(256, 8, 256, {'RIGIDROT_WORKER_BATCH': text})
    assert switches.worker_batch(256, 8, 256, {}) == 256
    assert [read(t) for t in ('0', '1', '64', '999', '', 'many')] == [0, 8, 64, 256, 256, 256]


def test_rt_priority_takes_0_to_99_and_names_the_variable_otherwise():
    assert switches.rt_priority(10, {}) == 10
    assert switches.rt_priority(10, {'RIGIDROT_RT_PRIORITY': ' '}) == 10
    assert switches.rt_priority(10, {'RIGIDROT_RT_PRIORITY': '0'}) == 0
    assert switches.rt_priority(10, {'RIGIDROT_RT_PRIORITY': '99'}) == 99
    for text in ('100', '-1', 'fast', '1.5'):
        with pytest.raises(ValueError, match=r'^RIGIDROT_RT_PRIORITY must be an integer '
                                             r'from 0 \(off\) to 99, got '):
            switches.rt_priority(10, {'RIGIDROT_RT_PRIORITY': text})


def test_turned_off_names_the_variable_of_a_switch():
    from rigidrot_ros.runtime import switches
    assert switches.turned_off(switches.pacer) == {'RIGIDROT_PACER': '0'}
    assert not switches.pacer(switches.turned_off(switches.pacer))
    assert switches.turned_off(switches.record_offload) == {'RIGIDROT_RECORD_OFFLOAD': '0'}
