"""A report as one self-contained HTML page: ``report.html`` beside
``report.md`` in the folders of ``bgc diagnose``, ``bgc monitor``, ``bgc
calibrate`` and ``bgc experiment``.

The page is laid out by a jinja2 template (``bgc/templates/*.html.j2``) from
the sentences, table cells and pictures the Markdown report is made of (the
helpers of :mod:`bgc.output.report`, :mod:`bgc.output.calibration_report`,
:mod:`bgc.output.tables`), so the two say the same. The environment escapes
every value (autoescape): a model's name, a path, a campaign's description
or a failure message is shown as text and cannot make markup, a script or a
link. The page fetches nothing: the pictures are embedded as ``data:`` URIs
of their PNG bytes, the stylesheet is inline and there is no script; its
Content-Security-Policy forbids any other source, so a browser would refuse
to fetch or run anything all the same. Its colours are from the Okabe-Ito
palette (distinguishable with the common colour-vision deficiencies), and
every colour goes with a word that says the same.

:func:`fragment` lays out the short summaries a notebook shows
(:mod:`bgc.output.summary`) with the same environment.
"""

from __future__ import annotations

import base64
import functools
from dataclasses import dataclass
from typing import Mapping

from .artifacts import mark_text

#: The file name of the page in a report folder.
PAGE = "report.html"


@dataclass(frozen=True, slots=True)
class Picture:
    """A picture of the page: its file in the folder, what it shows, its PNG as a ``data:`` URI."""

    name: str
    caption: str
    uri: str


@dataclass(frozen=True, slots=True)
class Table:
    """A table of the page: its column heads and rows of cells (plain text: the template escapes them)."""

    head: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]


def data_uri(png: bytes) -> str:
    """PNG bytes as a ``data:`` URI (an ``<img src>`` that needs no file and no fetch).

    >>> data_uri(b"PNG")
    'data:image/png;base64,UE5H'
    """
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def pictures(files: Mapping[str, bytes], captions: Mapping[str, str]) -> tuple[Picture, ...]:
    """The pictures among ``files`` (by file name) that ``captions`` names, in its order."""
    return tuple(Picture(name, caption, data_uri(files[name])) for name, caption in captions.items() if name in files)


def table(head, rows) -> Table:
    """A :class:`Table` of plain strings."""
    return Table(tuple(map(str, head)), tuple(tuple(map(str, row)) for row in rows))


@functools.cache
def _environment():
    import jinja2

    return jinja2.Environment(loader=jinja2.PackageLoader("bgc", "templates"), autoescape=True,
                              undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True,
                              keep_trailing_newline=True)


def page(template: str, source: str, **view) -> str:
    """Template ``template`` (``bgc/templates/``) laid out with ``view``,
    with bgc's mark after its doctype (``source``: what it comes from)."""
    text = _environment().get_template(template).render(**view)
    return mark_text(text, "html", source)


def fragment(template: str, **view) -> str:
    """Template ``template`` laid out with ``view`` as a piece of a page (a
    notebook's rich output, ``_repr_html_``): no document, no mark, no
    stylesheet (its styles inline), every value escaped as on a page."""
    return _environment().get_template(template).render(**view)
