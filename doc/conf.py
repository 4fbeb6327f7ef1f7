"""Sphinx configuration of the rigidrot_ros documentation (MyST Markdown pages, autodoc).

Build: ``sphinx-build -W --keep-going -b html doc <out>`` (``test/project/test_docs.py`` runs it).
The API page (``api.md``) is filled in here from the package's modules, so a module added
to one of the public subpackages appears there without editing the page.
"""

import os
import pkgutil
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import rigidrot_ros  # noqa: E402

project = 'rigidrot_ros'
author = 'rigidrot_ros maintainers'
copyright = 'rigidrot_ros maintainers'  # noqa: A001
release = rigidrot_ros.__version__
version = release

extensions = ['myst_parser', 'sphinx.ext.autodoc', 'sphinx.ext.napoleon', 'sphinx.ext.mathjax']
source_suffix = {'.md': 'markdown'}
root_doc = 'index'
# doc/bench holds the benchmark's results (csv, json, svg, png) and the Markdown fragments
# it generates for benchmarks.md to {include}: data and fragments, not pages of their own
# ('*' stops at a '/'); doc/bench/history/ holds pages: the timing logs and investigations.
exclude_patterns = ['_build', 'bench/*.md', 'bench/ratios', '**/.ipynb_checkpoints']

myst_enable_extensions = ['dollarmath', 'colon_fence']
myst_heading_anchors = 3

napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True
autodoc_member_order = 'bysource'
autodoc_typehints = 'description'
autodoc_default_options = {'members': True, 'show-inheritance': True}

html_theme = 'alabaster'
html_static_path = []
html_title = 'rigidrot_ros'

# The public API: packages whose __all__ is their API, and packages whose every module is.
API_PACKAGES = ('rigidrot_ros.core', 'rigidrot_ros.sensors')
API_MODULES_OF = ('rigidrot_ros.bag', 'rigidrot_ros.msgs', 'rigidrot_ros.scoring',
                  'rigidrot_ros.campaign', 'rigidrot_ros.estimators', 'rigidrot_ros.tools')
API_MODULES = ('rigidrot_ros.run.settings',)
API_MARKER = '% api-modules'


def api_modules():
    """Return the module names the API page documents, in page order."""
    names = list(API_PACKAGES)
    for package in API_MODULES_OF:
        path = os.path.join(ROOT, *package.split('.'))
        names += sorted(package + '.' + info.name for info in pkgutil.iter_modules([path])
                        if not info.name.startswith('_'))
    return names + list(API_MODULES)


def _fill_api(app, docname, source):
    """Replace the marker line of api.md by one automodule directive per public module."""
    if docname != 'api' or API_MARKER not in source[0]:
        return
    blocks = []
    for name in api_modules():
        blocks.append('## `{0}`\n\n```{{eval-rst}}\n.. automodule:: {0}\n```\n'.format(name))
    source[0] = source[0].replace(API_MARKER, '\n'.join(blocks))


def setup(app):
    """Register the API page's filler."""
    app.connect('source-read', _fill_api)
    return {'parallel_read_safe': True}
