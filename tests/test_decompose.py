"""``bgc compile --decompose`` (issue 49, point 4): a model split into
minimal submodels, each predicting its sensors from the readings of the
sensors around it.

The submodels' equations are derived here by hand: a chain of tanks with a
pressure sensor on each (each tank alone, its neighbours' pressures read),
and the two tanks with flow sensors (a flow sensor cuts no tank: the pipe
between them needs both). The process noise a read sensor brings into a
state is checked against its formula with the numbers worked out by hand.
"""

from __future__ import annotations

import json
import math

import pytest
import sympy
import yaml

from bgc.compiler import decompose, load
from bgc.errors import CodegenError
from bgc.pipeline import compile_model, decompose_model

from conftest import ROOT, bgc_cli

#: A chain of three tanks at their steady state for an inflow of 1 (every pipe carries 1: p3 = R3 = 1.5,
#: p2 = p3 + R2 = 2.5, p1 = p2 + R1 = 4.5), a pressure sensor on each tank.
CHAIN = """\
name: chain3
parameters: {C1: 1.0, C2: 2.0, C3: 0.5, R1: 2.0, R2: 1.0, R3: 1.5}
inputs: {f_in: 1.0}
elements:
  Sf_in: {kind: Sf, value: f_in}
  tank1: {kind: '0'}
  C1: {kind: C, initial: 4.5}
  pipe1: {kind: '1'}
  R1: {kind: R}
  tank2: {kind: '0'}
  C2: {kind: C, initial: 2.5}
  pipe2: {kind: '1'}
  R2: {kind: R}
  tank3: {kind: '0'}
  C3: {kind: C, initial: 1.5}
  pipe3: {kind: '1'}
  R3: {kind: R}
bonds:
  1: [Sf_in, tank1]
  2: [tank1, C1]
  3: [tank1, pipe1]
  4: [pipe1, R1]
  5: [pipe1, tank2]
  6: [tank2, C2]
  7: [tank2, pipe2]
  8: [pipe2, R2]
  9: [pipe2, tank3]
  10: [tank3, C3]
  11: [tank3, pipe3]
  12: [pipe3, R3]
measurements:
  p1: {expr: e2, noise: 0.01}
  p2: {expr: e6, noise: 0.02}
  p3: {expr: e10, noise: 0.01}
faults:
  R1: [abrupt]
  C2: [abrupt]
  p1: [bias, stuck]
  p3: [bias, drift]
simulation: {dt: 0.5, steps: 100, process_noise: 0.03}
"""


def _split(text: str, name: str = "chain3.yaml"):
    c = compile_model(name, text=text)
    return decompose.decompose(c.raw, c.numerics)


def _equations(sub):
    c = compile_model(f"{sub.name}.yaml", text=sub.text)
    return c, {x: rhs for x, rhs in zip(c.equations.states, c.equations.rhs)}


def _same(a, b) -> bool:
    """Equal once the fault parameters the compiler adds (a sensor's offset, an input's bias: 0 when
    healthy) are put at their healthy value."""
    healthy = {s: 0 for s in a.free_symbols if s.name.endswith(("_offset", "_bias", "_drift"))}
    return sympy.simplify(a.xreplace(healthy) - b) == 0


def test_a_chain_of_measured_tanks_splits_into_one_tank_each():
    d = _split(CHAIN)
    assert [(s.name, s.outputs, s.reads) for s in d.submodels] == [
        ("chain3_p1", ("p1",), ("p2",)), ("chain3_p2", ("p2",), ("p1", "p3")), ("chain3_p3", ("p3",), ("p2",))]
    C1, C2, C3, R1, R2, R3, f_in, p1, p2, p3, e2, e6, e10 = sympy.symbols(
        "C1 C2 C3 R1 R2 R3 f_in p1 p2 p3 e2 e6 e10")
    expected = {  # each tank's balance, its neighbours' pressures read
        "chain3_p1": {"e2": (f_in - (e2 - p2) / R1) / C1},
        "chain3_p2": {"e6": ((p1 - e6) / R1 - (e6 - p3) / R2) / C2},
        "chain3_p3": {"e10": ((p2 - e10) / R2 - e10 / R3) / C3},
    }
    for s in d.submodels:
        c, rhs = _equations(s)
        assert set(rhs) == set(expected[s.name])
        for x, f in expected[s.name].items():
            assert _same(rhs[x], f), (s.name, rhs[x])
        assert c.equations.outputs == s.outputs
        assert _same(c.equations.output_exprs[0], {"chain3_p1": e2, "chain3_p2": e6, "chain3_p3": e10}[s.name])


def test_faults_go_to_the_submodels_they_move_and_a_read_sensor_s_fault_becomes_its_input_s():
    d = _split(CHAIN)
    assert d.touching("R1") == ("chain3_p1", "chain3_p2")  # the pipe between tanks 1 and 2
    assert d.touching("C2") == ("chain3_p2",)
    assert d.touching("p1") == ("chain3_p1", "chain3_p2")  # its own, and the one that reads it
    assert d.touching("p3") == ("chain3_p2", "chain3_p3")
    middle = yaml.safe_load(d.submodels[1].text)
    # p1's bias stays a bias of the value delivered; a stuck reading is no fault an input takes
    assert middle["faults"]["p1"] == ["bias"] and middle["faults"]["p3"] == ["bias", "drift"]
    c = compile_model("chain3_p2.yaml", text=d.submodels[1].text)
    kinds = {(f.name, f.target) for f in c.model.faults}
    assert ("p1", "actuator") in kinds and ("p3", "actuator") in kinds and ("C2", "parameter") in kinds


def test_a_read_sensor_s_noise_raises_the_process_noise_of_the_states_it_drives():
    """Tank 2: df/dp1 = 1/(R1 C2) = 0.25, df/dp3 = 1/(R2 C2) = 0.5; the readings'
    stds 0.01 * 4.5 and 0.01 * 1.5; the state's own std 0.03 * 2.5 * sqrt(min(1, 2 dt / tau)) with
    tau = 1 / |(1/R1 + 1/R2) / C2| = 4/3."""
    d = _split(CHAIN)
    level = yaml.safe_load(d.submodels[1].text)["elements"]["C2"]["noise"]
    dt, scale = 0.5, 2.5
    factor = math.sqrt(min(1.0, 2 * dt / (4 / 3)))
    extra = dt * math.hypot(0.25 * 0.01 * 4.5, 0.5 * 0.01 * 1.5)
    assert level == pytest.approx(math.hypot(0.03 * scale * factor, extra) / (scale * factor), rel=1e-8)
    assert level > 0.03


def test_flow_sensors_cut_pipes_not_tanks():
    """The two tanks read by their three flows: tank 1 alone predicts its outflow F10 from the flow to
    tank 2 (F12) and the inflow; the pipe between them needs both tanks and reads both outflows."""
    d = _split((ROOT / "models" / "two_tank.yaml").read_text(), "two_tank.yaml")
    assert [(s.outputs, s.reads, s.inputs) for s in d.submodels] == [
        (("F10",), ("F12",), ("f_in",)), (("F12",), ("F10", "F20"), ("f_in",)), (("F20",), ("F12",), ())]
    C1, C2, R10, R12, R20, f_in, F10, F12, F20, e2, e7 = sympy.symbols(
        "C1 C2 R10 R12 R20 f_in F10 F12 F20 e2 e7")
    _, rhs = _equations(d.submodels[0])
    assert _same(rhs["e2"], (f_in - e2 / R10 - F12) / C1)
    c, rhs = _equations(d.submodels[1])
    assert _same(rhs["e2"], (f_in - F10 - (e2 - e7) / R12) / C1)
    assert _same(rhs["e7"], ((e2 - e7) / R12 - F20) / C2)
    assert _same(c.equations.output_exprs[0], (e2 - e7) / R12)
    _, rhs = _equations(d.submodels[2])
    assert _same(rhs["e7"], (F12 - e7 / R20) / C2)


def test_a_sensor_whose_submodel_would_hold_no_storage_cuts_nothing():
    """The DC motor's back-EMF sensor (e4) is a static function of the two speeds' neighbours: its
    submodel would hold no storage, so it stays a sensor of the electrical side."""
    d = _split((ROOT / "tests" / "data" / "models" / "dc_motor.yaml").read_text(), "dc_motor.yaml")
    assert all(compile_model(f"{s.name}.yaml", text=s.text).equations.states for s in d.submodels)
    assert sorted(o for s in d.submodels for o in s.outputs) == sorted(
        m.name for m in compile_model(ROOT / "tests" / "data" / "models" / "dc_motor.yaml").model.measurements)


def test_a_sensor_named_like_a_bond_variable_is_read_as_a_renamed_input():
    d = _split((ROOT / "models" / "circuit.yaml").read_text(), "circuit.yaml")
    reads = {a for s in d.submodels for _, a in s.read_as}
    assert reads and all(a.endswith("_reading") for a in reads)
    for s in d.submodels:
        compile_model(f"{s.name}.yaml", text=s.text)


def test_a_law_that_reads_a_measured_bond_elsewhere_reads_the_sensor():
    """Tank 1's inflow made a tenth of tank 3's pressure (a modulated source reading e10): tank 3's
    pressure is sensor p3's reading, so tank 1's submodel reads p3 instead of holding tank 3."""
    text = CHAIN.replace("  Sf_in: {kind: Sf, value: f_in}", "  Sf_in: {kind: MSf, value: 0.1 * e10}")
    d = _split(text.replace("inputs: {f_in: 1.0}\n", ""))
    first = d.submodels[0]
    assert first.reads == ("p2", "p3") and "C3" not in first.elements
    C1, R1, e2, p2, p3 = sympy.symbols("C1 R1 e2 p2 p3")
    _, rhs = _equations(first)
    assert _same(rhs["e2"], (sympy.Rational(1, 10) * p3 - (e2 - p2) / R1) / C1)


def test_a_law_that_reads_an_unmeasured_variable_beyond_a_cut_is_refused_with_its_place():
    """The inflow made a tenth of tank 3's net flow (f10): no sensor reads it, and tank 3 is beyond
    sensor p3's cut."""
    text = CHAIN.replace("  Sf_in: {kind: Sf, value: f_in}", "  Sf_in: {kind: MSf, value: 0.1 * f10}")
    with pytest.raises(CodegenError) as err:
        _split(text.replace("inputs: {f_in: 1.0}\n", ""))
    assert "element Sf_in reads bond 10" in str(err.value) and err.value.loc.line == 4


def test_a_model_with_modes_is_refused():
    with pytest.raises(CodegenError, match="has modes"):
        decompose_model(ROOT / "docs" / "examples" / "relay.yaml")


def test_bgc_compile_decompose_writes_each_submodel_as_a_model_file_and_its_folder(tmp_path):
    model = tmp_path / "chain3.yaml"
    model.write_text(CHAIN)
    r = bgc_cli("compile", str(model), "--decompose", "--no-pictures", "-o", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    assert "3 submodels of at most 1 of its 3 states" in r.stdout
    out = tmp_path / "out" / "chain3"
    plan = json.loads((out / "decomposition.json").read_text())
    assert [s["predicts"] for s in plan["submodels"]] == [["p1"], ["p2"], ["p3"]]
    assert plan["submodels"][1]["states"] == [{"state": "e6", "element": "C2"}]
    assert "chain3_p2: predicts p2 from p1, p3" in (out / "decomposition.txt").read_text()
    for name in ("chain3_p1", "chain3_p2", "chain3_p3"):
        assert (out / "submodels" / name / "numpy_model" / "nominal.py").is_file()
        text = (out / "submodels" / f"{name}.yaml").read_text()
        assert load.loads(text, name).data["name"] == name  # a model file of its own
    again = bgc_cli("compile", str(model), "--decompose", "--no-pictures", "-o", str(tmp_path / "out"))
    assert again.returncode == 0, again.stderr
    r = bgc_cli("compile", str(ROOT / "docs" / "examples" / "relay.yaml"), "--decompose", "-o", str(tmp_path / "x"))
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr


def test_a_submodel_s_noise_is_the_whole_plant_s_where_its_scales_differ():
    """A chain that starts empty: the scales of a submodel's signals come from its own nominal run,
    not the plant's, yet each sensor's std is the whole model's, and each state's the whole model's
    raised by what its read sensors bring (dt |df/dy| sigma, df/dy = 1/(R C) for a tank's neighbour)."""
    text = CHAIN.replace(", initial: 4.5}", "}").replace(", initial: 2.5}", "}").replace(", initial: 1.5}", "}")
    whole = compile_model("chain3.yaml", text=text)
    d = decompose.decompose(whole.raw, whole.numerics)
    sensor = dict(zip(whole.equations.outputs, whole.numerics.noise.measurement))
    state = dict(zip(whole.equations.state_elements, whole.numerics.noise.process))
    R = {"R1": 2.0, "R2": 1.0, "R3": 1.5}
    C = {"C1": 1.0, "C2": 2.0, "C3": 0.5}
    neighbours = {"C1": [("p2", "R1")], "C2": [("p1", "R1"), ("p3", "R2")], "C3": [("p2", "R2")]}
    for s in d.submodels:
        part = compile_model(f"{s.name}.yaml", text=s.text)
        noise = part.numerics.noise
        for name, std in zip(part.equations.outputs, noise.measurement):
            assert std == pytest.approx(sensor[name], rel=1e-8)
        for el, std in zip(part.equations.state_elements, noise.process):
            extra = 0.5 * math.hypot(*(sensor[y] / (R[r] * C[el]) for y, r in neighbours[el]))
            assert std == pytest.approx(math.hypot(state[el], extra), rel=1e-8)



def test_what_cannot_be_split_is_refused_in_one_line(tmp_path):
    """A model without sensors; a sensor whose part of the plant holds no storage (a resistor fed by a
    source, beside a tank with its own sensor): each a located one-line error, no traceback."""
    r = bgc_cli("compile", str(ROOT / "docs" / "examples" / "rc.yaml"), "--decompose", "-o", str(tmp_path / "o"))
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "has no sensors" in r.stderr, r.stderr
    model = tmp_path / "static.yaml"
    model.write_text("""\
name: static
parameters: {R: 2.0, R2: 1.0, C: 1.0}
inputs: {V: 1.0}
elements: {V: {kind: Se}, j: {kind: "1"}, R: {kind: R}, V2: {kind: Se, value: V}, k: {kind: "1"}, R2: {kind: R},
           C: {kind: C}}
bonds: {1: [V, j], 2: [j, R], 3: [V2, k], 4: [k, R2], 5: [k, C]}
measurements:
  I: {expr: f2}
  Q: {expr: e5}
""")
    r = bgc_cli("compile", str(model), "--decompose", "-o", str(tmp_path / "o"))
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
    assert "static.yaml:8:3" in r.stderr and "sensor I" in r.stderr and "holds no storage" in r.stderr


def test_a_sensor_written_as_its_bond_variable_alone_and_a_negative_reading():
    """``e6:`` alone (the sensor named like the bond variable it reads), and a plant run backwards
    (the inflow negative, every pressure negative): a read sensor's input starts at the plant's
    reading, sign included (tank 2 at -2.5 is what tank 1 and tank 3 read)."""
    text = CHAIN.replace("  p2: {expr: e6, noise: 0.02}", "  e6:").replace("inputs: {f_in: 1.0}",
                                                                            "inputs: {f_in: -1.0}")
    for v in ("4.5", "2.5", "1.5"):
        text = text.replace(f"initial: {v}}}", f"initial: -{v}}}")
    d = _split(text)
    assert [s.outputs for s in d.submodels] == [("e6",), ("p1",), ("p3",)]
    first = yaml.safe_load(d.submodels[1].text)
    assert first["inputs"]["e6_reading"]["value"] == -2.5
    assert yaml.safe_load(d.submodels[0].text)["inputs"]["p1"]["value"] == -4.5
    for s in d.submodels:
        compile_model(f"{s.name}.yaml", text=s.text)


def test_long_names_are_kept_within_what_a_model_file_may_hold():
    long_name = "a_chain_of_three_tanks_with_a_rather_long_name_for_its_model_file"[:64]
    text = CHAIN.replace("name: chain3", f"name: {long_name}").replace("p2", "p2_" + "x" * 60)
    d = _split(text)
    for s in d.submodels:
        assert len(s.name) <= 64
        c = compile_model(f"{s.name}.yaml", text=s.text)
        assert all(len(el.name) <= 64 for el in c.model.elements)
