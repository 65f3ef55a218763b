"""``bgc compile``: a model compiled into its folder of generated files."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..errors import BgcError, printable
from .common import print_errors


def add_parser(sub) -> None:
    p = sub.add_parser("compile", help="compile models into DIR/<model>/ (equations, TCG, DBNs, package, pictures)")
    p.add_argument("models", nargs="+", metavar="MODEL")
    p.add_argument("-o", "--output", default="generated", metavar="DIR",
                   help="output root (default: generated); bgc writes DIR/<model>/ only if it is empty or bgc wrote it")
    p.add_argument("--no-pictures", action="store_true", help="skip the SVG pictures")
    p.add_argument("--decompose", action="store_true",
                   help="split the model into minimal submodels (each predicts its sensors from the readings of the "
                        "sensors around it) and compile each with its faults, instead of the whole plant's fault "
                        "models: DIR/<model>/decomposition.txt and submodels/")
    p.add_argument("--check", action="store_true", help="compare with DIR instead of writing; exit 1 on a difference")
    p.add_argument("--engine", choices=["auto", "graphviz", "matplotlib"], default="auto",
                   help="picture renderer (auto: Graphviz dot when installed)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from .. import pipeline
    from ..output import artifacts

    failed = 0
    for path in args.models:
        start = time.perf_counter()
        try:
            if args.decompose:
                d = pipeline.decompose_model(path)
                texts, model = pipeline.decomposed_files(d), d.model
            else:
                c = pipeline.compile_model(path)
                texts, model = pipeline.generated_files(c), c.model
            outdir = Path(args.output) / model.name
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
                files.update(pipeline.decomposed_pictures(d, args.engine) if args.decompose
                             else pipeline.pictures(c, args.engine))
            artifacts.write_folder(outdir, files)
        except BgcError as exc:  # report, and go on with the other models (as bgc check does)
            print_errors(exc)
            failed = 1
            continue
        seconds = time.perf_counter() - start
        if args.decompose:
            n_dbn = sum(1 + len(part.dbn.faulty) for part in d.parts)
            largest = max((len(part.equations.states) for part in d.parts), default=0)
            print(f"{printable(str(path))}: wrote {printable(str(outdir))}/ ({len(files)} files: "
                  f"{len(d.parts)} submodels of at most {largest} of its {len(d.numerics.dbn.equations.states)} "
                  f"states, {n_dbn} DBNs{'' if args.no_pictures else ', pictures'}) in {seconds:.2f} s")
            continue
        each = c.modes or (c,)
        n_dbn = sum(1 + len(m.dbn.faulty) for m in each)
        what = f"{len(each)} modes' equations, TCGs" if len(each) > 1 else "equations, TCG"
        print(f"{printable(str(path))}: wrote {printable(str(outdir))}/ ({len(files)} files: {what}, "
              f"{n_dbn} DBNs{'' if args.no_pictures else ', pictures'}) in {seconds:.2f} s")
        for m in each:
            for d in m.causal.diagnostics:
                print(printable(f"  {'' if m is c else f'mode {m.name}: '}{d.severity}: {d.message}"))
    return failed
