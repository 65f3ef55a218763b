"""Command-line interface: the only module that prints or picks exit codes.

Exit codes: 0 success, 1 a model has errors (one line each, no traceback),
2 usage errors (argparse's convention).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from typing import Sequence

import time
from pathlib import Path

import numpy as np

from . import __version__, artifacts, codegen, draw, pipeline, render
from .errors import BgcError, ErrorGroup
from .ir import CausalBondGraph


def _error_lines(exc: BgcError) -> tuple[str, ...]:
    return exc.lines() if isinstance(exc, ErrorGroup) else (exc.line(),)


def summary(cbg: CausalBondGraph) -> str:
    """The text ``bgc check`` prints for a valid model."""
    m = cbg.model
    kinds = Counter(el.kind for el in m.elements)
    order = ["Se", "Sf", "MSe", "MSf", "R", "MR", "C", "I", "TF", "MTF", "GY", "MGY", "0", "1"]
    kind_text = ", ".join(f"{k} {kinds[k]}" for k in order if kinds[k])
    lines = [f"{m.source}: ok: {m.name}" + (f" ({m.description})" if m.description else "")]
    lines.append(f"  elements: {len(m.elements)} ({kind_text})")
    lines.append(f"  bonds: {len(m.bonds)}")
    states = sorted((s for s in cbg.storage if s.integral), key=lambda s: s.bond)
    listed = ", ".join(f"{s.state} ({s.element}, integral)" for s in states)
    lines.append(f"  states: {len(states)}" + (f": {listed}" if listed else ""))
    deriv = [s for s in cbg.storage if not s.integral]
    if deriv:
        lines.append("  derivative causality: " + ", ".join(f"{s.element} ({s.kind}, bond {s.bond})" for s in deriv))
    lines.append("  algebraic loops: " + (", ".join(f"closed by {r}" for r in cbg.arbitrary) or "none"))
    lines.append(f"  inputs: {', '.join(i.name for i in m.inputs) or 'none'}")
    measured = [y.name if y.text == y.name else f"{y.name} = {y.text}" for y in m.measurements]
    lines.append("  measurements: " + (", ".join(measured) or "none"))
    faults = [f"{f.parameter} ({'/'.join(f.kinds)})" for f in m.faults]
    lines.append("  fault candidates: " + (", ".join(faults) or "none"))
    warnings = [d for d in cbg.diagnostics if d.severity == "warning"]
    notes = [d for d in cbg.diagnostics if d.severity != "warning"]
    lines.append(f"  warnings: {len(warnings) or 'none'}")
    lines.extend(f"    warning: {d.message}" for d in warnings)
    if notes:
        lines.append(f"  notes: {len(notes)}")
        lines.extend(f"    note: {d.message}" for d in notes)
    return "\n".join(lines)


def cmd_check(args: argparse.Namespace) -> int:
    status = 0
    for path in args.models:
        try:
            cbg = pipeline.check_model(path)
        except BgcError as exc:
            for line in _error_lines(exc):
                print(line, file=sys.stderr)
            status = 1
            continue
        print(summary(cbg))
    return status


def cmd_compile(args: argparse.Namespace) -> int:
    failed = 0
    for path in args.models:
        start = time.perf_counter()
        try:
            c = pipeline.compile_model(path)
        except BgcError as exc:  # report, and go on with the other models (as bgc check does)
            if len(args.models) == 1:
                raise
            for line in _error_lines(exc):
                print(line, file=sys.stderr)
            failed = 1
            continue
        texts = codegen.text_files(c.dbn)
        files: dict[str, str | bytes] = dict(texts)
        outdir = Path(args.output) / c.model.name
        if args.check:
            diffs = artifacts.diff(outdir, texts)
            if diffs:
                for d in diffs:
                    print(d, file=sys.stderr)
                print(f"{outdir}: out of date; refresh with: bgc compile {path}", file=sys.stderr)
                return 1
            print(f"{outdir}: up to date ({len(files)} files)")
            continue
        if not args.no_pictures:
            files.update(codegen.pictures(c.dbn, args.engine))
        artifacts.write(outdir, files)
        seconds = time.perf_counter() - start
        n_dbn = 1 + len(c.dbn.faulty)
        print(f"{path}: wrote {outdir}/ ({len(files)} files: equations, TCG, {n_dbn} DBNs"
              f"{'' if args.no_pictures else ', pictures'}) in {seconds:.2f} s")
        for d in c.causal.diagnostics:
            print(f"  {d.severity}: {d.message}")
    return failed


def cmd_show(args: argparse.Namespace) -> int:
    if args.stage == "causality":  # only as far as causality: it shows why a later stage fails
        from types import SimpleNamespace

        causal = pipeline.check_model(args.model)
        c = SimpleNamespace(causal=causal, model=causal.model)
    else:
        c = pipeline.compile_model(args.model)
    stage, fmt = args.stage, args.format
    if args.fault and stage != "dbn":
        raise BgcError("--fault applies to 'bgc show dbn' only", None, "drop --fault or show the dbn stage")
    if stage == "dbn":
        name = "nominal"
        if args.fault:
            name = args.fault
            if name.count(":") != 1:
                raise BgcError(f"--fault {name}: expected PARAM:KIND", None, "e.g. --fault R_pipe:incipient")
        try:
            d = c.dbn.get(name)
        except KeyError as exc:
            raise BgcError(str(exc.args[0]), None, "pick a fault candidate and kind the model declares") from None
    texts = {
        ("causality", "text"): lambda: render.causality_text(c.causal),
        ("causality", "json"): lambda: render.to_json(render.causality_json(c.causal)),
        ("tcg", "text"): lambda: render.tcg_text(c.tcg),
        ("tcg", "json"): lambda: render.to_json(render.tcg_json(c.tcg)),
        ("tcg", "dot"): lambda: render.tcg_dot(c.tcg),
        ("equations", "text"): lambda: render.equations_text(c.equations),
        ("equations", "json"): lambda: render.to_json(render.equations_json(c.equations)),
        ("equations", "latex"): lambda: render.equations_latex(c.equations),
        ("dbn", "text"): lambda: render.dbn_text(d),
        ("dbn", "json"): lambda: render.to_json(render.dbn_json(d)),
        ("dbn", "dot"): lambda: render.dbn_dot(d),
    }
    if fmt in ("svg", "png"):
        if stage == "tcg":
            data = draw.tcg_picture(c.tcg, fmt, args.engine)
        elif stage == "dbn":
            data = draw.dbn_picture(d, fmt, args.engine)
        else:
            raise BgcError(f"stage {stage} has no picture", None, "pictures exist for tcg and dbn")
        suffix = f"-{codegen.dbn_file_stem(d.name)}" if stage == "dbn" else ""
        out = Path(args.output or f"{c.model.name}-{stage}{suffix}.{fmt}")
        artifacts.write_file(out, data)
        print(f"wrote {out}")
        return 0
    if (stage, fmt) not in texts:
        valid = sorted(f for s_, f in texts if s_ == stage)
        raise BgcError(f"stage {stage} has no format {fmt}", None, f"use one of: {', '.join(valid + ['svg', 'png'] if stage in ('tcg', 'dbn') else valid)}")
    text = texts[(stage, fmt)]()
    if args.output:
        artifacts.write_file(Path(args.output), text)
        print(f"wrote {args.output}")
    else:
        sys.stdout.write(text)
    return 0


def _parse_noise(text: str | None) -> tuple[float | None, float | None]:
    if not text:
        return None, None
    values = {"process": None, "measurement": None}
    for part in text.split(","):
        key, _, val = part.partition("=")
        key = key.strip()
        if key not in values:
            raise BgcError(f"--noise: unknown key '{key}'", None, "write process=0.03,measurement=0.02")
        try:
            values[key] = float(val)
        except ValueError:
            raise BgcError(f"--noise: '{val}' is not a number", None, "write process=0.03,measurement=0.02") from None
        if not np.isfinite(values[key]) or values[key] < 0:
            raise BgcError(f"--noise: {key} level must be a finite number >= 0", None,
                           "noise levels are fractions of the signal")
    return values["process"], values["measurement"]


def cmd_simulate(args: argparse.Namespace) -> int:
    from . import simulate as sim

    c = pipeline.compile_model(args.model)
    process, measurement = _parse_noise(args.noise)
    fault = sim.parse_fault(args.fault, c.equations) if args.fault else None
    if args.steps is not None and args.steps < 1:
        raise BgcError("--steps must be at least 1", None, "e.g. --steps 300")
    options = sim.SimulationOptions(steps=args.steps, process_noise=process, measurement_noise=measurement,
                                    seed=args.seed, fault=fault)
    start = time.perf_counter()
    result = sim.simulate(c.equations, options)
    out = Path(args.output or f"{c.model.name}-run.csv")
    artifacts.write_file(out, sim.to_csv(result))
    print(f"wrote {out}: {len(result.time)} steps of {c.model.name}, fault: "
          f"{fault.describe() if fault else 'none'} ({time.perf_counter() - start:.2f} s)")
    if args.plot:
        from . import plots

        artifacts.write_file(Path(args.plot), plots.simulation_figure(result, "png"))
        print(f"wrote {args.plot}")
    return 0


def cmd_filter(args: argparse.Namespace) -> int:
    from . import simulate as sim
    from .diagnosis import runtime

    c = pipeline.compile_model(args.model)
    try:
        text = Path(args.run_csv).read_text(encoding="utf-8")
    except OSError as exc:
        raise BgcError(f"{args.run_csv}: cannot read: {exc.strerror}", None, "give a CSV written by bgc simulate") from None
    run = sim.read_csv(text, args.run_csv)
    recorded = next((h.split(":")[0][len("model "):] for h in run.header if h.startswith("model ")), None)
    if recorded is not None and recorded != c.model.name:
        raise BgcError(f"{args.run_csv} is a run of model '{recorded}', not of '{c.model.name}'", None,
                       f"simulate {args.model} first, or filter with the model the run was made with")
    if args.particles < 1:
        raise BgcError("--particles must be at least 1", None, "e.g. --particles 200")
    if args.start is not None and not args.fault:
        raise BgcError("--start hands over to a fault model", None, "give --fault PARAM:KIND with --start")
    if not c.model.measurements:
        raise BgcError(f"{args.model}: {c.model.name} has no measurements, so there is nothing to filter", None,
                       "declare the plant's sensors under 'measurements'")
    if args.start is not None and not (run.time[0] <= args.start <= run.time[-1]):
        raise BgcError(f"--start {args.start:g} is outside the run ({run.time[0]:g} to {run.time[-1]:g})", None,
                       "hand over at a time inside the run")
    package = runtime.load_package(args.generated, c.model.name, args.model)
    name = args.fault.replace(":", "_") if args.fault else "nominal"
    results = []
    for method in (["gpf", "apf"] if args.method == "both" else [args.method]):
        with np.errstate(all="ignore"):  # particles outside a law's domain are weighted out and counted
            r = runtime.track(run, package, name, method, args.particles, args.seed, args.start)
        results.append(r)
        rmse = []
        for k, x in enumerate(r.state_names):
            truth = run.states.get(x, run.parameters.get(x))
            if truth is not None:
                ok = np.isfinite(r.mean[:, k])
                rmse.append(f"{x} {float(np.sqrt(np.mean((r.mean[ok, k] - truth[ok]) ** 2))):.4g}")
        print(f"{method.upper()} on {name}, N = {args.particles}: {len(r.time)} steps in {r.seconds:.3f} s, "
              f"mean ESS {float(np.mean(r.ess)):.0f}, resampled {int(r.resampled.sum())} times, "
              f"recoveries {r.recoveries}")
        print("  RMSE vs truth: " + ", ".join(rmse))
        last = ", ".join(f"{x} {m:.4g} +- {s:.2g}" for x, m, s in zip(r.state_names, r.mean[-1], r.std[-1]))
        print(f"  final estimate: {last}")
        fault = package.MODELS[name].FAULT
        if fault:
            p = fault["parameter"]
            nominal = dict(zip(package.MODELS[name].PARAMETERS, package.MODELS[name].THETA))[p]
            k = r.state_names.index(f"delta_{p}")
            if fault["kind"] == "abrupt":
                est, sd, what = nominal + r.mean[-1, k], r.std[-1, k], f"{p} = {nominal:g} + delta"
            else:
                est, sd, what = r.mean[-1, k], r.std[-1, k], f"slope of {p} (per unit time)"
            truth = run.parameters.get(p)
            true_text = ""
            if truth is not None:
                true_value = truth[-1] if fault["kind"] == "abrupt" else (truth[-1] - truth[-2]) / (run.time[-1] - run.time[-2])
                true_text = f" (true {true_value:.4g}, error {100 * abs(est - true_value) / abs(true_value or 1):.1f} %)"
            print(f"  estimate of {what} at t = {r.time[-1]:g}: {est:.4g} +- {sd:.2g}{true_text}")
    if args.plot:
        from . import plots

        artifacts.write_file(Path(args.plot), plots.tracking_figure(run, results, "png"))
        print(f"wrote {args.plot}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bgc", description="Bond-graph model compiler for model-based fault diagnosis.")
    parser.add_argument("--version", action="version", version=f"bgc {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    p = sub.add_parser("check", help="validate models and print a summary (elements, states, causality)")
    p.add_argument("models", nargs="+", metavar="MODEL", help="model files (YAML)")
    p.set_defaults(run=cmd_check)

    p = sub.add_parser("compile", help="compile models into generated/<model>/ (equations, TCG, DBNs, pictures)")
    p.add_argument("models", nargs="+", metavar="MODEL")
    p.add_argument("-o", "--output", default="generated", metavar="DIR", help="output root (default: generated)")
    p.add_argument("--no-pictures", action="store_true", help="skip the SVG pictures")
    p.add_argument("--check", action="store_true", help="compare with DIR instead of writing; exit 1 on a difference")
    p.add_argument("--engine", choices=["auto", "graphviz", "matplotlib"], default="auto",
                   help="picture renderer (auto: Graphviz dot when installed)")
    p.set_defaults(run=cmd_compile)

    p = sub.add_parser("show", help="print or render one stage of a model")
    p.add_argument("stage", choices=["causality", "tcg", "equations", "dbn"])
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--fault", metavar="PARAM:KIND", help="with dbn: the faulty DBN, e.g. R_pipe:incipient")
    p.add_argument("--format", default="text", choices=["text", "json", "dot", "latex", "svg", "png"])
    p.add_argument("-o", "--output", metavar="FILE", help="write to FILE (pictures default to MODEL-STAGE.FMT)")
    p.add_argument("--engine", choices=["auto", "graphviz", "matplotlib"], default="auto")
    p.set_defaults(run=cmd_show)

    p = sub.add_parser("simulate", help="simulate the plant (truth) with noise and an injected fault, to CSV")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--steps", type=int, default=None, help="number of samples (default: the model's)")
    p.add_argument("--fault", metavar="PARAM:KIND:MAGNITUDE@TIME",
                   help="inject a fault, e.g. R_pipe:incipient:0.5@165 (slope per unit time) or R_pipe:abrupt:31@165 (bias)")
    p.add_argument("--noise", metavar="process=Q,measurement=R", help="noise levels as fractions of the signal")
    p.add_argument("--seed", type=_seed, default=0, help="random seed, an integer >= 0")
    p.add_argument("-o", "--output", metavar="FILE.csv")
    p.add_argument("--plot", metavar="FILE.png", help="also plot measurements and states")
    p.set_defaults(run=cmd_simulate)

    p = sub.add_parser("filter", help="run a generated particle filter (GPF/APF) over a recorded run")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("run_csv", metavar="RUN.csv", help="a CSV written by bgc simulate")
    p.add_argument("--fault", metavar="PARAM:KIND", help="track with this fault model (default: nominal)")
    p.add_argument("--method", choices=["gpf", "apf", "both"], default="both")
    p.add_argument("--particles", type=int, default=200)
    p.add_argument("--seed", type=_seed, default=0, help="random seed, an integer >= 0")
    p.add_argument("--start", type=float, metavar="T",
                   help="with --fault: track the nominal model until T, then hand over to the fault model")
    p.add_argument("--generated", default="generated", metavar="DIR", help="where bgc compile wrote the package")
    p.add_argument("--plot", metavar="FILE.png")
    p.set_defaults(run=cmd_filter)
    return parser


def _seed(text: str) -> int:
    """argparse type of --seed: an integer >= 0 (NumPy's generators take no negative seed)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not an integer") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value} is negative: give an integer >= 0")
    return value


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except BgcError as exc:
        for line in _error_lines(exc):
            print(line, file=sys.stderr)
        return 1
    except OSError as exc:  # an output path that is a directory, a missing parent, no permission
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{where}{exc.strerror or exc} (choose a writable file path for the output)", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("bgc: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. bgc show ... | head
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
