"""``bgc monitor``: a stream of rows diagnosed as they arrive, events as they happen."""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from ..errors import BgcError
from ..data.runs import open_stream
from .common import (add_backend_option, add_data_options, add_prior_option, add_workers_option, backend_note,
    check_times, parse_noise, refuse_input_in_output, rows_of, seed, status, workers, write_report)


def add_parser(sub) -> None:
    p = sub.add_parser("monitor", help="diagnose a run as its rows arrive (a file being appended to, or - for "
                                       "standard input): events as they happen, the report at the end")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--data", metavar="RUN.csv|-", required=True,
                   help="the run's CSV (as bgc simulate writes): a file, a folder or a glob pattern of a logger's "
                        "files (read in the order of their names), or - for standard input")
    p.add_argument("--follow", action="store_true",
                   help="keep reading the file as another program appends to it (until Ctrl-C, or --idle)")
    p.add_argument("--idle", type=float, default=None, metavar="SECONDS",
                   help="with --follow: end the input after this many seconds without a new row")
    p.add_argument("--filter", choices=["gpf", "apf", "opf", "ckf"], default="gpf",
                   help="the nominal observer and hypothesis filters, as for bgc diagnose")
    p.add_argument("--particles", type=int, default=1000)
    p.add_argument("--seed", type=seed, default=0, help="random seed, an integer >= 0")
    p.add_argument("--noise", metavar="process=Q,measurement=R",
                   help="relative noise levels the filters assume; default: the model's")
    add_data_options(p)
    p.add_argument("--exclude-faulty-sensor", action="store_true",
                   help="with --checkpoint: when a checkpoint isolates a sensor fault, take that sensor out of the "
                        "nominal observer and go on watching with the others (an event says so)")
    p.add_argument("--checkpoint", type=float, default=None, metavar="TIME",
                   help="while tracking hypotheses, diagnose the data so far every TIME (default: only at the end)")
    p.add_argument("--episodes", action="store_true",
                   help="with --checkpoint: go on after a verdict, keeping a fault log: a fault isolated at a "
                        "checkpoint is accommodated in the model watched from then on (or its sensor taken out), "
                        "an episode not decided within --rearm is closed and the monitor re-armed; a '# repaired' "
                        "line of the stream takes the accommodated faults out again")
    p.add_argument("--rearm", type=float, default=None, metavar="TIME",
                   help="with --episodes: close an episode not decided this long after its alarm and watch again "
                        "(default: only an isolation closes one)")
    p.add_argument("--state", metavar="DIR",
                   help="save the monitor's state in this folder (made when missing) every --state-every rows and "
                        "at the end; a state found there is taken up: a restart goes on where it stopped")
    p.add_argument("--state-every", type=int, default=None, metavar="ROWS",
                   help="with --state: rows between two saves (default 100)")
    p.add_argument("--keep", type=float, default=None, metavar="TIME",
                   help="while watching, the record kept, in the model's time unit (default: 1024 steps; at least "
                        "the onsets' reach back plus the longest window): the memory stays bounded however long "
                        "the stream runs, and the report shows the record kept")
    p.add_argument("--generated", metavar="DIR",
                   help="use the package bgc compile wrote there (default: generate one)")
    add_prior_option(p)
    p.add_argument("-o", "--output", metavar="DIR", help="report folder (default: MODEL-monitor)")
    add_backend_option(p)
    add_workers_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from .. import api
    from ..data import runs
    from ..service import monitor
    from ..output import artifacts
    from ..diagnosis.options import DiagnosisOptions

    check_times(args, ("horizon", "gap", "checkpoint", "keep", "rearm"))
    if args.idle is not None and not (math.isfinite(args.idle) and args.idle >= 0):
        raise BgcError(f"--idle {args.idle:g}: give the seconds to wait for a new row, a number >= 0", None,
                       "e.g. --idle 60")
    if args.idle is not None and not args.follow:
        raise BgcError("--idle applies to --follow", None, "add --follow, or drop --idle")
    if args.exclude_faulty_sensor and args.checkpoint is None:
        raise BgcError("--exclude-faulty-sensor acts at checkpoints: a sensor fault is isolated there", None,
                       "add --checkpoint TIME, e.g. --checkpoint 10")
    if args.rearm is not None and not args.episodes:
        raise BgcError("--rearm applies to --episodes", None, "add --episodes, or drop --rearm")
    if args.state_every is not None and args.state is None:
        raise BgcError("--state-every applies to --state", None, "add --state DIR, or drop --state-every")
    if args.follow and args.data == "-":
        raise BgcError("--follow applies to a file: standard input ends when its writer closes it", None,
                       "drop --follow, or give the file")
    process, measurement = parse_noise(args.noise)
    options = DiagnosisOptions(filter=args.filter, particles=args.particles, seed=args.seed, horizon=args.horizon,
                               gap=args.gap, recheck=args.recheck, no_fault=args.no_fault, input_timing=args.input_timing,
                               keep=args.keep, detectors=args.detect, workers=workers(args))
    rows = None if args.follow else rows_of(args.data)  # a stream followed, or standard input: not known
    session = api.open(args.model, process_noise=process, measurement_noise=measurement, generated=args.generated,
                       prior_scale=args.prior_scale, backend=args.backend,
                       work=None if rows is None else (max(args.particles, 1), rows))
    backend_note(session, args)
    reading = session.reading(args.columns)  # the column map read before the stream
    out = Path(args.output or f"{session.name}-monitor")
    refuse_input_in_output(args.data, out)
    if args.state is not None and (Path(args.state).resolve() == out.resolve()
                                   or out.resolve() in Path(args.state).resolve().parents):
        raise BgcError(f"--state {args.state} is inside the report folder {out}", None,
                       "give the state a folder of its own, e.g. --state monitor-state")
    artifacts.check_folder(out, ("report.md", "report.json", "report.html", "manifest.json"),
                           "monitor")  # before the stream
    quiet = []

    def say(line: str) -> None:  # a reader that went away (| head) stops the printing, not the diagnosis
        if quiet:
            return
        try:
            print(line, flush=True)
        except BrokenPipeError:
            quiet.append(True)
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())

    files = None if args.data == "-" else runs.run_files(args.data)  # a folder or a pattern: several files
    if args.data == "-":
        stream, name = sys.stdin.buffer, "<stdin>"
    elif files is not None:  # read one after the other; followed, the last and those that appear after it
        stream = monitor.Follow(open_stream(str(files[0])), args.idle if args.follow else 0, path=str(files[0]),
                                say=say, pattern=args.data)
        name = args.data
    else:
        if args.follow and not os.path.exists(args.data):  # a logger that starts later: its file comes
            status(args, f"waiting for {args.data} to appear" + ("" if args.idle is None else
                                                                 f" (at most {args.idle:g} s)"))
            monitor.appeared(args.data, args.idle)
        stream, name = open_stream(args.data), args.data
        if args.follow:
            stream = monitor.Follow(stream, args.idle, path=args.data, say=say)
    r, failure = monitor.monitor(session, stream, name, options, say=say, checkpoint=args.checkpoint,
                                 exclude_faulty=args.exclude_faulty_sensor, reading=reading, state=args.state,
                                 state_every=monitor.STATE_EVERY if args.state_every is None else args.state_every,
                                 episodes=args.episodes, rearm=args.rearm)
    if quiet:
        sys.stdout = open(os.devnull, "w")
    write_report(r, str(out), "monitor")
    if failure is not None:
        raise failure
    return 0
