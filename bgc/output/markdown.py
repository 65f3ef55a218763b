"""Text from outside (a model's path, a campaign's title, a failure message)
placed in Markdown (``tables.md``, ``report.md``) as literal text: it cannot
make a heading, a table cell, a link, HTML or emphasis of its own."""

from __future__ import annotations

import re
from typing import Any

from ..errors import printable

#: Characters Markdown (CommonMark, GitHub's tables, strikethrough and math) reads as markup anywhere
#: in a line: each is written after a backslash.
_MARKUP = frozenset("\\`*[]<>|~$&#")
#: What makes a line a list item, a quote, a heading's underline or a numbered item where it starts.
_LINE_START = re.compile(r"[-+=]|\d{1,9}[.)](?= |$)")


def escape(text: Any, prose: bool = False) -> str:
    r"""``text`` as literal Markdown inline text: one line (a control
    character as its escape, :func:`bgc.errors.printable`; ``prose``: every
    run of white space, line ends included, as one space, as Markdown shows a
    paragraph), then a backslash before each character Markdown reads as
    markup (``\ ` * [ ] < > | ~ $ & #``), before ``_`` unless it stands
    between two letters or digits (there it is plain: ``R_pipe`` stays
    readable), and before what would start a list, a quote or a heading's
    underline at the start. Text placed at a line's start or in a table cell
    cannot make a heading, a cell, a link, HTML or emphasis.

    >>> escape("R_pipe:abrupt:-0.5@165"), escape("_x_ | *y*"), escape("# [a](http://b) <i>")
    ('R_pipe:abrupt:-0.5@165', '\\_x\\_ \\| \\*y\\*', '\\# \\[a\\](http://b) \\<i\\>')
    >>> print(escape("1. two" + chr(10) + "lines"), escape("a  " + chr(10) + chr(10) + " b", prose=True))
    1\. two\\nlines a b
    >>> print(escape("1.5"), escape("-1.5"), escape("x_"))
    1.5 \-1.5 x\_
    """
    text = printable(" ".join(str(text).split()) if prose else str(text)).strip()
    out = []
    for i, ch in enumerate(text):
        if ch in _MARKUP:
            out.append("\\" + ch)
        elif ch == "_" and not (0 < i < len(text) - 1 and text[i - 1].isalnum() and text[i + 1].isalnum()):
            out.append("\\_")
        else:
            out.append(ch)
    escaped = "".join(out)
    start = _LINE_START.match(escaped)
    if start:
        end = start.end()
        escaped = escaped[:end - 1] + "\\" + escaped[end - 1:]
    return escaped


def comment(text: Any) -> str:
    """``text`` inside an HTML comment: one line, no ``--`` (which could end it)."""
    return re.sub("-(?=-)", "- ", printable(str(text)))
