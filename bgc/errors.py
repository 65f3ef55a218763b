"""Errors of bgc: one subclass per compiler stage and per runtime part.

A :class:`BgcError` is a user error: the CLI prints its one-line message and exits
with status 1, without a traceback. Every message says what is wrong, where
(``models/ro.yaml:42:7`` or an element or bond name) and how to fix it. The
line passes through :func:`printable`, so text echoed from a model or a data
file (a newline, an ANSI escape) can never print a second line or colour the
terminal. :class:`InternalError` is a bug in bgc and keeps its traceback.

Examples
--------
>>> loc = SourceLoc("models/x.yaml", 3, 5)
>>> str(ValidationError("bond 4 names unknown element 'R9'", loc, "declare R9 under 'elements'"))
"models/x.yaml:3:5: bond 4 names unknown element 'R9' (declare R9 under 'elements')"
"""

from __future__ import annotations

from dataclasses import dataclass


def printable(text: str) -> str:
    r"""``text`` with every character that is not printable written as its
    Python escape (``\n``, ``\x1b``, ``\ud800``): one line, no terminal
    control sequences, encodable as UTF-8.

    >>> print(printable("a" + chr(10) + "b: ok" + chr(27) + "[31m"))
    a\nb: ok\x1b[31m
    """
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() else ch.encode("unicode_escape", "backslashreplace").decode("ascii")
                   for ch in text)


@dataclass(frozen=True, slots=True)
class SourceLoc:
    """A place in a model file; ``line`` and ``col`` count from 1."""

    file: str
    line: int
    col: int

    def __str__(self) -> str:
        return f"{printable(self.file)}:{self.line}:{self.col}"


class BgcError(Exception):
    """A user error: one line, with a location and a fix. ``bgc.Error`` is its
    public name; its families are :class:`ModelError` (the model file),
    :class:`RuntimeFailure` (its :class:`DataError`: recorded data),
    :class:`ArgumentError` (a call of the Python API; also a :class:`TypeError`
    or :class:`ValueError`), :class:`OutputError` and :class:`ExperimentError`."""

    def __init__(self, what: str, loc: SourceLoc | str | None = None, fix: str | None = None):
        self.what = what
        self.loc = loc
        self.fix = fix
        super().__init__(self.line())

    def line(self) -> str:
        """The one-line message the CLI prints (printable characters only)."""
        text = f"{self.loc}: {self.what}" if self.loc else self.what
        if self.fix:
            text += f" ({self.fix})"
        return printable(text)

    def sort_key(self) -> tuple:
        loc = self.loc
        if isinstance(loc, SourceLoc):
            return (loc.file, loc.line, loc.col, self.what)
        return (str(loc or ""), 0, 0, self.what)


class ErrorGroup(BgcError):
    """Several user errors found in one run, reported together."""

    def __init__(self, errors: list[BgcError]):
        self.errors = tuple(sorted(errors, key=BgcError.sort_key))
        super().__init__("; ".join(e.line() for e in self.errors))

    def lines(self) -> tuple[str, ...]:
        return tuple(e.line() for e in self.errors)


#: The public name of :class:`BgcError` (``bgc.Error``): ``except bgc.Error`` catches every user error.
Error = BgcError


class ModelError(BgcError):
    """The model file is wrong: the base of the compiler stages' errors (load,
    validation, expressions, causality, equations, code generation)."""


class LoadError(ModelError):
    """The file cannot be read or is not well-formed YAML."""


class ValidationError(ModelError):
    """The model breaks the schema or a semantic rule."""


class ExpressionError(ModelError):
    """An expression in the model is refused by the safe parser."""


class CausalityError(ModelError):
    """SCAP found a causal conflict."""


class EquationError(ModelError):
    """State equations cannot be derived (e.g. an unsolvable algebraic loop)."""


class CodegenError(ModelError):
    """Generated code cannot be produced for the model."""


class RuntimeFailure(BgcError):
    """An error of the runtime (simulation, recorded data, filters): the base
    class of its parts' errors."""


class SimulationError(RuntimeFailure):
    """A simulation request is malformed, or the simulated plant diverges."""


class DataError(RuntimeFailure):
    """A recorded run (CSV) cannot be read or does not fit the model."""


class TrackingError(RuntimeFailure):
    """A filter cannot run: no generated package, an unknown model, no
    measurements, a request beyond the memory."""


class CalibrationError(RuntimeFailure):
    """A calibration cannot be made: an unknown name to estimate, no data,
    a likelihood that is not finite at the model's values."""


class OutputError(BgcError):
    """An output cannot be written where asked (bgc does not replace files it
    did not write)."""


class ExperimentError(BgcError):
    """A campaign file is malformed, or a campaign cannot run (its output
    folder, its Dask scheduler)."""


class ArgumentError(BgcError):
    """A public function of bgc's Python API was called with an argument it
    cannot take (the API's counterpart of a refused command-line option)."""


class ArgumentTypeError(ArgumentError, TypeError):
    """An argument of the wrong type (``bgc.diagnose(5)``); also a
    :class:`TypeError`, as Python's convention has it."""


class ArgumentValueError(ArgumentError, ValueError):
    """An argument of the right type with a value out of range
    (``particles=0``, ``seed=-1``); also a :class:`ValueError`."""


class InternalError(Exception):
    """A bug in bgc: reported with its traceback."""
