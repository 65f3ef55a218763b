"""The validator: RawModel -> BondGraph, and every rule's error message.

Part 1 runs ``bgc check`` on every broken model in ``tests/data/invalid/``; each
file says, in its leading ``# expect: LINE:COL: text`` comments, where the error
is and a distinctive part of its message (locations counted by hand in the file).
Part 2 builds small models from YAML text and checks the BondGraph.
"""

import re
import subprocess
import textwrap

import pytest
import sympy

from bgc.errors import BgcError, ErrorGroup, ExpressionError, SourceLoc, ValidationError
from bgc.kinds import ELEMENT_KINDS, FAULT_KINDS
from bgc.compiler.load import load, loads
from bgc.compiler.validate import KINDS, validate

from conftest import MODELS, ROOT, bgc_cli

INVALID = ROOT / "tests" / "data" / "invalid"
FILES = sorted(p.name for p in INVALID.glob("*.yaml"))
EXPECT = re.compile(r"# expect: (\d+):(\d+): (.+)")
#: Files in which one mistake is (rightly) reported more than once.
MORE_THAN_ONE_LINE = {
    "two_effort_sources.yaml": "SCAP reports the conflict at each of the two sources",
    "hybrid_no_modes.yaml": "each switched junction is named",
}
#: Files a command in them would create if the model were run instead of refused.
SENTINELS = ("bgc_injection_sentinel", "bgc_tag_sentinel")


def expectations(name: str) -> list[tuple[int, int, str]]:
    """The ``# expect:`` lines at the top of a file (it may not be UTF-8: that is a test)."""
    out = []
    for line in (INVALID / name).read_bytes().decode("utf-8", "replace").splitlines():
        m = EXPECT.fullmatch(line.rstrip())
        if not m:
            break
        out.append((int(m[1]), int(m[2]), m[3]))
    return out


def bgc_check(*paths: str) -> subprocess.CompletedProcess:
    return bgc_cli("check", *paths)


@pytest.fixture(scope="module")
def batch():
    """One ``bgc check`` over every broken model.

    The CLI checks each file in turn and goes on after a broken one, prefixing
    every error with its file and printing ``FILE: ok: ...`` on stdout only for a
    valid model, so one process tells each file's verdict apart. (A process per
    file costs a second of imports each: too slow for 40 files.)
    """
    return bgc_check(*(f"tests/data/invalid/{name}" for name in FILES))


def lines_of(batch, name: str) -> list[str]:
    prefix = f"tests/data/invalid/{name}:"
    return [line for line in batch.stderr.splitlines() if line.startswith(prefix)]


def test_there_is_a_broken_model_for_each_rule():
    assert len(FILES) >= 25
    for name in FILES:
        assert expectations(name), f"{name} has no '# expect: LINE:COL: text' first line"


def test_bgc_check_fails_on_every_broken_model_without_a_traceback(batch):
    assert batch.returncode == 1
    assert "Traceback" not in batch.stderr
    assert batch.stdout == "", "a broken model was reported ok"
    form = re.compile(r"tests/data/invalid/([\w.]+\.yaml):(\d+):(\d+): \S.*")
    for line in batch.stderr.splitlines():
        assert form.fullmatch(line), f"not FILE:LINE:COL: message: {line!r}"
    for sentinel in SENTINELS:
        assert not (ROOT / sentinel).exists(), "a command in a model ran"


@pytest.mark.parametrize("name", FILES)
def test_bgc_check_reports_the_expected_errors(batch, name):
    assert f"tests/data/invalid/{name}: ok:" not in batch.stdout
    lines = lines_of(batch, name)
    assert lines, f"no error for {name}"
    n_lines = len((INVALID / name).read_bytes().splitlines())
    form = re.compile(rf"tests/data/invalid/{re.escape(name)}:(\d+):(\d+): \S.*")
    for line in lines:
        m = form.fullmatch(line)
        assert m, f"not FILE:LINE:COL: message: {line!r}"
        assert 1 <= int(m[1]) <= max(n_lines, 1), line
    for line_no, col, text in expectations(name):
        prefix = f"tests/data/invalid/{name}:{line_no}:{col}: "
        assert any(line.startswith(prefix) and text in line for line in lines), \
            f"expected {prefix}...{text}...\ngot:\n" + "\n".join(lines)


@pytest.mark.parametrize("name", [n for n in FILES if n not in MORE_THAN_ONE_LINE])
def test_one_mistake_gives_one_error_each(batch, name):
    """No cascade: an error is not reported again at every use of what it broke."""
    places = {(line, col) for line, col, _ in expectations(name)}
    assert len(lines_of(batch, name)) == len(places), "\n".join(lines_of(batch, name))


def test_three_independent_errors_come_out_of_one_run_in_file_order():
    r = bgc_check("tests/data/invalid/three_errors.yaml")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert [line.split(": ", 1)[0] for line in r.stderr.splitlines()] == [
        "tests/data/invalid/three_errors.yaml:8:3",
        "tests/data/invalid/three_errors.yaml:21:6",
        "tests/data/invalid/three_errors.yaml:23:3",
    ]


def test_unknown_kind_lists_every_valid_kind(batch):
    (line,) = lines_of(batch, "unknown_kind.yaml")
    assert "valid kinds: " + ", ".join(sorted(ELEMENT_KINDS)) in line
    assert KINDS == tuple(sorted(ELEMENT_KINDS))


def test_the_schema_lists_the_kinds_of_the_registry():
    """Element and fault kinds are declared once (bgc.kinds): the schema's
    enumerations are that registry (plus the junctions written as numbers,
    and a switched junction's stuck_on and stuck_off, bgc.ir.SWITCH_FAULTS)."""
    from bgc.compiler.validate import schema
    from bgc.ir import SWITCH_FAULTS

    defs = schema()["$defs"]
    assert set(defs["element"]["properties"]["kind"]["enum"]) == set(ELEMENT_KINDS) | {0, 1}
    assert defs["faultKinds"]["items"]["enum"] == list(FAULT_KINDS) + list(SWITCH_FAULTS)


def test_a_valid_model_among_broken_ones_is_still_checked(batch):
    r = bgc_check("tests/data/invalid/unknown_kind.yaml", "models/two_tank.yaml", "tests/data/invalid/no_storage.yaml")
    assert r.returncode == 1
    assert r.stdout.startswith("models/two_tank.yaml: ok: two_tank")
    errors = [line for line in r.stderr.splitlines() if not line.startswith("warning: models/two_tank.yaml: ")]
    assert errors == lines_of(batch, "unknown_kind.yaml") + lines_of(batch, "no_storage.yaml")


# ------------------------------------------------------------ unit tests
def build(text: str):
    return validate(loads(textwrap.dedent(text), "m.yaml"))


def errors(text: str) -> tuple[BgcError, ...]:
    with pytest.raises(ErrorGroup) as info:
        build(text)
    return info.value.errors


def same(x, y) -> bool:
    return sympy.simplify(x - y) == 0


S = sympy.Symbol

# Elements and bonds are declared out of order on purpose.
RC = """\
name: rc
description: an RC circuit
parameters:
  R: {value: 2.5, unit: ohm, description: resistor}
  C: 0.5
  gain: 3
inputs:
  V: {signal: step, value: 1.0, final: 2.0, start: 5.0, unit: V}
  slope_in: {signal: ramp, value: 0.0, slope: 0.5}
  level: 7.0
elements:
  j: {kind: "1"}
  V: {kind: Se}
  R: {kind: R}
  C: {kind: C, initial: 1.5}
bonds:
  3: [j, C]
  1: [V, j]
  2: [j, R]
measurements:
  f2:
  P: {expr: "gain*e3 + level", noise: 0.1, unit: V, description: scaled voltage}
faults:
  R: [incipient, abrupt]
  C: {kinds: [abrupt], direction: decrease, prior: 0.2}
"""


def test_bond_graph_content():
    g = build(RC)
    assert (g.name, g.description, g.source) == ("rc", "an RC circuit", "m.yaml")
    assert [e.name for e in g.elements] == ["C", "R", "V", "j"]              # sorted by name
    assert [(b.number, b.tail, b.head) for b in g.bonds] == [(1, "V", "j"), (2, "j", "R"), (3, "j", "C")]
    assert g.bond(2).loc == SourceLoc("m.yaml", 19, 3)
    assert g.element("R").loc == SourceLoc("m.yaml", 14, 3)
    assert [e.kind for e in g.elements] == ["C", "R", "Se", "1"]


def test_parameters():
    g = build(RC)
    assert [(p.name, p.value, p.unit, p.description) for p in g.parameters] == [
        ("C", 0.5, None, None), ("R", 2.5, "ohm", "resistor"), ("gain", 3.0, None, None)]
    assert g.parameter_values() == {"C": 0.5, "R": 2.5, "gain": 3.0}
    assert g.parameters[1].loc == SourceLoc("m.yaml", 4, 3)


def test_element_parameter_defaults_to_the_parameter_named_like_it():
    g = build(RC)
    assert g.element("R").parameter == S("R") and g.element("C").parameter == S("C")
    assert g.element("R").law is None and g.element("R").source is None
    g2 = build(RC.replace("R: {kind: R}", 'R: {kind: R, parameter: "2*C + gain"}'))
    assert same(g2.element("R").parameter, 2 * S("C") + S("gain"))


def test_source_value_defaults_to_the_input_named_like_it():
    g = build(RC)
    assert g.element("V").source == S("V") and g.element("V").parameter is None
    g2 = build(RC.replace("V: {kind: Se}", 'V: {kind: Se, value: "level - V/2"}'))
    assert same(g2.element("V").source, S("level") - S("V") / 2)
    g3 = build(RC.replace("V: {kind: Se}", "V: {kind: Se, value: 12}"))
    assert g3.element("V").source == 12


def test_initial_state_defaults_to_zero_for_storage_only():
    g = build(RC)
    assert g.element("C").initial == 1.5
    assert g.element("R").initial is None and g.element("j").initial is None
    assert build(RC.replace("C: {kind: C, initial: 1.5}", "C: {kind: C}")).element("C").initial == 0.0


def test_inputs_and_their_signals():
    g = build(RC)
    inputs = {i.name: i for i in g.inputs}
    assert [i.name for i in g.inputs] == ["V", "level", "slope_in"]
    v = inputs["V"].signal
    assert (v.kind, v.value, v.final, v.start, v.slope) == ("step", 1.0, 2.0, 5.0, None)
    assert inputs["V"].unit == "V"
    r = inputs["slope_in"].signal
    assert (r.kind, r.value, r.slope, r.start) == ("ramp", 0.0, 0.5, 0.0)   # a ramp starts at 0 by default
    c = inputs["level"].signal
    assert (c.kind, c.value, c.final, c.start, c.slope) == ("constant", 7.0, None, None, None)


def test_measurements_are_sympy_expressions():
    g = build(RC)
    ms = {m.name: m for m in g.measurements}
    assert [m.name for m in g.measurements] == ["P", "f2"]
    assert ms["f2"].expr == S("f2") and ms["f2"].text == "f2"
    assert same(ms["P"].expr, S("gain") * S("e3") + S("level"))
    assert (ms["P"].noise, ms["P"].unit, ms["P"].description) == (0.1, "V", "scaled voltage")
    assert ms["f2"].noise == 0.02  # the default measurement noise
    assert ms["P"].loc == SourceLoc("m.yaml", 22, 3)


def test_measurement_noise_default_follows_the_simulation_section():
    g = build(RC + "simulation: {measurement_noise: 0.07}\n")
    assert {m.name: m.noise for m in g.measurements} == {"P": 0.1, "f2": 0.07}


def test_fault_candidates_and_their_defaults():
    g = build(RC)
    faults = {f.parameter: f for f in g.faults}
    assert [f.parameter for f in g.faults] == ["C", "R"]
    assert (faults["R"].kinds, faults["R"].direction, faults["R"].prior) == (("abrupt", "incipient"), "both", 0.01)
    assert (faults["C"].kinds, faults["C"].direction, faults["C"].prior) == (("abrupt",), "decrease", 0.2)
    assert faults["C"].loc == SourceLoc("m.yaml", 25, 3)


def test_settings_defaults():
    g = build(RC)
    assert (g.settings.dt, g.settings.steps, g.settings.process_noise, g.settings.measurement_noise) \
        == (1.0, 300, 0.03, 0.02)
    assert g.settings.loc("dt") == SourceLoc("m.yaml", 1, 1)  # no simulation section: errors point at the name
    g2 = build(RC + "simulation: {dt: 0.25, steps: 40}\n")
    assert (g2.settings.dt, g2.settings.steps, g2.settings.process_noise, g2.settings.measurement_noise) \
        == (0.25, 40, 0.03, 0.02)
    # the places errors about the settings point at: the keys as written (line 26 of the text)
    assert g2.settings.loc("dt") == SourceLoc("m.yaml", 26, 14)
    assert g2.settings.loc("steps") == SourceLoc("m.yaml", 26, 24)
    assert g2.settings.loc("process_noise") == SourceLoc("m.yaml", 26, 1)


def test_junction_kind_may_be_written_as_a_number():
    g = build(RC.replace('j: {kind: "1"}', "j: {kind: 1}"))
    assert g.element("j").kind == "1"


# Bond 5 joins the 0-junction 'tank' to the orifice R_o; e5 is the pressure across
# it and f5 the flow through it.
ORIFICE = """\
name: tank
parameters: {C1: 2.0, cd: 0.4, k: 3.0}
inputs: {q_in: 1.0}
elements:
  Q: {kind: Sf, value: q_in}
  tank: {kind: "0"}
  C1: {kind: C}
  R_o: {kind: R, law: "f = cd*sqrt(e)"}
bonds:
  1: [Q, tank]
  4: [tank, C1]
  5: [tank, R_o]
"""


def test_nonlinear_law_in_the_bond_variables_of_the_element():
    law = build(ORIFICE).element("R_o").law
    assert law.output == "f5"
    assert same(law.expr, S("cd") * sympy.sqrt(S("e5")))
    assert law.text == "f = cd*sqrt(e)"
    assert law.loc == SourceLoc("m.yaml", 8, 23)
    assert build(ORIFICE).element("R_o").parameter is None


def test_nonlinear_law_in_resistance_form():
    law = build(ORIFICE.replace("f = cd*sqrt(e)", "e = k*f*abs(f)")).element("R_o").law
    assert law.output == "e5"
    assert same(law.expr, S("k") * S("f5") * sympy.Abs(S("f5")))


def test_law_left_side_must_be_e_or_f():
    (err,) = errors(ORIFICE.replace("f = cd*sqrt(e)", "q = cd*sqrt(e)"))
    assert "gives 'q', not e or f" in err.what and err.loc == SourceLoc("m.yaml", 8, 23)


def test_law_of_an_element_without_exactly_one_bond_is_reported_not_dropped():
    # once the element silently vanished and SCAP crashed on its bonds
    (err,) = errors(ORIFICE + "  6: [tank, R_o]\n")
    assert "R element R_o has 2 bonds, needs exactly 1" in err.what


def test_modulated_elements_may_use_bond_variables():
    g = build(ORIFICE.replace('R_o: {kind: R, law: "f = cd*sqrt(e)"}', 'R_o: {kind: MR, parameter: "k*(1 + e4)"}')
              .replace("Q: {kind: Sf, value: q_in}", 'Q: {kind: MSf, value: "q_in*tanh(e4)"}'))
    assert same(g.element("R_o").parameter, S("k") * (1 + S("e4")))
    assert same(g.element("Q").source, S("q_in") * sympy.tanh(S("e4")))


def test_modulated_law_may_use_another_bond_variable():
    law = build(ORIFICE.replace('{kind: R, law: "f = cd*sqrt(e)"}', '{kind: MR, law: "f = cd*e4*sqrt(e)"}')
                ).element("R_o").law
    assert same(law.expr, S("cd") * S("e4") * sympy.sqrt(S("e5")))


@pytest.mark.parametrize("element, fix", [
    ('R_o: {kind: R, law: "f = cd*e4*sqrt(e)"}', "use kind MR"),
    ('R_o: {kind: R, parameter: "k*e4"}', "use kind MR"),
    ('Q: {kind: Sf, value: "q_in*f4"}', "use kind MSf"),
    ('C1: {kind: C, parameter: "C1*e5"}', "a C element is never modulated"),
])
def test_unmodulated_elements_may_not_use_bond_variables(element, fix):
    name = element.split(":")[0]
    text = re.sub(rf"^  {name}: .*$", "  " + element, ORIFICE, flags=re.M)
    (err,) = errors(text)
    assert isinstance(err, ValidationError) and "depends on bond variable" in err.what
    assert fix in err.line()


def test_several_errors_are_reported_together_sorted_by_place():
    text = RC.replace("gain: 3", "np: 3").replace('  P: {expr: "gain*e3 + level", noise: 0.1, unit: V,'
                                                  ' description: scaled voltage}\n', "  P: {expr: \"e3 + q\"}\n")
    text = text.replace("  2: [j, R]\n", "  2: [j, R]\n  4: [j, Rx]\n")
    errs = errors(text)
    places = [(e.loc.line, e.loc.col) for e in errs]
    assert places == sorted(places) and len(errs) == 3
    assert "parameter name 'np' is reserved" in errs[0].what
    assert "bond 4 names unknown element 'Rx'" in errs[1].what
    assert isinstance(errs[2], ExpressionError) and "undefined name 'q'" in errs[2].what
    assert places == [(6, 3), (20, 6), (23, 13)]


def test_a_model_that_is_not_a_mapping():
    (err,) = errors("- just\n- a list\n")
    assert "must be a mapping" in err.what and err.loc == SourceLoc("m.yaml", 1, 1)


@pytest.mark.parametrize("section", ["parameters", "inputs", "measurements", "faults", "simulation"])
def test_a_section_that_is_not_a_mapping_is_an_error_not_a_crash(section):
    text = re.sub(rf"^{section}:.*\n(  .*\n)*", "", RC, flags=re.M) + f"{section}: 5\n"
    errs = errors(text)
    assert any(f"{section} must be an object" in e.what for e in errs), [e.line() for e in errs]


def test_the_three_models_validate():
    for path in sorted(MODELS.glob("*.yaml")):
        g = validate(load(path))
        assert g.name == path.stem and g.source == str(path)


def test_ro_membrane_resistance_is_modulated_by_the_conductivity():
    # models/ro.yaml: MR_memb: parameter "R_memb*((e27 - K0)/K_slope + 29)/29"
    g = validate(load(MODELS / "ro.yaml"))
    mr = g.element("MR_memb")
    assert mr.kind == "MR"
    assert same(mr.parameter, S("R_memb") * ((S("e27") - S("K0")) / S("K_slope") + 29) / 29)
    msf = g.element("MSf_k")
    assert same(msf.source, S("k_scale") * S("f10") * (6 * S("k_scale") * S("f18") + sympy.Rational(1, 10)))


# ------------------------------------------------------- numbers and schema fixes
def at_value(text: str, written: str, literal: str) -> tuple[int, int]:
    """Line and column (from 1) of ``literal`` inside the first ``written`` in ``text``."""
    before = text[: text.index(written) + written.index(literal)]
    return before.count("\n") + 1, len(before) - (before.rfind("\n") + 1) + 1


@pytest.mark.parametrize("old, new, where", [
    ("C: 0.5", "C: .inf", "parameters.C is infinite"),
    ("C: 0.5", "C: -.inf", "parameters.C is minus infinite"),
    ("C: 0.5", "C: .NaN", "parameters.C is NaN"),
    ("C: 0.5", "C: 1.0e+400", "parameters.C is infinite"),                 # overflows to .inf
    ("C: 0.5", "C: 1" + "0" * 400, "parameters.C is too large"),           # an int: float() would raise
    ("{value: 2.5, unit: ohm", "{value: -.inf, unit: ohm", "parameters.R.value is minus infinite"),
    ("level: 7.0", "level: .nan", "inputs.level is NaN"),
    ("value: 1.0, final: 2.0", "value: 1.0, final: .inf", "inputs.V.final is infinite"),
    ("start: 5.0", "start: .inf", "inputs.V.start is infinite"),
    ("start: 5.0", "start: -.inf", "inputs.V.start is minus infinite"),   # not also 'out of range'
    ("slope: 0.5", "slope: .nan", "inputs.slope_in.slope is NaN"),
    ("initial: 1.5", "initial: .nan", "elements.C.initial is NaN"),
    ("C: {kind: C, initial: 1.5}", "C: {kind: C, noise: .nan}", "elements.C.noise is NaN"),
    ("V: {kind: Se}", "V: {kind: Se, value: .inf}", "elements.V.value is infinite"),
    ("R: {kind: R}", "R: {kind: R, parameter: .nan}", "elements.R.parameter is NaN"),
    ("noise: 0.1", "noise: .inf", "measurements.P.noise is infinite"),
    ("prior: 0.2", "prior: .nan", "faults.C.prior is NaN"),
    ("prior: 0.2", "prior: .inf", "faults.C.prior is infinite"),          # not also 'out of range'
])
def test_a_number_that_is_not_finite_is_refused_where_it_is(old, new, where):
    text = RC.replace(old, new, 1)
    assert text != RC
    (err,) = errors(text)
    assert isinstance(err, ValidationError)
    assert err.what.startswith(where) and ("not a finite number" in err.what or "too large" in err.what)
    assert "write a finite number" in err.fix
    literal = re.search(r"-?\.(inf|nan|NaN)|1\.0e\+400|10{400}", new)[0]
    assert (err.loc.line, err.loc.col) == at_value(text, new, literal)


@pytest.mark.parametrize("setting", ["dt: .inf", "dt: .nan", "steps: .inf", "process_noise: .nan",
                                     "measurement_noise: .inf", "dt: 1.0e+999"])
def test_a_simulation_setting_that_is_not_finite_is_refused(setting):
    (err,) = errors(RC + f"simulation: {{{setting}}}\n")
    assert err.what.startswith("simulation." + setting.split(":")[0]) and "not a finite number" in err.what
    assert err.loc == SourceLoc("m.yaml", 26, 16 + len(setting.split(":")[0]))  # "simulation: {" is 13


def test_a_non_finite_value_where_no_number_goes_gets_the_schema_error_only():
    (err,) = errors(RC.replace("name: rc", "name: .inf"))
    assert err.what == "name must be a string, not a number" and err.fix
    (err,) = errors(RC.replace("R: {kind: R}", "R: {kind: .nan}"))
    assert "unknown element kind" in err.what


def test_a_non_finite_value_under_an_unknown_key_is_not_reported_again():
    (err,) = errors(RC + "solver: {tol: .inf, atol: [.nan]}\n")
    assert err.what.startswith("unknown section 'solver'")
    (err,) = errors(RC.replace("prior: 0.2}", "prior: 0.2, weight: .nan}"))
    assert err.what.startswith("unknown key 'weight'")


@pytest.mark.parametrize("old, new, where", [
    ("noise: 0.1", "noise: 0", "measurements.P.noise"),
    ("noise: 0.1", "noise: 0.0", "measurements.P.noise"),
    ("  f2:\n", "  f2: {noise: 0}\n", "measurements.f2.noise"),
])
def test_zero_sensor_noise_is_refused(old, new, where):
    (err,) = errors(RC.replace(old, new))
    assert err.what.startswith(f"{where} must be positive")
    assert "give a positive noise level" in err.fix


def test_zero_default_measurement_noise_is_refused_but_zero_process_noise_is_not():
    (err,) = errors(RC + "simulation: {measurement_noise: 0}\n")
    assert err.what == "simulation.measurement_noise must be positive, not 0"
    assert err.loc == SourceLoc("m.yaml", 26, 33) and "give a positive noise level" in err.fix
    g = build(RC.replace("C: {kind: C, initial: 1.5}", "C: {kind: C, initial: 1.5, noise: 0}")
              + "simulation: {process_noise: 0, measurement_noise: 1.0e-6}\n")
    assert g.settings.process_noise == 0.0 and g.element("C").noise == 0.0
    assert {m.name: m.noise for m in g.measurements} == {"P": 0.1, "f2": 1e-6}


# One broken place per case: every error the schema finds has a fix (the brief's rule).
SCHEMA_CASES = [
    # (replace, with, start of what, part of the fix)
    ("name: rc", "name: 12", "name must be a string, not a number", "write text"),
    ("C: 0.5", "C: one", "parameters.C must be a number, not text 'one'", "write a number"),
    ("C: 0.5", "C: 2*R", "parameters.C must be a number", "a formula goes in an element's 'parameter'"),
    ("C: 0.5", "C: '1e3'", "parameters.C must be a number, not text '1e3'", "write 1e3 without quotes"),
    ("C: 0.5", 'C: "1.5e-3"', "parameters.C must be a number", "write 1.5e-3 without quotes"),
    ("C: 0.5", 'C: "2E-5"', "parameters.C must be a number", "write 2E-5 without quotes"),
    ("C: 0.5", "C: 2.5e-3x", "parameters.C must be a number, not text '2.5e-3x'", "write a number such as 1.5"),
    ("C: 0.5", 'C: "0.5"', "parameters.C must be a number, not text '0.5'", "write 0.5 without quotes"),
    ("C: 0.5", "C: true", "parameters.C must be a number, not a boolean", "write a number"),
    ("C: 0.5", "C:", "parameters.C must be a number, not empty", "write a number"),
    ("initial: 1.5", "initial: [1]", "elements.C.initial must be a number, not a list", "write a number"),
    ("  f2:\n", "  f2: 3\n", "measurements.f2 must be empty or a mapping", "write 'f2:' alone"),
    ("R: [incipient, abrupt]", "R: abrupt", "faults.R must be an array", "write a list such as [abrupt]"),
    ("kinds: [abrupt]", "kinds: abrupt", "faults.C.kinds must be an array", "write a list"),
    ("kinds: [abrupt]", "kinds: [abrupt, abrupt]", "faults.C.kinds lists 'abrupt' more than once",
     "list each kind once"),
    ("kinds: [abrupt]", "kinds: []", "faults.C.kinds is empty", "list at least one of: abrupt, incipient"),
    ("R: [incipient, abrupt]", "R: []", "faults.R is empty", "list at least one of: abrupt, incipient"),
    ("prior: 0.2", "prior: 0", "faults.C.prior is out of range", "use a number > 0 and <= 1"),
    ("prior: 0.2", "prior: 1.5", "faults.C.prior is out of range", "use a number > 0 and <= 1"),
    ("start: 5.0", "start: -1.0", "inputs.V.start is out of range", "use a number >= 0"),
    ("initial: 1.5", "initial: 1.5, noise: -0.1", "elements.C.noise is out of range", "use a number >= 0"),
    ("3: [j, C]", "3: [j, C, R]", "bonds.3 must list exactly two elements", "write [tail, head]"),
    ("3: [j, C]", "3: j", "bonds.3 must be an array", "write [tail, head]"),
    ("parameters:\n", "parameters: 5\nx:\n", "parameters must be an object", "write a mapping"),
    ("direction: decrease", "direction: down", "'down' is not valid for faults.C.direction",
     "choose one of: both, decrease, increase"),
    ("R: {kind: R}", "R: {kind: R, resistance: 1}", "element R of kind R has no key 'resistance'",
     "keys of an R: description, kind, law, parameter"),
    ("name: rc", "nom: rc", "the model is missing 'name'", "add 'name: ...'"),
]
SIMULATION_CASES = [
    ("dt: -0.5", "simulation.dt is out of range: -0.5 is less than or equal to the minimum of 0", "use a number > 0"),
    ("dt: 0", "simulation.dt is out of range", "use a number > 0"),
    ("steps: 0", "simulation.steps is out of range: 0 is less than the minimum of 1", "use a whole number >= 1"),
    ("steps: 2.5", "simulation.steps must be an integer, not a number", "write a whole number"),
    ("steps: '1e3'", "simulation.steps must be an integer, not text '1e3'", "write 1e3 without quotes"),
    ("steps: 2.5e-1", "simulation.steps must be an integer, not a number", "write a whole number"),
    ("process_noise: -1.0", "simulation.process_noise is out of range", "use a number >= 0"),
    ("measurement_noise: -1.0", "simulation.measurement_noise must be positive", "give a positive noise level"),
]


@pytest.mark.parametrize("old, new, what, fix", SCHEMA_CASES
                         + [("", "simulation: {" + s + "}\n", w, f) for s, w, f in SIMULATION_CASES])
def test_every_schema_error_has_a_fix(old, new, what, fix):
    text = RC.replace(old, new, 1) if old else RC + new
    assert text != RC
    errs = [e for e in errors(text) if e.what.startswith(what)]
    assert len(errs) == 1, [e.line() for e in errors(text)]
    (err,) = errs
    assert err.fix and fix in err.fix, err.line()
    assert "\n" not in err.line()


def test_a_schema_error_without_a_specific_message_still_has_a_fix():
    import jsonschema

    from bgc.compiler.validate import _schema_message

    err = jsonschema.ValidationError("5 is not a multiple of 2", validator="multipleOf", validator_value=2,
                                     instance=5, schema={"multipleOf": 2})
    what, fix, _ = _schema_message(err, ("simulation", "steps"))
    assert what == "simulation.steps: 5 is not a multiple of 2" and "docs/format.md" in fix


# ------------------------------------------------ domain, quantity, time unit
def test_the_schema_lists_the_domains_of_the_registry():
    from bgc.compiler.validate import schema
    from bgc.kinds import DOMAINS

    assert schema()["properties"]["domain"]["enum"] == sorted(DOMAINS)


def test_a_model_declares_its_domain_time_unit_and_a_state_quantity():
    text = RC.replace("description: an RC circuit", "description: an RC circuit\ndomain: electrical")
    text = text.replace("C: {kind: C, initial: 1.5}", "C: {kind: C, initial: 1.5, quantity: charge voltage}")
    g = build(text + "simulation: {dt: 0.5, time_unit: ms}\n")
    assert g.domain == "electrical"
    assert g.element("C").quantity == "charge voltage"
    assert (g.settings.dt, g.settings.time_unit) == (0.5, "ms")


def test_without_them_none_is_declared():
    g = build(RC)
    assert (g.domain, g.element("C").quantity, g.settings.time_unit) == (None, None, None)


def test_an_unknown_domain_and_a_quantity_off_a_storage_element_are_refused():
    text = RC.replace("description: an RC circuit", "description: an RC circuit\ndomain: acoustic")
    assert any("domain" in str(e) and "hydraulic" in str(e) for e in errors(text))
    text = RC.replace("R: {kind: R}", "R: {kind: R, quantity: heat}")
    assert any("has no key 'quantity'" in str(e) for e in errors(text))


@pytest.mark.parametrize("fault, message", [
    ("spring: [abrupt]", "fault names 'spring', an element (C), not a parameter (a fault is on a parameter (its "
                         "parameter is 1/k_s): write 'k_s: [abrupt]')"),
    ("damper: [abrupt, incipient]", "fault names 'damper', an element (R), not a parameter (a fault is on a "
                                    "parameter (its parameter is c): write 'c: [abrupt, incipient]')"),
    ("v: [abrupt]", "fault names 'v', an element (1), not a parameter (a junction has no parameter"),
])
def test_a_fault_naming_an_element_points_to_its_parameter(fault, message):
    text = (ROOT / "tests" / "data" / "models" / "mass_spring_damper.yaml").read_text(encoding="utf-8")
    head, _, _ = text.partition("faults:")
    with pytest.raises(BgcError) as info:
        validate(loads(head + "faults:\n  " + fault + "\n", "msd.yaml"))
    assert message in str(info.value)
