"""Command-line interface: parses, calls the pipeline or the runtime, prints,
picks exit codes; no logic of its own.

Exit codes: 0 success, 1 a model or a request has errors (one line each, no
traceback), 2 usage errors (argparse's convention). A closed pipe (``bgc show
... | head``) ends quietly with status 0.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path
from typing import Sequence

from . import __version__, pipeline
from .errors import BgcError, ErrorGroup, printable
from .model import warmup


def _error_lines(exc: BgcError) -> tuple[str, ...]:
    return exc.lines() if isinstance(exc, ErrorGroup) else (exc.line(),)


def _report(exc: BgcError) -> None:
    for line in _error_lines(exc):
        print(line, file=sys.stderr)


def cmd_check(args: argparse.Namespace) -> int:
    from .output import render

    status = 0
    for path in args.models:
        try:
            c = pipeline.compile_model(path)
        except BgcError as exc:
            _report(exc)
            status = 1
            continue
        print(render.check_summary(c.equations, c.numerics))
    return status


def cmd_compile(args: argparse.Namespace) -> int:
    from .output import artifacts

    failed = 0
    for path in args.models:
        start = time.perf_counter()
        try:
            c = pipeline.compile_model(path)
            texts = pipeline.generated_files(c)
            outdir = Path(args.output) / c.model.name
            if args.check:
                diffs = artifacts.diff(outdir, texts)
                if diffs:
                    for d in diffs:
                        print(printable(d) if d.startswith("missing: ") else d, file=sys.stderr, end="" if
                              d.endswith("\n") else "\n")
                    print(f"{printable(str(outdir))}: out of date; refresh with: bgc compile {printable(str(path))}",
                          file=sys.stderr)
                    return 1
                print(f"{printable(str(outdir))}: up to date ({len(texts)} files)")
                continue
            files: dict[str, str | bytes] = dict(texts)
            if not args.no_pictures:
                files.update(pipeline.pictures(c, args.engine))
            artifacts.write_folder(outdir, files)
        except BgcError as exc:  # report, and go on with the other models (as bgc check does)
            _report(exc)
            failed = 1
            continue
        seconds = time.perf_counter() - start
        n_dbn = 1 + len(c.dbn.faulty)
        print(f"{printable(str(path))}: wrote {printable(str(outdir))}/ ({len(files)} files: equations, TCG, "
              f"{n_dbn} DBNs{'' if args.no_pictures else ', pictures'}) in {seconds:.2f} s")
        for d in c.causal.diagnostics:
            print(printable(f"  {d.severity}: {d.message}"))
    return failed


def cmd_show(args: argparse.Namespace) -> int:
    from .output import artifacts, draw, render

    stage, fmt = args.stage, args.format
    if args.fault and stage != "dbn":
        raise BgcError("--fault applies to 'bgc show dbn' only", None, "drop --fault or show the dbn stage")
    texts = {
        ("bondgraph", "text"): lambda: render.bondgraph_text(causal),
        ("bondgraph", "json"): lambda: render.to_json(render.bondgraph_json(causal)),
        ("bondgraph", "dot"): lambda: render.bondgraph_dot(causal),
        ("causality", "text"): lambda: render.causality_text(causal),
        ("causality", "json"): lambda: render.to_json(render.causality_json(causal)),
        ("causality", "dot"): lambda: render.bondgraph_dot(causal),
        ("tcg", "text"): lambda: render.tcg_text(c.tcg),
        ("tcg", "json"): lambda: render.to_json(render.tcg_json(c.tcg)),
        ("tcg", "dot"): lambda: render.tcg_dot(c.tcg),
        ("equations", "text"): lambda: render.equations_text(c.equations),
        ("equations", "json"): lambda: render.to_json(render.equations_json(c.equations)),
        ("equations", "latex"): lambda: render.equations_latex(c.equations),
        ("signatures", "text"): lambda: render.signatures_text(c.signatures, c.numerics),
        ("signatures", "json"): lambda: render.to_json(render.signatures_json(c.signatures)),
        ("dbn", "text"): lambda: render.dbn_text(d),
        ("dbn", "json"): lambda: render.to_json(render.dbn_json(d)),
        ("dbn", "dot"): lambda: render.dbn_dot(d),
    }
    pictures = {"bondgraph", "causality", "tcg", "dbn"}
    if (stage, fmt) not in texts and not (fmt in ("svg", "png") and stage in pictures):
        valid = sorted(f for s_, f in texts if s_ == stage) + (["svg", "png"] if stage in pictures else [])
        raise BgcError(f"stage {stage} has no format {printable(fmt)}", None, f"use one of: {', '.join(valid)}")
    if stage in ("bondgraph", "causality"):  # only as far as causality: it shows why a later stage fails
        causal = pipeline.assign_causality(args.model)
        model_name = causal.model.name
    else:
        c = pipeline.compile_model(args.model)
        model_name = c.model.name
    d = None
    if stage == "dbn":
        name = args.fault or "nominal"
        if args.fault and name.count(":") != 1:
            raise BgcError(f"--fault {name!r}: expected PARAM:KIND", None, "e.g. --fault R_pipe:incipient")
        try:
            d = c.dbn.get(name)
        except KeyError as exc:
            raise BgcError(str(exc.args[0]), None, "pick a fault candidate and kind the model declares") from None
    if fmt in ("svg", "png"):
        if stage in ("bondgraph", "causality"):  # the causal strokes are the causality
            data = draw.bondgraph_picture(causal, fmt, args.engine)
        elif stage == "tcg":
            data = draw.tcg_picture(c.tcg, fmt, args.engine)
        else:
            data = draw.dbn_picture(d, fmt, args.engine)
        suffix = f"-{artifacts.dbn_file_stem(d.name)}" if stage == "dbn" else ""
        out = Path(args.output or f"{model_name}-{stage}{suffix}.{fmt}")
        artifacts.write_file(out, data)
        print(f"wrote {printable(str(out))}")
        return 0
    text = texts[(stage, fmt)]()
    if args.output:
        source = causal.model.display_source if stage in ("bondgraph", "causality") else c.model.display_source
        artifacts.write_file(Path(args.output), artifacts.mark_text(text, fmt, source))
        print(f"wrote {printable(args.output)}")
    else:
        sys.stdout.write(text)
        sys.stdout.flush()
    return 0


def _parse_noise(text: str | None) -> tuple[float | None, float | None]:
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


def cmd_simulate(args: argparse.Namespace) -> int:
    from .output import artifacts
    from .analysis import simulate as sim

    c = pipeline.compile_model(args.model, args.prior_scale)
    process, measurement = _parse_noise(args.noise)
    fault = sim.parse_fault(args.fault, c.numerics) if args.fault else None
    if args.steps is not None:
        sim.check_steps(args.steps, c.numerics, "--steps")
    unexpected = sim.outside_prior(fault, c.numerics) if fault else None
    if unexpected:
        print(f"warning: {unexpected}", file=sys.stderr)
    options = sim.SimulationOptions(steps=args.steps, process_noise=process, measurement_noise=measurement,
                                    seed=args.seed, fault=fault)
    start = time.perf_counter()
    result = sim.simulate(c.numerics, options)
    out = Path(args.output or f"{c.model.name}-run.csv")
    artifacts.write_file(out, sim.to_csv(result))
    print(f"wrote {printable(str(out))}: {len(result.time)} steps of {c.model.name}, fault: "
          f"{fault.describe() if fault else 'none'} ({time.perf_counter() - start:.2f} s)")
    if args.plot:
        from .output import plots
        from .output.labels import labels_of

        artifacts.write_file(Path(args.plot), plots.simulation_figure(
            result, "png", labels_of(c.model), sim.noise_free(c.numerics, options).clean_measurements))
        print(f"wrote {printable(args.plot)}")
    return 0


def cmd_filter(args: argparse.Namespace) -> int:
    import numpy as np

    from .output import artifacts
    from .data import runs
    from .analysis import track
    from .model import package as packages

    c = pipeline.compile_model(args.model)
    run = runs.read_run(args.run_csv)
    track.check_run_of(run, c.model.name, args.run_csv)
    backend = packages.resolve_backend(args.backend)
    package = packages.load_package(args.generated, c.model.name, args.model, backend=backend)
    name = _fault_model(c, args.fault) if args.fault else "nominal"
    seconds, compiled, _ = warmup.warm_up(package, steps=(name,))  # the filtered model's whole step
    if compiled:
        print(f"numba backend: {compiled} kernels compiled in {seconds:.1f} s (kept in numba's disk cache)",
              file=sys.stderr)
    track.check_request(run, package, name, args.particles, args.start)
    from .output.labels import labels_of

    results = []
    for method in (["gpf", "apf"] if args.method == "both" else [args.method]):
        r = track.track(run, package, name, method, args.particles, args.seed, args.start)
        results.append(r)
        rmse = ", ".join(f"{x} {v:.4g}" for x, v in r.rmse(run).items())
        print(f"{method.upper()} on {name}, N = {args.particles}: {len(r.time)} steps in {r.seconds:.3f} s, "
              f"mean ESS {float(np.mean(r.ess)):.0f}, resampled {int(r.resampled.sum())} times, "
              f"recoveries {r.recoveries}")
        print("  RMSE vs truth: " + (rmse or "no truth in the run"))
        last = ", ".join(f"{x} {m:.4g} +- {s:.2g}" for x, m, s in zip(r.state_names, r.mean[-1], r.std[-1]))
        print(f"  final estimate: {last}")
        est = track.fault_estimate(r, package, run, labels_of(c.model).per_time)
        if est is not None:
            true_text = ""
            if est.truth is not None:
                true_text = f" (true {est.truth:.4g}, error {100 * est.relative_error:.1f} %)"
            print(f"  estimate of {est.what} at t = {est.time:g}: {est.value:.4g} +- {est.std:.2g}{true_text}")
    if args.plot:
        from .output import plots

        artifacts.write_file(Path(args.plot), plots.tracking_figure(run, results, "png", labels_of(c.model)))
        print(f"wrote {printable(args.plot)}")
    return 0


def _fault_model(c, fault: str) -> str:
    """The generated module of ``PARAM:KIND`` (a sensor's or actuator's fault
    also by its name in the model, ``F12:bias``); an unknown one as written
    (the package's check names the valid ones)."""
    try:
        return c.dbn.get(fault).name.replace(":", "_")
    except KeyError:
        return fault.replace(":", "_")


def cmd_diagnose(args: argparse.Namespace) -> int:
    from . import api
    from .diagnosis.options import DiagnosisOptions

    if (args.data is None) == (args.scenario is None):
        raise BgcError("give --data RUN.csv or --scenario NAME:KIND:MAGNITUDE@TIME", None,
                       "e.g. --scenario R_pipe:incipient:0.5@165, or --scenario none for a fault-free run")
    if args.data is not None and args.steps is not None:
        raise BgcError("--steps applies to --scenario: a recorded run has its own length", None,
                       "drop --steps, or simulate a scenario")
    _check_times(args, ("horizon", "gap"))
    _refuse_input_in_output(args.data, Path(args.output) if args.output else None)
    process, measurement = _parse_noise(args.noise)
    progress = _Progress()
    try:
        options = DiagnosisOptions(method=args.filter, particles=args.particles, seed=args.seed,
                                   identify=args.identify, rank=args.rank, refine=args.refine,
                                   horizon=args.horizon, gap=args.gap, recheck=args.recheck)
        session = api.open(args.model, process_noise=process, measurement_noise=measurement,
                           generated=args.generated, prior_scale=args.prior_scale, backend=args.backend)
        _backend_note(session)
        r = api.diagnose(session, data=args.data, scenario=args.scenario, seed=args.seed, steps=args.steps,
                         options=options, progress=progress)
    finally:
        progress.close()
    _write_report(r, args.output or f"{r.model}-diagnosis", "diagnose")
    return 0


def _backend_note(session) -> None:
    """On the compiled backend, one line on stderr: its kernels compiled (how long) or loaded."""
    if session.backend_note():
        print(f"bgc: {session.backend_note()}", file=sys.stderr, flush=True)


def _write_report(r, output: str, command: str) -> Path:
    """Write diagnosis report ``r`` into folder ``output`` (report.json,
    report.md, report.html, plots, the run when simulated:
    :func:`bgc.output.report.report_files`), print its verdict, estimate and
    notable events, and return the folder."""
    from .output import artifacts, events, report

    files = report.report_files(r, command)
    out = Path(output)
    artifacts.write_folder(out, files)
    d = r.diagnosis
    print(f"{r.model}: {d.verdict}" + (f": {', '.join(d.candidates)}" if d.candidates else ""))
    if d.detection is not None:
        print(f"  detected at t = {events.time_text(d.time_of(d.detection.step))} ({d.detection.sensor}), "
              f"onset t = {events.time_text(d.time_of(d.onset))}")  # a logger's Unix time in full
    for line in report.plain_words(d, r.labels):
        print(f"  {printable(line)}")
    e = d.estimate
    if e is not None and d.verdict != "no fault":
        truth = f" (true {e.truth:.4g})" if e.truth is not None else ""
        edge = {"high": ", at the upper bound of its prior", "low": ", at the lower bound of its prior"}
        print(f"  {e.magnitude} of {e.parameter}: {e.value:.4g} in [{e.low:.4g}, {e.high:.4g}] "
              f"({100 * e.level:.0f} %{edge.get(e.bound, '')}){truth}")
    if command == "diagnose":
        for line in events.notes(d.events, d.time_of):
            print(f"  note: {printable(line)}")
    print(f"wrote {printable(str(out))}/: report.md, report.json, report.html, {len(files) - 4} more files "
          f"(diagnosis {d.seconds:.1f} s)")
    return out


def cmd_monitor(args: argparse.Namespace) -> int:
    from . import api
    from .service import monitor
    from .output import artifacts
    from .diagnosis.options import DiagnosisOptions

    _check_times(args, ("horizon", "gap", "checkpoint"))
    if args.idle is not None and not (math.isfinite(args.idle) and args.idle >= 0):
        raise BgcError(f"--idle {args.idle:g}: give the seconds to wait for a new row, a number >= 0", None,
                       "e.g. --idle 60")
    if args.idle is not None and not args.follow:
        raise BgcError("--idle applies to --follow", None, "add --follow, or drop --idle")
    if args.exclude_faulty_sensor and args.checkpoint is None:
        raise BgcError("--exclude-faulty-sensor acts at checkpoints: a sensor fault is isolated there", None,
                       "add --checkpoint TIME, e.g. --checkpoint 10")
    if args.follow and args.data == "-":
        raise BgcError("--follow applies to a file: standard input ends when its writer closes it", None,
                       "drop --follow, or give the file")
    process, measurement = _parse_noise(args.noise)
    options = DiagnosisOptions(method=args.filter, particles=args.particles, seed=args.seed, horizon=args.horizon,
                               gap=args.gap, recheck=args.recheck)
    session = api.open(args.model, process_noise=process, measurement_noise=measurement, generated=args.generated,
                       prior_scale=args.prior_scale, backend=args.backend)
    _backend_note(session)
    out = Path(args.output or f"{session.name}-monitor")
    _refuse_input_in_output(args.data, out)
    artifacts.check_folder(out, ("report.md", "report.json", "report.html", "manifest.json"),
                           "monitor")  # before the stream
    if args.data == "-":
        stream, name = sys.stdin.buffer, "<stdin>"
    else:
        stream, name = _open_stream(args.data), args.data
        if args.follow:
            stream = monitor.Follow(stream, args.idle, path=args.data)
    quiet = []

    def say(line: str) -> None:  # a reader that went away (| head) stops the printing, not the diagnosis
        if quiet:
            return
        try:
            print(line, flush=True)
        except BrokenPipeError:
            quiet.append(True)
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())

    r, failure = monitor.monitor(session, stream, name, options, say=say, checkpoint=args.checkpoint,
                                 exclude_faulty=args.exclude_faulty_sensor)
    if quiet:
        sys.stdout = open(os.devnull, "w")
    _write_report(r, str(out), "monitor")
    if failure is not None:
        raise failure
    return 0


def _check_times(args: argparse.Namespace, names) -> None:
    """Refuse --horizon, --gap, --checkpoint that are not times above 0, naming the flag."""
    for name in names:
        value = getattr(args, name, None)
        if value is not None and not (math.isfinite(value) and 0 < value <= 1e12):
            raise BgcError(f"--{name} {value:g}: give a time above 0 in the model's time unit", None,
                           f"e.g. --{name} 300")


def _refuse_input_in_output(data: str | None, out: Path | None) -> None:
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


def _open_stream(path: str):
    """A run file or a named pipe, opened for reading (not a device that never ends)."""
    import stat

    try:
        mode = os.stat(path).st_mode
        if not (stat.S_ISREG(mode) or stat.S_ISFIFO(mode)):
            raise BgcError(f"{printable(path)} is not a regular file or a pipe", None,
                           "give a run file, a named pipe, or - for standard input")
        return open(path, "rb")
    except OSError as exc:
        raise BgcError(f"{printable(path)}: {printable(exc.strerror or str(exc))}", None,
                       "give a run file, or - for standard input") from None


def cmd_distinguish(args: argparse.Namespace) -> int:
    from . import api
    from .output import artifacts, plots, render

    process, measurement = _parse_noise(args.noise)
    progress = _Progress("distinguish")
    try:
        r = api.distinguishability(args.model, args.scenario, change=args.change, at=args.at,
                                   process_noise=process, measurement_noise=measurement, steps=args.steps,
                                   progress=progress)
    finally:
        progress.close()
    text = render.to_json(render.distinguishability_json(r)) if args.format == "json" else \
        render.distinguishability_text(r)
    if args.output:
        artifacts.write_file(Path(args.output), artifacts.mark_text(text, args.format, r.source))
        print(f"wrote {printable(args.output)}")
    else:
        sys.stdout.write(text)
        sys.stdout.flush()
    if args.plot:
        artifacts.write_file(Path(args.plot), plots.distinguishability_figure(r, "png"))
        print(f"wrote {printable(args.plot)}")
    return 0


def cmd_experiment(args: argparse.Namespace) -> int:
    from .experiment import campaign
    from .output import tables
    from .model import package as packages

    # local workers get a name (numba compiled once, before they start); a Dask cluster's workers choose
    # by what they have installed
    backend = packages.resolve_backend(args.backend) if not args.scheduler else args.backend

    # what can be refused without the models: before they compile
    campaign.check_workers(args.workers, "--workers")
    if args.scheduler:
        campaign.check_scheduler(args.scheduler, args.connect_timeout)
        if args.workers is not None:
            print("bgc: --workers is for local processes: the Dask cluster's own workers run the campaign",
                  file=sys.stderr)
    c = campaign.load_campaign(args.config, max_runs=args.max_runs)
    out = Path(args.output or Path("out") / c.name)
    folder = printable(str(out))

    def started(s: campaign.CampaignStart) -> None:
        if s.quarantined:
            print(f"bgc: {s.quarantined} line{'s' if s.quarantined > 1 else ''} of {folder}/{campaign.RUNS} could "
                  f"not be read: kept as they were in {printable(str(s.quarantine))} (a run among them runs again)",
                  file=sys.stderr)
        if s.workers is not None and s.limited_by == "memory":
            print(f"bgc: starting {s.workers} local processes: the available memory holds no more at "
                  f"{campaign.WORKER_MEMORY // 2**20} MiB each", file=sys.stderr)
        elif s.workers is not None and s.limited_by == "runs" and s.requested is not None:
            print(f"bgc: --workers {s.requested}: starting {s.workers} local process{'es' if s.workers > 1 else ''}"
                  f", one per run to do", file=sys.stderr)
        where = (f"the Dask cluster at {printable(args.scheduler)}" if s.workers is None else
                 f"{s.workers} local process{'es' if s.workers != 1 else ''}")
        plan = f"{s.total} runs" if not s.reused else f"{s.total} runs ({s.reused} done before, {s.todo} to run)"
        if s.todo:
            print(f"campaign {c.name}: {plan} on {where}, results in {folder}/", file=sys.stderr)
        else:
            print(f"campaign {c.name}: {plan}: every run done before, results in {folder}/", file=sys.stderr)

    try:
        r = campaign.run_campaign(c, out, scheduler=args.scheduler, workers=args.workers,
                                  progress=None if not args.no_progress else False,
                                  connect_timeout=args.connect_timeout, on_start=started,
                                  backend=backend)
    except KeyboardInterrupt:
        print(f"bgc: interrupted; finished runs are in {folder}/{campaign.RUNS}: run the same command "
              "to resume", file=sys.stderr)
        return 130
    print(tables.summary_markdown(list(r.rows)), end="")
    kept = (f"; {r.quarantined} unreadable line{'s' if r.quarantined > 1 else ''} of {campaign.RUNS} kept in "
            f"{printable(str(r.quarantine))}" if r.quarantined else "")
    print(f"{c.name}: {r.ran} runs done, {r.reused} reused from an earlier run, {r.failed} failed "
          f"({r.seconds:.1f} s); tables in {folder}/tables.md, the page with tables and plots in "
          f"{folder}/report.html, plots in {folder}/plots/{kept}")
    return 1 if r.failed and r.failed == r.ran and r.ran else 0


class _Progress:
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


def cmd_calibrate(args: argparse.Namespace) -> int:
    import bgc

    from .api import check_calibration_output

    from .output import artifacts, calibration_report

    out = Path(args.output)
    folder = Path(args.report) if args.report else out.with_name(out.stem + "-report")
    check_calibration_output(out, args.model, args.data)  # before any work
    for item in args.data:
        _refuse_input_in_output(item, folder)
    artifacts.check_folder(folder, (*calibration_report.PICTURES, "report.md", "report.json", "report.html",
                                    "manifest.json"),
                           "calibrate")
    start = time.perf_counter()
    session = bgc.open(args.model, backend=args.backend)
    _backend_note(session)
    report = session.calibrate(list(args.data), args.estimate)
    report.write(out)
    report.write_report(folder)
    cal = report.calibration
    print(f"wrote {printable(str(out))}: {report.name} calibrated on {cal.samples} samples of "
          f"{', '.join(printable(s) for s in cal.sources)} ({time.perf_counter() - start:.1f} s); report in "
          f"{printable(str(folder))}")
    for e in cal.estimates:
        if not e.identifiable:
            print(printable(f"  {e.name}: not identifiable, kept at {e.start_level:.6g} ({e.why})"))
            continue
        std = f" (std {e.value:.4g} in [{e.low:.4g}, {e.high:.4g}])" if e.kind == "measurement_noise" else ""
        bound = ""
        if e.at_bound:
            bound = ", the data show none" if e.value == 0 else ", at the end of the range searched"
        print(printable(f"  {e.name}: {e.level:.6g} in [{e.level_low:.6g}, {e.level_high:.6g}] (95 %){std}, "
                        f"was {e.start_level:.6g}{bound}"))
    for i in cal.innovations:
        print(printable(f"  innovations of {i.sensor}: mean {i.mean:+.3f}, variance {i.variance:.3f}, Ljung-Box "
                        f"p = {i.p_value:.3g} ({i.lags} lags)"))
    print(printable(f"  {cal.verdict}"))
    return 0


def _add_prior_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--prior-scale", type=_above_zero, default=1.0, metavar="K",
                   help="widen every fault's prior of its size (and drift rate) by K (default 1: the model's; a "
                        "fault's own 'size' and 'rate' in the model set it per fault)")


def _add_backend_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--backend", choices=["auto", "numpy", "numba"], default="auto",
                   help="the generated package the filters run on: numpy, or numba (compiled; pip install "
                        "'bgc[fast]'); auto (default): numba when installed (BGC_BACKEND first). The result does "
                        "not depend on it")


def _add_data_options(p: argparse.ArgumentParser) -> None:
    """The options of real data, shared by bgc diagnose and bgc monitor."""
    p.add_argument("--horizon", type=float, default=None, metavar="TIME",
                   help="the detector's false-alarm rate is per this much time (default: the model's run length, "
                        "simulation.steps x dt)")
    p.add_argument("--gap", type=float, default=None, metavar="TIME",
                   help="missing samples longer than this are reported as a gap (default: 10 steps of dt)")
    p.add_argument("--no-recheck", dest="recheck", action="store_false",
                   help="do not weigh the fault models the symbols ruled out before a verdict (faster; trusts the "
                        "symbols, as the thesis does)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bgc", description="Bond-graph model compiler for model-based fault diagnosis.")
    parser.add_argument("--version", action="version", version=f"bgc {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    p = sub.add_parser("check", help="check models through every compiler stage and print a summary")
    p.add_argument("models", nargs="+", metavar="MODEL", help="model files (YAML)")
    p.set_defaults(run=cmd_check)

    p = sub.add_parser("compile", help="compile models into DIR/<model>/ (equations, TCG, DBNs, package, pictures)")
    p.add_argument("models", nargs="+", metavar="MODEL")
    p.add_argument("-o", "--output", default="generated", metavar="DIR",
                   help="output root (default: generated); bgc writes DIR/<model>/ only if it is empty or bgc wrote it")
    p.add_argument("--no-pictures", action="store_true", help="skip the SVG pictures")
    p.add_argument("--check", action="store_true", help="compare with DIR instead of writing; exit 1 on a difference")
    p.add_argument("--engine", choices=["auto", "graphviz", "matplotlib"], default="auto",
                   help="picture renderer (auto: Graphviz dot when installed)")
    p.set_defaults(run=cmd_compile)

    p = sub.add_parser("calibrate", help="estimate noise levels and nominal values from healthy recordings, and "
                                         "write the calibrated model (a new YAML)")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--data", nargs="+", required=True, metavar="HEALTHY.csv",
                   help="fault-free recordings of the plant (run files, as bgc simulate writes)")
    p.add_argument("--estimate", default="noise", metavar="WHAT",
                   help="what to estimate, separated by commas: noise (every sensor's noise and the process "
                        "level), measurement_noise, process_noise, initial (each recording's initial state), "
                        "parameter names (default: noise)")
    p.add_argument("-o", "--output", required=True, metavar="CALIBRATED.yaml",
                   help="the calibrated model: a new file (never the model file, nor a file bgc did not write)")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="the calibration report's folder: report.md, report.json, report.html, pictures (default: "
                        "CALIBRATED-report beside the calibrated model)")
    _add_backend_option(p)
    p.set_defaults(run=cmd_calibrate)

    p = sub.add_parser("show", help="print or render one stage of a model (bondgraph: the causal bond graph "
                                    "drawn, with power half-arrows and causal strokes)")
    p.add_argument("stage", choices=["bondgraph", "causality", "tcg", "equations", "signatures", "dbn"])
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--fault", metavar="PARAM:KIND",
                   help="with dbn: the faulty DBN, e.g. R_pipe:incipient, or a sensor's P_memb:bias")
    p.add_argument("--format", default="text", metavar="FORMAT",
                   help="text, json, dot, latex (equations) or a picture: svg, png (bondgraph, causality, tcg, dbn)")
    p.add_argument("-o", "--output", metavar="FILE", help="write to FILE (pictures default to MODEL-STAGE.FMT)")
    p.add_argument("--engine", choices=["auto", "graphviz", "matplotlib"], default="auto")
    p.set_defaults(run=cmd_show)

    p = sub.add_parser("simulate", help="simulate the plant (truth) with noise and an injected fault, to CSV")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--steps", type=int, default=None, help="number of samples (default: the model's)")
    p.add_argument("--fault", metavar="NAME:KIND:MAGNITUDE@TIME",
                   help="inject a fault, e.g. R_pipe:incipient:0.5@165 (slope per unit time), R_pipe:abrupt:31@165 "
                        "(bias), a sensor's P_memb:bias:0.3@100 or an actuator's u_pump:gain:-0.2@100")
    p.add_argument("--noise", metavar="process=Q,measurement=R", help="noise levels as fractions of the signal")
    p.add_argument("--seed", type=_seed, default=0, help="random seed, an integer >= 0")
    p.add_argument("-o", "--output", metavar="FILE.csv")
    p.add_argument("--plot", metavar="FILE.png", help="also plot measurements and states")
    _add_prior_option(p)
    p.set_defaults(run=cmd_simulate)

    p = sub.add_parser("filter", help="run a generated particle filter (GPF/APF) over a recorded run")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("run_csv", metavar="RUN.csv", help="a CSV written by bgc simulate")
    p.add_argument("--fault", metavar="PARAM:KIND", help="track with this fault model (default: nominal)")
    p.add_argument("--method", choices=["gpf", "apf", "opf", "both"], default="both",
                   help="gpf, apf, opf (the locally optimal proposal) or both (gpf and apf)")
    p.add_argument("--particles", type=int, default=200)
    p.add_argument("--seed", type=_seed, default=0, help="random seed, an integer >= 0")
    p.add_argument("--start", type=float, metavar="T",
                   help="with --fault: track the nominal model until T, then the fault model (its fault from the "
                        "sample at T)")
    p.add_argument("--generated", default="generated", metavar="DIR",
                   help="where bgc compile wrote the package (its -o DIR; default: generated)")
    p.add_argument("--plot", metavar="FILE.png")
    _add_backend_option(p)
    p.set_defaults(run=cmd_filter)

    p = sub.add_parser("diagnose", help="detect, isolate and identify a fault in a run (report and plots)")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--data", metavar="RUN.csv", help="a recorded run (a CSV as bgc simulate writes)")
    p.add_argument("--scenario", metavar="NAME:KIND:MAGNITUDE@TIME",
                   help="simulate this fault (or 'none'), then diagnose, e.g. R_pipe:incipient:0.5@165; MAGNITUDE "
                        "is an abrupt fault's bias (in the parameter's units) or an incipient fault's slope (per "
                        "unit of time)")
    p.add_argument("--filter", choices=["gpf", "apf", "opf", "ckf"], default="gpf",
                   help="gpf (the thesis's generic filter), apf (auxiliary), opf (the locally optimal proposal) or "
                        "ckf (cubature Kalman filters alone, no particles: exact on plants linear in their states, "
                        "for sensors sharp against the process noise, where particle filters degenerate)")
    p.add_argument("--particles", type=int, default=1000)
    p.add_argument("--seed", type=_seed, default=0, help="random seed, an integer >= 0")
    p.add_argument("--noise", metavar="process=Q,measurement=R",
                   help="relative noise levels of the data (and of a simulated scenario); default: the model's. "
                        "measurement=R replaces every sensor's own level; process=Q scales the states' levels")
    p.add_argument("--steps", type=int, default=None, help="with --scenario: samples to simulate")
    p.add_argument("--generated", metavar="DIR",
                   help="use the package bgc compile wrote there (default: generate one for this run)")
    p.add_argument("--identify", choices=["kalman", "filter"], default="kalman",
                   help="kalman (default): weigh the hypotheses and size the fault with the magnitude held static, "
                        "by cubature Kalman filters on a grid of onsets and magnitudes; filter: by the particle "
                        "filters' own magnitude state (the thesis's method)")
    p.add_argument("--rank", action="store_true",
                   help="with --identify filter: weigh the surviving hypotheses by particle filters with the fault "
                        "magnitude held static, on a grid")
    p.add_argument("--refine", action="store_true",
                   help="estimate the fault magnitude by the particle filters' marginal likelihood on a grid "
                        "(slower; a check of the estimate for strongly nonlinear plants)")
    _add_data_options(p)
    _add_prior_option(p)
    p.add_argument("-o", "--output", metavar="DIR", help="report folder (default: MODEL-diagnosis)")
    _add_backend_option(p)
    p.set_defaults(run=cmd_diagnose)

    p = sub.add_parser("monitor", help="diagnose a run as its rows arrive (a file being appended to, or - for "
                                       "standard input): events as they happen, the report at the end")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--data", metavar="RUN.csv|-", required=True,
                   help="the run's CSV (as bgc simulate writes): a file, or - for standard input")
    p.add_argument("--follow", action="store_true",
                   help="keep reading the file as another program appends to it (until Ctrl-C, or --idle)")
    p.add_argument("--idle", type=float, default=None, metavar="SECONDS",
                   help="with --follow: end the input after this many seconds without a new row")
    p.add_argument("--filter", choices=["gpf", "apf", "opf", "ckf"], default="gpf",
                   help="the nominal observer and hypothesis filters, as for bgc diagnose")
    p.add_argument("--particles", type=int, default=1000)
    p.add_argument("--seed", type=_seed, default=0, help="random seed, an integer >= 0")
    p.add_argument("--noise", metavar="process=Q,measurement=R",
                   help="relative noise levels the filters assume; default: the model's")
    _add_data_options(p)
    p.add_argument("--exclude-faulty-sensor", action="store_true",
                   help="with --checkpoint: when a checkpoint isolates a sensor fault, take that sensor out of the "
                        "nominal observer and go on watching with the others (an event says so)")
    p.add_argument("--checkpoint", type=float, default=None, metavar="TIME",
                   help="while tracking hypotheses, diagnose the data so far every TIME (default: only at the end)")
    p.add_argument("--generated", metavar="DIR",
                   help="use the package bgc compile wrote there (default: generate one)")
    _add_prior_option(p)
    p.add_argument("-o", "--output", metavar="DIR", help="report folder (default: MODEL-monitor)")
    _add_backend_option(p)
    p.set_defaults(run=cmd_monitor)

    p = sub.add_parser("distinguish", help="predict which faults the data of a scenario can tell apart (before "
                       "any data: noise, size, onset and kind of the fault)")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--scenario", metavar="NAME:KIND:MAGNITUDE@TIME",
                   help="one fault, e.g. R_pipe:incipient:0.5@165 (default: every candidate, kind and direction)")
    p.add_argument("--change", type=_above_zero, default=0.3,
                   help="without --scenario: the relative change of each parameter (a drift reaches it at the end "
                        "of the run; default 0.3)")
    p.add_argument("--at", type=_above_zero, default=0.5,
                   help="without --scenario: the onset, as a fraction of the run (default 0.5)")
    p.add_argument("--noise", metavar="process=Q,measurement=R", help="relative noise levels (default: the model's)")
    p.add_argument("--steps", type=_positive, default=None, help="samples of the run (default: the model's; at most "
                   "what the prediction's memory allows, 2 GB: bgc says how many)")
    p.add_argument("--format", choices=["text", "json"], default="text")
    p.add_argument("-o", "--output", metavar="FILE", help="write to FILE instead of printing")
    p.add_argument("--plot", metavar="FILE.png", help="also draw the probabilities as a heat map")
    p.set_defaults(run=cmd_distinguish)

    p = sub.add_parser("experiment", help="run a campaign of diagnoses (grid or randomised) and write its tables")
    p.add_argument("config", metavar="CONFIG.yaml")
    p.add_argument("-o", "--output", metavar="DIR", help="results folder (default: out/CAMPAIGN); an interrupted "
                   "campaign resumes from it")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run on this Dask distributed scheduler "
                   "(e.g. tcp://10.0.0.5:8786) instead of local processes")
    p.add_argument("--workers", type=_positive, default=None,
                   help="local processes (default: one per core; at most 4 per core, and never more than the runs "
                        "to do)")
    p.add_argument("--max-runs", type=_positive, default=100_000, metavar="N",
                   help="refuse a campaign of more than N runs (default 100000), counted before any is expanded")
    p.add_argument("--connect-timeout", type=_above_zero, default=10.0, metavar="SECONDS",
                   help="with --scheduler: seconds to wait for the scheduler to answer (default 10; a refused "
                        "connection fails at once)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_backend_option(p)
    p.set_defaults(run=cmd_experiment)
    return parser


def _at_least(low: int, message: str):
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


_positive = _at_least(1, "{value}: give an integer >= 1")
#: --seed: NumPy's generators take no negative seed.
_seed = _at_least(0, "{value} is negative: give an integer >= 0")


def _above_zero(text: str) -> float:
    """An argparse type: a finite number above 0."""
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text}: give a number above 0")
    return value


def _quiet_stdout() -> None:
    """After a closed pipe: send what is left of stdout to /dev/null, so the
    interpreter's final flush raises nothing."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except BrokenPipeError:  # e.g. bgc show ... | head: the reader has gone, as with other CLIs
        _quiet_stdout()
        return 0
    except BgcError as exc:
        _report(exc)
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


if __name__ == "__main__":
    sys.exit(main())
