"""Sphinx's configuration of bgc's API reference, generated from the docstrings.

Build it with ``.venv/bin/python -m sphinx -b html docs/reference out/reference``;
tests/test_api_reference.py builds it with ``-W``, so a docstring Sphinx cannot read fails the test.
The docstrings use numpydoc sections (Parameters, Returns, Raises, Examples): napoleon reads them."""

import sys
from pathlib import Path

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
#: bgc's package docstring has a glossary section: a heading napoleon does not know.
napoleon_custom_sections = ["Glossary"]

exclude_patterns = ["_build"]
html_theme = "alabaster"
