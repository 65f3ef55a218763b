"""The command line: ``bgc COMMAND ...``, one module per command (each its
``add_parser`` and ``run``); parses, calls the pipeline or the API, prints,
picks exit codes; no logic of its own.

Exit codes: 0 success, 1 a model or a request has errors (one line each, no
traceback), 2 usage errors (argparse's convention). A closed pipe (``bgc show
... | head``) ends quietly with status 0.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Sequence

from .. import __version__
from ..errors import BgcError, printable
from . import analyse, cache, calibrate, check, compile, diagnose, distinguish, experiment, filter, monitor, show, simulate
from .common import print_errors

#: The commands, in the order ``bgc --help`` lists them.
COMMANDS = (check, compile, calibrate, show, simulate, filter, diagnose, monitor, distinguish, analyse, experiment,
            cache)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bgc", description="Bond-graph model compiler for model-based fault diagnosis.")
    parser.add_argument("--version", action="version", version=f"bgc {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help=VERBOSE)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    for p in sub.choices.values():  # after the command too: bgc diagnose ... -v
        p.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS, help=VERBOSE)
    return parser


#: What -v does.
VERBOSE = ("also say on stderr what bgc chose and did (the model compiled or read from bgc's cache, the "
           "backend and why, numba's kernels); without it stderr holds only errors and warnings")


def _quiet_stdout() -> None:
    """After a closed pipe: send what is left of stdout to /dev/null, so the
    interpreter's final flush raises nothing."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _shows(shown):
    """``warnings.showwarning`` that prints bgc's own warnings (its cache
    could not be used: :class:`bgc.api.cache.CacheWarning`) as one line on
    stderr, and others as ``shown`` does."""
    def show(message, category, filename, lineno, file=None, line=None) -> None:
        from ..api.cache import CacheWarning

        if issubclass(category, CacheWarning):
            print(printable(f"warning: {message}"), file=sys.stderr if file is None else file)
        else:
            shown(message, category, filename, lineno, file, line)
    return show


def main(argv: Sequence[str] | None = None) -> int:
    import warnings

    from ..arguments import DOOR

    parser = build_parser()
    args = parser.parse_args(argv)
    door = DOOR.set("cli")  # messages name the options typed (bgc.arguments.spelled), until main returns
    shown = warnings.showwarning
    warnings.showwarning = _shows(shown)
    try:
        return args.run(args)
    except BrokenPipeError:  # e.g. bgc show ... | head: the reader has gone, as with other CLIs
        _quiet_stdout()
        return 0
    except BgcError as exc:
        print_errors(exc)
        return 1
    except MemoryError:  # named: the command and its input files (the model, the run)
        named = [str(f) for f in getattr(args, "models", None) or []]
        named += [str(getattr(args, key)) for key in ("model", "config", "run_csv") if getattr(args, key, None)]
        named += [f"--data {args.data}"] if getattr(args, "data", None) else []
        on = f" on {', '.join(named)}" if named else ""
        print(printable(f"bgc {args.command}: out of memory{on} (use fewer particles, steps or a smaller model)"),
              file=sys.stderr)
        return 1
    except OSError as exc:  # e.g. a full disk or no permission while writing an output
        where = f"{printable(str(exc.filename))}: " if exc.filename else ""
        print(f"{where}{printable(exc.strerror or str(exc))} (check the path and the disk)", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("bgc: interrupted", file=sys.stderr)
        return 130
    finally:
        warnings.showwarning = shown
        DOOR.reset(door)
