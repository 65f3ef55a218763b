"""``bgc show``: one stage of a model printed or drawn."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import BgcError, printable


def add_parser(sub) -> None:
    p = sub.add_parser("show", help="print or render one stage of a model (bondgraph: the causal bond graph "
                                    "drawn, with power half-arrows and causal strokes; causality: the strokes, "
                                    "each storage element's causality and each junction's strong bond)")
    p.add_argument("stage", choices=["bondgraph", "causality", "tcg", "equations", "signatures", "dbn"])
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--fault", metavar="PARAM:KIND",
                   help="with dbn: the faulty DBN, e.g. R_pipe:incipient, or a sensor's P_memb:bias")
    p.add_argument("--intermittent", action="store_true",
                   help="with dbn --fault: the fault's DBN as one that comes and goes (its indicator switching)")
    p.add_argument("--format", default="text", metavar="FORMAT",
                   help="text, json, dot, latex (equations) or a picture: svg, png (bondgraph, causality, tcg, dbn)")
    p.add_argument("-o", "--output", metavar="FILE", help="write to FILE (pictures default to MODEL-STAGE.FMT)")
    p.add_argument("--engine", choices=["auto", "graphviz", "matplotlib"], default="auto")
    p.add_argument("--mode", metavar="MODE", help="a model with modes: the stage in this mode (dbn without it: "
                                                  "the DBN across the modes, the mode a node)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from .. import pipeline
    from ..output import artifacts, draw, render

    stage, fmt = args.stage, args.format
    if args.fault and stage != "dbn":
        raise BgcError("--fault applies to 'bgc show dbn' only", None, "drop --fault or show the dbn stage")
    if args.intermittent and not (stage == "dbn" and args.fault):
        raise BgcError("--intermittent applies to 'bgc show dbn --fault PARAM:KIND' only", None,
                       "add --fault with a step fault, or drop --intermittent")
    texts = {
        ("bondgraph", "text"): lambda: render.bondgraph_text(causal),
        ("bondgraph", "json"): lambda: render.to_json(render.bondgraph_json(causal)),
        ("bondgraph", "dot"): lambda: render.bondgraph_dot(causal),
        ("causality", "text"): lambda: render.causality_text(causal),
        ("causality", "json"): lambda: render.to_json(render.causality_json(causal)),
        ("causality", "dot"): lambda: render.bondgraph_dot(causal, causal=True),
        ("tcg", "text"): lambda: render.tcg_text(c.tcg),
        ("tcg", "json"): lambda: render.to_json(render.tcg_json(c.tcg)),
        ("tcg", "dot"): lambda: render.tcg_dot(c.tcg),
        ("equations", "text"): lambda: render.equations_text(c.equations),
        ("equations", "json"): lambda: render.to_json(render.equations_json(c.equations)),
        ("equations", "latex"): lambda: render.equations_latex(c.equations),
        ("signatures", "text"): lambda: render.signatures_text(c.signatures, getattr(c, "numerics", None)),
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
        causal = pipeline.assign_causality(args.model, args.mode)
        model_name = causal.model.name
    else:
        c = _compiled(args.model, args.mode, stage)
        model_name = c.model.name
    d = _chosen_dbn(c, args) if stage == "dbn" else None
    if fmt in ("svg", "png"):
        if stage == "bondgraph":
            data = draw.bondgraph_picture(causal, fmt, args.engine)
        elif stage == "causality":  # the strokes bold, each storage element's causality, each junction's strong bond
            data = draw.causality_picture(causal, fmt, args.engine)
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


def _chosen_dbn(c, args: argparse.Namespace):
    """The DBN ``bgc show dbn`` draws of compiled model ``c``: the nominal
    one, or ``--fault``'s (across the modes of a model with modes), as one
    that comes and goes with ``--intermittent``."""
    from .. import pipeline
    from ..compiler import dbn as dbn_stage
    from ..compiler.hybrid_dbn import across_modes
    from ..kinds import comes_and_goes

    name = args.fault or "nominal"
    if args.fault and name.count(":") != 1:
        raise BgcError(f"--fault {name!r}: expected PARAM:KIND", None, "e.g. --fault R_pipe:incipient")
    try:
        d = across_modes(c.model, c.modes, name) if isinstance(c, pipeline.Hybrid) else c.dbn.get(name)
    except KeyError as exc:
        raise BgcError(str(exc.args[0]), None, "pick a fault candidate and kind the model declares") from None
    if args.intermittent:
        try:
            d = dbn_stage.intermittent(d)
        except KeyError as exc:
            steps = [f.name for f in c.dbn.faulty if f.kind is not None and comes_and_goes(f.kind)] \
                if hasattr(c, "dbn") else []
            raise BgcError(f"--intermittent: {exc.args[0]}", None, "give --fault a step fault"
                           + (f", e.g. --fault {steps[0]}" if steps else ": this model lists none")) from None
    return d


def _compiled(model: str, mode: str | None, stage: str):
    """What a stage after causality is shown from: the compiled model, or
    for a model with modes the compiled mode ``mode`` (its TCG, equations,
    signatures and DBNs; the priors of the fault magnitudes are not shown)."""
    from .. import pipeline

    c = pipeline.check_model(model)
    if not isinstance(c, pipeline.Hybrid):
        if mode is not None:
            raise pipeline.unknown_mode(c.model, mode)
        return c
    if stage == "dbn" and mode is None:  # the DBN across the modes
        return c
    return c.mode(mode)
