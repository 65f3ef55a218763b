"""Stable text, JSON and Graphviz DOT dumps of every IR (what ``bgc show`` prints).

Everything is sorted (bonds by number, variables by bond then e/f, names
alphabetically), so the same model always gives the same text.
"""

from __future__ import annotations

import dataclasses
import json
import re
from typing import Any

from ..errors import printable
from ..ir import CausalBondGraph, Dbn, FaultSignatures, Numerics, StateSpaceModel, TemporalCausalGraph, var_key
from ..kinds import ELEMENT_KINDS, FAULT_KINDS, ROLES, kind_of, releases
from .labels import Labels
from .layout import DBN_BANDS, dbn_band, signal_links


def to_json(data: Any) -> str:
    """Canonical JSON: sorted keys, two-space indent, final newline."""
    return json.dumps(data, indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def _num(v: float) -> float | int:
    return int(v) if float(v).is_integer() and abs(v) < 1e15 else float(v)


# ------------------------------------------------------------------- causality
def strong_bonds(cbg: CausalBondGraph) -> tuple[tuple[str, str, tuple[int, ...]], ...]:
    """Each junction's strong bond (Karnopp, Margolis and Rosenberg, ch. 5):
    (junction, kind, bonds), the bonds whose other end sets the junction's
    common variable: the effort of a 0-junction (its one causal stroke at
    the junction), the flow of a 1-junction (its one stroke away from it).
    SCAP leaves exactly one; more or none is a causal conflict."""
    out = []
    for el in cbg.model.elements:
        if el.kind not in ("0", "1"):
            continue
        common = "effort_by" if el.kind == "0" else "flow_by"
        bonds = tuple(b.number for b in cbg.model.bonds_of(el.name)
                      if getattr(cbg.causality(b.number), common) != el.name)
        out.append((el.name, el.kind, bonds))
    return tuple(out)


def strong_bond_text(kind: str, bonds: tuple[int, ...]) -> str:
    """``strong bond 3 (sets the effort)``; a conflict when not one bond."""
    common = "effort" if kind == "0" else "flow"
    if len(bonds) == 1:
        return f"strong bond {bonds[0]} (sets the {common})"
    return f"causal conflict: {len(bonds)} bonds set the {common}" + (f" ({', '.join(map(str, bonds))})"
                                                                       if bonds else "")


def storage_text(s) -> str:
    """A storage element's causality: ``integral, state e4`` or ``derivative``."""
    return f"integral, state {s.state}" if s.integral else "derivative"


def causality_text(cbg: CausalBondGraph) -> str:
    m = cbg.model
    lines = [f"# causal bond graph of {m.name} (SCAP); stroke = end that receives the effort",
             f"{'bond':>5}  {'from -> to':<28} {'effort by':<12} {'flow by (stroke)':<12}"]
    for b in m.bonds:
        c = cbg.causality(b.number)
        lines.append(f"{b.number:>5}  {b.tail + ' -> ' + b.head:<28} {c.effort_by:<12} {c.flow_by:<12}")
    lines.append("storage:")
    for s in cbg.storage:
        lines.append(f"  {s.element} ({s.kind}, bond {s.bond}): {storage_text(s)}")
    junctions = strong_bonds(cbg)
    if junctions:
        lines.append("junctions (the strong bond sets a 0-junction's common effort, a 1-junction's common flow):")
    for name, kind, bonds in junctions:
        lines.append(f"  {name} ({kind}): {strong_bond_text(kind, bonds)}")
    lines.append("resistors assigned arbitrarily: " + (", ".join(cbg.arbitrary) or "none"))
    for d in cbg.diagnostics:
        lines.append(f"{d.severity}: {d.message}")
    return "\n".join(lines) + "\n"


def causality_json(cbg: CausalBondGraph) -> dict:
    return {
        "model": cbg.model.name,
        "bonds": [{"bond": c.bond, "effort_by": c.effort_by, "flow_by": c.flow_by} for c in cbg.bonds],
        "storage": [{"element": s.element, "kind": s.kind, "bond": s.bond, "integral": s.integral,
                     "state": s.state if s.integral else None} for s in cbg.storage],
        "junctions": [{"junction": name, "kind": kind, "strong_bonds": list(bonds)}
                      for name, kind, bonds in strong_bonds(cbg)],
        "arbitrary": list(cbg.arbitrary),
        "diagnostics": [{"severity": d.severity, "message": d.message, "element": d.element} for d in cbg.diagnostics],
    }


# ------------------------------------------------------------------ bond graph
def bondgraph_text(cbg: CausalBondGraph) -> str:
    """The causal bond graph as a list: every element with its kind, every
    bond with the end its half-arrow points at (power goes tail to head) and
    the end its causal stroke sits at (the element that receives the effort)."""
    m = cbg.model
    lines = [f"# bond graph of {m.name}: half arrow at the head (power tail -> head); causal stroke (SCAP) at the "
             "end that receives the effort"]
    lines.extend(_mode_lines(m))
    width = max([len(el.name) for el in m.elements] + [7])
    lines.append("elements:")
    from ..compiler.modes import zero_sources

    zero = zero_sources(m)
    for el in m.elements:
        kind = ELEMENT_KINDS[el.kind]
        note = f" ({el.description})" if el.name in zero else " (switched: ON)" if el.switch else ""
        lines.append(f"  {el.name:<{width}} {el.kind:<4} {kind.title}{note}")
    lines.append("bonds:")
    for b in m.bonds:
        c = cbg.causality(b.number)
        end = "head" if c.flow_by == b.head else "tail"
        lines.append(f"  {b.number:>4}  {b.tail:>{width}} -> {b.head:<{width}}  stroke at the {end} "
                     f"({c.flow_by}; effort by {c.effort_by})")
    links = signal_links(m)
    if links:
        lines.append("signal links: " + ", ".join(f"bond {b} -> {el}" for b, el in links))
    return "\n".join(lines) + "\n"


def _mode_lines(m) -> list[str]:
    """For one mode of a model with modes: which switched junctions are ON and which OFF."""
    if m.modes is None:
        return []
    present = {el.name for el in m.elements}
    on = [j for j in m.modes.switches if j in present]
    off = [j for j in m.modes.switches if j not in present]
    mode = next((x.name for x in m.modes.modes if set(x.on) == set(on)), "?")
    return [f"# mode {mode}: switched junctions ON: {', '.join(on) or 'none'}; OFF: {', '.join(off) or 'none'} "
            "(each OFF junction a zero source on each of its bonds)"]


def bondgraph_json(cbg: CausalBondGraph) -> dict:
    m = cbg.model
    return {
        "model": m.name,
        "elements": [{"name": el.name, "kind": el.kind} for el in m.elements],
        "bonds": [{"bond": b.number, "tail": b.tail, "head": b.head, "effort_by": cbg.causality(b.number).effort_by,
                   "stroke_at": cbg.causality(b.number).flow_by} for b in m.bonds],
        "signal_links": [{"bond": b, "element": el} for b, el in signal_links(m)],
    }


def bondgraph_dot(cbg: CausalBondGraph, causal: bool = False) -> str:
    """Graphviz DOT of the causal bond graph: ``lvee`` is the half-arrow at
    the head, ``tee`` the causal stroke (Graphviz draws the first shape of an
    arrow name next to the node). ``causal`` (``bgc show causality``): each
    storage element's causality and each junction's strong bond written
    under its name, the strong bonds drawn bold."""
    m = cbg.model
    notes = {s.element: storage_text(s) for s in cbg.storage} if causal else {}
    strong = set()
    for name, kind, bonds in strong_bonds(cbg) if causal else ():
        notes[name] = strong_bond_text(kind, bonds)
        strong.update(bonds)
    title = "causality_" if causal else "bondgraph_"
    lines = [f"graph {_dot_id(title + m.name)} {{", "  layout=neato; overlap=false; splines=true;",
             '  node [fontname="Helvetica", fontsize=11, shape=plaintext];',
             '  edge [fontname="Helvetica", fontsize=9, dir=both];']
    for el in m.elements:
        text = el.kind + ":" + el.name + (f"\\n{notes[el.name]}" if el.name in notes else "")
        lines.append(f"  {_dot_id(el.name)} [label={_dot_id(text)}];")
    for b in m.bonds:
        at_head = cbg.causality(b.number).flow_by == b.head
        head, tail = ("teelvee", "none") if at_head else ("lvee", "tee")
        bold = ", penwidth=2.5" if b.number in strong else ""
        lines.append(f"  {_dot_id(b.tail)} -- {_dot_id(b.head)} [label={_dot_id(str(b.number))}, "
                     f"arrowhead={head}, arrowtail={tail}{bold}];")
    for b, el in signal_links(m):
        bond = m.bond(b)
        lines.append(f"  {_dot_id(bond.head)} -- {_dot_id(el)} [style=dashed, color=\"#2060c0\", dir=forward, "
                     f"arrowhead=normal, label={_dot_id('signal of ' + str(b))}];")
    lines.append("}")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------- TCG
def tcg_text(tcg: TemporalCausalGraph) -> str:
    g = tcg.graph
    lines = [f"# temporal causal graph of {tcg.model.name}: source -[label]-> target  (element; parameters)"]
    for e in tcg.edges:
        params = ", ".join(f"{p}{_effect_sign(s)}" for p, s in zip(e.parameters, e.effects)) or "-"
        dt = "  [temporal]" if e.temporal else ""
        arrow = f"-[{e.label}]->"
        lines.append(f"{e.source:>8} {arrow:<16} {e.target:<8} ({e.element or '-'}; {params}){dt}")
    lines.append("# simplified TCG (states, inputs, measured variables)")
    for a, b, d in sorted(tcg.simplified.edges(data=True), key=lambda t: (var_key(t[0]), var_key(t[1]))):
        arrow = "-[dt]->" if d["temporal"] else "------>"
        lines.append(f"{a:>8} {arrow:<16} {b:<8} ({', '.join(d['parameters']) or '-'})")
    roles = {}
    for n, d in g.nodes(data=True):
        roles.setdefault(d["role"], []).append(n)
    for role in sorted(roles):
        lines.append(f"# {role}: {', '.join(sorted(roles[role], key=var_key))}")
    return "\n".join(lines) + "\n"


def _effect_sign(s: int | None) -> str:
    return {1: "(+)", -1: "(-)", 0: "(0)"}.get(s, "(?)")


def tcg_json(tcg: TemporalCausalGraph) -> dict:
    g = tcg.graph
    nodes = []
    for n in sorted(g.nodes, key=var_key):
        d = g.nodes[n]
        item = {"id": n, "kind": d["kind"], "role": d["role"], "measured": d["measured"],
                "bond": d.get("bond"), "element": d.get("element")}
        if "definition" in d:
            item["definition"] = str(d["definition"])
        if "derivative" in d:
            item["derivative"] = str(d["derivative"])
        nodes.append(item)
    edges = [{"source": e.source, "target": e.target, "label": e.label, "relation": e.relation,
              "element": e.element, "parameters": list(e.parameters), "effects": list(e.effects),
              "sign": e.sign, "temporal": e.temporal} for e in tcg.edges]
    simplified = [{"source": a, "target": b, "temporal": d["temporal"], "parameters": list(d["parameters"])}
                  for a, b, d in sorted(tcg.simplified.edges(data=True), key=lambda t: (var_key(t[0]), var_key(t[1])))]
    return {"model": tcg.model.name, "nodes": nodes, "edges": edges, "simplified_edges": simplified}


def _dot_id(name: str) -> str:
    return '"' + name.replace('"', '\\"') + '"'


def tcg_edge_label(e) -> str:
    """An edge's label in the pictures: the relation's label, then the
    parameters it involves that the label does not name (a modulated
    element's, a signal's gain): ``1/MR_memb [K0, K_slope, R_memb]``, so a
    fault of any of them shows where it enters."""
    named = set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", e.label))
    extra = [p for p in e.parameters if p not in named]
    return f"{e.label} [{', '.join(extra)}]" if extra else e.label


def tcg_inputs(tcg: TemporalCausalGraph) -> list[tuple[str, str, str]]:
    """The model's inputs as the pictures draw them, feeding the TCG: (input,
    the source variable it sets, label), the label naming the source element
    and the parameters an actuator fault adds (``<input>_gain``,
    ``<input>_offset``), sorted."""
    g = tcg.graph
    faults: dict[str, list[str]] = {}
    for f in tcg.model.faults:
        if f.target == "actuator":
            faults.setdefault(f.subject, []).append(f.parameter)
    out = []
    for n in sorted(g.nodes, key=var_key):
        for u in g.nodes[n].get("inputs", ()):
            params = sorted(set(faults.get(u, ())))
            element = g.nodes[n].get("element") or "source"
            out.append((u, n, f"{element} [{', '.join(params)}]" if params else element))
    return sorted(out, key=lambda t: (t[0], var_key(t[1])))


def tcg_dot(tcg: TemporalCausalGraph) -> str:
    g = tcg.graph
    lines = [f"digraph {_dot_id('tcg_' + tcg.model.name)} {{", "  rankdir=LR;",
             '  node [fontname="Helvetica", fontsize=11];', '  edge [fontname="Helvetica", fontsize=9];']
    inputs = tcg_inputs(tcg)
    for u in sorted({u for u, _, _ in inputs}):
        lines.append(f'  {_dot_id(u)} [shape=cds, style=filled, fillcolor="#9fd39a"];')
    for n in sorted(g.nodes, key=var_key):
        d = g.nodes[n]
        shape = {"state": "doublecircle", "input": "diamond", "measurement": "box"}.get(d["role"], "circle")
        if d["measured"] and d["role"] != "measurement":
            shape = "box" if d["role"] == "algebraic" else shape
        lines.append(f"  {_dot_id(n)} [shape={shape}];")
    for u, n, text in inputs:
        lines.append(f'  {_dot_id(u)} -> {_dot_id(n)} [label={_dot_id(text)}, color="#2e7d32"];')
    for e in tcg.edges:
        style = ', style=bold, color="#b03030"' if e.temporal else ""
        lines.append(f"  {_dot_id(e.source)} -> {_dot_id(e.target)} [label={_dot_id(tcg_edge_label(e))}{style}];")
    lines.append("}")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------- equations
def equations_text(ssm: StateSpaceModel) -> str:
    import sympy  # here only: a report's JSON (to_json) is written without it

    lines = [f"# state equations of {ssm.model.name}: dx/dt = f(x, u, theta), y = h(x, u, theta)",
             f"# states x: {', '.join(f'{x} ({el})' for x, el in zip(ssm.states, ssm.state_elements))}",
             f"# inputs u: {', '.join(ssm.inputs) or '-'}",
             f"# parameters theta: {', '.join(f'{p}={v:g}' for p, v in zip(ssm.parameters, ssm.parameter_values))}"]
    for x, f in zip(ssm.states, ssm.rhs):
        lines.append(f"d{x}/dt = {sympy.sstr(f)}")
    for y, h in zip(ssm.outputs, ssm.output_exprs):
        lines.append(f"{y} = {sympy.sstr(h)}")
    if ssm.loops:
        lines.append("# algebraic loops solved: " + "; ".join(", ".join(loop) for loop in ssm.loops))
    return "\n".join(lines) + "\n"


def equations_latex(ssm: StateSpaceModel) -> str:
    """The state equations as a LaTeX ``aligned`` block (for amsmath), each name
    typeset by :func:`latex_name`; the last line ends without ``\\``, which would
    add an empty line to the block."""
    import sympy

    names = {s: latex_name(s.name) for f in (*ssm.rhs, *ssm.output_exprs) for s in f.free_symbols}
    lines = [rf"\frac{{d{latex_name(x)}}}{{dt}} &= {sympy.latex(f, symbol_names=names)}"
             for x, f in zip(ssm.states, ssm.rhs)]
    lines += [rf"{latex_name(y)} &= {sympy.latex(h, symbol_names=names)}"
              for y, h in zip(ssm.outputs, ssm.output_exprs)]
    return "\n".join([f"% state equations of {ssm.model.name}, generated by bgc", r"\begin{aligned}",
                      " \\\\\n".join(lines), r"\end{aligned}"]) + "\n"


_LATEX_HEAD = re.compile(r"([A-Za-z]+)([0-9]*)")


def latex_name(name: str) -> str:
    r"""A model's name in LaTeX, the same rule for states, inputs, parameters
    and outputs. The name's letters are the symbol: a Greek letter's name is
    the letter (sympy's table: ``tau`` -> ``\tau``, ``Omega`` -> ``\Omega``),
    one letter stays as it is, several are one italic word (``\mathit{speed}``,
    not the product s p e e d). The digits after them and each part after an
    underscore are the subscript, separated by commas, upright unless all are
    digits: ``e4`` -> ``e_{4}``, ``F10`` -> ``F_{10}``, ``C_memb`` ->
    ``C_{\mathrm{memb}}``, ``f_in_offset`` -> ``f_{\mathrm{in,offset}}``
    (a space would vanish in math mode), ``F10_offset`` ->
    ``F_{\mathrm{10,offset}}``. A name the rule does not fit (``x__y``,
    ``lambda_``, ``a1b``) is typeset upright as written."""
    head, *parts = name.split("_")
    m = _LATEX_HEAD.fullmatch(head)
    if m is None or not all(parts):
        return r"\mathrm{" + name.replace("_", r"\_") + "}"
    letters, digits = m.groups()
    symbol = _greek(letters) or (letters if len(letters) == 1 else rf"\mathit{{{letters}}}")
    sub = [digits, *parts] if digits else parts
    if not sub:
        return symbol
    if all(p.isdigit() for p in sub):
        return f"{symbol}_{{{','.join(sub)}}}"
    return rf"{symbol}_{{\mathrm{{{','.join(_greek(p) or p for p in sub)}}}}}"


def _greek(word: str) -> str | None:
    """``\\tau`` for ``tau``: sympy's Greek letters (not its other symbols or
    modifiers, which would turn ``xbar`` into an x with a bar)."""
    from sympy.printing.latex import greek_letters_set, tex_greek_dictionary

    if word in tex_greek_dictionary:
        return tex_greek_dictionary[word]
    return "\\" + word if word in greek_letters_set else None


def equations_json(ssm: StateSpaceModel) -> dict:
    return {
        "model": ssm.model.name,
        "states": [{"name": x, "element": el, "initial": _num(v), "derivative": str(f)}
                   for x, el, v, f in zip(ssm.states, ssm.state_elements, ssm.initial, ssm.rhs)],
        "inputs": [{"name": i.name, "signal": i.signal.kind, "value": _num(i.signal.value)} for i in ssm.model.inputs],
        "parameters": [{"name": p, "value": _num(v)} for p, v in zip(ssm.parameters, ssm.parameter_values)],
        "outputs": [{"name": y, "expression": str(h), "noise": _num(m.noise)}
                    for y, h, m in zip(ssm.outputs, ssm.output_exprs, ssm.model.measurements)],
        "variables": {v: str(e) for v, e in ssm.variables},
        "algebraic_loops": [list(loop) for loop in ssm.loops],
    }


# ------------------------------------------------------------------ signatures
def prior_rows(num: Numerics) -> list[str]:
    """Each fault model's prior of its magnitude, in the model's units and
    as a fraction of the fault's scale (a drift's over the horizon too):
    what ``bgc check`` and ``bgc show signatures`` print."""
    model = num.equations.model
    labels = Labels(time_unit=model.settings.time_unit)
    horizon = model.settings.steps * model.settings.dt
    by = {c.parameter: c for c in model.faults}
    rows = []
    for f in num.faults:
        c = by[f.parameter]
        kind = FAULT_KINDS[f.kind]
        unit = "" if kind.factor else (model.unit(c.name) or "")
        lo, hi = f.prior
        per = f" {labels.per_time}" if kind.drifts else ""
        scale = {"parameter": f"|{c.name}| = {f.scale:.4g}",
                 "sensor": f"{c.name}'s nominal reading {f.scale:.4g}" if not kind.noise else
                 f"{c.name}'s noise std (its factor 1; 1 + b times it)",
                 "actuator": f"{c.name}'s nominal value {f.scale:.4g}" if kind.suffix != "gain" else "gain 1"}
        relative = f"{100 * lo / f.scale:+.3g} % to {100 * hi / f.scale:+.3g} %{per}"
        if kind.drifts:
            relative += f" ({100 * lo * horizon / f.scale:+.3g} % to {100 * hi * horizon / f.scale:+.3g} % over the " \
                        f"horizon of {horizon:g} {labels.time_word})"
        declared = c.rate if kind.drifts else c.size
        source = "declared" if declared is not None else "default"
        rows.append(f"{c.target} {c.name} {f.kind}: {kind.magnitude} {lo:.4g} to {hi:.4g}"
                    f"{(' ' + unit) if unit else ''}{per}, {relative} of {scale[c.target]} ({source})")
    return rows


def signatures_text(s: FaultSignatures, num: Numerics | None = None) -> str:
    """The signature table: one row per fault, symbols at orders 0..n per
    measurement; with ``num``, each fault's prior of its magnitude."""
    shown = max(s.orders, 1) + 1
    model = s.equations.model.name
    width = max([len(m) for m in s.measurements] + [shown])
    name_width = max([len(x.name) for x in s.signatures] + [5])
    lines = [f"# fault signatures of {model}: TRANSCEND forward propagation on the TCG",
             f"# per measurement, the deviation at derivative orders 0..{shown - 1} (0: magnitude, a jump;"
             " 1: slope; ...):",
             "# + above nominal, - below, 0 none, ? undetermined; orders up to "
             f"{s.orders} separate every pair of faults the full signatures separate",
             f"{'fault':<{name_width}}  " + "  ".join(f"{m:<{width}}" for m in s.measurements) + "  first to deviate"]
    for x in s.signatures:
        cells = "  ".join(f"{''.join(sym_[:shown]):<{width}}" for sym_ in x.symbols)
        lines.append(f"{x.name:<{name_width}}  {cells}  {', '.join(x.first) or '-'}")
    lines.append("ambiguity groups (identical signatures): "
                 + ("; ".join(", ".join(grp) for grp in s.ambiguity) if s.ambiguity else "none"))
    lines.append("parameters that enter the model as one combination: "
                 + ("; ".join(", ".join(grp) for grp in s.structural) if s.structural else "none"))
    lines.append("undetectable with these sensors: " + (", ".join(s.undetectable) or "none"))
    if num is not None and num.faults:
        lines.append("priors of the fault magnitudes (uniform; 'size' and 'rate' in the model declare them):")
        lines.extend(f"  {printable(row)}" for row in prior_rows(num))
    return "\n".join(lines) + "\n"


def signatures_json(s: FaultSignatures) -> dict:
    return {
        "model": s.equations.model.name,
        "measurements": list(s.measurements),
        "orders": s.orders,
        "signatures": [{"fault": x.name, "parameter": x.parameter, "direction": "+" if x.direction > 0 else "-",
                        "kind": x.kind, "symbols": {m: "".join(sym_) for m, sym_ in zip(s.measurements, x.symbols)},
                        "first": list(x.first)} for x in s.signatures],
        "ambiguity_groups": [list(g) for g in s.ambiguity],
        "structural_groups": [list(g) for g in s.structural],
        "undetectable": list(s.undetectable),
    }


# ------------------------------------------------------------------------- DBN
def dbn_nodes(d: Dbn) -> list[str]:
    g = d.graph
    order = {"input": 0, "mode": 0.5, "fault_indicator": 1, **{f"fault_{k.magnitude}": 2 for k in FAULT_KINDS.values()},
             "fault_parameter": 3, "state": 4, "measurement": 5}
    return sorted(g.nodes, key=lambda n: (g.nodes[n]["slice"], order[g.nodes[n]["role"]],
                                          var_key(g.nodes[n]["variable"])))


def _arcs(d: Dbn) -> list[tuple[str, str, str]]:
    idx = {n: i for i, n in enumerate(dbn_nodes(d))}
    return sorted(((a, b, k) for a, b, k in d.graph.edges(data="arc")), key=lambda t: (idx[t[0]], idx[t[1]]))


def dbn_text(d: Dbn) -> str:
    """A DBN as text: its nodes (id, role), then its arcs (from, to, kind; in a
    model with modes, an arc that holds in some modes only lists them)."""
    g = d.graph
    lines = [f"# two-slice DBN '{d.name}'"]
    for n in dbn_nodes(d):
        lines.append(f"node {n:<22} {g.nodes[n]['role']}")
    for a, b, k in _arcs(d):
        modes = g.edges[a, b].get("modes")
        lines.append(f"arc  {a:>22} -> {b:<22} {k}" + (f" (in {modes.replace(',', ', ')})" if modes else ""))
    return "\n".join(lines) + "\n"


def dbn_json(d: Dbn) -> dict:
    g = d.graph
    return {
        "name": d.name, "parameter": d.parameter, "kind": d.kind,
        "nodes": [{"id": n, **{k: g.nodes[n][k] for k in sorted(g.nodes[n])}} for n in dbn_nodes(d)],
        "arcs": [{"source": a, "target": b, "arc": k,
                  **({"modes": d.graph.edges[a, b]["modes"].split(",")} if "modes" in d.graph.edges[a, b] else {})}
                 for a, b, k in _arcs(d)],
    }


def dbn_dot(d: Dbn) -> str:
    """Graphviz DOT of a DBN, drawn as the matplotlib picture is: a cluster
    per slice (t, then t+1), the bands of :data:`~bgc.output.layout.DBN_BANDS`
    as ranks from top to bottom (``rank=same`` across both slices, with
    ``newrank``), each band's name at the left. An arc within a band (a
    variable that persists) runs left to right, so slice t stands left."""
    g = d.graph
    shape = {"state": "circle", "measurement": "box", "input": "diamond", "fault_indicator": "octagon",
             **{f"fault_{k.magnitude}": "hexagon" for k in FAULT_KINDS.values()}, "fault_parameter": "doublecircle",
             "mode": "Msquare"}
    nodes = dbn_nodes(d)
    bands: dict[int, list[str]] = {}
    for n in nodes:
        bands.setdefault(dbn_band(g.nodes[n]["role"]), []).append(n)
    names = {b: _dot_id("band " + DBN_BANDS[b][0]) for b in bands}
    lines = [f"digraph {_dot_id('dbn_' + d.name)} {{", "  newrank=true; rankdir=TB; ranksep=0.5;",
             '  node [fontname="Helvetica", fontsize=11];', "  // the bands, top to bottom, named at the left"]
    for b in sorted(bands):
        lines.append(f'  {names[b]} [shape=plaintext, label={_dot_id(DBN_BANDS[b][0])}, fontcolor="#505050"];')
    lines.append("  " + " -> ".join(names[b] for b in sorted(bands)) + " [style=invis];")
    for k, title in ((0, "t"), (1, "t+1")):
        lines.append(f"  subgraph {_dot_id('cluster_slice_' + str(k))} {{")
        lines.append(f"    label={_dot_id('slice ' + title)};")
        for n in nodes:
            if g.nodes[n]["slice"] == k:
                lines.append(f"    {_dot_id(n)} [shape={shape[g.nodes[n]['role']]}, label={_dot_id(g.nodes[n]['variable'])}];")
        lines.append("  }")
    for b in sorted(bands):
        lines.append(f"  {{rank=same; {names[b]}; {'; '.join(_dot_id(n) for n in bands[b])};}}")
        lines.append(f"  {names[b]} -> {_dot_id(bands[b][0])} [style=invis];")
    style = {"persistence": 'color="#808080"', "temporal": 'color="#b03030", style=bold', "intra": "color=black",
             "fault": 'color="#2060c0"', "drift": 'color="#2060c0", style=dashed', "indicator": "style=dotted",
             "switching": 'color="#c06000", style=bold',
             "mode": 'color="#208040"', "guard": 'color="#208040", style=bold', "command": 'color="#208040"',
             "timer": 'color="#208040"', "reset": 'color="#208040", style=dotted',
             "release": 'color="#208040", style=dashed'}
    for a, b, k in _arcs(d):
        modes = g.edges[a, b].get("modes")  # a model with modes: an arc of some modes only, dashed and named
        extra = f', style=dashed, tooltip={_dot_id("in " + modes)}' if modes else ""
        lines.append(f"  {_dot_id(a)} -> {_dot_id(b)} [{style[k]}{extra}];")
    lines.append("}")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- bgc check
def element_kinds_text(m) -> str:
    """How many elements of each kind bond graph ``m`` has, sources first:
    ``'Sf 1, C 2, R 3, 0 2, 1 1'``."""
    order = sorted(ELEMENT_KINDS.values(), key=lambda k: (ROLES.index(k.role), k.base, k.modulated))
    counts = {k.name: sum(el.kind == k.name for el in m.elements) for k in order}
    return ", ".join(f"{k} {n}" for k, n in counts.items() if n)


def fault_candidates_text(m) -> str:
    """Bond graph ``m``'s fault candidates with their kinds:
    ``'R10 (abrupt/incipient), F10 (bias/drift)'`` (empty: none)."""
    kinds: dict[str, list[str]] = {}
    for f in m.faults:  # a sensor's or input's faults may change two symbols: one entry per name
        kinds.setdefault(f.name, []).extend(f.kinds)
    return ", ".join(f"{name} ({'/'.join(k)})" for name, k in kinds.items())


def check_summary(ssm: StateSpaceModel, num: Numerics | None = None) -> str:
    """What ``bgc check`` prints for a model that compiles: elements, states,
    causality findings, algebraic loops (each with the resistors that close
    it), inputs, measurements, fault candidates. Model text is printed
    escaped (one line per item, no control characters)."""
    cbg = ssm.tcg.causal
    m = cbg.model
    lines = [f"{m.source}: ok: {m.name}" + (f" ({m.description})" if m.description else "")]
    lines.append(f"  elements: {len(m.elements)} ({element_kinds_text(m)})")
    lines.append(f"  bonds: {len(m.bonds)}")
    states = sorted(cbg.states, key=lambda s: s.bond)
    listed = ", ".join(f"{s.state} ({s.element}, integral)" for s in states)
    lines.append(f"  states: {len(states)}" + (f": {listed}" if listed else ""))
    deriv = [s for s in cbg.storage if not s.integral]
    if deriv:
        lines.append("  derivative causality: " + ", ".join(f"{s.element} ({s.kind}, bond {s.bond})" for s in deriv))
    g = ssm.tcg.graph
    loops = []
    for loop in ssm.loops:
        closing = sorted({g.nodes[v].get("element") for v in loop} & set(cbg.arbitrary))
        loops.append(f"through {', '.join(loop)}" + (f", closed by {' and '.join(closing)}" if closing else ""))
    lines.append(f"  algebraic loops: {len(loops) or 'none'}" + (": " + "; ".join(loops) if loops else ""))
    lines.append(f"  inputs: {', '.join(i.name for i in m.inputs) or 'none'}")
    measured = [y.name if y.text == y.name else f"{y.name} = {y.text}" for y in m.measurements]
    lines.append("  measurements: " + (", ".join(measured) or "none"))
    lines.append("  fault candidates: " + (fault_candidates_text(m) or "none"))
    if num is not None and num.faults:
        lines.append("  priors of the fault magnitudes:")
        lines.extend(f"    {printable(row)}" for row in prior_rows(num))
    warnings = [d for d in cbg.diagnostics if d.severity == "warning"]
    notes = [d for d in cbg.diagnostics if d.severity != "warning"]
    lines.append(f"  warnings: {len(warnings) or 'none'}")
    lines.extend(f"    warning: {d.message}" for d in warnings)
    if notes:
        lines.append(f"  notes: {len(notes)}")
        lines.extend(f"    note: {d.message}" for d in notes)
    return "\n".join(printable(line) for line in lines)


def hybrid_summary(model, modes) -> str:
    """What ``bgc check`` prints for a model with modes: the model's parts,
    then each mode (the switched junctions ON, its states, derivative
    causality, algebraic loops), the transitions (kind, guard or time,
    resets) with the causality each changes, and the warnings."""
    from ..compiler.modes import causality_changes, compile_stuck, no_hysteresis, states

    m = model
    lines = [f"{m.source}: ok: {m.name}" + (f" ({m.description})" if m.description else "")]
    lines.append(f"  elements: {len(m.elements)} ({element_kinds_text(m)})")
    lines.append(f"  bonds: {len(m.bonds)}")
    lines.append(f"  switched junctions: {', '.join(m.modes.switches)}")
    every = states(modes)
    lines.append(f"  states: {len(every)} over the modes: {', '.join(every)}")
    lines.append(f"  modes: {len(modes)} (the first is the mode at time 0)")
    for mode in modes:
        spec = m.modes.mode(mode.name)
        on = ", ".join(spec.on) or "none"
        own = ", ".join(mode.equations.states) or "none"
        lines.append(f"    {mode.name}: on {on}; states {own}" + (f" ({spec.description})" if spec.description else ""))
        deriv = [s for s in mode.causal.storage if not s.integral]
        if deriv:
            lines.append("      derivative causality: " + ", ".join(f"{s.element} ({s.kind}, bond {s.bond})"
                                                                     for s in deriv))
        if mode.equations.loops:
            lines.append("      algebraic loops: " + "; ".join(", ".join(loop) for loop in mode.equations.loops))
    by_name = {mode.name: mode for mode in modes}
    lines.append(f"  transitions: {len(m.modes.transitions)}")
    for t in m.modes.transitions:
        how = (f"when {t.guard.text}" + (f" (threshold's std {t.tolerance:g})" if t.tolerance else "")
               if t.kind == "autonomous" else f"after {t.after:g}" if t.kind == "timed"
               else "controlled (the data say the mode)")
        resets = ", ".join(f"{x} := {e}" for x, e in t.resets)
        lines.append(f"    {t.source} -> {t.target}: {how}" + (f"; reset {resets}" if resets else ""))
        changes = causality_changes(by_name[t.source], by_name[t.target])
        if changes:
            lines.append("      causality: " + "; ".join(changes))
    lines.append(f"  inputs: {', '.join(i.name for i in m.inputs) or 'none'}")
    measured = [y.name if y.text == y.name else f"{y.name} = {y.text}" for y in m.measurements]
    lines.append("  measurements: " + (", ".join(measured) or "none"))
    lines.append("  fault candidates: " + (fault_candidates_text(m) or "none"))
    if m.modes.stuck:
        lines.append(f"  switch faults: {len(m.modes.stuck)} (fault models with no size: the diagnosis weighs them "
                     "over their onsets)")
    for fault in m.modes.stuck:
        stuck = compile_stuck(m, modes, fault)
        runs = [f"{mode.name} runs as {same}" if same else f"{mode.name} runs in a configuration of its own"
                for mode, same in zip(modes, stuck.same) if same != mode.name]
        none = [mode.name for mode, same in zip(modes, stuck.same) if same == mode.name]
        if fault.releases:  # until a mode asks for the switch so: the modes where it cannot happen end it
            lines.append(f"    {fault.title}: " + "; ".join(runs) + f", until a mode with {fault.junction} "
                         f"{fault.state} (" + ", ".join(none) + ") ends it")
        else:
            lines.append(f"    {fault.title}: " + "; ".join(runs) + (f"; no effect in {', '.join(none)}" if none
                                                                       else ""))
    # a storage element in derivative causality is listed under its mode (an idle one: a switch cut it off)
    warnings = sorted({d.message for mode in modes for d in mode.causal.diagnostics
                       if d.severity == "warning" and "derivative causality" not in d.message})
    warnings += no_hysteresis(m.modes.transitions, {p.name: p.value for p in m.parameters})
    lines.append(f"  warnings: {len(warnings) or 'none'}")
    lines.extend(f"    warning: {w}" for w in warnings)
    return "\n".join(printable(line) for line in lines)


# ----------------------------------------------------------- distinguishability
def _noise_text(noise) -> str:
    process, measurement = noise
    if process is None and measurement is None:
        return "the model's noise"
    return ", ".join(f"{name} noise {v:g}" for name, v in (("process", process), ("measurement", measurement))
                     if v is not None)


def distinguishability_text(r) -> str:
    """:class:`bgc.api.DistinguishabilityReport` as text: for one scenario, a
    table of its rivals; for every candidate, each one's predicted ambiguity
    group."""
    lines = [f"# distinguishability of {r.model} at {_noise_text(r.noise)}, {r.steps} samples "
             "(Eriksson, Frisk and Krysander 2013; docs/diagnosis.md section 7)",
             "# E: expected log Bayes factor of the truth against a rival, over the data sets the noise can produce; "
             "sd: its spread",
             "# P: probability that the data, with the priors, name the truth over the rival; "
             f"a rival with P < {r.distinctions[0].level if r.distinctions else 0.95:g} is in the predicted "
             "ambiguity group"]
    lines += [f"# input u:{name}: {signal.text} (instead of the model's)" for name, signal in r.signals]
    if getattr(r, "modes", None) is not None:
        lines.append(f"# modes: {printable(r.modes)} (the controlled changes; from the first mode)" if r.modes else
                     "# modes: those the noise-free plant reaches by its guards and timed transitions")
    if r.scenario is not None:
        d = r.distinctions[0]
        lines.append(f"truth: {printable(r.scenario)} ({d.truth}, from sample {d.onset})")
        if getattr(r, "first_appearance", False):  # an intermittent fault that goes away inside the run
            lines.append(f"# an intermittent fault: its first appearance is told apart, over the {r.steps} samples "
                         "before it first goes away (bgc monitor --episodes names each appearance and its going "
                         "away as the step it is)")
        if getattr(r, "warning", None):
            lines.append(f"warning: {printable(r.warning)}")
        lines.append(f"divergence from no fault: {d.divergence:.4g} (an ideal detector's P of telling it from no "
                     f"fault {d.detectability:.3f}: a likelihood test of the whole run that knows the fault's shape)")
        rate = getattr(r, "detector", None)
        per_run = _per_run(r)
        lines += ideal_delay_lines(r, d, per_run)
        if rate is not None:  # the ideal detector held at bgc's detector's false-alarm probability over the run
            held = d.power(per_run)
            if f"{held:.3f}" != f"{d.detectability:.3f}":
                lines.append(f"the ideal detector held at bgc's detector's false-alarm probability ({per_run:.3g} "
                             f"over the run): P {held:.3f}")
            lines += detector_lines(rate, held, r.dt)
        width = max([len(x.name) for x in d.rivals] + [5])
        lines.append(f"{'rival':<{width}}  {'E':>10}  {'sd':>9}  {'P':>6}  best fit (magnitude from t)")
        for x in d.rivals:
            size = ("moved" if releases(kind_of(x.name)) else "stuck") if getattr(x, "stuck", False) else \
                f"{x.magnitude:.4g}"  # a switch's fault: no size
            fit = "no fault" if x.magnitude == 0 else f"{size} from t = {(x.onset + 1) * r.dt:g}"
            lines.append(f"{x.name:<{width}}  {x.expected:>10.4g}  {x.std:>9.3g}  {x.probability:>6.3f}  {fit}")
        lines.append("predicted ambiguity group: " + (", ".join(d.group) or "none"))
        return "\n".join(lines) + "\n"
    lines.append(f"# each fault: a change of {100 * r.change:g} % of its scale (a parameter's value, a sensor's "
                 "reading, an input's value; a drift reaches it at the end "
                 f"of the run) from t = {(r.distinctions[0].onset + 1) * r.dt if r.distinctions else 0:g}")
    width = max([len(d.label) for d in r.distinctions] + [5])
    lines.append(f"{'fault':<{width}}  {'divergence':>10}  predicted ambiguity group (P)")
    for d in r.distinctions:
        if d.detectability < d.level:
            group = "not told from no fault (P " + f"{d.detectability:.2f})"
        else:
            group = ", ".join(f"{x.name} ({x.probability:.2f})" for x in d.rivals if x.probability < d.level) or "none"
        lines.append(f"{d.label:<{width}}  {d.divergence:>10.4g}  {group}")
    return "\n".join(lines) + "\n"


#: One letter per level of ``bgc analyse`` in its matrix's cells.
LEVEL_LETTERS = {"structural": "S", "qualitative": "Q", "quantitative": "N"}


def analysis_text(r) -> str:
    """``bgc analyse``'s report (:class:`bgc.api.analyse.AnalysisReport`):
    per fault what detects it, the isolability matrix with a letter per
    level, the classes of faults not told apart, and why."""
    f, levels = r.faults, r.levels
    letters = "".join(LEVEL_LETTERS[lv.name] for lv in levels)
    lines = [f"# analysis of {r.model}: {len(f)} faults, sensors {', '.join(r.sensors)}; levels: "
             + ", ".join(f"{LEVEL_LETTERS[lv.name]} {lv.name}" for lv in levels)]
    lines.append("# S: the equations' structure (as the Fault Diagnosis Toolbox); Q: the TRANSCEND signatures once "
                 "every sensor shows its symbols")
    if r.by_mode:
        lines.append(f"# S and Q across the modes {', '.join(r.by_mode)}: a fault detected, or a pair told apart, in "
                     "some mode" + ("" if r.steps is None else "; N over a run through the modes"
                                    + (f" ({r.modes})" if r.modes else " (its guards')")))
    if r.steps is not None:
        noise = "the model's noise" if r.noise == (None, None) else \
            f"noise process={r.noise[0] or 1:g}, measurement={r.noise[1] or 1:g} of the model's"
        lines.append(f"# N: bgc distinguish, each fault a change of {100 * r.change:g} % of its scale from "
                     f"{100 * r.at:g} % of a {r.steps}-sample run, {noise}, told at P >= {r.level:g}")
    width = max(len(x) for x in (*f, "fault"))
    number = len(str(len(f)))
    lines.append("")
    lines.append(f"{'#':>{number}}  {'fault':<{width}}  {'target':<9}  detected by")
    for i, name in enumerate(f):
        seen = "".join(LEVEL_LETTERS[lv.name] if lv.detectable[i] else "." for lv in levels)
        lines.append(f"{i + 1:>{number}}  {name:<{width}}  {r.targets[i]:<9}  {seen}")
    lines.append("")
    lines.append(f"isolability: row = the fault that happened, column (its #) = the fault it is told from; "
                 f"{letters} per level, . where that level cannot tell them apart")
    cell = max(len(letters), number)
    lines.append((" " * (number + width + 2) + "  " + " ".join(f"{j + 1:<{cell}}" for j in range(len(f)))).rstrip())
    for i, name in enumerate(f):
        cells = ["-" * len(letters) if i == j else
                 "".join(LEVEL_LETTERS[lv.name] if lv.isolable[i][j] else "." for lv in levels)
                 for j in range(len(f))]
        lines.append(f"{i + 1:>{number}}  {name:<{width}}  " + " ".join(f"{c:<{cell}}" for c in cells).rstrip())
    lines.append("")
    for lv in levels:
        groups = lv.classes(f)
        missed = [x for x, d in zip(f, lv.detectable) if not d]
        text = "; ".join(["{" + ", ".join(g) + "}" for g in groups]) or "none"
        lines.append(f"{lv.name}: not detected: {', '.join(missed) or 'none'}; not told apart (both ways): {text}")
    for mode, pair in r.by_mode.items():
        for lv in pair:
            missed = [x for x, d in zip(f, lv.detectable) if not d]
            groups = "; ".join("{" + ", ".join(g) + "}" for g in lv.classes(f)) or "none"
            lines.append(f"  in {mode}, {lv.name}: not detected: {', '.join(missed) or 'none'}; "
                         f"not told apart: {groups}")
    for a, b in zip(levels, levels[1:]):
        for x, y in ((a, b), (b, a)):
            pairs = r.more(x.name, y.name)
            if pairs:
                lines.append(f"{x.name} tells {len(pairs)} ordered pair(s) apart that {y.name} does not: "
                             + ", ".join(f"{i} from {j}" for i, j in pairs[:8]) + (", ..." if len(pairs) > 8 else ""))
    if r.placement is not None:
        lines += [""] + placement_lines(r.placement)
    if r.input_tests:
        lines += ["", "input tests for the faults the declared inputs leave undetected (P: probability of detection):"]
        for fault, u, text, p, p0 in r.input_tests:
            lines.append(f"  {fault}: none of the input tests tried detects it better (P {p0:.3f})" if u is None else
                         f"  {fault}: P {p0:.3f} -> {p:.3f} with {u}={text} "
                         f"(bgc distinguish {r.source}{distinguish_options(r)} --input {u}='{text}')")
    lines.append("")
    lines.append("why not:")
    for i, name in enumerate(f):
        for j, other in enumerate(f):
            reasons = [f"{LEVEL_LETTERS[lv.name]}: {printable(lv.why[i, j])}" for lv in levels if (i, j) in lv.why]
            if reasons:
                what = f"{name} not detected" if i == j else f"{name} not told from {other}"
                lines.append(f"  {what}: " + "; ".join(reasons))
    return "\n".join(lines) + "\n"


def distinguish_options(r) -> str:
    """The options of ``bgc distinguish`` that reproduce the quantitative level of analysis ``r``."""
    out = ""
    if r.change != 0.3:
        out += f" --change {r.change:g}"
    if r.at != 0.5:
        out += f" --at {r.at:g}"
    if r.noise != (None, None):
        out += f" --noise process={r.noise[0] or 1:g},measurement={r.noise[1] or 1:g}"
    if r.steps is not None and r.steps_given:
        out += f" --steps {r.steps}"
    if r.modes:
        out += f" --modes {r.modes}"
    return out


def placement_lines(p) -> list[str]:
    """``bgc analyse --place-sensors``'s answer, as lines."""
    detected, pairs = p.reachable
    twins = sum(1 for c in p.candidates if c.beside)
    lines = [f"sensor placement (structural{' and qualitative' if p.reachable_qualitative else ''}; candidates: "
             f"{len(p.candidates) - twins} bond variables no sensor reads"
             + (f", {twins} second sensor(s) on a measured quantity" if twins else "")
             + f"): structurally now {len(p.now[0])} faults "
             f"detected and {len(p.now[1])} ordered pairs told apart, with every candidate {len(detected)} and "
             f"{len(pairs)}"]
    if p.reachable_qualitative:
        lines.append(f"  by the signatures now {len(p.now_qualitative[0])} and {len(p.now_qualitative[1])}, with "
                     f"every candidate {len(p.reachable_qualitative[0])} and {len(p.reachable_qualitative[1])}")
    never = [f for f in p.faults if f not in detected]
    if never:
        lines.append(f"  no candidate detects: {', '.join(never)}")
    untold = sorted((a, b) for a in detected for b in p.faults if a != b and (a, b) not in pairs)
    if untold:
        lines.append("  no candidate tells apart: " + ", ".join(f"{a} from {b}" for a, b in untold[:8])
                     + (", ..." if len(untold) > 8 else ""))
    if not p.sets:
        lines.append("  no set of candidates within --most gives as much: raise --most")
    elif p.sets == ((),):
        lines.append("  no sensor to add: the sensors there give what every candidate would")
    else:
        reads = {c.name: f"= {c.expr}" + (f", a second sensor beside {c.beside}" if c.beside else "")
                 for c in p.candidates}
        lines.append(f"  the cheapest sets (cost {p.cost:g}), each enough" + (f" (the first {len(p.sets)}; there are "
                     "more)" if p.more else "") + ":")
        lines += [f"    {', '.join(f'{v} ({reads[v]})' for v in s)}" for s in p.sets]
        if getattr(p, "checked", None):
            lines.append(f"  checked by bgc distinguish (the quantitative level; now {p.checked_now[0]} faults detected "
                         f"and {p.checked_now[1]} ordered pairs told apart), the sets in its order, --write the first:")
            lines += [f"    {', '.join(s)}: {d} and {n}" for s, (d, n) in zip(p.sets, p.checked)]
    return lines


def _per_run(r) -> float:
    """The false-alarm probability over the run of a prediction's scenario at
    which the ideal detector is held: bgc's detector's, scaled from its
    horizon to the run, when its runs were measured; else the campaigns' 1 %
    (:data:`bgc.analysis.distinguish.FALSE_ALARM`)."""
    from ..analysis.distinguish import FALSE_ALARM

    rate = getattr(r, "detector", None)
    if rate is None:
        return FALSE_ALARM
    return min(1.0, rate.false_alarm * r.steps * r.dt / rate.horizon) if rate.horizon else rate.false_alarm


def _ideal_delay(r, d, per_run: float) -> float | None:
    """The bound of :meth:`~bgc.analysis.distinguish.Distinction.ideal_delay`
    in time units after the first sample that sees the fault; None: none."""
    late = d.ideal_delay(per_run)  # None for a noise fault, whose reach is not kept
    return None if late is None else late * r.dt


def ideal_delay_lines(r, d, per_run: float) -> list[str]:
    """How soon any detector holding ``per_run`` false alarms over the run
    could see scenario ``d``: the least delay by which half of its runs can
    alarm (Neyman and Pearson; bgc's detector's own median is on its line)."""
    if not getattr(d, "reach", ()):
        return []
    delay = _ideal_delay(r, d, per_run)
    unit = f" {r.time_unit}" if getattr(r, "time_unit", None) else ""
    how = "(the likelihood ratio that knows the fault's onset and size; Neyman-Pearson)"
    if delay is None:
        return [f"no detector at a false-alarm probability of {per_run:.3g} over the run alarms in half of the runs "
                f"by the run's end {how}"]
    return [f"no detector at a false-alarm probability of {per_run:.3g} over the run alarms in half of the runs "
            f"sooner than {delay:g}{unit} after the first sample that sees the fault {how}"]


def detector_lines(rate, ideal: float, dt: float) -> list[str]:
    """bgc's detector on a scenario (:class:`bgc.api.detection.DetectorRate`)
    beside the ideal detector's probability ``ideal`` (held at the same
    false-alarm probability): the rate, how it was had, and which of the
    two the user will see when they differ."""
    unit = f" {rate.time_unit}" if rate.time_unit else " time units"
    delay = f", median delay {rate.median_delay:g}{unit}" if rate.median_delay is not None else ""
    tests = getattr(rate, "detectors", ("mean",))
    which = "" if len(tests) == 1 else f", tests {', '.join(tests)}"
    out = [f"bgc's detector ({rate.method}, {rate.particles} particles{which}, false-alarm probability {rate.false_alarm:g} "
           f"per {rate.horizon:g}{unit}): detects it in {rate.detected} of {rate.runs} simulated runs, P "
           f"{rate.probability:.2f} in [{rate.low:.2f}, {rate.high:.2f}] (95 %, Wilson; seeds {rate.first_seed} to "
           f"{rate.first_seed + rate.runs - 1}){delay}"
           + (f"; {rate.false_alarms} alarm(s) before the onset" if rate.false_alarms else "")]
    if rate.high < ideal - 0.05:
        out.append(f"  what a diagnosis will show: bgc's detector, which tests the residuals over windows "
                   f"without knowing the fault's shape; expect 'no fault' in about {100 * (1 - rate.probability):.0f} "
                   "% of such runs (a longer run, a larger fault, a test input or a sensor nearer the fault helps)")
    elif rate.low > ideal + 0.05:
        out.append("  bgc's detector sees it more often than the ideal detector's P suggests (an alarm is not an "
                   "isolation: the rivals below still hold)")
    return out


def distinguishability_json(r) -> dict:
    rate = getattr(r, "detector", None)
    per_run = _per_run(r)
    return {
        "inputs": {name: dataclasses.asdict(signal) for name, signal in r.signals},
        "detector": None if rate is None else {
            "runs": rate.runs, "detected": rate.detected, "false_alarms": rate.false_alarms,
            "probability": rate.probability, "low": rate.low, "high": rate.high, "median_delay": rate.median_delay,
            "method": rate.method, "particles": rate.particles, "false_alarm": rate.false_alarm,
            "horizon": rate.horizon, "first_seed": rate.first_seed, "time_unit": rate.time_unit,
            "detectors": list(getattr(rate, "detectors", ("mean",)))},
        "model": r.model, "steps": r.steps, "dt": r.dt, "time_unit": getattr(r, "time_unit", None),
        "noise": {"process": r.noise[0], "measurement": r.noise[1]},
        "scenario": r.scenario, "change": r.change, "at": r.at, "warning": getattr(r, "warning", None),
        "modes": getattr(r, "modes", None),
        "faults": [{
            "fault": d.label, "model": d.truth, "magnitude": d.magnitude, "onset_sample": d.onset,
            "divergence": d.divergence, "detectability": d.detectability, "misfit": d.misfit, "level": d.level,
            "ideal_delay": {"false_alarm": per_run, "delay": _ideal_delay(r, d, per_run)}
            if getattr(d, "reach", ()) else None,
            "group": list(d.group),
            "rivals": [{"model": x.name, "expected": x.expected, "std": x.std, "probability": x.probability,
                        "onset_sample": x.onset, "magnitude": x.magnitude, "stuck": getattr(x, "stuck", False)}
                       for x in d.rivals],
        } for d in r.distinctions],
    }


def decomposition_json(d, parts) -> dict:
    """A model's submodels (:class:`bgc.compiler.decompose.Decomposition`) as
    plain data, each with its compiled states (``parts``: the submodels compiled)."""
    return {"model": d.model, "submodels": [
        {"name": s.name, "predicts": list(s.outputs), "reads": list(s.reads),
         "reads_as": dict(s.read_as), "inputs": list(s.inputs), "elements": list(s.elements),
         "states": [{"state": x, "element": el} for x, el in zip(c.equations.states, c.equations.state_elements)],
         "faults": list(s.faults), "fault_models": [f.name for f in c.dbn.faulty]}
        for s, c in zip(d.submodels, parts)]}


def decomposition_text(d, parts) -> str:
    """What ``decomposition.txt`` says: per submodel, what it predicts from
    what, its states and the faults it can see."""
    n = max((len(c.equations.states) for c in parts), default=0)
    lines = [f"{d.model}: {len(d.submodels)} submodel(s), the largest with {n} state(s); each predicts its "
             "sensors from the plant's inputs and the readings of the sensors around it", ""]
    for s, c in zip(d.submodels, parts):
        states = ", ".join(f"{x} ({el})" for x, el in zip(c.equations.states, c.equations.state_elements))
        read = {r: a for r, a in s.read_as}
        reads = ", ".join(r if a == r else f"{r} (as input {a})" for r, a in read.items())
        lines.append(f"{s.name}: predicts {', '.join(s.outputs)}" + (f" from {reads}" if reads else ""))
        if s.inputs:
            lines.append(f"  plant inputs: {', '.join(s.inputs)}")
        lines.append(f"  states: {states}")
        lines.append(f"  elements: {', '.join(s.elements)}")
        lines.append(f"  faults it sees: {', '.join(s.faults) if s.faults else 'none'} "
                     f"({len(c.dbn.faulty)} fault model(s))")
    return "\n".join(lines) + "\n"
