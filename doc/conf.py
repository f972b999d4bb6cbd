"""Sphinx configuration of the dmf_sim documentation (myst Markdown pages).

Built three ways, all with this file:

* ``make docs`` (and ``make test``): ``sphinx-build -W -b html doc doc/_build/html``;
* standalone: ``sphinx-build -W -b html doc <out>`` from the repository root;
* rosdoc2 on a ROS docs farm: ``rosdoc2.yaml`` beside ``package.xml`` points its Sphinx builder
  at this directory (``sphinx_sourcedir: doc``).

No network: no intersphinx inventories are fetched, so the build works offline. The pages take a
few seconds; the API pages most of the rest (autodoc imports and reads every module).
"""
import functools
import os
import re
import sys

# The package is documented from this source tree (the repository root is the parent of doc/),
# so the API pages show the code beside them, installed or not. rosdoc2 runs this file from a
# wrapper elsewhere (__file__ is the wrapper's): there the built and sourced package is imported.
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if os.path.isfile(os.path.join(ROOT, 'dmf_sim', '__init__.py')) and ROOT not in sys.path:
    sys.path.insert(0, ROOT)

project = 'dmf_sim'
author = 'dmf_sim developers'
copyright = '2026, dmf_sim developers'  # noqa: A001 (Sphinx's name)
release = '0.1.0'
version = release

extensions = [
    'myst_parser',
    'sphinx.ext.autodoc',
    'sphinx.ext.napoleon',
    'sphinx.ext.mathjax',
]

source_suffix = {'.md': 'markdown'}
root_doc = 'index'
exclude_patterns = ['_build', 'Thumbs.db', '.DS_Store']

# Markdown: $...$ math, definition lists, anchors for headings down to ### so pages link to
# sections as [text](node.md#topics-and-qos).
myst_enable_extensions = ['dollarmath', 'deflist', 'colon_fence']
myst_heading_anchors = 3

# API reference: the docstrings are the reference. ROS and the message packages are not needed
# to document the ROS-free core; mock them so the site builds on a plain pip install.
autodoc_mock_imports = ['rclpy', 'std_msgs', 'sensor_msgs', 'diagnostic_msgs', 'rosgraph_msgs',
                        'std_srvs', 'builtin_interfaces', 'rcl_interfaces', 'launch',
                        'launch_ros', 'ament_index_python']
autodoc_member_order = 'bysource'
autodoc_typehints = 'none'     # signatures stay readable; the docstrings give types and units
autodoc_default_options = {'members': True, 'show-inheritance': True}
napoleon_google_docstring = True
napoleon_numpy_docstring = False

html_theme = 'alabaster'
html_title = 'dmf_sim'
html_static_path = []
# The mathjax script is loaded by the reader's browser, not at build time.


# -- Docstrings that are not valid reStructuredText -------------------------------------------
# The modules' docstrings are written for people reading the source (equations in plain text,
# |x| for a modulus, ASCII tables). One that does not parse cleanly as reStructuredText is shown
# preformatted, exactly as written, instead of failing the -W build; a docstring that parses is
# rendered normally. Hand-written pages get no such leniency: every warning there fails the build.

_ROLE = re.compile(r':[\w:+.-]+:`[^`]*`')
_DIRECTIVE = re.compile(r'^(\s*)\.\. [\w:+.-]+::.*$', re.M)


@functools.lru_cache(maxsize=1)
def _check_settings():
    """The docutils settings of the check, made once: building them (an option parser of every
    docutils option) cost more than parsing the docstring itself, once per docstring."""
    from docutils.frontend import get_default_settings
    from docutils.parsers.rst import Parser

    settings = get_default_settings(Parser)
    for name, value in {'report_level': 5, 'halt_level': 5, 'warning_stream': False,
                        'file_insertion_enabled': False, 'raw_enabled': False}.items():
        setattr(settings, name, value)
    return settings


@functools.lru_cache(maxsize=None)
def _parses_cleanly(text):
    """True when the docstring is valid reStructuredText. Checked with plain docutils, its
    Sphinx roles and directives blanked out, so the check registers nothing in the real build;
    parse errors are system_message nodes, an undefined |substitution| (found by the transform)
    leaves a problematic node."""
    import copy

    from docutils import nodes
    from docutils.parsers.rst import Parser
    from docutils.transforms.references import Substitutions
    from docutils.utils import new_document

    document = new_document('<docstring>', copy.copy(_check_settings()))
    Parser().parse(_DIRECTIVE.sub(r'\1..', _ROLE.sub('``x``', text)), document)
    document.transformer.add_transform(Substitutions)
    document.transformer.apply_transforms()
    problems = [m for m in document.findall(nodes.system_message) if m['level'] >= 2]
    return not problems and not any(True for _ in document.findall(nodes.problematic))


def _docstring_as_written(app, what, name, obj, options, lines):
    if not lines or _parses_cleanly('\n'.join(lines)):
        return
    text = [line.rstrip() for line in lines]
    lines[:] = ['::', ''] + ['    ' + line if line else '' for line in text] + ['']


def setup(app):
    # after napoleon (priority 500), which turns Google-style sections into reStructuredText
    app.connect('autodoc-process-docstring', _docstring_as_written, priority=900)
    return {'parallel_read_safe': True}
