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


def test_show_causality_draws_the_same_picture(tmp_path, bondgraph_svgs):
    assert show(tmp_path, "causality", "models/circuit.yaml", "--format", "svg") == bondgraph_svgs["circuit"]


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
    at = {n: centre(g[f"label-{n}"]) for n in ("V", "n", "C")}
    stroke = [((x1 + x2) / 2, (y1 + y2) / 2) for (x1, y1), (x2, y2) in
              (path_points(g[f"stroke-{b}"]) for b in (1, 3))]
    assert _nearer(stroke[0], at["n"], at["V"]) and _nearer(stroke[1], at["C"], at["n"])
    assert "storage element in derivative causality" in " ".join(t for grp in g.values() for t in texts(grp))
