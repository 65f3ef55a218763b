"""``bgc analyse``: which faults a model's sensors can detect and tell apart, before the plant runs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import BgcError, printable
from .common import Progress, above_zero, parse_noise, positive


def add_parser(sub) -> None:
    p = sub.add_parser("analyse",
                       help="which faults the sensors can detect and tell apart, at three levels: the equations' "
                            "structure, the signatures, and the data's noise (before the plant runs)")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--no-quantitative", action="store_true",
                   help="the structural and qualitative levels only (no distinguishability: seconds less)")
    p.add_argument("--change", type=above_zero, default=0.3,
                   help="the quantitative level: each fault's change, relative to its scale (default 0.3)")
    p.add_argument("--at", type=above_zero, default=0.5,
                   help="the quantitative level: the onset, as a fraction of the run (default 0.5)")
    p.add_argument("--noise", metavar="process=Q,measurement=R", help="relative noise levels (default: the model's)")
    p.add_argument("--steps", type=positive, default=None, help="samples of the run (default: the model's)")
    p.add_argument("--modes", metavar="MODE@TIME,...",
                   help="a model with modes: the quantitative level's controlled changes of mode over the run "
                        "(default: the modes its guards and timed transitions reach)")
    p.add_argument("--place-sensors", action="store_true",
                   help="also the cheapest sets of sensors to add so that every fault is detected and every pair told "
                        "apart structurally, as far as the candidates can (every effort and flow, or --costs)")
    p.add_argument("--costs", metavar="FILE.yaml",
                   help="with --place-sensors: the candidate sensors and their costs, a mapping of bond variables "
                        "to numbers, e.g. {e2: 1, f1: 3} (default: every effort and flow at cost 1)")
    p.add_argument("--place-by", choices=["structural", "qualitative"], default="qualitative",
                   help="with --place-sensors: the levels the sensors must reach what every candidate gives at: "
                        "structural, or structural and qualitative (default)")
    p.add_argument("--most", type=positive, default=2, help="with --place-sensors: at most this many sensors added "
                   "(default 2)")
    p.add_argument("--write", metavar="NEW.yaml",
                   help="with --place-sensors: write the model with the first cheapest set added to this new file")
    p.add_argument("--design-inputs", action="store_true",
                   help="for each fault the declared inputs leave undetected, the input test (a step, square wave, "
                        "sine or PRBS of an input) that detects it best, with the probability it reaches")
    p.add_argument("--format", choices=["text", "json"], default="text")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="write analysis.md, analysis.html, analysis.json and isolability.png there instead of printing")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..api.analyse import analyse
    from ..output import artifacts, plots, render

    process, measurement = parse_noise(args.noise)
    for flag, value in (("--costs", args.costs), ("--write", args.write), ("--most", args.most != 2 or None),
                        ("--place-by", args.place_by != "qualitative" or None)):
        if value and not args.place_sensors:
            raise BgcError(f"{flag} applies to --place-sensors", None, f"add --place-sensors, or drop {flag}")
    if args.design_inputs and args.no_quantitative:
        raise BgcError("--design-inputs needs the quantitative level", None, "drop --no-quantitative")
    costs = _costs(args.costs) if args.costs else None
    if args.write:
        from ..output import artifacts as _a

        if Path(args.write).exists() and Path(args.write).resolve() == Path(args.model).resolve():
            raise BgcError(f"--write {printable(args.write)} is the model file: it is never replaced", None,
                           "write the model with its sensors to a new file")
        _a.check_writable(Path(args.write), "the model with its sensors")
    names = ("analysis.md", "analysis.html", "analysis.json", "isolability.png", "manifest.json")
    if args.output:
        artifacts.check_folder(Path(args.output), names, "analyse")  # refused before the work, not after
    progress = Progress("analyse")
    try:
        r = analyse(args.model, quantitative=not args.no_quantitative, change=args.change, at=args.at,
                    process_noise=process, measurement_noise=measurement, steps=args.steps, progress=progress,
                    place_sensors=args.place_sensors, costs=costs, most=args.most, place_by=args.place_by,
                    design_inputs=args.design_inputs, modes=args.modes)
    except BgcError as exc:
        if costs is not None and "costs names" in str(exc):  # said of the file, not of the API's argument
            raise BgcError(f"--costs {printable(args.costs)}: {str(exc).split(': ', 1)[1].split(' (')[0]}", None,
                           "name efforts and flows of the model's bonds (bgc show bondgraph MODEL lists them), "
                           "or a sensor, for a second sensor beside it") \
                from None
        raise
    finally:
        progress.close()
    text = render.analysis_text(r)
    if args.write:
        from ..api.analyse import with_sensors

        if not r.placement.sets or not r.placement.sets[0]:
            raise BgcError("--write: no sensor to add" + ("" if r.placement.sets else f" within --most {args.most}"),
                           None, "drop --write" if r.placement.sets else "raise --most")
        first = r.placement.sets[0]
        written = r.placement.written(first)
        with_sensors(args.model, written, args.write)
        named = [n if n == w else f"{n} (as {w}{'' if w == v else f': {v}'})"  # a second sensor: its variable
                 for n, (w, v) in zip(first, written)]
        text += f"wrote {printable(args.write)}: {args.model} with {', '.join(named)} added\n"
    data = render.to_json(r.to_dict())
    if not args.output:
        sys.stdout.write(data if args.format == "json" else text)
        sys.stdout.flush()
        return 0
    from ..output import analysis_report

    png = plots.analysis_figure(r, "png")
    files = {"analysis.md": analysis_report.markdown(r), "analysis.html": analysis_report.page(r, {"isolability.png": png}),
             "analysis.json": data, "isolability.png": png}  # the folder's manifest.json lists them
    files["manifest.json"] = artifacts.manifest(files, "analyse")
    artifacts.write_folder(Path(args.output), files)
    print(f"wrote {printable(args.output)}/: {', '.join(names[:4])}")
    return 0


def _costs(path: str) -> dict:
    """The ``--costs`` file: a mapping of bond variables to costs (finite
    numbers >= 0), each named once, read safely."""
    import math

    import yaml

    fix = "give a YAML file of {variable: cost}, e.g. {e2: 1, f1: 3}"
    try:
        text = Path(path).read_text(encoding="utf-8")
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise BgcError(f"--costs {printable(path)}: cannot be read ({printable(str(exc).splitlines()[0])})", None,
                       fix) from None
    if isinstance(node, yaml.MappingNode):
        keys = [k.value for k, _ in node.value if isinstance(k, yaml.ScalarNode)]
        twice = sorted({k for k in keys if keys.count(k) > 1})
        if twice:
            raise BgcError(f"--costs {printable(path)}: {printable(twice[0])} is named twice", None,
                           "give each variable one cost")
    if not isinstance(data, dict) or not data or not all(
            isinstance(k, str) and isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            and v >= 0 for k, v in data.items()):
        raise BgcError(f"--costs {printable(path)}: not a mapping of bond variables to costs >= 0", None,
                       "write e.g. {e2: 1, f1: 3}")
    return {k: float(v) for k, v in data.items()}
