"""Sphinx's configuration of bgc's API reference, generated from the docstrings.

Build it with ``.venv/bin/python -m sphinx -b html docs/reference out/reference``;
tests/test_api_reference.py builds it with ``-W``, so a docstring Sphinx cannot read fails the test.
The docstrings use numpydoc sections (Parameters, Returns, Raises, Examples): napoleon reads them."""

import sys
from pathlib import Path

from sphinx.ext import napoleon

#: The checkout: its ``bgc`` is documented, installed or not.
ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402  (after the path: the checkout's bgc)

project = "bgc"
author = "bgc's authors"
version = release = bgc.__version__

extensions = ["sphinx.ext.autodoc", "sphinx.ext.napoleon"]
#: Members in the order of the source (or of a module's ``__all__``): the order the code presents them in.
autodoc_member_order = "bysource"
napoleon_google_docstring = False
napoleon_numpy_docstring = True
#: bgc's package docstring has a glossary: a section napoleon does not know.
napoleon_custom_sections = ["Glossary"]

exclude_patterns = ["_build"]
html_theme = "alabaster"

#: What autodoc calls an attribute's, a data's or a property's docstring.
_ATTRIBUTES = ("attribute", "data", "property")


def _numpy_sections(app, what, name, obj, options, lines):
    """napoleon's reading of the sections, but an attribute's or a property's docstring read as any
    other: napoleon takes a first line's text before a colon for the attribute's type, and bgc's first
    lines are sentences ("The onset, in the model's time unit (None: no fault)")."""
    napoleon._process_docstring(app, "object" if what in _ATTRIBUTES else what, name, obj, options, lines)


def setup(app):
    """Put :func:`_numpy_sections` in the place of napoleon's own reader."""
    ours = [lst for lst in app.events.listeners["autodoc-process-docstring"]
            if lst.handler is napoleon._process_docstring]
    if not ours:
        raise RuntimeError("docs/reference/conf.py: napoleon's docstring reader is not where it was: update setup()")
    for listener in ours:
        app.disconnect(listener.id)
    app.connect("autodoc-process-docstring", _numpy_sections)
