"""Pictures of the bond graph, the TCG and the DBNs: Graphviz ``dot`` when
installed, otherwise a matplotlib drawing with a fixed layout, so a picture
always comes out.

The bond graph is drawn as one draws it by hand (Karnopp, Margolis and
Rosenberg, *System Dynamics*, ch. 3 and 5): each bond a line with its number,
the power half-arrow at the end that receives the power (the bond's head),
and the causal stroke of SCAP at the end whose element receives the effort
(the other end imposes it); signal links of modulated elements are dashed
arrows. Where the elements sit is :mod:`bgc.output.layout`.

The matplotlib SVG output is made deterministic (fixed hash salt, no date, text
kept as text).
"""

from __future__ import annotations

import io
import math
import multiprocessing
import os
import shutil
import subprocess
from collections.abc import Callable
from dataclasses import dataclass

from ..ir import CausalBondGraph, Dbn, DbnModel, TemporalCausalGraph, var_key
from ..kinds import FAULT_KINDS, element_kind
from .artifacts import dbn_file_stem, mark_picture
from .layout import (CHAR_WIDTH, DBN_BAND_STEP, DbnLayout, bond_graph_layout, boxes_overlap, dbn_layout, label, label_size,
                     segment_hits_box, signal_links)
from .render import bondgraph_dot, dbn_dot, dbn_nodes, strong_bonds, tcg_dot, tcg_edge_label, tcg_inputs

#: DBN node roles of the fault magnitudes (``fault_bias``, ``fault_slope``).
_MAGNITUDE_ROLES = tuple(f"fault_{k.magnitude}" for k in FAULT_KINDS.values())
_ROLE_COLOR = {"state": "#f4c7a1", "input": "#c9e4c5", "signal": "#9fd39a", "measurement": "#a9c8ec",
               "algebraic": "#ffffff",
               "fault_indicator": "#e0e0e0", **{r: "#d6b4e8" for r in _MAGNITUDE_ROLES},
               "fault_parameter": "#e8b4c8", "mode": "#f0e68c"}


def graphviz_available() -> bool:
    return shutil.which("dot") is not None


def render_dot(dot_text: str, fmt: str) -> bytes:
    """Render DOT text with Graphviz (``fmt`` is ``svg`` or ``png``)."""
    out = subprocess.run(["dot", f"-T{fmt}"], input=dot_text.encode(), capture_output=True, check=True, timeout=60)
    return out.stdout


def tcg_picture(tcg: TemporalCausalGraph, fmt: str, engine: str = "auto") -> bytes:
    """The TCG as an SVG or PNG picture (Graphviz when installed, else matplotlib), with bgc's mark."""
    return mark_picture(_tcg_picture(tcg, fmt, engine), fmt)


def _tcg_picture(tcg: TemporalCausalGraph, fmt: str, engine: str) -> bytes:
    if engine == "graphviz" or (engine == "auto" and graphviz_available()):
        return render_dot(tcg_dot(tcg), fmt)
    g = tcg.graph
    bonds = sorted({d["bond"] for _, d in g.nodes(data=True) if d.get("bond") is not None})
    col = {b: i for i, b in enumerate(bonds)}
    pos = {}
    for n, d in g.nodes(data=True):
        if d["kind"] == "effort":
            pos[n] = (col[d["bond"]], 1.0)
        elif d["kind"] == "flow":
            pos[n] = (col[d["bond"]], 0.0)
    meas = sorted((n for n, d in g.nodes(data=True) if d["kind"] == "measurement"), key=var_key)
    for i, n in enumerate(meas):
        src = min((pos[p][0] for p in g.predecessors(n) if p in pos), default=i)
        pos[n] = (src + 0.5, -1.0 if i % 2 == 0 else -1.5)
    inputs = tcg_inputs(tcg)
    for u in sorted({u for u, _, _ in inputs}):  # beside the first variable it sets, outside the rows
        x, y = min((pos[n] for v, n, _ in inputs if v == u), key=lambda p: p[0])
        pos[u] = (x - 0.35, 1.9) if y > 0.5 else (x - 0.45, -0.8)
    edges = [(u, n) for u, n, _ in inputs] + [(e.source, e.target) for e in tcg.edges]
    labels = {(u, n): text for u, n, text in inputs}
    labels.update({(e.source, e.target): tcg_edge_label(e) for e in tcg.edges})
    temporal = {(e.source, e.target) for e in tcg.edges if e.temporal}
    roles = {n: ("measurement" if d["measured"] else d["role"]) for n, d in g.nodes(data=True)}
    roles.update({u: "signal" for u, _, _ in inputs})
    width = max(6.0, 1.1 * len(bonds))
    legend = [("node", _ROLE_COLOR[r], text) for r, text in _TCG_ROLES if r in roles.values()]
    legend.append(("edge", _HIGHLIGHT, "integrating edge (dt/C, dt/I: a state's derivative)"))
    legend.append(("edge", _EDGE, "algebraic edge; [..]: parameters it involves beyond its label"))
    nodes = sorted(g.nodes, key=var_key) + sorted({u for u, _, _ in inputs})
    return _draw(_Graph(pos, nodes, edges, labels, temporal, roles, {n: n for n in nodes}, f"TCG of {tcg.model.name}",
                        (width, 5.6 if meas else 4.2), tuple(legend)), fmt)


#: The legends' node entries, in the order they are listed.
_TCG_ROLES = (("signal", "input (the model's; [..]: an actuator fault's parameter)"),
              ("input", "source variable (an Se's effort, an Sf's flow)"), ("state", "state (integral causality)"),
              ("algebraic", "algebraic variable"), ("measurement", "measured variable"))
_DBN_ROLES = (("input", "input u"), ("mode", "mode q (and the time in it)"), ("state", "state x"),
              ("measurement", "measurement y"),
              ("fault_indicator", "fault indicator D (is the fault present)"),
              *((r, "fault magnitude delta (bias or slope)") for r in _MAGNITUDE_ROLES[:1]),
              ("fault_parameter", "drifting parameter (incipient fault)"))
_HIGHLIGHT, _EDGE = "#b03030", "#404040"


def dbn_picture(d: Dbn, fmt: str, engine: str = "auto") -> bytes:
    """A DBN as an SVG or PNG picture, with bgc's mark."""
    return mark_picture(_dbn_picture(d, fmt, engine), fmt)


def _dbn_picture(d: Dbn, fmt: str, engine: str) -> bytes:
    if engine == "graphviz" or (engine == "auto" and graphviz_available()):
        return render_dot(dbn_dot(d), fmt)
    g = d.graph
    lay = dbn_layout(d)
    roles = {n: g.nodes[n]["role"] for n in g.nodes}
    present = {_MAGNITUDE_ROLES[0] if r in _MAGNITUDE_ROLES else r for r in roles.values()}
    legend = [("node", _ROLE_COLOR[r], text) for r, text in _DBN_ROLES if r in present]
    switching = {(a, b) for a, b, k in g.edges(data="arc") if k == "switching"}
    legend.append(("edge", _HIGHLIGHT, "temporal arc: integration from slice t to t+1"
                   + ("; the indicator switching (a fault that comes and goes)" if switching else "")))
    legend.append(("edge", _EDGE, "other arcs: persistence, measurement, fault"
                   + (", mode (guard, timer, command, reset"
                      + (", release" if any(k == "release" for _, _, k in g.edges(data="arc")) else "") + ")"
                      if "mode" in present else "")))
    x0, x1 = lay.slices[0][1] - 1.5, lay.slices[1][2] + 0.4
    y0, y1 = lay.bands[-1][1] - 0.6, lay.bands[0][1] + 0.85
    bottom = (0.25 + 0.2 * math.ceil(len(legend) / 2))
    size = (x1 - x0 + 0.2, (y1 - y0) / 0.92 + bottom + 0.4)
    temporal = {(a, b) for a, b, k in g.edges(data="arc") if k == "temporal"} | switching
    graph = _Graph(lay.positions, dbn_nodes(d), sorted(g.edges), {}, temporal, roles,
                   {n: g.nodes[n]["variable"] for n in g.nodes}, f"DBN '{d.name}': slice t (left), t+1 (right)",
                   size, tuple(legend), (x0, x1, y0, y1), lambda ax: _dbn_bands(ax, lay))
    return _draw(graph, fmt)


def _dbn_bands(ax, lay: DbnLayout) -> None:
    """A DBN picture's frame: a light stripe behind every other band, each
    band's name at the left, each slice's name over its column."""
    from matplotlib.patches import Rectangle

    left, right = lay.slices[0][1] - 1.45, lay.slices[1][2] + 0.35
    for i, (name, y) in enumerate(lay.bands):
        if i % 2 == 0:
            ax.add_patch(Rectangle((left, y - DBN_BAND_STEP / 2), right - left, DBN_BAND_STEP, fc="#f3f3f3",
                                   ec="none", zorder=0, gid=f"band-{i}"))
        ax.text(left + 0.08, y, name, ha="left", va="center", fontsize=8, style="italic", color="#505050",
                gid=f"band-name-{i}")
    top = lay.bands[0][1] + DBN_BAND_STEP / 2
    for name, a, b in lay.slices:
        ax.text((a + b) / 2, top + 0.12, name, ha="center", va="bottom", fontsize=9, fontweight="bold",
                gid=f"slice-name-{name.replace(' ', '-')}")
    middle = (lay.slices[0][2] + lay.slices[1][1]) / 2
    ax.plot([middle, middle], [lay.bands[-1][1] - DBN_BAND_STEP / 2, top], color="#a0a0a0", lw=0.8, ls=(0, (4, 3)),
            zorder=0)


#: Box colours of element roles in the bond graph picture (as the TCG's: sources green, storage orange).
_ELEMENT_COLOR = {"source": "#c9e4c5", "storage": "#f4c7a1", "resistor": "#ffffff", "two_port": "#e6dcf5",
                  "junction": "#e0e0e0"}
_ROLE_TITLE = {"source": "source (Se, Sf)", "storage": "storage (C, I)", "resistor": "resistor (R)",
               "two_port": "two-port (TF, GY)", "junction": "junction (0, 1)"}
#: Drawing sizes of a bond's marks, in inches.
_BARB = (0.14, 0.075)
_STROKE = 0.085
_NUMBER_OFFSET = 0.11
_RC = {"svg.hashsalt": "bgc", "svg.fonttype": "none", "font.size": 8, "path.simplify": False}


def bondgraph_picture(cbg: CausalBondGraph, fmt: str, engine: str = "auto") -> bytes:
    """The causal bond graph as an SVG or PNG picture: elements, numbered
    bonds, power half-arrows, causal strokes, with a legend; bgc's mark."""
    return mark_picture(_bondgraph_picture(cbg, fmt, engine), fmt)


def causality_picture(cbg: CausalBondGraph, fmt: str, engine: str = "auto") -> bytes:
    """The causality of the bond graph (``bgc show causality``) as an SVG or
    PNG picture: the bond graph's layout with the causal strokes drawn bold
    (the power half-arrows pale), each storage element's causality written
    by it (integral: its state; derivative), each junction's strong bond
    drawn thick and named by the junction; bgc's mark."""
    return mark_picture(_bondgraph_picture(cbg, fmt, engine, causal=True), fmt)


def _bondgraph_picture(cbg: CausalBondGraph, fmt: str, engine: str, causal: bool = False) -> bytes:
    if engine == "graphviz" or (engine == "auto" and graphviz_available()):
        return render_dot(bondgraph_dot(cbg, causal), fmt)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    model = cbg.model
    lay = bond_graph_layout(model)
    pos = {n: (x, y) for n, x, y in lay.positions}
    text = {el.name: label(el) for el in model.elements}
    role = {el.name: element_kind(el.kind).role for el in model.elements}
    derivative = {s.element for s in cbg.storage if not s.integral}
    boxes = {n: (*pos[n], *label_size(text[n])) for n in pos}
    x0 = min(x - w / 2 for x, _, w, _ in boxes.values()) - 0.35
    x1 = max(x + w / 2 for x, _, w, _ in boxes.values()) + 0.35
    y0 = min(y - h / 2 for _, y, _, h in boxes.values()) - 0.35
    y1 = max(y + h / 2 for _, y, _, h in boxes.values()) + 0.35
    notes = _legend_lines(bool(derivative), bool(signal_links(model)), causal)
    legend_h, title_h = max(1.25, 0.45 + 0.17 * len(notes)), 0.4
    width = max(x1 - x0, 7.8)
    x0, x1 = (x0 + x1) / 2 - width / 2, (x0 + x1) / 2 + width / 2
    height = (y1 - y0) + legend_h + title_h
    with matplotlib.rc_context(_RC):
        fig = plt.figure(figsize=(width, height))
        ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0 - legend_h, y1 + title_h)
        ax.axis("off")
        title = (f"causality of {model.name} by SCAP: causal strokes, storage causality, strong bonds" if causal
                 else f"bond graph of {model.name}, causality by SCAP")
        ax.text((x0 + x1) / 2, y1 + title_h / 2, title, ha="center", va="center", fontsize=10)
        links = []
        for bond, element in signal_links(model):
            b = model.bond(bond)
            mid = ((pos[b.tail][0] + pos[b.head][0]) / 2, (pos[b.tail][1] + pos[b.head][1]) / 2)
            _, end = _clip((*mid, 0.0, 0.0), boxes[element])
            links.append((mid, end))
            ax.add_patch(FancyArrowPatch(mid, end, arrowstyle="-|>", linestyle=(0, (3, 2)), color="#2060c0",
                                         lw=0.8, shrinkA=0, shrinkB=0, mutation_scale=8,
                                         gid=f"signal-{bond}-{element}"))
        number_boxes: list = []
        ends = {b.number: _clip(boxes[b.tail], boxes[b.head]) for b in model.bonds}
        lines = [*links, *ends.values()]
        marks = [(x, y, 0.26, 0.26) for t, h in ends.values() for x, y in (t, h)]  # strokes and half-arrows
        strong = {n for _, _, bonds in strong_bonds(cbg) for n in bonds} if causal else set()
        for b in model.bonds:
            c = cbg.causality(b.number)
            tail, head = ends[b.number]
            _draw_bond(ax, tail, head, stroke_at_head=(c.flow_by == b.head), number=b.number,
                       obstacles=[*boxes.values(), *marks, *number_boxes], lines=lines, placed=number_boxes,
                       causal=causal, strong=b.number in strong)
        if causal:
            _causality_notes(ax, cbg, boxes, [*boxes.values(), *marks, *number_boxes], lines)
        for n in sorted(pos):
            x, y, w, h = boxes[n]
            ax.add_patch(FancyBboxPatch((x - w / 2, y - h / 2), w, h, boxstyle="round,pad=0,rounding_size=0.05",
                                        fc=_ELEMENT_COLOR[role[n]], ec="#b03030" if n in derivative else "#202020",
                                        lw=1.4 if n in derivative else 0.8, gid=f"element-{n}", zorder=3))
            ax.text(x, y, text[n], ha="center", va="center", fontsize=8, zorder=4, gid=f"label-{n}",
                    fontweight="bold" if role[n] == "junction" else "normal")
        _bondgraph_legend(ax, x0, y0 - legend_h, x1, legend_h, notes, causal)
        buf = io.BytesIO()
        meta = {"Date": None, "Creator": None} if fmt == "svg" else {"Software": None}
        fig.savefig(buf, format=fmt, metadata=meta, dpi=110)
        plt.close(fig)
    return buf.getvalue()


def _clip(a, b):
    """The ends of a bond from box ``a`` to box ``b`` (x, y, width, height):
    where the line between their centres leaves each box, with a small gap."""
    (ax_, ay, aw, ah), (bx, by, bw, bh) = a, b
    dx, dy = bx - ax_, by - ay
    length = math.hypot(dx, dy) or 1.0

    def out(w, h):
        tx = (w / 2 + 0.03) / abs(dx) if abs(dx) > 1e-12 else math.inf
        ty = (h / 2 + 0.03) / abs(dy) if abs(dy) > 1e-12 else math.inf
        return min(tx, ty, 0.45) if length > 0 else 0.0

    ta, tb = out(aw, ah), 1.0 - out(bw, bh)
    return (ax_ + ta * dx, ay + ta * dy), (ax_ + tb * dx, ay + tb * dy)


def _draw_bond(ax, tail, head, stroke_at_head: bool, number: int | str, obstacles, lines, placed,
               gid: bool = True, causal: bool = False, strong: bool = False) -> None:
    """One bond: its line, the half-arrow at the head (on the left of the
    direction of power), the causal stroke across the end that receives the
    effort, and its number beside the middle (where it clears the boxes in
    ``obstacles`` and the segments in ``lines``; ``placed`` gets its box).
    ``causal``: the stroke bold and the half-arrow pale; ``strong``: the
    line thick (a junction's strong bond)."""
    (tx, ty), (hx, hy) = tail, head
    length = math.hypot(hx - tx, hy - ty) or 1.0
    ux, uy = (hx - tx) / length, (hy - ty) / length
    nx_, ny = -uy, ux
    tag = (lambda what: f"{what}-{number}") if gid else (lambda what: None)
    ax.plot([tx, hx], [ty, hy], color="#202020", lw=2.6 if strong else 1.0, solid_capstyle="butt", gid=tag("bond"),
            zorder=2)
    back, side = _BARB
    ax.plot([hx, hx - back * ux + side * nx_], [hy, hy - back * uy + side * ny],
            color="#a8a8a8" if causal else "#202020", lw=1.0,
            solid_capstyle="round", gid=tag("half-arrow"), zorder=2)
    sx, sy = (hx, hy) if stroke_at_head else (tx, ty)
    half = _STROKE * (1.4 if causal else 1.0)
    ax.plot([sx - half * nx_, sx + half * nx_], [sy - half * ny, sy + half * ny], color="#b03030",
            lw=3.0 if causal else 1.6, solid_capstyle="butt", gid=tag("stroke"), zorder=2)
    w, h = label_size(str(number))[0] - 0.06, 0.16
    mx, my = (tx + hx) / 2, (ty + hy) / 2
    choices = [(mx - _NUMBER_OFFSET * nx_ * s - 0.05 * nx_ * s * abs(ux), my - _NUMBER_OFFSET * ny * s)
               for s in (1, -1)]
    choices += [(mx + t * ux - off * nx_ * s, my + t * uy - off * ny * s)
                for off in (_NUMBER_OFFSET, 1.8 * _NUMBER_OFFSET) for t in (0.15, -0.15, 0.3, -0.3) for s in (1, -1)]
    def clear(c):
        return not any(boxes_overlap((*c, w, h), o, 0.0) for o in obstacles) and \
            not any(segment_hits_box(p, q, (*c, w, h)) for p, q in lines)

    at = next((c for c in choices if clear(c)), choices[0])
    placed.append((*at, w, h))
    ax.text(at[0], at[1], str(number), ha="center", va="center", fontsize=7, color="#303080",
            gid=tag("bond-number"), zorder=5,
            bbox={"boxstyle": "square,pad=0.05", "fc": "white", "ec": "none", "alpha": 0.85})


def _legend_lines(derivative: bool, signals: bool, causal: bool) -> list[str]:
    """What the legend of the bond graph picture (``causal``: of the
    causality picture) says about the marks drawn."""
    lines = ["half arrow: power flows from A to B (it sits at the end that receives the power)",
             "red stroke: causal stroke (SCAP): B, at the stroke, receives the effort; A imposes it (and B the flow)",
             "n: the bond's number in the model; e<n> and f<n> are its effort and flow"]
    if causal:
        lines.append("thick bond: a junction's strong bond; it sets a 0-junction's effort (its one stroke at the "
                     "junction), a 1-junction's flow")
        lines.append("italic note: a storage element's causality (integral: its state; derivative: no state), "
                     "a junction's strong bond")
    if signals:
        lines.append("dashed blue arrow: signal link (a modulated element reads that bond's variable)")
    if derivative:
        lines.append("red box: storage element in derivative causality")
    return lines


def _bondgraph_legend(ax, x0: float, y0: float, x1: float, height: float, lines: list[str], causal: bool) -> None:
    """What the marks mean (``lines``), under the graph in a band of
    ``height``: a sample bond from A to B whose effort A imposes, and the
    colours of the element roles."""
    from matplotlib.patches import FancyBboxPatch

    top = y0 + height - 0.15
    ax.plot([x0 + 0.2, x1 - 0.2], [top + 0.05, top + 0.05], color="#c0c0c0", lw=0.6)
    a, b = (x0 + 0.45, top - 0.3), (x0 + 1.75, top - 0.3)
    for (x, y), name in ((a, "A"), (b, "B")):
        ax.text(x, y, name, ha="center", va="center", fontsize=8,
                bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "#202020", "lw": 0.8})
    _draw_bond(ax, (a[0] + 0.2, a[1]), (b[0] - 0.2, b[1]), stroke_at_head=True, number="n", obstacles=[],
               lines=[], placed=[], gid=False, causal=causal)
    for i, line in enumerate(lines):
        ax.text(x0 + 2.1, top - 0.12 - 0.17 * i, line, ha="left", va="center", fontsize=7)
    x = x0 + 0.25
    for r, title in _ROLE_TITLE.items():
        w = label_size(title)[0] * 0.85
        ax.add_patch(FancyBboxPatch((x, y0 + 0.07), w, 0.2, boxstyle="round,pad=0,rounding_size=0.04",
                                    fc=_ELEMENT_COLOR[r], ec="#202020", lw=0.6))
        ax.text(x + w / 2, y0 + 0.17, title, ha="center", va="center", fontsize=7)
        x += w + 0.15


def _causality_notes(ax, cbg: CausalBondGraph, boxes: dict, obstacles: list, lines: list) -> None:
    """By each storage element its causality (``integral: e4``,
    ``derivative``) and by each junction its strong bond (``strong bond
    2``; a conflict in red): under its box, else above, right, left or at a
    corner, nearer first, where the note clears the boxes in ``obstacles``
    and the segments in ``lines`` (else where it hits the fewest); each
    note placed joins the obstacles."""
    notes = {s.element: ("integral: " + s.state if s.integral else "derivative", s.integral) for s in cbg.storage}
    for name, _, bonds in strong_bonds(cbg):
        notes[name] = ((f"strong bond {bonds[0]}", True) if len(bonds) == 1 else
                       (f"conflict: {len(bonds)} strong bonds", False))
    for name in sorted(notes):
        text, fine = notes[name]
        x, y, w, h = boxes[name]
        tw, th = CHAR_WIDTH * 0.85 * len(text) + 0.1, 0.17
        choices = [(x + sx * ((w + tw) / 2 + gap), y + sy * ((h + th) / 2 + gap))
                   for gap in (0.04, 0.2) for sx, sy in ((0, -1), (0, 1), (1, 0), (-1, 0), (1, -1), (-1, -1), (1, 1),
                                                        (-1, 1))]

        def hits(c):
            return sum(boxes_overlap((*c, tw, th), o, 0.0) for o in obstacles) + \
                sum(segment_hits_box(p, q, (*c, tw, th)) for p, q in lines)

        at = min(choices, key=hits)
        obstacles.append((*at, tw, th))
        ax.text(at[0], at[1], text, ha="center", va="center", fontsize=7, style="italic", zorder=5,
                color="#205080" if fine else "#b03030", gid=f"causality-{name}",
                bbox={"boxstyle": "square,pad=0.05", "fc": "white", "ec": "none", "alpha": 0.85})


#: The bends an edge of the TCG or a DBN may take (fractions of its length, to its left), tried in order
#: after its first choice until one passes through no other node's box.
_BENDS = (0.0, 0.1, -0.1, 0.2, -0.2, 0.3, -0.3, 0.45, -0.45)


@dataclass(frozen=True)
class _Graph:
    """What :func:`_draw` draws: nodes at ``pos`` as labelled boxes coloured
    by role, ``edges`` as curved arrows (``highlight`` in red) with
    ``edge_labels`` placed apart, ``legend`` entries (``node``/``edge``,
    colour, text) under the graph; ``limits`` (x0, x1, y0, y1) of the axes,
    None for the nodes' extent and a margin; ``decorate`` draws on the axes
    under the graph (a DBN's bands)."""

    pos: dict
    nodes: list
    edges: list
    edge_labels: dict
    highlight: set
    roles: dict
    node_labels: dict
    title: str
    size: tuple[float, float]
    legend: tuple = ()
    limits: tuple[float, float, float, float] | None = None
    decorate: Callable | None = None


def _curve(p1, p2, rad: float, n: int = 60):
    """Points of a quadratic Bezier from p1 to p2 bent by ``rad`` (a
    fraction of the length, to the left)."""
    import numpy as np

    a, b = np.asarray(p1, float), np.asarray(p2, float)
    d = b - a
    ctrl = (a + b) / 2 + rad * np.array([-d[1], d[0]])
    t = np.linspace(0.0, 1.0, n)[:, None]
    return (1 - t) ** 2 * a + 2 * (1 - t) * t * ctrl + t ** 2 * b


def _inside(pts, boxes, margin: float):
    """Which of ``pts`` lie in each box (x, y, width, height): a boolean
    array of shape (boxes, points)."""
    import numpy as np

    b = np.asarray(boxes, float).reshape(-1, 4)
    return ((np.abs(pts[None, :, 0] - b[:, None, 0]) < b[:, None, 2] / 2 + margin)
            & (np.abs(pts[None, :, 1] - b[:, None, 1]) < b[:, None, 3] / 2 + margin))


def _route(a: str, b: str, boxes: dict, bends) -> tuple:
    """An edge's curve from node ``a`` to ``b``: the first of ``bends``
    whose curve passes through no other node's box (else the one through
    the fewest), trimmed where it leaves ``a``'s box and enters ``b``'s.
    Returns its points and the unit tangent at its tip."""
    import numpy as np

    others = [box for n, box in boxes.items() if n not in (a, b)]
    best, fewest = None, None
    for rad in bends:
        pts = _curve(boxes[a][:2], boxes[b][:2], rad)
        out = ~(_inside(pts, [boxes[a], boxes[b]], 0.03).any(axis=0))
        first = int(np.argmax(out))
        last = len(out) - int(np.argmax(out[::-1]))
        pts = pts[first:last] if out.any() and last - first >= 2 else pts[[0, -1]]
        hits = int(_inside(pts, others, 0.02).any(axis=1).sum()) if others else 0
        if fewest is None or hits < fewest:
            best, fewest = pts, hits
        if hits == 0:
            break
    tangent = best[-1] - best[-2]
    return best, tangent / (float(np.hypot(*tangent)) or 1.0)


def _bends(a: str, b: str, pos: dict, edges: set, highlighted: bool) -> tuple[float, ...]:
    """The bends :func:`_route` tries for edge a -> b: to its left only when
    b -> a is drawn too (the two part), a clear bend first along a row (to
    the right for a ``highlighted`` edge, so that red and black arcs along a
    row of a DBN run on either side of it)."""
    if (b, a) in edges:
        return (0.18, 0.3, 0.45)
    if abs(pos[a][1] - pos[b][1]) < 1e-9:
        return (-0.18 if highlighted else 0.18, *_BENDS)
    return (0.06, *_BENDS)


def _draw(graph: _Graph, fmt: str) -> bytes:
    """The picture of ``graph`` (:class:`_Graph`) as ``fmt`` bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.collections import LineCollection, PolyCollection

    g = graph
    with matplotlib.rc_context(_RC):
        fig, ax = plt.subplots(figsize=g.size)
        ax.set_title(g.title)
        xs, ys = [p[0] for p in g.pos.values()], [p[1] for p in g.pos.values()]
        x0, x1, y0, y1 = g.limits or (min(xs) - 0.7, max(xs) + 0.7, min(ys) - 0.7, max(ys) + 0.7)
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.axis("off")
        fig.subplots_adjust(left=0.01, right=0.99, top=0.92, bottom=_legend(fig, g.legend, g.size[1]))
        box = ax.get_position()
        per_x, per_y = (x1 - x0) / (box.width * g.size[0]), (y1 - y0) / (box.height * g.size[1])
        boxes = {}
        for n in g.nodes:
            w, h = label_size(g.node_labels[n])
            boxes[n] = (*g.pos[n], w * per_x, h * per_y)
        if g.decorate is not None:
            g.decorate(ax)
        edge_set = set(g.edges)
        lines, heads, colors, labelled = [], [], [], []
        for a, b in g.edges:
            pts, tan = _route(a, b, boxes, _bends(a, b, g.pos, edge_set, (a, b) in g.highlight))
            lines.append(np.vstack([pts[:-1:3], pts[-1:]]))  # every third point: the file stays small
            tip, normal = pts[-1], np.array([-tan[1], tan[0]])
            heads.append([tip, tip - 0.07 * tan + 0.025 * normal, tip - 0.07 * tan - 0.025 * normal])
            colors.append(_HIGHLIGHT if (a, b) in g.highlight else _EDGE)
            if (a, b) in g.edge_labels:
                labelled.append((f"edge-label-{a}-{b}", pts, g.edge_labels[(a, b)]))
        ax.add_collection(LineCollection(lines, colors=colors, linewidths=0.8))
        ax.add_collection(PolyCollection(heads, facecolors=colors, edgecolors=colors, linewidths=0.5))
        for n in g.nodes:
            x, y = g.pos[n]
            ax.text(x, y, g.node_labels[n], ha="center", va="center", fontsize=8, gid=f"node-{n}",
                    bbox={"boxstyle": "round,pad=0.3" if g.roles[n] != "measurement" else "square,pad=0.3",
                          "fc": _ROLE_COLOR.get(g.roles[n], "#ffffff"), "ec": "#202020", "lw": 0.8})
        _place_labels(fig, ax, labelled, list(boxes.values()))
        buf = io.BytesIO()
        meta = {"Date": None, "Creator": None} if fmt == "svg" else {"Software": None}
        fig.savefig(buf, format=fmt, metadata=meta, dpi=110)
        plt.close(fig)
    return buf.getvalue()


def _legend(fig, legend, height: float) -> float:
    """The legend entries (``node``/``edge``, colour, text) in two columns
    at the foot of ``fig``; the fraction of its height they take."""
    if not legend:
        return 0.01
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [Patch(fc=c, ec="#202020", lw=0.6, label=t) if k == "node" else Line2D([], [], color=c, lw=1.2, label=t)
               for k, c, t in legend]
    fig.legend(handles=handles, loc="lower center", ncol=2, fontsize=7, frameon=False,
               bbox_to_anchor=(0.5, 0.0)).set_gid("legend")
    return min(0.4, (0.25 + 0.2 * math.ceil(len(handles) / 2)) / height)


#: Where along its curve an edge's label may sit (fractions of its points, the middle first) and beside it
#: (multiples of the label's height, across the curve).
_LABEL_ALONG = (0.5, 0.4, 0.6, 0.3, 0.7, 0.2, 0.8)
_LABEL_ACROSS = (0.0, 0.9, -0.9)


def _place_labels(fig, ax, labelled, node_boxes) -> None:
    """Each edge's label (gid, curve points, text) at the first spot along
    its curve, then beside it (:data:`_LABEL_ALONG`, :data:`_LABEL_ACROSS`),
    whose box overlaps no label placed before and no node box; where every
    spot does, the one that overlaps the fewest. Boxes are measured as drawn
    (the renderer's text extents, in pixels)."""
    import numpy as np

    renderer = fig.canvas.get_renderer()
    to_px = ax.transData.transform
    nodes = [(*to_px((x, y)), *(abs(to_px((x + w, y + h)) - to_px((x, y))))) for x, y, w, h in node_boxes]
    placed: list[tuple] = []
    for gid, pts, text in labelled:
        t = ax.text(0, 0, text, fontsize=6, ha="center", va="center", color="#303080", gid=gid,
                    bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.8})
        extent = t.get_window_extent(renderer)
        pad = 0.2 * 6 * fig.dpi / 72
        w, h = extent.width + 2 * pad, extent.height + 2 * pad
        px = to_px(pts)
        best, fewest = None, None
        for across in _LABEL_ACROSS:
            for along in _LABEL_ALONG:
                i = min(len(px) - 2, int(along * (len(px) - 1)))
                d = px[i + 1] - px[i]
                normal = np.array([-d[1], d[0]]) / (float(np.hypot(*d)) or 1.0)
                spot = (px[i] + px[i + 1]) / 2 + across * h * normal
                clashes = sum(boxes_overlap((*spot, w, h), o, 0.0) for o in placed) * 2 \
                    + sum(boxes_overlap((*spot, w, h), o, 0.0) for o in nodes)
                if fewest is None or clashes < fewest:
                    best, fewest = spot, clashes
                if clashes == 0:
                    break
            if fewest == 0:
                break
        placed.append((*best, w, h))
        t.set_position(ax.transData.inverted().transform(best))


def pictures(dbns: DbnModel, engine: str = "auto", workers: int | None = None) -> dict[str, bytes]:
    """SVG pictures of the TCG and of every DBN (the names of
    :func:`~bgc.output.artifacts.picture_names`), rendered on up to ``workers``
    processes (default: the number of CPUs, at most 4)."""
    jobs: list[tuple[str, object]] = [("tcg.svg", dbns.equations.tcg)]
    jobs += [(f"dbn/{dbn_file_stem(d.name)}.svg", d) for d in (dbns.nominal, *dbns.faulty)]
    n = workers if workers is not None else min(4, os.cpu_count() or 1)
    if n > 1 and len(jobs) > 3 and "fork" in multiprocessing.get_all_start_methods():
        global _JOBS
        _JOBS = (jobs, engine)
        try:
            with multiprocessing.get_context("fork").Pool(n) as pool:
                images = pool.map(_render_job, range(len(jobs)))
        finally:
            _JOBS = None
    else:
        images = [_render(obj, engine) for _, obj in jobs]
    return {name: img for (name, _), img in zip(jobs, images)}


_JOBS: tuple | None = None


def _render_job(i: int) -> bytes:
    jobs, engine = _JOBS
    return _render(jobs[i][1], engine)


def _render(obj: object, engine: str) -> bytes:
    if isinstance(obj, TemporalCausalGraph):
        return tcg_picture(obj, "svg", engine)
    return dbn_picture(obj, "svg", engine)
