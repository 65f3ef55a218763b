"""``bgc analyse``: which faults a model's sensors can detect and tell apart, before the plant runs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import printable
from .common import Progress, above_zero, parse_noise, positive


def add_parser(sub) -> None:
    p = sub.add_parser("analyse",
                       help="which faults the sensors can detect and tell apart, at three levels: the equations' "
                            "structure, the signatures, and the data's noise (before the plant runs)")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--structure-only", action="store_true",
                   help="the structural and qualitative levels only (no distinguishability: seconds less)")
    p.add_argument("--change", type=above_zero, default=0.3,
                   help="the quantitative level: each fault's change, relative to its scale (default 0.3)")
    p.add_argument("--at", type=above_zero, default=0.5,
                   help="the quantitative level: the onset, as a fraction of the run (default 0.5)")
    p.add_argument("--noise", metavar="process=Q,measurement=R", help="relative noise levels (default: the model's)")
    p.add_argument("--steps", type=positive, default=None, help="samples of the run (default: the model's)")
    p.add_argument("--format", choices=["text", "json"], default="text")
    p.add_argument("-o", "--output", metavar="DIR",
                   help="write analysis.md, analysis.json and isolability.png there instead of printing")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..api.analyse import analyse
    from ..output import artifacts, plots, render

    process, measurement = parse_noise(args.noise)
    names = ("analysis.md", "analysis.json", "isolability.png", "manifest.json")
    if args.output:
        artifacts.check_folder(Path(args.output), names, "analyse")  # refused before the work, not after
    progress = Progress("analyse")
    try:
        r = analyse(args.model, quantitative=not args.structure_only, change=args.change, at=args.at,
                    process_noise=process, measurement_noise=measurement, steps=args.steps, progress=progress)
    finally:
        progress.close()
    text = render.analysis_text(r)
    data = render.to_json(r.to_dict())
    if not args.output:
        sys.stdout.write(data if args.format == "json" else text)
        sys.stdout.flush()
        return 0
    files = {"analysis.md": artifacts.mark_text("```\n" + text + "```\n", "md", r.source),
             "analysis.json": artifacts.mark_text(data, "json", r.source),
             "isolability.png": plots.analysis_figure(r, "png")}
    files["manifest.json"] = artifacts.manifest(files, "analyse")
    artifacts.write_folder(Path(args.output), files)
    print(f"wrote {printable(args.output)}/: {', '.join(names[:3])}")
    return 0
