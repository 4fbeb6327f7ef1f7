"""The commands the docs give: they install what they run, and overwrite no committed file.

Read from the Markdown's fenced blocks (README.md and doc/*.md) and from setup.py's
``extras_require`` (parsed, not run).
"""

import ast
import glob
import os
import re
import shlex

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PAGES = [os.path.join(ROOT, 'README.md')] + sorted(glob.glob(os.path.join(ROOT, 'doc',
                                                                          '*.md')))
#: Options that name a file or a path prefix the command writes.
OUTPUT_OPTIONS = ('-o', '--output', '--plot', '--json', '--csv', '--out')
#: Suffixes a command adds to a path prefix (the charts write PREFIX.png and PREFIX.svg).
SUFFIXES = ('', '.png', '.svg', '.pdf', '.json', '.csv')


def _blocks(path):
    with open(path, encoding='utf-8') as fh:
        text = fh.read()
    return re.findall(r'^```[a-z]*\n(.*?)^```', text, flags=re.S | re.M)


def _commands(block):
    """Shell lines of a block, continuation lines joined, comments dropped."""
    joined = re.sub(r'\\\n\s*', ' ', block)
    for line in joined.splitlines():
        line = line.split(' #', 1)[0].strip()
        if line and not line.startswith('#'):
            yield line


def _extras():
    with open(os.path.join(ROOT, 'setup.py'), encoding='utf-8') as fh:
        tree = ast.parse(fh.read())
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == 'extras_require':
            return ast.literal_eval(node.value)
    raise AssertionError('setup.py has no extras_require')


def test_the_docs_extra_installs_what_the_sphinx_command_needs():
    docs = _extras().get('docs')
    assert docs, 'setup.py needs a docs extra (sphinx, myst-parser)'
    names = {re.split(r'[<>=!\[ ]', req)[0].lower() for req in docs}
    assert {'sphinx', 'myst-parser'} <= names, docs
    found = 0
    for page in PAGES:
        for block in _blocks(page):
            if 'sphinx-build' not in block:
                continue
            found += 1
            before = block[:block.index('sphinx-build')]
            assert re.search(r'pip install [^\n]*\.\[([a-z,]*,)?docs(,[a-z,]*)?\]', before), \
                f'{os.path.relpath(page, ROOT)}: a block runs sphinx-build without first ' \
                f'installing the docs extra:\n{block}'
    assert found, 'no sphinx-build command in the docs'


def test_no_documented_command_writes_over_a_committed_file():
    writes = []
    for page in PAGES:
        for block in _blocks(page):
            for line in _commands(block):
                try:
                    words = shlex.split(line)
                except ValueError:
                    continue
                for opt, arg in zip(words, words[1:]):
                    if opt in OUTPUT_OPTIONS and '$' not in arg and not os.path.isabs(arg):
                        writes.append((os.path.relpath(page, ROOT), line, arg))
    assert any('campaign.charts' in line for _, line, _ in writes), writes
    clobbered = [(page, line) for page, line, arg in writes
                 if any(os.path.isfile(os.path.join(ROOT, arg + s)) for s in SUFFIXES)]
    assert not clobbered, f'documented commands that overwrite committed files: {clobbered}'
