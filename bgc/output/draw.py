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

from ..ir import CausalBondGraph, Dbn, DbnModel, TemporalCausalGraph, var_key
from ..kinds import FAULT_KINDS, element_kind
from .artifacts import dbn_file_stem, mark_picture
from .layout import bond_graph_layout, boxes_overlap, label, label_size, segment_hits_box, signal_links
from .render import bondgraph_dot, dbn_dot, dbn_nodes, tcg_dot, tcg_edge_label, tcg_inputs

#: DBN node roles of the fault magnitudes (``fault_bias``, ``fault_slope``).
_MAGNITUDE_ROLES = tuple(f"fault_{k.magnitude}" for k in FAULT_KINDS.values())
_ROLE_COLOR = {"state": "#f4c7a1", "input": "#c9e4c5", "signal": "#9fd39a", "measurement": "#a9c8ec",
               "algebraic": "#ffffff",
               "fault_indicator": "#e0e0e0", **{r: "#d6b4e8" for r in _MAGNITUDE_ROLES},
               "fault_parameter": "#e8b4c8"}


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
    return _draw(pos, nodes, edges, labels, temporal, roles, {n: n for n in nodes}, f"TCG of {tcg.model.name}",
                 (width, 5.6 if meas else 4.2), fmt, legend)


#: The legends' node entries, in the order they are listed.
_TCG_ROLES = (("signal", "input (the model's; [..]: an actuator fault's parameter)"),
              ("input", "source variable (an Se's effort, an Sf's flow)"), ("state", "state (integral causality)"),
              ("algebraic", "algebraic variable"), ("measurement", "measured variable"))
_DBN_ROLES = (("input", "input u"), ("state", "state x"), ("measurement", "measurement y"),
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
    column = {"input": 0, "fault_indicator": 0, **{r: 0 for r in _MAGNITUDE_ROLES}, "fault_parameter": 0,
              "state": 1, "measurement": 2}
    groups: dict[tuple[int, int], list[str]] = {}
    for n in dbn_nodes(d):
        a = g.nodes[n]
        groups.setdefault((a["slice"], column[a["role"]]), []).append(n)
    tallest = max(len(v) for v in groups.values())
    pos = {}
    for (slice_, c), members in groups.items():
        top = (tallest - len(members)) / 2.0
        for r, n in enumerate(members):
            pos[n] = (slice_ * 3.8 + c * 1.1, -(top + r))
    rows = {k: len(v) for k, v in groups.items()}
    temporal = {(a, b) for a, b, k in g.edges(data="arc") if k == "temporal"}
    roles = {n: g.nodes[n]["role"] for n in g.nodes}
    labels_n = {n: g.nodes[n]["variable"] for n in g.nodes}
    height = max(4.0, 0.8 * max(rows.values()) + 1.5) + 0.8
    present = {_MAGNITUDE_ROLES[0] if r in _MAGNITUDE_ROLES else r for r in roles.values()}
    legend = [("node", _ROLE_COLOR[r], text) for r, text in _DBN_ROLES if r in present]
    legend.append(("edge", _HIGHLIGHT, "temporal arc: integration from slice t to t+1"))
    legend.append(("edge", _EDGE, "other arcs: persistence, measurement, fault"))
    return _draw(pos, dbn_nodes(d), sorted(g.edges), {}, temporal, roles, labels_n,
                 f"DBN '{d.name}': slice t (left), t+1 (right)", (9.0, height), fmt, legend)


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


def _bondgraph_picture(cbg: CausalBondGraph, fmt: str, engine: str) -> bytes:
    if engine == "graphviz" or (engine == "auto" and graphviz_available()):
        return render_dot(bondgraph_dot(cbg), fmt)
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
    legend_h, title_h = 1.25, 0.4
    width = max(x1 - x0, 7.8)
    x0, x1 = (x0 + x1) / 2 - width / 2, (x0 + x1) / 2 + width / 2
    height = (y1 - y0) + legend_h + title_h
    with matplotlib.rc_context(_RC):
        fig = plt.figure(figsize=(width, height))
        ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0 - legend_h, y1 + title_h)
        ax.axis("off")
        ax.text((x0 + x1) / 2, y1 + title_h / 2, f"bond graph of {model.name}, causality by SCAP",
                ha="center", va="center", fontsize=10)
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
        for b in model.bonds:
            c = cbg.causality(b.number)
            tail, head = ends[b.number]
            _draw_bond(ax, tail, head, stroke_at_head=(c.flow_by == b.head), number=b.number,
                       obstacles=[*boxes.values(), *marks, *number_boxes], lines=lines, placed=number_boxes)
        for n in sorted(pos):
            x, y, w, h = boxes[n]
            ax.add_patch(FancyBboxPatch((x - w / 2, y - h / 2), w, h, boxstyle="round,pad=0,rounding_size=0.05",
                                        fc=_ELEMENT_COLOR[role[n]], ec="#b03030" if n in derivative else "#202020",
                                        lw=1.4 if n in derivative else 0.8, gid=f"element-{n}", zorder=3))
            ax.text(x, y, text[n], ha="center", va="center", fontsize=8, zorder=4, gid=f"label-{n}",
                    fontweight="bold" if role[n] == "junction" else "normal")
        _bondgraph_legend(ax, x0, y0 - legend_h, x1, bool(derivative), bool(signal_links(model)))
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
               gid: bool = True) -> None:
    """One bond: its line, the half-arrow at the head (on the left of the
    direction of power), the causal stroke across the end that receives the
    effort, and its number beside the middle (where it clears the boxes in
    ``obstacles`` and the segments in ``lines``; ``placed`` gets its box)."""
    (tx, ty), (hx, hy) = tail, head
    length = math.hypot(hx - tx, hy - ty) or 1.0
    ux, uy = (hx - tx) / length, (hy - ty) / length
    nx_, ny = -uy, ux
    tag = (lambda what: f"{what}-{number}") if gid else (lambda what: None)
    ax.plot([tx, hx], [ty, hy], color="#202020", lw=1.0, solid_capstyle="butt", gid=tag("bond"), zorder=2)
    back, side = _BARB
    ax.plot([hx, hx - back * ux + side * nx_], [hy, hy - back * uy + side * ny], color="#202020", lw=1.0,
            solid_capstyle="round", gid=tag("half-arrow"), zorder=2)
    sx, sy = (hx, hy) if stroke_at_head else (tx, ty)
    ax.plot([sx - _STROKE * nx_, sx + _STROKE * nx_], [sy - _STROKE * ny, sy + _STROKE * ny], color="#b03030",
            lw=1.6, solid_capstyle="butt", gid=tag("stroke"), zorder=2)
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


def _bondgraph_legend(ax, x0: float, y0: float, x1: float, derivative: bool, signals: bool) -> None:
    """What the marks mean, under the graph: a sample bond from A to B whose
    effort A imposes, and the colours of the element roles."""
    from matplotlib.patches import FancyBboxPatch

    top = y0 + 1.1
    ax.plot([x0 + 0.2, x1 - 0.2], [top + 0.05, top + 0.05], color="#c0c0c0", lw=0.6)
    a, b = (x0 + 0.45, top - 0.3), (x0 + 1.75, top - 0.3)
    for (x, y), name in ((a, "A"), (b, "B")):
        ax.text(x, y, name, ha="center", va="center", fontsize=8,
                bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "#202020", "lw": 0.8})
    _draw_bond(ax, (a[0] + 0.2, a[1]), (b[0] - 0.2, b[1]), stroke_at_head=True, number="n", obstacles=[],
               lines=[], placed=[], gid=False)
    lines = ["half arrow: power flows from A to B (it sits at the end that receives the power)",
             "red stroke: causal stroke (SCAP): B, at the stroke, receives the effort; A imposes it (and B the flow)",
             "n: the bond's number in the model; e<n> and f<n> are its effort and flow"]
    if signals:
        lines.append("dashed blue arrow: signal link (a modulated element reads that bond's variable)")
    if derivative:
        lines.append("red box: storage element in derivative causality")
    for i, line in enumerate(lines):
        ax.text(x0 + 2.1, top - 0.12 - 0.17 * i, line, ha="left", va="center", fontsize=7)
    x = x0 + 0.25
    for r, title in _ROLE_TITLE.items():
        w = label_size(title)[0] * 0.85
        ax.add_patch(FancyBboxPatch((x, y0 + 0.07), w, 0.2, boxstyle="round,pad=0,rounding_size=0.04",
                                    fc=_ELEMENT_COLOR[r], ec="#202020", lw=0.6))
        ax.text(x + w / 2, y0 + 0.17, title, ha="center", va="center", fontsize=7)
        x += w + 0.15


def _curve(p1, p2, rad: float, shrink: float, n: int = 24):
    """Points of a quadratic Bezier from p1 to p2 bent by ``rad`` (fraction of
    the length, to the left), trimmed by ``shrink`` at both ends; and the unit
    tangent at the end."""
    import numpy as np

    a, b = np.asarray(p1, float), np.asarray(p2, float)
    d = b - a
    length = float(np.hypot(*d)) or 1.0
    ctrl = (a + b) / 2 + rad * np.array([-d[1], d[0]])
    t = np.linspace(0.0, 1.0, n)[:, None]
    pts = (1 - t) ** 2 * a + 2 * (1 - t) * t * ctrl + t ** 2 * b
    seg = np.hypot(*np.diff(pts, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    keep = (s >= shrink) & (s <= s[-1] - shrink)
    pts = pts[keep] if keep.sum() >= 2 else pts[[0, -1]]
    tangent = pts[-1] - pts[-2]
    tangent = tangent / (float(np.hypot(*tangent)) or 1.0)
    return pts, tangent, length


def _draw(pos, nodes, edges, edge_labels, highlight, roles, node_labels, title, size, fmt, legend=()) -> bytes:
    """Nodes as labelled boxes coloured by role, edges as curved arrows
    (``highlight`` in red), and ``legend`` entries (``node``/``edge``,
    colour, text) under the graph."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.collections import LineCollection, PolyCollection

    with matplotlib.rc_context({"svg.hashsalt": "bgc", "svg.fonttype": "none", "font.size": 8,
                                "path.simplify": False}):
        fig, ax = plt.subplots(figsize=size)
        ax.set_title(title)
        edge_set = set(edges)
        lines, heads, colors = [], [], []
        for a, b in edges:
            rad = 0.18 if (b, a) in edge_set or abs(pos[a][1] - pos[b][1]) < 1e-9 else 0.06
            pts, tan, _ = _curve(pos[a], pos[b], rad, 0.22)
            color = _HIGHLIGHT if (a, b) in highlight else _EDGE
            lines.append(pts)
            tip = pts[-1]
            normal = np.array([-tan[1], tan[0]])
            heads.append([tip, tip - 0.07 * tan + 0.025 * normal, tip - 0.07 * tan - 0.025 * normal])
            colors.append(color)
            if (a, b) in edge_labels:
                mid = pts[len(pts) // 2]
                ax.text(mid[0], mid[1], edge_labels[(a, b)], fontsize=6, ha="center", va="center",
                        color="#303080", bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none",
                                               "alpha": 0.8})
        ax.add_collection(LineCollection(lines, colors=colors, linewidths=0.8))
        ax.add_collection(PolyCollection(heads, facecolors=colors, edgecolors=colors, linewidths=0.5))
        for n in nodes:
            x, y = pos[n]
            ax.text(x, y, node_labels[n], ha="center", va="center", fontsize=8,
                    bbox={"boxstyle": "round,pad=0.3" if roles[n] != "measurement" else "square,pad=0.3",
                          "fc": _ROLE_COLOR.get(roles[n], "#ffffff"), "ec": "#202020", "lw": 0.8})
        xs = [p[0] for p in pos.values()]
        ys = [p[1] for p in pos.values()]
        ax.set_xlim(min(xs) - 0.7, max(xs) + 0.7)
        ax.set_ylim(min(ys) - 0.7, max(ys) + 0.7)
        ax.axis("off")
        bottom = 0.01
        if legend:
            from matplotlib.lines import Line2D
            from matplotlib.patches import Patch

            handles = [Patch(fc=c, ec="#202020", lw=0.6, label=t) if k == "node" else
                       Line2D([], [], color=c, lw=1.2, label=t) for k, c, t in legend]
            bottom = min(0.4, (0.25 + 0.2 * math.ceil(len(handles) / 2)) / size[1])
            fig.legend(handles=handles, loc="lower center", ncol=2, fontsize=7, frameon=False,
                       bbox_to_anchor=(0.5, 0.0)).set_gid("legend")
        buf = io.BytesIO()
        meta = {"Date": None, "Creator": None} if fmt == "svg" else {"Software": None}
        fig.subplots_adjust(left=0.01, right=0.99, top=0.92, bottom=bottom)
        fig.savefig(buf, format=fmt, metadata=meta, dpi=110)
        plt.close(fig)
    return buf.getvalue()


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
