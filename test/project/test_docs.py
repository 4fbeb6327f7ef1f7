"""The documentation: the Sphinx build is clean, and the README's relative links resolve.

The build runs as ``sphinx-build -W --keep-going -b html doc <tmp>`` in a separate process,
so a broken link or cross-reference, a missing include or a docstring whose markup
docutils cannot parse fails this test with the warnings in the message.
"""

import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DOC = os.path.join(ROOT, 'doc')
README = os.path.join(ROOT, 'README.md')

_FENCE = re.compile(r'^(```|~~~).*?^\1', re.M | re.S)
_CODE = re.compile(r'`[^`\n]*`')
_COMMENT = re.compile(r'<!--.*?-->', re.S)
# [text](target) and ![alt](target), an optional "title" after the target
_LINK = re.compile(r'!?\[[^\]]*\]\(\s*(?:<([^>\n]+)>|([^)\s]+))(?:\s+"[^"]*")?\s*\)')
_EXTERNAL = re.compile(r'^[a-z][a-z0-9+.-]*:', re.I)


def relative_links(markdown):
    """Return the relative link targets of a Markdown text, without their #fragments.

    Links inside fenced code blocks, inline code and HTML comments are not links.
    External links (a scheme such as ``https:``) and pure ``#fragment`` links are left
    out.
    """
    text = _COMMENT.sub('', _CODE.sub('', _FENCE.sub('', markdown)))
    targets = []
    for bracketed, bare in _LINK.findall(text):
        target = bracketed or bare
        if _EXTERNAL.match(target) or target.startswith('#'):
            continue
        targets.append(target.split('#', 1)[0])
    return targets


def test_relative_links_finds_and_filters():
    text = ('[a](doc/a.md#x) ![b](doc/b.png "t") [c](https://e.org/c.md) [d](#d)\n'
            '`[e](e.md)` <!-- [f](f.md) -->\n```sh\n[g](g.md)\n```\n[h](<doc/h page.md>)')
    assert relative_links(text) == ['doc/a.md', 'doc/b.png', 'doc/h page.md']


def test_readme_relative_links_exist():
    with open(README, encoding='utf-8') as f:
        targets = relative_links(f.read())
    assert len(targets) >= 5, f'expected the README to link its pages, found {targets}'
    missing = [t for t in targets if not os.path.exists(os.path.join(ROOT, t))]
    assert not missing, f'README.md links to files that do not exist: {missing}'


def test_sphinx_build_has_no_warnings(tmp_path):
    out = subprocess.run(
        [sys.executable, '-m', 'sphinx', '-W', '--keep-going', '-q', '-b', 'html',
         '-d', str(tmp_path / 'doctrees'), DOC, str(tmp_path / 'html')],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, ('sphinx-build -W failed:\n' + out.stdout + out.stderr)
    assert 'WARNING' not in out.stderr and 'ERROR' not in out.stderr, out.stderr
    for page in ('index', 'node', 'sensors', 'recording', 'core', 'models', 'benchmarks',
                 'api'):
        assert (tmp_path / 'html' / f'{page}.html').is_file(), f'{page}.html not built'
    # the estimator loop is the README's block, included (not copied) into recording.md
    recording = (tmp_path / 'html' / 'recording.html').read_text(encoding='utf-8')
    assert 'EST_PID' in recording, 'the README estimator loop is not in recording.html'
    api = (tmp_path / 'html' / 'api.html').read_text(encoding='utf-8')
    for name in ('rigidrot_ros.core.solve', 'rigidrot_ros.core.Scene',
                 'rigidrot_ros.sensors.Gyro', 'rigidrot_ros.run.settings.scene_from_params',
                 'rigidrot_ros.scoring.score'):
        assert f'id="{name}' in api, f'the API page does not document {name}'
