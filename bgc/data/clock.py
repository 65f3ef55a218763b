"""How a run's times are put into words: the one rule that tells absolute
times (a logger's Unix seconds, ISO 8601 timestamps as bgc reads them) from
times counted from some start, and how each kind is written.

bgc reads a timestamp as seconds since 1970-01-01 UTC converted to the
model's ``time_unit`` (:func:`bgc.data.columns.iso_seconds`), so a run's
times are numbers either way. A run whose first time, once in seconds
(:func:`bgc.data.columns.unit_seconds`; a model without a time unit counts
in seconds, as a timestamp is read), is at least :data:`ABSOLUTE_SECONDS`
and below :data:`LAST_SECONDS` has absolute times: messages and reports
write them as ISO 8601 UTC timestamps, ``2026-03-02T06:31:00.5Z`` (the
fraction of a second as far as it is not zero, to the microsecond), and
plots as the time since the first sample, its date in the axis label
(:func:`bgc.output.plots.time_axis`). Other runs' times are written as
numbers, 12 significant digits (:func:`time_text`). A :class:`Clock` is
that decision, made once from a run's times and the model's time unit and
handed to whatever writes the run's times; durations (a window, a delay,
a gap's steps) stay numbers.

>>> clock = Clock.of([1772433000.5, 1772433001.0], "s")
>>> clock.absolute, clock.text(1772433060.5), clock.text(1772433060.0)
(True, '2026-03-02T06:31:00.5Z', '2026-03-02T06:31:00Z')
>>> Clock.of([29540550.0], "min").text(29540551.0)
'2026-03-02T06:31:00Z'
>>> Clock.of([0.0, 0.05], "s").text(60.5), Clock().text(1772433060.5)
('60.5', '1772433060.5')
"""

from __future__ import annotations

import datetime
import math
from dataclasses import dataclass

import numpy as np

from .columns import unit_seconds

#: A run whose first time is this many seconds after 1970-01-01 UTC or later (1973-03-03) has absolute
#: times: a logger's Unix seconds, or ISO timestamps as bgc reads them (bgc.data.columns.iso_seconds).
ABSOLUTE_SECONDS = 1e8
#: ... and a first time this many seconds after it or later (the year 5138) is a number, not a date.
LAST_SECONDS = 1e11
_EPOCH = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)


def time_text(t) -> str:
    """A time as a number, as messages and reports print the times of a
    run that are not absolute: 12 significant digits (a logger's Unix time
    keeps its fraction of a second)."""
    return f"{t:.12g}"


@dataclass(frozen=True, slots=True)
class Clock:
    """How one run's times are written (module docstring): ``seconds``, the
    seconds in one of the model's time units when the run's times are
    absolute, None when they are written as numbers (``Clock()``)."""

    seconds: float | None = None

    @classmethod
    def of(cls, time, time_unit: str | None) -> Clock:
        """The clock of a run whose times are ``time`` (its first decides:
        one time will do) in the model's ``time_unit`` (None: seconds)."""
        t = np.asarray(time, dtype=float).ravel()
        seconds = unit_seconds(time_unit)
        if t.size and np.isfinite(t[0]) and seconds is not None and \
                ABSOLUTE_SECONDS <= t[0] * seconds < LAST_SECONDS:
            return cls(seconds)
        return cls()

    @property
    def absolute(self) -> bool:
        """Whether the run's times are absolute (written as dates)."""
        return self.seconds is not None

    def instant(self, t) -> datetime.datetime | None:
        """Time ``t`` of the run (in the model's time unit) as a UTC date and
        time, rounded to the microsecond; None when the run's times are not
        absolute, or ``t`` is not finite or no date of the years 1 to 9999."""
        if self.seconds is None or not math.isfinite(t):
            return None
        try:
            return _EPOCH + datetime.timedelta(microseconds=round(float(t) * (self.seconds * 1e6)))
        except (OverflowError, ValueError):
            return None

    def text(self, t) -> str:
        """Time ``t`` of the run in words: an ISO 8601 UTC timestamp when the
        run's times are absolute (``2026-03-02T06:31:00.5Z``), else a number
        (:func:`time_text`)."""
        when = self.instant(t)
        if when is None:
            return time_text(t)
        fraction = f"{when.microsecond:06d}".rstrip("0")
        return (f"{when.year:04d}-{when.month:02d}-{when.day:02d}T{when.hour:02d}:{when.minute:02d}:"
                f"{when.second:02d}" + (f".{fraction}" if fraction else "") + "Z")
