"""Checks of the arguments of bgc's Python API, as the command line checks
its options: a wrong type is an :class:`~bgc.errors.ArgumentTypeError` (also
a :class:`TypeError`), a value out of range an
:class:`~bgc.errors.ArgumentValueError` (also a :class:`ValueError`), each
one line naming the function (``func``) and the argument.

>>> integer("bgc.diagnose", "particles", 100.5, 1, "at least 1 particle is needed", "particles=1000")
Traceback (most recent call last):
...
bgc.errors.ArgumentTypeError: bgc.diagnose: particles=100.5 is not an integer (give an integer >= 1, e.g. particles=1000)
"""

from __future__ import annotations

import math
import numbers
import os
from contextvars import ContextVar

import numpy as np

from .errors import ArgumentTypeError, ArgumentValueError, printable

#: The largest relative noise level (``bgc ... --noise``).
MAX_NOISE = 1e6


#: Which door the request came in by: ``python`` (the API) or ``cli`` (set by :func:`bgc.cli.main.main`).
DOOR: ContextVar[str] = ContextVar("bgc_door", default="python")


def spelled(python: str, flag: str) -> str:
    """A request's name as the caller wrote it: the Python argument
    (``scenario``) from the API, the option (``--scenario``) from the
    command line (:data:`DOOR`), so that a message names what the user typed.

    >>> spelled("steps", "--steps")
    'steps'
    """
    return flag if DOOR.get() == "cli" else python


def renamed(func: str, new: str, value, old: str, old_value, default=None):
    """The value of argument ``new``, given as it is or under its old name
    ``old`` (then with a :class:`DeprecationWarning`); both given is an
    :class:`~bgc.errors.ArgumentValueError`. ``default`` when neither is."""
    import warnings

    if old_value is None:
        return default if value is None else value
    if value is not None:
        raise ArgumentValueError(f"{func}: {new}={shown(value)} and {old}={shown(old_value)} name one thing", None,
                                 f"give {new}= alone ({old}= is its old name)")
    warnings.warn(f"{func}: {old}= is deprecated, its name is {new}= (as the command line's --{new})",
                  DeprecationWarning, stacklevel=3)
    return old_value


def is_integer(value) -> bool:
    """Whether ``value`` is an integer (Python's or NumPy's; a bool is not one here)."""
    return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))


def is_real(value) -> bool:
    """Whether ``value`` is a real number (a bool is not one here)."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def as_float(value) -> float:
    """A real number as a float; an integer beyond the floats (``10**400``) as
    an infinity of its sign, for the range check that follows to refuse."""
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def shown(value) -> str:
    """A value as an argument is shown in a message: its repr, shortened."""
    try:
        text = repr(value)
    except Exception:  # noqa: BLE001 - any repr of a caller's object may fail; the type still says it
        text = f"<{type(value).__name__}>"
    return printable(text if len(text) <= 40 else text[:37] + "...")


def integer(func: str, name: str, value, low: int | None, below: str, example: str) -> None:
    """An integer (a bool is not one here) >= ``low`` (None: any); ``below`` says what a smaller one is."""
    if not is_integer(value):
        raise ArgumentTypeError(f"{func}: {name}={shown(value)} is not an integer", None,
                                f"give an integer{'' if low is None else f' >= {low}'}, e.g. {example}")
    if low is not None and value < low:
        raise ArgumentValueError(f"{func}: {name}={int(value)} {below}" if below.startswith("is ")
                                 else f"{func}: {name}={int(value)}: {below}", None,
                                 f"give an integer >= {low}, e.g. {example}")


def real(func: str, name: str, value, low: float, high: float, what: str, low_ok: bool = False,
          high_ok: bool = False) -> None:
    """A finite real number (not a bool) between ``low`` and ``high`` (each included when ``*_ok``)."""
    if not is_real(value):
        raise ArgumentTypeError(f"{func}: {name}={shown(value)} is not a number", None, f"give {what}")
    v = as_float(value)
    if not (math.isfinite(v) and (low <= v if low_ok else low < v) and (v <= high if high_ok else v < high)):
        raise ArgumentValueError(f"{func}: {name}={v:g} is out of range", None, f"give {what}")


def noise_levels(func: str, process: float | None, measurement: float | None) -> None:
    """Relative noise levels as ``--noise`` takes them: finite, >= 0, at most
    ``MAX_NOISE``; the measurement level above 0."""
    for name, value in (("process_noise", process), ("measurement_noise", measurement)):
        if value is None:
            continue
        if not is_real(value):
            raise ArgumentTypeError(f"{func}: {name}={shown(value)} is not a number", None,
                                    "noise levels are fractions of the signal, e.g. 0.02")
        level = as_float(value)
        if not (math.isfinite(level) and 0 <= level <= MAX_NOISE):
            raise ArgumentValueError(f"{func}: {name}={level:g}: a level must be a finite number >= 0 and at most 1e6",
                                     None, "noise levels are fractions of the signal, e.g. 0.02")
    if measurement is not None and measurement == 0:
        raise ArgumentValueError(f"{func}: measurement_noise=0: a noiseless sensor makes the filters' likelihood "
                                 "degenerate", None, "give a measurement level above 0, e.g. 0.02")


def path(func: str, name: str, value, optional: bool = False) -> None:
    """A file or folder path (str or os.PathLike); None too when ``optional``."""
    if value is None and optional:
        return
    if not isinstance(value, (str, os.PathLike)):
        raise ArgumentTypeError(f"{func}: {name}={shown(value)} is not a path", None,
                                "give a str or a pathlib.Path")


def text(func: str, name: str, value, optional: bool = False) -> None:
    """A str; None too when ``optional``."""
    if value is None and optional:
        return
    if not isinstance(value, str):
        raise ArgumentTypeError(f"{func}: {name}={shown(value)} is not a string", None,
                                "e.g. 'R_pipe:incipient:0.5@165'" if name == "scenario" else "give a str")


def choice(func: str, name: str, value, choices: tuple[str, ...]) -> None:
    """One of ``choices`` (a str that is not one is out of range, anything else of the wrong type)."""
    if not isinstance(value, str) or value not in choices:
        error = ArgumentValueError if isinstance(value, str) else ArgumentTypeError
        raise error(f"{func}: {name}={shown(value)} is not one of {', '.join(choices)}", None,
                    f"give e.g. {name.rpartition('.')[2]}={choices[0]!r}")


def flag(func: str, name: str, value) -> None:
    """True or False, nothing else (1 and "no" are not flags)."""
    if not isinstance(value, bool):
        raise ArgumentTypeError(f"{func}: {name}={shown(value)} is not True or False", None,
                                f"give {name}=True or {name}=False")


def callable_or_none(func: str, name: str, value) -> None:
    """A function (``progress``), or None."""
    if value is not None and not callable(value):
        raise ArgumentTypeError(f"{func}: {name}={shown(value)} is not callable", None,
                                "give a function of one str, or None")
