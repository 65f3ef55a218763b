"""Pictures: the bond graph drawn (bgc show bondgraph), the TCG's inputs and
parameters, the DBN legend.

The expected facts come from the model files read as plain YAML and from
bond-graph theory, not from bgc's own output: every element and bond of the
YAML is drawn; one causal stroke per bond; an Se imposes the effort (its
stroke is at the other end), an Sf the flow (its stroke is at the Sf), a C in
integral causality the effort and an I the flow (every storage element of the
shipped models is in integral causality: their states are the thesis's).
"""

import math
import re
import subprocess
import xml.etree.ElementTree as ET

import pytest
import yaml

from bgc.cli import main

from conftest import ROOT, bgc_cli

SHIPPED = ["ro", "circuit", "two_tank"]
SVG = "{http://www.w3.org/2000/svg}"


def yaml_model(name: str) -> dict:
    return yaml.safe_load((ROOT / "models" / f"{name}.yaml").read_text())


def show(tmp_path, *args: str) -> bytes:
    out = tmp_path / "picture"
    assert main(["show", *args, "--engine", "matplotlib", "-o", str(out)]) == 0
    return out.read_bytes()


def groups(svg: bytes) -> dict[str, ET.Element]:
    root = ET.fromstring(svg)
    return {g.get("id"): g for g in root.iter(f"{SVG}g") if g.get("id")}


def texts(element: ET.Element) -> list[str]:
    return [t.text or "" for t in element.iter(f"{SVG}text")]


def centre(group: ET.Element) -> tuple[float, float]:
    """The anchor of the group's text (a label is centred on its element)."""
    t = next(group.iter(f"{SVG}text"))
    return float(t.get("x")), float(t.get("y"))


def path_points(group: ET.Element) -> list[tuple[float, float]]:
    d = next(group.iter(f"{SVG}path")).get("d")
    numbers = [float(v) for v in re.findall(r"-?\d+(?:\.\d+)?", d)]
    return list(zip(numbers[::2], numbers[1::2]))


@pytest.fixture(scope="module")
def bondgraph_svgs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bg")
    return {name: show(tmp, "bondgraph", f"models/{name}.yaml", "--format", "svg") for name in SHIPPED}


@pytest.mark.parametrize("name", SHIPPED)
def test_every_element_and_bond_of_the_yaml_is_drawn(bondgraph_svgs, name):
    model = yaml_model(name)
    g = groups(bondgraph_svgs[name])
    drawn = " ".join(t for grp in g.values() for t in texts(grp))
    for element in model["elements"]:
        assert f"label-{element}" in g and element in " ".join(texts(g[f"label-{element}"]))
        assert element in drawn
    for number in model["bonds"]:
        assert texts(g[f"bond-number-{number}"]) == [str(number)]


@pytest.mark.parametrize("name", SHIPPED)
def test_one_causal_stroke_and_one_half_arrow_per_bond(bondgraph_svgs, name):
    bonds = yaml_model(name)["bonds"]
    g = groups(bondgraph_svgs[name])
    strokes = [k for k in g if k.startswith("stroke-")]
    arrows = [k for k in g if k.startswith("half-arrow-")]
    assert len(strokes) == len(bonds) and len(arrows) == len(bonds)
    assert sorted(strokes) == sorted(f"stroke-{n}" for n in bonds)


def _nearer(point, a, b) -> bool:
    """Is ``point`` nearer to ``a`` than to ``b``?"""
    return math.dist(point, a) < math.dist(point, b)


@pytest.mark.parametrize("name", SHIPPED)
def test_strokes_sit_where_the_element_kinds_put_them(bondgraph_svgs, name):
    """Se: stroke away from the Se; Sf: at the Sf; C (integral): away from
    the C; I (integral): at the I. The half arrow points at the bond's head."""
    model = yaml_model(name)
    kinds = {n: str(e["kind"]) for n, e in model["elements"].items()}
    g = groups(bondgraph_svgs[name])
    at = {n: centre(g[f"label-{n}"]) for n in kinds}
    checked = 0
    for number, (tail, head) in model["bonds"].items():
        (x1, y1), (x2, y2) = path_points(g[f"stroke-{number}"])
        stroke = ((x1 + x2) / 2, (y1 + y2) / 2)
        tip = path_points(g[f"half-arrow-{number}"])[0]
        assert _nearer(tip, at[head], at[tail]), f"bond {number}: half arrow not at {head}"
        for end, other in ((tail, head), (head, tail)):
            kind = kinds[end]
            if kind in ("Se", "C"):  # imposes the effort: the stroke is at the other end
                assert _nearer(stroke, at[other], at[end]), f"bond {number}: {kind} {end}"
                checked += 1
            elif kind in ("Sf", "I"):  # imposes the flow, receives the effort: the stroke is at it
                assert _nearer(stroke, at[end], at[other]), f"bond {number}: {kind} {end}"
                checked += 1
    assert checked >= 3


def test_circuit_source_bond_by_hand():
    """Bond 1 of the circuit, Ve -> j1a: the voltage source imposes the
    effort, so its stroke is at j1a; power flows into j1a."""
    from bgc.output import render
    from bgc.pipeline import assign_causality

    c = assign_causality(ROOT / "models" / "circuit.yaml")
    line = next(l for l in render.bondgraph_text(c).splitlines() if l.strip().startswith("1 "))
    assert "Ve -> j1a" in line and "stroke at the head (j1a; effort by Ve)" in line
    dot = render.bondgraph_dot(c)
    assert '"Ve" -- "j1a" [label="1", arrowhead=teelvee, arrowtail=none];' in dot


@pytest.mark.parametrize("name", SHIPPED)
def test_png_pictures_of_every_shipped_model(tmp_path, name):
    png = show(tmp_path, "bondgraph", f"models/{name}.yaml", "--format", "png")
    assert png.startswith(b"\x89PNG\r\n\x1a\n")
    width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    assert width >= 600 and height >= 300


@pytest.mark.parametrize("name", SHIPPED)
def test_show_causality_draws_what_the_bond_graph_picture_does_not(tmp_path, bondgraph_svgs, name):
    """The causality picture: the same bonds and strokes, and by each
    storage element of the YAML its causality (every one of the shipped
    models is integral: a state), by each junction its strong bond: the one
    bond whose stroke is at a 0-junction, the one bond whose stroke is away
    from a 1-junction (read here from the drawn strokes)."""
    svg = show(tmp_path, "causality", f"models/{name}.yaml", "--format", "svg")
    assert svg != bondgraph_svgs[name]
    model = yaml_model(name)
    kinds = {n: str(e["kind"]) for n, e in model["elements"].items()}
    g = groups(svg)
    at = {n: centre(g[f"label-{n}"]) for n in kinds}
    assert sorted(k for k in g if k.startswith("stroke-")) == sorted(f"stroke-{n}" for n in model["bonds"])
    for element, kind in kinds.items():
        if kind in ("C", "I"):
            assert texts(g[f"causality-{element}"])[0].startswith("integral: ")
        elif kind in ("0", "1"):
            strong = []
            for number, ends in model["bonds"].items():
                if element not in ends:
                    continue
                other = ends[1] if ends[0] == element else ends[0]
                (x1, y1), (x2, y2) = path_points(g[f"stroke-{number}"])
                at_junction = _nearer(((x1 + x2) / 2, (y1 + y2) / 2), at[element], at[other])
                if at_junction == (kind == "0"):
                    strong.append(number)
            assert len(strong) == 1 and texts(g[f"causality-{element}"]) == [f"strong bond {strong[0]}"]
        else:
            assert f"causality-{element}" not in g
    legend = " ".join(t for grp in g.values() for t in texts(grp))
    assert "strong bond" in legend and "integral" in legend


def test_show_causality_dot_and_text_name_the_strong_bonds():
    r = run("show", "causality", "models/circuit.yaml", "--format", "dot")
    assert r.returncode == 0 and '"j1a" [label="1:j1a\\nstrong bond 2 (sets the flow)"];' in r.stdout
    assert '"j0a" -- "C1" [label="4", arrowhead=lvee, arrowtail=tee, penwidth=2.5];' in r.stdout
    assert run("show", "bondgraph", "models/circuit.yaml", "--format", "dot").stdout != r.stdout
    text = run("show", "causality", "models/circuit.yaml").stdout
    assert "  j0a (0): strong bond 4 (sets the effort)" in text and "  C1 (C, bond 4): integral, state e4" in text


def test_the_picture_is_the_same_bytes_twice(tmp_path, bondgraph_svgs):
    again = show(tmp_path, "bondgraph", "models/ro.yaml", "--format", "svg")
    assert again == bondgraph_svgs["ro"]
    assert b"<dc:date>" not in again


def test_the_legend_says_what_the_marks_mean(bondgraph_svgs):
    text = " ".join(t for grp in groups(bondgraph_svgs["ro"]).values() for t in texts(grp))
    assert "half arrow: power flows from A to B" in text
    assert "causal stroke" in text and "receives the effort" in text
    assert "signal link" in text  # the RO's modulated membrane and conductivity source


def test_signal_links_of_the_ro_plant(bondgraph_svgs):
    """MR_memb reads e27 (the conductivity K); MSf_k reads f10 and f18 (its value in the YAML)."""
    g = groups(bondgraph_svgs["ro"])
    assert {k for k in g if k.startswith("signal-")} == {"signal-27-MR_memb", "signal-10-MSf_k", "signal-18-MSf_k"}


# ------------------------------------------------------------------------ TCG, DBN
def test_tcg_picture_names_the_inputs_and_the_parameters_on_edges(tmp_path):
    ro = show(tmp_path, "tcg", "models/ro.yaml", "--format", "svg").decode()
    model = yaml_model("ro")
    for u in model["inputs"]:  # the pump torques
        assert f">{u}<" in ro
    assert "k_scale" in ro  # the conductivity source's gain, on its signal edges
    assert "R_memb" in ro  # the membrane resistance modulated by K
    tanks = show(tmp_path, "tcg", "models/two_tank.yaml", "--format", "svg").decode()
    assert ">f_in<" in tanks and "f_in_offset" in tanks  # the inflow's actuator fault (f_in: [bias])
    assert "integrating edge" in tanks


def test_dbn_picture_has_a_legend(tmp_path):
    svg = show(tmp_path, "dbn", "models/ro.yaml", "--fault", "R_pipe:incipient", "--format", "svg")
    g = groups(svg)
    legend = " ".join(texts(g["legend"]))
    for words in ("state", "measurement", "fault indicator", "fault magnitude", "drifting parameter",
                  "temporal arc"):
        assert words in legend


# -------------------------------------------------------------------- bad input
def run(*args: str) -> subprocess.CompletedProcess:
    return bgc_cli(*args)


@pytest.mark.parametrize("args, says", [
    (("show", "bondgraph", "models/ro.yaml", "--format", "gif"), "stage bondgraph has no format gif"),
    (("show", "bondgraph", "models/ro.yaml", "--format", "latex"), "use one of: dot, json, text, svg, png"),
    (("show", "bondgraph", "models/nope.yaml", "--format", "svg"), "models/nope.yaml: no such file"),
    (("show", "equations", "models/ro.yaml", "--format", "svg"), "stage equations has no format svg"),
])
def test_bad_input_is_one_line_exit_1(args, says):
    r = run(*args)
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0], r.stderr


def test_a_model_a_later_stage_refuses_is_still_drawn(tmp_path):
    """A C on a 0-junction whose effort an Se fixes is in derivative
    causality (the equations stage refuses it): the picture still comes out,
    the Se's stroke at the junction, the C's at the C (it receives the
    effort), with the red-box note in the legend."""
    model = tmp_path / "deriv.yaml"
    model.write_text("""name: deriv
parameters: {R: 1.0, C: 2.0}
inputs: {V: 1.0}
elements: {V: {kind: Se}, n: {kind: "0"}, R: {kind: R}, C: {kind: C}}
bonds: {1: [V, n], 2: [n, R], 3: [n, C]}
measurements: {f3: {}}
""")
    svg = show(tmp_path, "causality", str(model), "--format", "svg")
    g = groups(svg)
    assert texts(g["causality-C"]) == ["derivative"]
    at = {n: centre(g[f"label-{n}"]) for n in ("V", "n", "C")}
    stroke = [((x1 + x2) / 2, (y1 + y2) / 2) for (x1, y1), (x2, y2) in
              (path_points(g[f"stroke-{b}"]) for b in (1, 3))]
    assert _nearer(stroke[0], at["n"], at["V"]) and _nearer(stroke[1], at["C"], at["n"])
    assert "storage element in derivative causality" in " ".join(t for grp in g.values() for t in texts(grp))


# ------------------------------------------------------------------ DBN layout
def _dbn(model: str, fault: str | None):
    from bgc.pipeline import compile_model

    c = compile_model(ROOT / "models" / f"{model}.yaml")
    return c.dbn.get(fault or "nominal")


#: A band's rank, top to bottom, by the node roles the DBN compiler writes (bgc/compiler/dbn.py).
BAND_OF_ROLE = {"input": 0, "fault_indicator": 1, "fault_bias": 1, "fault_slope": 1, "fault_value": 1,
                "fault_parameter": 1, "state": 2, "measurement": 3}


@pytest.mark.parametrize("model, fault", [("ro", "R_pipe:incipient"), ("circuit", None), ("two_tank", None),
                                          ("circuit", "C1:abrupt")])
def test_dbn_slices_stand_side_by_side_in_bands(model, fault):
    """Slice t's column left of slice t+1's; in each slice the bands go
    inputs, faults, states, measurements from top to bottom; one band, one
    height in both slices."""
    from bgc.output.layout import dbn_layout

    d = _dbn(model, fault)
    pos = dbn_layout(d).positions
    nodes = d.graph.nodes
    left = [pos[n][0] for n in nodes if nodes[n]["slice"] == 0]
    right = [pos[n][0] for n in nodes if nodes[n]["slice"] == 1]
    assert max(left) < min(right)
    for k in (0, 1):
        height = {}
        for n in nodes:
            if nodes[n]["slice"] == k:
                height.setdefault(BAND_OF_ROLE[nodes[n]["role"]], set()).add(pos[n][1])
        assert all(len(h) == 1 for h in height.values()), height
        ordered = [next(iter(height[b])) for b in sorted(height)]
        assert ordered == sorted(ordered, reverse=True)  # the first band on top
    for n in nodes:
        if nodes[n]["slice"] == 0:
            twin = n[:-len("@t")] + "@t+1"
            assert pos[n][1] == pos[twin][1]


def test_dbn_picture_names_its_bands_and_slices_and_places_the_nodes_so(tmp_path):
    svg = show(tmp_path, "dbn", "models/ro.yaml", "--fault", "R_pipe:incipient", "--format", "svg")
    g = groups(svg)
    names = [" ".join(texts(g[k])) for k in sorted(k for k in g if k.startswith("band-name-"))]
    assert names == ["inputs u", "faults", "states x", "measurements y"]
    assert "slice t" in texts(g["slice-name-slice-t"]) and "slice t+1" in texts(g["slice-name-slice-t+1"])
    at = {k[len("node-"):]: centre(g[k]) for k in g if k.startswith("node-")}
    assert max(x for n, (x, _) in at.items() if n.endswith("@t")) < \
        min(x for n, (x, _) in at.items() if n.endswith("@t+1"))
    # SVG's y grows downward: the inputs over the fault nodes over the states over the measurements
    assert at["e1@t+1"][1] < at["R_pipe@t+1"][1] < at["f3@t+1"][1] < at["F_back@t+1"][1]


def test_dbn_dot_ranks_the_bands_across_both_slices():
    from bgc.output import render

    dot = render.dbn_dot(_dbn("circuit", "C1:abrupt"))
    assert "newrank=true" in dot and "rankdir=TB" in dot
    assert 'subgraph "cluster_slice_0"' in dot and 'subgraph "cluster_slice_1"' in dot
    assert '{rank=same; "band inputs u"; "e1@t"; "e1@t+1";}' in dot
    assert '{rank=same; "band faults"; "D_C1@t"; "delta_C1@t"; "D_C1@t+1"; "delta_C1@t+1";}' in dot
    bands = [line.split(";")[1].strip() for line in dot.splitlines() if "{rank=same;" in line]
    assert bands == ['"band inputs u"', '"band faults"', '"band states x"', '"band measurements y"']


# ---------------------------------------------------------------- TCG labels
def _edge_label_boxes(monkeypatch, name: str) -> list:
    """The TCG picture of shipped model ``name`` drawn with matplotlib: its
    edge labels' boxes as drawn (pixels, from the renderer)."""
    from matplotlib.figure import Figure

    from bgc.output import draw
    from bgc.pipeline import compile_model

    boxes: list = []
    save = Figure.savefig

    def capture(fig, *args, **kwargs):
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        boxes.extend((t.get_text(), t.get_bbox_patch().get_window_extent(renderer))
                     for ax in fig.axes for t in ax.texts if (t.get_gid() or "").startswith("edge-label-"))
        return save(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", capture)
    draw.tcg_picture(compile_model(ROOT / "models" / f"{name}.yaml").tcg, "svg", "matplotlib")
    return boxes


@pytest.mark.parametrize("name", SHIPPED)
def test_tcg_edge_labels_do_not_overlap(monkeypatch, name):
    boxes = _edge_label_boxes(monkeypatch, name)
    assert len(boxes) >= 20
    clashes = [(a, b) for i, (a, box) in enumerate(boxes) for b, other in boxes[i + 1:] if box.overlaps(other)]
    assert clashes == []
