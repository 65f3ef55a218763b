"""Where the elements of a bond graph picture and the nodes of a DBN
picture sit: deterministic layouts.

A bond graph reads best as its junction structure with the one-port elements
hung around it, the way one draws it by hand (Karnopp, Margolis and
Rosenberg, *System Dynamics*, ch. 3). The layout follows that:

1. The *spine* of each connected part is the elements with two bonds or
   more (junctions, TF, GY): it is laid out by Kamada and Kawai's spring
   layout (deterministic: no random start), turned so that its longest
   extent runs left to right.
2. Each one-port (Se, Sf, C, I, R and their modulated forms) is placed next
   to its junction, in the free direction that keeps it farthest from the
   bonds already there and clear of every label placed so far (element
   names are wide, so the clearance is measured against their boxes).
3. Parts without a spine (a source bonded to a storage element) are a row;
   the parts stand side by side, largest first.

Positions are in inches of the drawing and rounded, so the picture's bytes do
not depend on the last bits of the optimiser.

A two-slice DBN (:func:`dbn_layout`) is drawn as two columns, slice t on the
left and slice t+1 on the right, each in the horizontal bands of
:data:`DBN_BANDS` from top to bottom: what drives the plant, what may fail,
what it stores, what is read.

Examples
--------
>>> from bgc.compiler.load import loads
>>> from bgc.compiler.validate import validate
>>> g = validate(loads('''
... name: rc
... parameters: {R: 1.0, C: 2.0}
... inputs: {V: 1.0}
... elements: {V: {kind: Se}, j: {kind: "1"}, R: {kind: R}, C: {kind: C}}
... bonds: {1: [V, j], 2: [j, R], 3: [j, C]}
... '''))
>>> lay = bond_graph_layout(g)
>>> sorted(n for n, _, _ in lay.positions)
['C', 'R', 'V', 'j']
>>> lay.at("j")
(0.0, 0.0)
>>> signal_links(g)
()
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..ir import BondGraph, Dbn, Element, var_key
from ..kinds import FAULT_KINDS, element_kind

#: Inches per character of an element's label, and a label's height (font size 8).
CHAR_WIDTH = 0.075
LABEL_HEIGHT = 0.22
#: Length of a bond between two spine elements, and from a junction to a one-port.
SPINE_BOND = 1.45
LEAF_BOND = 0.95
#: Room between two parts of a model that no bond joins.
PART_GAP = 0.9
#: The bands of a DBN picture, top to bottom: (the name written at the side, the node roles in it).
DBN_BANDS = (("inputs u", ("input",)), ("mode q", ("mode",)),
             ("faults", ("fault_indicator", *(f"fault_{k}" for k in dict.fromkeys(
                 f.magnitude for f in FAULT_KINDS.values())), "fault_parameter")),
             ("states x", ("state",)), ("algebraic", ("algebraic",)), ("measurements y", ("measurement",)))
#: A DBN picture's room between two nodes of a band, between two bands' rows and between the slices.
DBN_NODE_GAP, DBN_BAND_STEP, DBN_SLICE_GAP = 0.45, 1.1, 1.6


def label(el: Element) -> str:
    """What the picture writes for an element: ``kind:name`` (``R:R_pipe``),
    the kind alone being the standard symbol of a junction (``1:J_fp``)."""
    return f"{el.kind}:{el.name}"


def label_size(text: str) -> tuple[float, float]:
    """Width and height (inches) of a label's box in the picture."""
    return CHAR_WIDTH * len(text) + 0.16, LABEL_HEIGHT


@dataclass(frozen=True, slots=True)
class BondGraphLayout:
    """Each element's centre (name, x, y), in inches, sorted by name."""

    positions: tuple[tuple[str, float, float], ...]

    def at(self, name: str) -> tuple[float, float]:
        for n, x, y in self.positions:
            if n == name:
                return x, y
        raise KeyError(name)


def signal_links(model: BondGraph) -> tuple[tuple[int, str], ...]:
    """The signal links of the modulated elements: (bond, element) when the
    element's value, parameter or law reads a variable of that bond (not one
    of its own), sorted."""
    own = {el.name: {b.number for b in model.bonds_of(el.name)} for el in model.elements}
    links = set()
    for el in model.elements:
        exprs = [e for e in (el.source, el.parameter, el.law.expr if el.law else None) if e is not None]
        for e in exprs:
            for s in e.free_symbols:
                name = s.name
                if name[:1] in "ef" and name[1:].isdigit() and int(name[1:]) not in own[el.name]:
                    links.add((int(name[1:]), el.name))
    return tuple(sorted(links))


def bond_graph_layout(model: BondGraph) -> BondGraphLayout:
    """Positions of every element of ``model`` (see the module docstring)."""
    import networkx as nx

    g = nx.Graph()
    for el in sorted(model.elements, key=lambda el: el.name):
        g.add_node(el.name, role=element_kind(el.kind).role)
    for b in model.bonds:
        g.add_edge(b.tail, b.head)
    labels = {el.name: label(el) for el in model.elements}
    parts = sorted((sorted(c) for c in nx.connected_components(g)), key=lambda c: (-len(c), c))
    links = signal_links(model)
    placed: dict[str, tuple[float, float]] = {}
    left = 0.0
    for part in parts:
        pos = _part_layout(g.subgraph(part), labels)
        near = _linked_place(pos, placed, model, links, labels) if placed else None
        if near is not None:
            placed.update(near)
            continue
        x0 = min(x - label_size(labels[n])[0] / 2 for n, (x, _) in pos.items())
        x1 = max(x + label_size(labels[n])[0] / 2 for n, (x, _) in pos.items())
        shift = left - x0 if placed else 0.0
        for n, (x, y) in pos.items():
            placed[n] = (x + shift, y)
        left = max(left, x1 + shift + PART_GAP)
    return BondGraphLayout(tuple(sorted((n, round(x, 3) + 0.0, round(y, 3) + 0.0)
                                        for n, (x, y) in placed.items())))


def _linked_place(pos: dict, placed: dict, model: BondGraph, links, labels: dict[str, str]) -> dict | None:
    """A part that signal links join to what is placed already: the free
    spot near the elements it reads or is read by (shortest links, no box
    on a box or on a bond), the part mirrored left to right if that is
    shorter; None when no link joins it."""
    ends = {b.number: (b.tail, b.head) for b in model.bonds}
    pairs = []  # (a node of this part, a point of the placed drawing)
    for bond, element in links:
        t, h = ends[bond]
        if element in pos and t in placed and h in placed:
            pairs.append((element, ((placed[t][0] + placed[h][0]) / 2, (placed[t][1] + placed[h][1]) / 2)))
        elif element in placed and t in pos and h in pos:
            pairs.append((t, placed[element]))
            pairs.append((h, placed[element]))
    if not pairs:
        return None
    cx = sum(p[1][0] for p in pairs) / len(pairs)
    cy = sum(p[1][1] for p in pairs) / len(pairs)
    mx = sum(x for x, _ in pos.values()) / len(pos)
    my = sum(y for _, y in pos.values()) / len(pos)
    boxes = [(x, y, *label_size(labels[n])) for n, (x, y) in placed.items()]
    segments = [(placed[a], placed[b]) for a, b in ends.values() if a in placed and b in placed]
    best, best_score = None, None
    for mirror in (1, -1):
        local = {n: (mirror * (x - mx), y - my) for n, (x, y) in pos.items()}
        for i in range(-24, 25):
            for j in range(-24, 25):
                dx, dy = cx + 0.25 * i, cy + 0.25 * j
                moved = {n: (x + dx, y + dy) for n, (x, y) in local.items()}
                length = sum(math.hypot(moved[n][0] - x, moved[n][1] - y) for n, (x, y) in pairs)
                # the score's first term is at least its length's (crossings add to it), and a tie goes to the
                # spot tried first: a spot whose length alone reaches the best score cannot win, and its
                # clearances and crossings (nearly all the search's time) are not worth computing
                if best_score is not None and round(0.15 * length, 6) >= best_score[0]:
                    continue
                mine = [(x, y, *label_size(labels[n])) for n, (x, y) in moved.items()]
                if any(boxes_overlap(a, b, 0.3) for a in mine for b in boxes):
                    continue
                if any(segment_hits_box(p, q, (x, y, w + 0.2, h + 0.2)) for p, q in segments
                       for x, y, w, h in mine):
                    continue
                own = [(moved[a], moved[b]) for a, b in ends.values() if a in moved and b in moved]
                crossings = sum(_segments_cross(p, q, r, s) for p, q in own for r, s in segments)
                crossings += sum(_segments_cross(moved[n], target, r, s) for n, target in pairs
                                 for r, s in segments) * 0.25
                score = (round(crossings + 0.15 * length, 6), mirror < 0, i, j)
                if best_score is None or score < best_score:
                    best, best_score = moved, score
    return best


def _part_layout(g, labels: dict[str, str]) -> dict[str, tuple[float, float]]:
    """One connected part: the spine, then the one-ports around it."""
    import networkx as nx

    spine = sorted(n for n in g if g.degree(n) >= 2)
    if not spine:  # a source on a storage element: a row
        row = sorted(g, key=lambda n: (g.nodes[n]["role"] != "source", n))
        pos, x = {}, 0.0
        for i, n in enumerate(row):
            w = label_size(labels[n])[0]
            if i:
                x += w / 2
            pos[n] = (x, 0.0)
            x += w / 2 + LEAF_BOND
        return pos
    if len(spine) == 1:
        pos = {spine[0]: (0.0, 0.0)}
    else:
        sub = nx.Graph()
        sub.add_nodes_from(spine)
        sub.add_edges_from(sorted(g.subgraph(spine).edges))
        raw = nx.kamada_kawai_layout(sub, pos=nx.circular_layout(sub))
        fed = [n for n in spine if any(g.nodes[m]["role"] == "source" for m in g[n])]
        pos = _normalise({n: (float(p[0]), float(p[1])) for n, p in raw.items()}, sub, fed)
        pos = _spread(pos, sub, labels)
    for hub in spine:
        for leaf in sorted(n for n in g[hub] if n not in pos):
            pos[leaf] = _leaf_position(hub, leaf, g, pos, labels)
    return pos


def _normalise(pos: dict, g, fed: list[str]) -> dict:
    """Scale to SPINE_BOND per bond (median), centre, and turn the longest
    extent left to right (principal axis), with a fixed orientation: the
    junctions the sources feed (``fed``) on the left and above, as far as
    they decide it, else the first element by name."""
    import numpy as np

    names = sorted(pos)
    p = np.array([pos[n] for n in names])
    p = p - p.mean(axis=0)
    lengths = sorted(float(np.hypot(*(np.array(pos[a]) - np.array(pos[b])))) for a, b in g.edges)
    median = lengths[len(lengths) // 2] or 1.0
    p = p * (SPINE_BOND / median)
    _, vecs = np.linalg.eigh(p.T @ p)
    axis = vecs[:, -1]
    if abs(axis[0]) < 1e-12:
        axis = np.array([1.0, 0.0])
    axis = axis * (1 if axis[0] > 0 else -1)
    normal = np.array([-axis[1], axis[0]])
    q = np.column_stack([p @ axis, p @ normal])
    rows = [names.index(n) for n in fed]
    for k, sign in ((0, 1.0), (1, -1.0)):  # x: fed junctions left (mean below 0); y: above
        mean = float(q[rows, k].mean()) if rows else 0.0
        value = mean if abs(mean) > 1e-6 else float(q[0, k])
        if abs(value) > 1e-9 and sign * value > 0:
            q[:, k] = -q[:, k]
    return {n: (float(x), float(y)) for n, (x, y) in zip(names, q)}


def _spread(pos: dict, g, labels: dict[str, str], rounds: int = 60) -> dict:
    """Push apart spine elements whose label boxes (with a margin) overlap:
    along the axis where the overlap is smaller."""
    pos = dict(pos)
    names = sorted(pos)
    for _ in range(rounds):
        moved = False
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                (xa, ya), (xb, yb) = pos[a], pos[b]
                wa, ha = label_size(labels[a])
                wb, hb = label_size(labels[b])
                ox = (wa + wb) / 2 + 0.45 - abs(xa - xb)
                oy = (ha + hb) / 2 + 0.55 - abs(ya - yb)
                if ox <= 0 or oy <= 0:
                    continue
                moved = True
                if oy <= ox:
                    d = oy / 2 * (1 if ya >= yb else -1)
                    pos[a], pos[b] = (xa, ya + d), (xb, yb - d)
                else:
                    d = ox / 2 * (1 if xa >= xb else -1)
                    pos[a], pos[b] = (xa + d, ya), (xb - d, yb)
        if not moved:
            break
    return pos


def _leaf_position(hub: str, leaf: str, g, pos: dict, labels: dict[str, str]) -> tuple[float, float]:
    """Where a one-port goes next to its junction: the direction (of 24) that
    is farthest in angle from the bonds already at the junction, among those
    whose label box clears every box and bond placed so far; up and down
    first when it is a tie (labels are wide)."""
    hx, hy = pos[hub]
    taken = [math.atan2(pos[n][1] - hy, pos[n][0] - hx) for n in g[hub] if n in pos]
    w, h = label_size(labels[leaf])
    best, best_score = None, None
    for k in range(24):
        angle = math.radians(90 - 15 * k)
        # the bond runs from box edge to box edge: the centre sits farther out sideways
        reach = LEAF_BOND + abs(math.cos(angle)) * (w + label_size(labels[hub])[0]) / 2 \
            + abs(math.sin(angle)) * (h + LABEL_HEIGHT) / 2
        x, y = hx + reach * math.cos(angle), hy + reach * math.sin(angle)
        gap = min((_angle_between(angle, t) for t in taken), default=math.pi)
        clash = sum(boxes_overlap((x, y, w, h), (px, py, *label_size(labels[n])), 0.12)
                    for n, (px, py) in pos.items())
        crossing = sum(_segments_cross((hx, hy), (x, y), pos[a], pos[b])
                       for a, b in g.edges if a in pos and b in pos and hub not in (a, b))
        through = sum(segment_hits_box((hx, hy), (x, y), (px, py, *label_size(labels[n])))
                      for n, (px, py) in pos.items() if n != hub)
        score = (clash + crossing + through, -round(gap, 6), -abs(math.sin(angle)), k)
        if best_score is None or score < best_score:
            best, best_score = (x, y), score
    return best


def _angle_between(a: float, b: float) -> float:
    d = abs(a - b) % (2 * math.pi)
    return min(d, 2 * math.pi - d)


def boxes_overlap(a, b, margin: float) -> bool:
    ax, ay, aw, ah = a
    bx, by, bw, bh = b
    return abs(ax - bx) < (aw + bw) / 2 + margin and abs(ay - by) < (ah + bh) / 2 + margin


def _segments_cross(p1, p2, q1, q2) -> bool:
    def orient(a, b, c):
        v = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        return 0 if abs(v) < 1e-12 else (1 if v > 0 else -1)

    return (orient(p1, p2, q1) * orient(p1, p2, q2) < 0) and (orient(q1, q2, p1) * orient(q1, q2, p2) < 0)


def segment_hits_box(p1, p2, box) -> bool:
    """Does the segment pass through the box (sampled)?"""
    bx, by, bw, bh = box
    for i in range(1, 20):
        t = i / 20
        x, y = p1[0] + t * (p2[0] - p1[0]), p1[1] + t * (p2[1] - p1[1])
        if abs(x - bx) < bw / 2 and abs(y - by) < bh / 2:
            return True
    return False


@dataclass(frozen=True, slots=True)
class DbnLayout:
    """A DBN picture's layout (inches): each node's centre, each band drawn
    (its name and the y of its row), and each slice's column (its name and
    the x of its left and right edges)."""

    positions: dict[str, tuple[float, float]]
    bands: tuple[tuple[str, float], ...]
    slices: tuple[tuple[str, float, float], ...]


def dbn_band(role: str) -> int:
    """The index in :data:`DBN_BANDS` of the band a node role is drawn in."""
    return next(i for i, (_, roles) in enumerate(DBN_BANDS) if role in roles)


def dbn_layout(d: Dbn) -> DbnLayout:
    """Where the nodes of DBN ``d`` sit: slice t's column left of slice
    t+1's, the bands of :data:`DBN_BANDS` that have nodes one under the other
    at the same heights in both slices, and in each band one row, the nodes
    in role then variable order (the same order in both slices, so an arc
    that persists a variable runs across at one height), centred in its
    column."""
    g = d.graph
    rows: dict[tuple[int, int], list[str]] = {}
    roles = [r for _, band in DBN_BANDS for r in band]
    for n in sorted(g.nodes, key=lambda n: (roles.index(g.nodes[n]["role"]), var_key(g.nodes[n]["variable"]))):
        a = g.nodes[n]
        rows.setdefault((a["slice"], dbn_band(a["role"])), []).append(n)
    widths = {n: label_size(g.nodes[n]["variable"])[0] for n in g.nodes}

    def row_width(members: list[str]) -> float:
        return sum(widths[n] for n in members) + DBN_NODE_GAP * (len(members) - 1)

    column = max(row_width(m) for m in rows.values())
    used = sorted({b for _, b in rows})
    y_of = {b: -DBN_BAND_STEP * i for i, b in enumerate(used)}
    positions = {}
    for (slice_, band), members in rows.items():
        x = slice_ * (column + DBN_SLICE_GAP) + (column - row_width(members)) / 2
        for n in members:
            positions[n] = (round(x + widths[n] / 2, 3), y_of[band])
            x += widths[n] + DBN_NODE_GAP
    slices = tuple((title, k * (column + DBN_SLICE_GAP), k * (column + DBN_SLICE_GAP) + column)
                   for k, title in enumerate(("slice t", "slice t+1")))
    return DbnLayout(positions, tuple((DBN_BANDS[b][0], y_of[b]) for b in used), slices)
