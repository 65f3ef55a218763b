"""Command-line interface: the only module that prints or picks exit codes.

Exit codes: 0 success, 1 a model has errors (one line each, no traceback),
2 usage errors (argparse's convention).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from typing import Sequence

from . import __version__, pipeline
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
    states = [s for s in cbg.storage if s.integral]
    lines.append(f"  states: {len(states)}: " + ", ".join(f"{s.state} ({s.element}, integral)" for s in states))
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bgc", description="Bond-graph model compiler for model-based fault diagnosis.")
    parser.add_argument("--version", action="version", version=f"bgc {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    p = sub.add_parser("check", help="validate models and print a summary (elements, states, causality)")
    p.add_argument("models", nargs="+", metavar="MODEL", help="model files (YAML)")
    p.set_defaults(run=cmd_check)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except BgcError as exc:
        for line in _error_lines(exc):
            print(line, file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("bgc: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
