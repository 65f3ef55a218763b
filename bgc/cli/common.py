"""What the commands share: the options of several (noise, backend, prior,
real data), the argparse types, the checks of times and output folders, the
progress line, the diagnosis report's printing, and the one-line errors."""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from ..errors import BgcError, ErrorGroup, printable
from ..kinds import fault_kind
from ..model import DEFAULT_BACKEND


def error_lines(exc: BgcError) -> tuple[str, ...]:
    return exc.lines() if isinstance(exc, ErrorGroup) else (exc.line(),)

def print_errors(exc: BgcError) -> None:
    for line in error_lines(exc):
        print(line, file=sys.stderr)

def parse_noise(text: str | None) -> tuple[float | None, float | None]:
    import math

    if not text:
        return None, None
    values: dict[str, float | None] = {"process": None, "measurement": None}
    for part in text.split(","):
        key, _, val = part.partition("=")
        key = key.strip()
        if key not in values:
            raise BgcError(f"--noise: unknown key {key!r}", None, "write process=0.03,measurement=0.02")
        try:
            values[key] = float(val)
        except ValueError:
            raise BgcError(f"--noise: {val!r} is not a number", None, "write process=0.03,measurement=0.02") from None
        if not math.isfinite(values[key]) or values[key] < 0 or values[key] > 1e6:
            raise BgcError(f"--noise: {key} level must be a finite number >= 0 and at most 1e6", None,
                           "noise levels are fractions of the signal, e.g. 0.02")
        if key == "measurement" and values[key] == 0:
            raise BgcError("--noise: measurement level 0 makes the filters' likelihood degenerate", None,
                           "give a measurement level above 0, e.g. 0.02 (as a model's sensor noise)")
    return values["process"], values["measurement"]

def check_times(args: argparse.Namespace, names) -> None:
    """Refuse --horizon, --gap, --checkpoint that are not times above 0, naming the flag."""
    for name in names:
        value = getattr(args, name, None)
        if value is not None and not (math.isfinite(value) and 0 < value <= 1e12):
            raise BgcError(f"--{name} {value:g}: give a time above 0 in the model's time unit", None,
                           f"e.g. --{name} 300")

def refuse_input_in_output(data: str | None, out: Path | None) -> None:
    """Refuse a data file inside the folder the command writes: it may hold a file of the same name."""
    if data is None or data == "-" or out is None:
        return
    try:
        inside = Path(data).resolve().parent == out.resolve()
    except OSError:
        return
    if inside:
        raise BgcError(f"--data {printable(data)} is in the output folder {printable(str(out))}, which this command "
                       "rewrites", None, "copy the run elsewhere first, or write the report to another folder (-o)")

class Progress:
    """One line on stderr saying what ``bgc COMMAND`` is doing, rewritten in
    place, on a terminal (stderr then holds only errors when it is a file or
    a pipe)."""

    def __init__(self, command: str = "diagnose"):
        self.command = command
        self.tty = sys.stderr.isatty()
        self.width = 0

    def __call__(self, text: str) -> None:
        if not self.tty:
            return
        line = printable(f"bgc {self.command}: {text}")
        sys.stderr.write("\r" + line.ljust(self.width))
        sys.stderr.flush()
        self.width = len(line)

    def close(self) -> None:
        if self.tty and self.width:
            sys.stderr.write("\r" + " " * self.width + "\r")
            sys.stderr.flush()

def rows_of(path: str | None) -> int | None:
    """About how many samples the run file ``path`` holds (its lines; for
    ``--backend auto``'s estimate of the work), None when it is not a
    regular file (standard input, a pipe) or cannot be read."""
    import stat

    if path is None or path == "-":
        return None
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return None
        lines = 0
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                lines += block.count(b"\n")
    except OSError:
        return None
    return max(lines, 1)

def verbose(args: argparse.Namespace) -> bool:
    """Whether ``-v`` was given (status lines on stderr)."""
    return bool(getattr(args, "verbose", False))

def status(args: argparse.Namespace, text: str) -> None:
    """A status line on stderr, with ``-v`` only: without it stderr holds errors and warnings alone."""
    if verbose(args):
        print(printable(f"bgc: {text}"), file=sys.stderr, flush=True)

def backend_note(session, args: argparse.Namespace) -> None:
    """With ``-v``: where the model came from (bgc's compile cache, or
    compiled), the backend and why, and on the compiled backend its kernels
    compiled (how long) or loaded. The compiled backend chosen by ``auto``
    but unavailable (running on NumPy): a warning, with or without ``-v``."""
    status(args, session.model_note())
    if session.fallback is not None:
        print(printable(f"warning: {session.backend_note()}"), file=sys.stderr, flush=True)
        return
    status(args, f"backend {session.backend} ({session.backend_reason})")
    if session.backend_note():
        status(args, session.backend_note())

def write_report(r, output: str, command: str) -> Path:
    """Write diagnosis report ``r`` into folder ``output`` (report.json,
    report.md, report.html, plots, the run when simulated:
    :func:`bgc.output.report.report_files`), print its verdict, estimate and
    notable events (the run's times as the diagnosis's clock writes them:
    ISO 8601 timestamps for a run of absolute times), and return the folder."""
    from ..output import artifacts, events, report

    files = report.report_files(r, command)
    out = Path(output)
    artifacts.write_folder(out, files)
    d = r.diagnosis
    print(f"{r.model}: {d.verdict}" + (f": {', '.join(d.candidates)}" if d.candidates else ""))
    if d.detection is not None:
        det, when = d.detection, d.clock.text(d.time_of(d.detection.step))
        if det.test == "change":  # found over the record at its end (the whole one, or the one kept while watching)
            end = ("the data's end" if det.raised >= len(d.time) - 1
                   else f"t = {d.clock.text(d.time_of(det.raised))}")
            at = f"{end} (the change test: the residuals of {det.sensor} changed at t = {when})"
        else:
            at = f"t = {when} ({det.sensor}{'' if det.test == 'mean' else f', the {det.test} test'})"
        print(f"  alarm at {at}: no fault explains the data better than chance" if d.onset is None  # a false one
              else f"  detected at {at}, onset t = {d.clock.text(d.onset)}")
    for line in report.plain_words(d, r.labels):
        print(f"  {printable(line)}")
    e = d.estimate
    if e is not None and d.verdict != "no fault" and not fault_kind(e.kind).discrete:  # (a stuck switch: no size)
        truth = f" (true {e.truth:.4g})" if e.truth is not None else ""
        edge = {"high": ", at the upper bound of its prior", "low": ", at the lower bound of its prior"}
        print(f"  {e.magnitude} of {e.parameter}: {e.value:.4g} in [{e.low:.4g}, {e.high:.4g}] "
              f"({100 * e.level:.0f} %{edge.get(e.bound, '')}){truth}")
    if command == "diagnose":
        for line in events.notes(d.events, d.time_of, clock=d.clock):
            print(f"  note: {printable(line)}")
    print(f"wrote {printable(str(out))}/: report.md, report.json, report.html, {len(files) - 4} more files "
          f"(diagnosis {d.seconds:.1f} s)")
    return out

def fault_model(c, fault: str) -> str:
    """The generated module of ``PARAM:KIND`` (a sensor's or actuator's fault
    also by its name in the model, ``F12:bias``); an unknown one as written
    (the package's check names the valid ones)."""
    try:
        return c.dbn.get(fault).name.replace(":", "_")
    except KeyError:
        return fault.replace(":", "_")

def add_prior_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--prior-scale", type=above_zero, default=1.0, metavar="K",
                   help="widen every fault's prior of its size (and drift rate) by K (default 1: the model's; a "
                        "fault's own 'size' and 'rate' in the model set it per fault)")

def add_backend_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--backend", choices=["auto", "numpy", "numba"], default=DEFAULT_BACKEND,
                   help="the generated package the filters run on: numpy, or numba (compiled; pip install "
                        "'bgc[fast]'); auto (default): numba when installed (BGC_BACKEND first). The result does "
                        "not depend on it")

def add_workers_option(p: argparse.ArgumentParser) -> None:
    """``--workers N``: the processes a diagnosis weighs its hypotheses on (:func:`workers`)."""
    from ..diagnosis.options import WORKERS, WORKERS_ENV

    p.add_argument("--workers", type=positive, default=None, metavar="N",
                   help=f"processes the hypotheses' filters run on (1: this one); default: {WORKERS_ENV} when set, "
                        f"else {WORKERS}. The result does not depend on it")


def workers(args: argparse.Namespace) -> int:
    """``--workers``, else the environment's ``BGC_WORKERS``, else 2
    (:func:`bgc.diagnosis.options.default_workers`, the API's default too)."""
    from ..diagnosis.options import default_workers

    return args.workers if args.workers is not None else default_workers()


def add_columns_option(p: argparse.ArgumentParser) -> None:
    """``--columns MAP.yaml``: a logger's columns to bgc's (bgc.data.columns)."""
    p.add_argument("--columns", metavar="MAP.yaml", default=None,
                   help="a column map: the logger's column names to bgc's (u:NAME, y:NAME), with a scale and an "
                        "offset to the model's units, and the logger's time column (docs/format.md, section 9)")


def add_signal_option(p: argparse.ArgumentParser) -> None:
    """``--input NAME=SIGNAL`` (repeatable): an input driven by another signal than the model's."""
    p.add_argument("--input", action="append", default=[], metavar="NAME=SIGNAL", dest="signals",
                   help="drive input NAME with SIGNAL instead of the model's, written as in the model's inputs "
                        "section, e.g. --input F='{signal: sine, value: 0, amplitude: 2, period: 1.5}' (sine, "
                        "square, prbs, chirp, step, ramp or a number; repeatable)")


def signals_of(texts: list[str], inputs: tuple[str, ...]) -> tuple:
    """The ``--input`` options as (name, :class:`~bgc.ir.Signal`) pairs, one per input."""
    if not texts:
        return ()  # without importing the compiler's checks (and sympy with them: 0.6 s)
    from ..compiler.validate import signal_option

    out = dict(signal_option(text, inputs) for text in texts)
    if len(out) < len(texts):
        raise BgcError("--input names an input twice", None, "give each input one signal")
    return tuple(out.items())


def add_data_options(p: argparse.ArgumentParser) -> None:
    """The options of real data, shared by bgc diagnose and bgc monitor."""
    add_columns_option(p)
    p.add_argument("--horizon", type=float, default=None, metavar="TIME",
                   help="the detector's false-alarm rate is per this much time (default: the model's run length, "
                        "simulation.steps x dt)")
    p.add_argument("--detect", type=detectors, default=("mean",), metavar="TESTS",
                   help="the detector's tests, comma-separated: mean (the residuals' windowed mean, always), drift "
                        "(long and ramp-weighted windows: slow drifts), variance (a burst of noise, a frozen "
                        "sensor), frozen (readings that repeat to the last digit), pooled (every sensor's residuals at "
                        "once, whitened: a fault that moves several a little each), matched (each fault model's own response, "
                        "matched against the Kalman observer's whitened innovations: a listed fault soonest), or "
                        "all; they share the false-alarm rate (default: mean)")
    p.add_argument("--gap", type=float, default=None, metavar="TIME",
                   help="missing samples longer than this are reported as a gap (default: 10 steps of dt)")
    p.add_argument("--input-timing", choices=("end", "start"), default=None,
                   help="what a row's u: value is: end, held over the step that ends at the row's time (bgc's own "
                        "files), or start, set at the row's time and acting until the next row (many loggers); "
                        "default: as the data's header says ('# input timing: start'), else end")
    p.add_argument("--no-recheck", dest="recheck", action="store_false",
                   help="do not weigh the fault models the symbols ruled out before a verdict (faster; trusts the "
                        "symbols, as the thesis does)")
    p.add_argument("--faults-only", dest="no_fault", action="store_false",
                   help="after an alarm, weigh the fault models alone, not no fault (a false alarm) beside them "
                        "(the thesis's verdict: an alarm always ends in a fault named or unexplained)")

def detectors(text: str) -> tuple[str, ...]:
    """An argparse type: ``--detect``'s families of tests, the mean test first and always."""
    from ..diagnosis.detect import TESTS, tests_named

    named = tests_named(text)
    if named is None:
        raise argparse.ArgumentTypeError(f"{text!r}: give some of {', '.join(TESTS)}, comma-separated, or all")
    return named


def at_least(low: int, message: str):
    """An argparse type: an integer >= ``low``; ``message`` (with ``{value}``) says what is wrong."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if value < low:
            raise argparse.ArgumentTypeError(message.format(value=value))
        return value
    return parse

positive = at_least(1, "{value}: give an integer >= 1")

#: --seed: NumPy's generators take no negative seed.
seed = at_least(0, "{value} is negative: give an integer >= 0")

def above_zero(text: str) -> float:
    """An argparse type: a finite number above 0."""
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text}: give a number above 0")
    return value
