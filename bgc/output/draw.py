"""Pictures of the TCG and the DBNs: Graphviz ``dot`` when installed, otherwise a
matplotlib drawing with a fixed layered layout, so a picture always comes out.

The matplotlib SVG output is made deterministic (fixed hash salt, no date, text
kept as text).
"""

from __future__ import annotations

import io
import multiprocessing
import os
import shutil
import subprocess

from ..ir import Dbn, DbnModel, TemporalCausalGraph, var_key
from ..kinds import FAULT_KINDS
from .artifacts import dbn_file_stem, mark_picture
from .render import dbn_dot, dbn_nodes, tcg_dot

#: DBN node roles of the fault magnitudes (``fault_bias``, ``fault_slope``).
_MAGNITUDE_ROLES = tuple(f"fault_{k.magnitude}" for k in FAULT_KINDS.values())
_ROLE_COLOR = {"state": "#f4c7a1", "input": "#c9e4c5", "measurement": "#a9c8ec", "algebraic": "#ffffff",
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
    labels = {(e.source, e.target): e.label for e in tcg.edges}
    temporal = {(e.source, e.target) for e in tcg.edges if e.temporal}
    roles = {n: ("measurement" if d["measured"] else d["role"]) for n, d in g.nodes(data=True)}
    width = max(6.0, 1.1 * len(bonds))
    return _draw(pos, sorted(g.nodes, key=var_key), [(e.source, e.target) for e in tcg.edges], labels, temporal,
                 roles, {n: n for n in g.nodes}, f"TCG of {tcg.model.name} (red: integrating edges)",
                 (width, 4.8 if meas else 3.4), fmt)


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
    height = max(4.0, 0.8 * max(rows.values()) + 1.5)
    return _draw(pos, dbn_nodes(d), sorted(g.edges), {}, temporal, roles, labels_n,
                 f"DBN '{d.name}': slice t (left), t+1 (right)", (9.0, height), fmt)


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


def _draw(pos, nodes, edges, edge_labels, highlight, roles, node_labels, title, size, fmt) -> bytes:
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
            color = "#b03030" if (a, b) in highlight else "#404040"
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
        buf = io.BytesIO()
        meta = {"Date": None, "Creator": None} if fmt == "svg" else {"Software": None}
        fig.subplots_adjust(left=0.01, right=0.99, top=0.92, bottom=0.01)
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
