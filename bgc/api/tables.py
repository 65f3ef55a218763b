"""A result as a table: :class:`Table`, rows of plain numbers, text and lists, with
:meth:`Table.to_frame` for a pandas DataFrame (the ``data`` extra: ``pip install 'bgc[data]'``)."""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ..errors import ArgumentValueError


def pandas():
    """pandas, or an error saying how to install it (it is an optional extra)."""
    try:
        import pandas as pd
    except ImportError:
        raise ArgumentValueError("to_frame() needs pandas, which is not installed", None,
                                 "pip install 'bgc[data]' (or pandas), or read the Table's rows") from None
    return pd


def frame(rows: Sequence[Mapping[str, Any]], columns: Sequence[str] | None = None):
    """A pandas DataFrame of ``rows`` (dicts; ``columns``: their order, default
    the first row's keys then any new ones): numbers stay numbers (None and
    NaN are missing), lists stay lists."""
    pd = pandas()
    if columns is None:
        seen: dict[str, None] = {}
        for row in rows:
            seen.update(dict.fromkeys(row))
        columns = list(seen)
    return pd.DataFrame([[row.get(c) for c in columns] for row in rows], columns=list(columns))


@dataclass(frozen=True, slots=True)
class Table:
    """Rows of one kind of result (``columns`` in order; each row a tuple of
    numbers, text, bools, lists or None): iterate it for dicts,
    :meth:`to_frame` for a DataFrame, ``print`` it for aligned text."""

    columns: tuple[str, ...]
    rows: tuple[tuple, ...]

    @classmethod
    def of(cls, rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> Table:
        return cls(tuple(columns), tuple(tuple(r.get(c) for c in columns) for r in rows))

    def __len__(self) -> int:
        return len(self.rows)

    def __iter__(self) -> Iterator[dict[str, Any]]:
        return (dict(zip(self.columns, r)) for r in self.rows)

    def column(self, name: str) -> list:
        """The values of column ``name``, in row order."""
        if name not in self.columns:
            raise ArgumentValueError(f"Table.column: no column {name!r}", None,
                                     "columns: " + ", ".join(self.columns))
        j = self.columns.index(name)
        return [r[j] for r in self.rows]

    def to_frame(self):
        """The table as a pandas DataFrame (numbers as numbers, lists as lists)."""
        return frame(list(self), self.columns)

    def __str__(self) -> str:
        cells = [list(self.columns)] + [[_cell(v) for v in r] for r in self.rows]
        widths = [max(len(row[j]) for row in cells) for j in range(len(self.columns))]
        return "\n".join("  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in cells)

    def __repr__(self) -> str:
        return f"<bgc Table: {len(self.rows)} rows of {', '.join(self.columns)}>"


def _cell(v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return " ".join(str(x) for x in v)
    return str(v)
