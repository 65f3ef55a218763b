"""``bgc analyse`` (issue 49, point 1): detectability and isolability of a
model's faults at three levels, before the plant runs.

The structural level is checked three ways: by hand on the two tanks (the
structural model written out below), against the Fault Diagnosis Toolbox
(the ``faultdiagnosistoolbox`` package, a test-only dependency) on every
shipped and test plant of one mode, and on small structures whose
overdetermined part is known. The qualitative level is checked by hand on
the two tanks' signatures, the quantitative one against ``bgc distinguish``
on the same model.
"""

from __future__ import annotations

import json

import pytest

from bgc.analysis import isolability, structure
from bgc.api.analyse import analyse, with_sensors
from bgc.compiler import load
from bgc.output import render
from bgc.pipeline import compile_model

from conftest import ROOT, bgc_cli, compiled

TWO_TANK = ROOT / "models" / "two_tank.yaml"

#: Every plant of one mode the repository ships or tests with.
PLANTS = sorted(p for p in [*(ROOT / "models").glob("*.yaml"), *(ROOT / "tests" / "data" / "models").glob("*.yaml")]
                if not load.declares_modes(p))


def test_the_overdetermined_part_of_small_structures():
    """Known decompositions: two equations in one unknown are a redundancy
    (both in M+); a chain x1 -> x2 with one equation each is just determined
    (none); a third equation on x2 makes the chain's end redundant, and the
    equation that only fixes x1 stays outside."""
    S = structure.StructuralModel
    assert S(("a", "b"), ("x",), {"a": {"x"}, "b": {"x"}}, {}).overdetermined() == {"a", "b"}
    chain = {"a": {"x1"}, "b": {"x1", "x2"}}
    assert S(("a", "b"), ("x1", "x2"), chain, {}).overdetermined() == set()
    assert S(("a", "b", "c"), ("x1", "x2"), {**chain, "c": {"x2"}}, {}).overdetermined() == {"a", "b", "c"}
    # a: x1 alone; b, c: x2 twice: only b and c are redundant
    assert S(("a", "b", "c"), ("x1", "x2"), {"a": {"x1"}, "b": {"x2"}, "c": {"x2"}}, {}).overdetermined() == {"b", "c"}


def test_the_two_tanks_structure_by_hand():
    """The two tanks' structural model, written from their state equations

        C1 de2 = f_in + f_in_offset - (e2 - e7)/R12 - e2/R10
        C2 de7 = (e2 - e7)/R12 - e7/R20
        F10 = e2/R10 + F10_offset,  F12 = (e2 - e7)/R12 + F12_offset,  F20 = e7/R20 + F20_offset

    with each fault parameter an unknown of its own (v_p = p + f_p): 16
    equations (2 dynamic, 2 differential, 3 measurements, 9 faults) in 13
    unknowns (e2, e7, de2, de7 and the 9 v_p), so 3 redundancies. Every
    fault's equation is in one: detectable. C1 and f_in_offset enter the
    first dynamic equation only, so every redundancy that holds one holds
    the other: they cannot be told apart; every other ordered pair can (a
    sensor's offset is in its measurement alone; R10, R12, R20 each in a
    measurement the others are not in)."""
    c = compiled("two_tank")
    faults = tuple(sorted({f.parameter for f in c.model.faults}))
    m = structure.of_equations(c.equations, {p: p for p in faults})
    assert len(m.equations) == 16 and len(m.unknowns) == 13
    assert m.holds["dyn_e2"] == {"de2", "e2", "e7", "v_C1", "v_R12", "v_R10", "v_f_in_offset"}
    assert m.holds["meas_F12"] == {"e2", "e7", "v_R12", "v_F12_offset"}
    assert m.holds["diff_e7"] == {"de7", "e7"}
    names, matrix = m.matrix()
    assert all(m.detectable(f) for f in names)
    alike = {("C1", "f_in_offset"), ("f_in_offset", "C1")}
    for i, a in enumerate(names):
        for j, b in enumerate(names):
            assert matrix[i][j] == (i != j and (a, b) not in alike), (a, b)


def fdt_model(m: structure.StructuralModel):
    """The Fault Diagnosis Toolbox's model of the same structure: a
    differential constraint per state (``fdt.DiffConstraint``), every other
    equation by the variables it holds."""
    import faultdiagnosistoolbox as fdt  # the test extra's (pyproject.toml)
    faults = list(m.faults)
    known = sorted({z for e in m.equations for z in m.known[e]})
    rels = []
    for e in m.equations:
        if m.kind[e] == "differential":
            x = e.removeprefix("diff_")
            rels.append(fdt.DiffConstraint(f"d{x}", x))
        else:
            rels.append(sorted(m.holds[e]) + sorted(m.known[e]) + [f for f in faults if m.faults[f] == e])
    return fdt.DiagnosisModel({"type": "VarStruc", "x": list(m.unknowns), "f": faults, "z": known, "rels": rels})


@pytest.mark.parametrize("path", PLANTS, ids=lambda p: p.stem)
def test_structural_results_equal_the_fault_diagnosis_toolboxs(path):
    if "faults:" not in path.read_text(encoding="utf-8"):  # nothing to analyse: said in one line
        with pytest.raises(ValueError, match="declares no fault candidates"):
            analyse(path, quantitative=False)
        return
    r = analyse(path, quantitative=False)
    m = r.structure
    tool = fdt_model(m)
    detected, missed = tool.DetectabilityAnalysis()
    mine = r.get("structural")
    assert set(detected) == {f for f, d in zip(r.faults, mine.detectable) if d}
    assert set(missed) == {f for f, d in zip(r.faults, mine.detectable) if not d}
    im = tool.IsolabilityAnalysis()  # im[i][j] = 1: fault i cannot be told from fault j
    for i in range(len(r.faults)):
        for j in range(len(r.faults)):
            assert mine.isolable[i][j] == (i != j and not im[i][j]), (path.stem, r.faults[i], r.faults[j])


def test_the_two_tanks_signatures_by_hand():
    """Qualitatively (magnitude and slope at each sensor once it moves):
    C1 up and f_in_offset down both lower the first tank's level and every
    flow (F10 -, F12 -, F20 -), so they are alike, as the structure says;
    R10 down, R12 up and R20 up, as drifts, all raise F10 and lower F12 and
    F20 (R12 holds water in tank 1; R10 and R20 push it round so that tank
    1 rises and tank 2 falls in the end), so the signatures cannot tell
    them apart although the structure can; every sensor offset moves its own
    sensor only and is told from every plant fault, which moves all three."""
    r = analyse(TWO_TANK, quantitative=False)
    q = r.get("qualitative")
    assert q.classes(r.faults) == (("C1", "f_in_offset"), ("R10", "R12", "R20"))
    assert set(r.more("structural", "qualitative")) == {(a, b) for a in ("R10", "R12", "R20")
                                                        for b in ("R10", "R12", "R20") if a != b}
    assert r.more("qualitative", "structural") == ()
    why = q.why[r.faults.index("R12"), r.faults.index("R20")]
    assert "show the same symbols: F10 + slope +, F12 - slope -, F20 - slope -" in why


@pytest.mark.parametrize("path", PLANTS, ids=lambda p: p.name)
def test_the_pairs_the_signatures_cannot_tell_apart_are_worked_out_at_once_as_one_by_one(path):
    """The qualitative level finds the pairs of signatures nothing refutes for all pairs at once
    (``isolability._alike``, arrays); each pair is checked against the rule read one pair at a time
    (``isolability._refutes``, which says why)."""
    from bgc.pipeline import analysis_model

    sigs = analysis_model(path).signatures
    every = sigs.signatures
    alike = isolability._alike(every)
    for a, sa in enumerate(every):
        for b, sb in enumerate(every):
            assert alike[a, b] == (isolability._refutes(sa, sb, sigs.measurements) is None), (sa.name, sb.name)


@pytest.mark.slow
@pytest.mark.long
def test_the_quantitative_level_is_bgc_distinguishs():
    """At the model's noise and constant inputs the capacitances change
    nothing at steady state (bgc check warns of it): not detected; every
    other fault is, and the quantitative level tells R10, R12 and R20 apart,
    which their signatures cannot; the pairs it calls alike are those whose
    rival bgc distinguish puts in the predicted ambiguity group."""
    from bgc import api

    r = analyse(TWO_TANK)
    n = r.get("quantitative")
    assert [f for f, d in zip(r.faults, n.detectable) if not d] == ["C1", "C2"]
    assert {(a, b) for a in ("R10", "R12", "R20") for b in ("R10", "R12", "R20") if a != b} <= \
        set(r.more("quantitative", "qualitative"))
    d = api.distinguishability(TWO_TANK)
    grouped = {(x.truth.rsplit("_", 1)[0], g.rsplit("_", 1)[0]) for x in d.distinctions
               if x.detectability >= 0.95 for g in x.group}
    told = n.pairs()
    for i, a in enumerate(r.faults):
        for j, b in enumerate(r.faults):
            if i != j and n.detectable[i]:
                assert ((i, j) in told) == ((a, b) not in grouped), (a, b)


def test_bgc_analyse_prints_and_writes_its_folder(tmp_path):
    p = bgc_cli("analyse", TWO_TANK, "--no-quantitative")
    assert p.returncode == 0, p.stderr
    assert "C1 not told from f_in_offset: S: every redundancy that holds C1's equation holds f_in_offset's" in p.stdout
    assert p.stderr == ""
    p = bgc_cli("analyse", TWO_TANK, "--no-quantitative", "--format", "json")
    data = json.loads(p.stdout)
    assert data["levels"]["structural"]["classes"] == [["C1", "f_in_offset"]] and data["quantitative"] is None
    p = bgc_cli("analyse", TWO_TANK, "--no-quantitative", "-o", tmp_path / "a")
    assert p.returncode == 0 and (tmp_path / "a" / "isolability.png").read_bytes()[:4] == b"\x89PNG"
    md = (tmp_path / "a" / "analysis.md").read_text(encoding="utf-8")
    assert md.startswith("# What the sensors of two_tank can detect and tell apart\n")
    assert "| 1 C1 | -- | SQ | SQ | SQ | SQ | SQ | SQ | SQ | .. |" in md  # C1 not told from f_in_offset (9)
    page = (tmp_path / "a" / "analysis.html").read_text(encoding="utf-8")
    assert "<li>C1 not told from f_in_offset: structural: every redundancy" in page and "data:image/png" in page
    assert json.loads((tmp_path / "a" / "manifest.json").read_text())["command"].startswith("analyse")


def test_bad_arguments_are_refused_in_one_line():
    p = bgc_cli("analyse", TWO_TANK, "--no-quantitative", "--modes", "a@1")
    assert p.returncode != 0 and "has no modes" in p.stderr and len(p.stderr.strip().splitlines()) == 1
    with pytest.raises(TypeError, match="quantitative=1 is not True or False"):
        analyse(TWO_TANK, quantitative=1)
    assert isolability.LEVELS == ("structural", "qualitative", "quantitative")


def test_the_sensor_that_splits_the_tanks_inflow_from_its_capacity_by_hand(tmp_path):
    """Structurally: C1 and the inflow's actuator bias enter the first tank's
    dynamic equation only; a sensor on the delivered inflow f1 (= f_in +
    f_in_offset) knows the actuator's share, and one on C1's flow f2 (= C1
    de2, with e2 = R10 F10 measured) knows the capacity's: each alone
    separates them; no sensor on a pressure does (each is a state the flows
    give already). Costs choose between them; the model written with f1
    reads back and its analysis separates the pair at both levels."""
    def structural(**kw):
        return analyse(TWO_TANK, quantitative=False, place_sensors=True, place_by="structural", **kw).placement

    p = structural()
    assert p.cost == 1 and set(p.sets) == {("f1",), ("f2",)} and p.reachable_qualitative is None
    assert len(p.now[1]) + 2 == len(p.reachable[1]) and p.reachable[0] == p.now[0] == set(p.faults)
    assert structural(costs={"f1": 5, "f2": 1}).sets == (("f2",),)
    assert structural(costs={"e2": 1}).sets == ((),)
    out = tmp_path / "placed.yaml"
    p = bgc_cli("analyse", TWO_TANK, "--no-quantitative", "--place-sensors", "--place-by", "structural",
                "--write", out)
    assert p.returncode == 0, p.stderr
    assert f"wrote {out}: {TWO_TANK} with f1 added" in p.stdout
    assert "  # bgc analyse --place-sensors: a sensor added on f1\n  f1: {expr: f1}\n" in out.read_text(encoding="utf-8")
    placed = analyse(out, quantitative=False)
    assert placed.get("structural").classes(placed.faults) == ()
    i, j = placed.faults.index("C1"), placed.faults.index("f_in_offset")
    assert {(i, j), (j, i)} <= placed.get("qualitative").pairs()


def test_sensors_placed_by_the_signatures_too_are_the_cheapest_that_reach_both_levels(tmp_path):
    """With the qualitative level as well, the two tanks' resistors must be
    told apart by their signatures: no single sensor does it (checked on
    every candidate's model written out and analysed afresh), each set given
    does, at both levels, as every candidate together."""
    r = analyse(TWO_TANK, quantitative=False, place_sensors=True)
    p = r.placement
    assert p.cost == 2 and p.sets and all(len(s) == 2 for s in p.sets)
    for k, sensors in enumerate([*((c.name,) for c in p.candidates), p.sets[0]]):
        out = tmp_path / f"m{k}.yaml"
        with_sensors(TWO_TANK, p.variables(sensors), out)
        a = analyse(out, quantitative=False)
        reaches = len(a.get("structural").pairs()) == len(p.reachable[1]) and \
            len(a.get("qualitative").pairs()) == len(p.reachable_qualitative[1])
        assert reaches == (len(sensors) == 2), sensors


def test_a_second_gauge_on_the_measured_pressure_splits_its_offset_from_the_drain(tmp_path):
    """docs/examples/level_gauge.yaml: one state, the tank's pressure e2, read
    by the gauge p = e2 + p_offset; the drain's R in the junction's flow.
    Structurally the gauge's one redundancy (the tank's balance, C de2/dt =
    f_in - e2/R, checked against p) holds both faults: not told apart either
    way. A second gauge p' = e2 holds no p_offset: {p, p'} is a redundancy
    of the offset alone and {the balance, p'} of R alone, so it splits them
    both ways; so does a flow meter on the drain (f3 = e2/R) or on the tank
    (f2), which give e2's derivative without the gauge. A second sensor is a
    candidate only beside a sensor a fault is declared on (the two tanks
    with sensors: F12, not F10 or F20), or where a costs file names the
    measured quantity; with flow meters four times a gauge's cost it is the
    one set, and the model written with it, read back and analysed afresh
    (a model with two measurements, no placement in it), tells the two
    faults apart at every level."""
    gauge = ROOT / "docs" / "examples" / "level_gauge.yaml"
    p = analyse(gauge, quantitative=False, place_sensors=True, place_by="structural").placement
    assert p.now == (frozenset({"R", "p_offset"}), frozenset())
    assert p.reachable[1] == {("R", "p_offset"), ("p_offset", "R")}
    assert p.cost == 1 and set(p.sets) == {("f2",), ("f3",), ("p'",)}
    twin = {c.name: c for c in p.candidates}["p'"]
    assert (twin.reads, twin.beside, str(twin.expr)) == ("e2", "p", "e2")
    sensors = analyse(ROOT / "tests" / "data" / "models" / "two_tank_sensors.yaml", quantitative=False,
                      place_sensors=True).placement
    assert {c.name for c in sensors.candidates if c.beside} == {"F12'"}
    costs = {"e2": 1, "f2": 4, "f3": 4}
    assert analyse(gauge, quantitative=False, place_sensors=True, costs=costs).placement.sets == (("p'",),)
    written = tmp_path / "costs.yaml"
    written.write_text("{e2: 1, f2: 4, f3: 4}\n", encoding="utf-8")
    out = tmp_path / "two_gauges.yaml"
    run = bgc_cli("analyse", gauge, "--no-quantitative", "--place-sensors", "--costs", written, "--write", out)
    assert run.returncode == 0, run.stderr
    assert "p' (= e2, a second sensor beside p)" in run.stdout and "with p' (as e2) added" in run.stdout
    assert "  # bgc analyse --place-sensors: a sensor added on e2\n  e2: {expr: e2}\n" in out.read_text(encoding="utf-8")
    placed = analyse(out, quantitative=False)
    assert placed.get("structural").classes(placed.faults) == ()
    i, j = placed.faults.index("R"), placed.faults.index("p_offset")
    assert {(i, j), (j, i)} <= placed.get("qualitative").pairs()
    for r, told in ((analyse(gauge, quantitative=False), False), (placed, True)):  # the toolbox agrees
        im = fdt_model(r.structure).IsolabilityAnalysis()  # im[a][b] = 1: a cannot be told from b
        a, b = r.faults.index("R"), r.faults.index("p_offset")
        assert (not im[a][b], not im[b][a]) == (told, told), (r.faults, im)


def test_a_second_gauge_is_placed_across_the_modes_of_a_pumped_tank(tmp_path):
    """tests/data/models/pumped_gauge.yaml: the gauge's tank with a pump
    switched on and off. In both modes the tank's balance, C de4/dt = (E -
    e4)/R_p - e4/R or -e4/R, is the gauge's one redundancy and holds both
    faults; a second gauge p' = e4 splits them in both (its own redundancy
    with p holds the offset alone). Priced below every other bond variable,
    it is the one set; the model written with it, read back, has each
    mode's structure equal to the Fault Diagnosis Toolbox's and the two
    faults told apart in every mode."""
    from bgc.api.analyse import _stuck_configs, _stuck_equations

    pumped = ROOT / "tests" / "data" / "models" / "pumped_gauge.yaml"
    p = analyse(pumped, quantitative=False, place_sensors=True).placement
    assert p.now[1] == frozenset() and p.reachable[1] == {("R", "p_offset"), ("p_offset", "R")}
    assert ("p'",) in p.sets and p.variables(["p'"]) == ["e4"]
    costs = {name: 4 for name in ("e2", "f1", "f4", "f5")} | {"e4": 1}
    p = analyse(pumped, quantitative=False, place_sensors=True, costs=costs).placement
    assert p.sets == (("p'",),) and p.cost == 1
    other = analyse(pumped, quantitative=False, place_sensors=True, costs={"e5": 1, "f5": 4}).placement
    assert other.sets == (("p'",),) and other.variables(["p'"]) == ["e5"]  # the tank's pressure by another bond
    out = tmp_path / "two_gauges.yaml"
    with_sensors(pumped, p.variables(p.sets[0]), out)
    c = compile_model(out)
    faults = ("R", "p_offset")
    sensors = {f.parameter: f.subject for f in c.model.faults if f.target == "sensor"}
    enters = _stuck_equations(c, _stuck_configs(c, c.model.modes.stuck))
    for m in c.modes:
        level, model = isolability.structural(m.equations, faults, sensors, enters[m.name])
        im = fdt_model(model).IsolabilityAnalysis()
        assert level.isolable[0][1] and level.isolable[1][0] and not im[0][1] and not im[1][0], m.name


def test_a_second_differential_gauge_on_an_expression_no_bond_carries(tmp_path):
    """tests/data/models/three_tanks_dp.yaml: three tanks in a row, one
    differential gauge dP = e2 - e10 across the first and the last (no bond
    carries that difference: the pipes' efforts are e2 - e6 and e6 - e10),
    which may drift off zero. Its one redundancy holds every equation: R12,
    R23 and dP_offset are not told apart at all. A second gauge dP' on the
    same expression holds no offset; with it the model less either pipe's
    equation is still overdetermined (the two gauges fix e2 - e10 twice), and
    so is the model less dP's equation: every fault told from every other
    structurally. By the signatures dP' shows what dP shows of the pipes (a
    rise of either resistance raises the first tank's pressure against the
    last's) and nothing of dP's offset: the offset is told from both pipes
    both ways, the pipes not from each other. Written (named dP_2, its text
    the first gauge's), read back and analysed afresh, with the Fault
    Diagnosis Toolbox agreeing; and a gauge whose text is an expression on a
    model with modes (the pumped tank's gauge read as 2*e4) gets its second
    in every mode."""
    dp = ROOT / "tests" / "data" / "models" / "three_tanks_dp.yaml"
    before = analyse(dp, quantitative=False)
    assert before.get("structural").pairs() == set() and before.get("qualitative").pairs() == set()
    p = analyse(dp, quantitative=False, place_sensors=True, place_by="structural").placement
    twin = {c.name: c for c in p.candidates}["dP'"]
    assert (twin.reads, twin.beside, twin.shows, str(twin.expr), twin.written) == \
        ("e2 - e10", "dP", "dP", "-e10 + e2", ("dP_2", "e2 - e10"))
    assert ("dP'",) in p.sets and p.written(["dP'"]) == [("dP_2", "e2 - e10")]
    out = tmp_path / "two_gauges.yaml"
    run = bgc_cli("analyse", dp, "--no-quantitative", "--place-sensors", "--place-by", "structural")
    assert run.returncode == 0, run.stderr
    assert "dP' (= -e10 + e2, a second sensor beside dP)" in run.stdout, run.stdout
    with_sensors(dp, [twin.written], out)
    assert "  dP_2: {expr: e2 - e10}\n" in out.read_text(encoding="utf-8")
    placed = analyse(out, quantitative=False)
    i, j, k = (placed.faults.index(f) for f in ("R12", "R23", "dP_offset"))
    assert placed.get("structural").pairs() == {(a, b) for a in (i, j, k) for b in (i, j, k) if a != b}
    assert placed.get("qualitative").pairs() == {(i, k), (k, i), (j, k), (k, j)}
    im = fdt_model(placed.structure).IsolabilityAnalysis()  # im[a][b] = 1: a cannot be told from b
    assert all(not im[a][b] for a in range(3) for b in range(3) if a != b), im
    pumped = tmp_path / "scaled_gauge.yaml"
    pumped.write_text((ROOT / "tests" / "data" / "models" / "pumped_gauge.yaml").read_text(encoding="utf-8")
                      .replace("p: {expr: e4,", "p: {expr: 2*e4,"), encoding="utf-8")
    q = analyse(pumped, quantitative=False, place_sensors=True).placement
    assert ("p'",) in q.sets and q.written(["p'"]) == [("p_2", "2*e4")]
    assert {str(c.expr) for c in q.candidates if c.name == "p'"} == {"2*e4"}
    scaled = tmp_path / "two_scaled_gauges.yaml"
    with_sensors(pumped, q.written(["p'"]), scaled)
    c = compile_model(scaled)
    sensors = {f.parameter: f.subject for f in c.model.faults if f.target == "sensor"}
    for m in c.modes:  # in both modes the offset and the drain told apart both ways, as with the gauge on e4
        level, model = isolability.structural(m.equations, ("R", "p_offset"), sensors, {})
        im = fdt_model(model).IsolabilityAnalysis()
        assert level.isolable[0][1] and level.isolable[1][0] and not im[0][1] and not im[1][0], m.name


def test_a_costs_file_prices_a_second_gauge_on_an_expression_by_the_gauges_name(tmp_path):
    """A costs file prices bond variables, and no bond variable carries
    the differential gauge's e2 - e10 (tests/data/models/three_tanks_dp.yaml):
    named by the gauge's own name, ``dP``, it prices the second gauge on
    the gauge's model text. The second gauge alone tells every fault from
    every other structurally (the test above, the Fault Diagnosis Toolbox
    agreeing): with the pipes' flows priced 5 and dP 3, it is the one
    cheapest set, of cost 3, and the file written holds dP_2 on e2 - e10;
    with dP not named it is no candidate. On a model with modes the
    pumped tank's gauge read as 2*e4 is priced the same way in every mode.
    A name that is neither a bond variable nor a sensor is refused in one
    line."""
    dp = ROOT / "tests" / "data" / "models" / "three_tanks_dp.yaml"
    flows = {"f4": 5, "f8": 5}
    priced = analyse(dp, quantitative=False, place_sensors=True, place_by="structural", costs=flows | {"dP": 3})
    p = priced.placement
    twin = {c.name: c for c in p.candidates}["dP'"]
    assert (twin.cost, twin.written, str(twin.expr)) == (3.0, ("dP_2", "e2 - e10"), "-e10 + e2")
    assert (p.sets, p.cost) == ((("dP'",),), 3.0)
    listed = {c["name"]: c for c in priced.to_dict()["placement"]["candidates"]}  # the same analysis, as JSON
    assert listed["dP'"]["model_text"] == "e2 - e10" and listed["dP'"]["cost"] == 3.0
    unnamed = analyse(dp, quantitative=False, place_sensors=True, place_by="structural", costs=flows).placement
    assert "dP'" not in {c.name for c in unnamed.candidates}
    costs = tmp_path / "costs.yaml"
    costs.write_text("{f4: 5, f8: 5, dP: 3}\n", encoding="utf-8")
    out = tmp_path / "two_gauges.yaml"
    run = bgc_cli("analyse", dp, "--no-quantitative", "--place-sensors", "--place-by", "structural", "--costs", costs,
                  "--write", out)
    assert run.returncode == 0, run.stderr
    assert "  dP_2: {expr: e2 - e10}\n" in out.read_text(encoding="utf-8")
    pumped = tmp_path / "scaled_gauge.yaml"
    pumped.write_text((ROOT / "tests" / "data" / "models" / "pumped_gauge.yaml").read_text(encoding="utf-8")
                      .replace("p: {expr: e4,", "p: {expr: 2*e4,"), encoding="utf-8")
    q = analyse(pumped, quantitative=False, place_sensors=True, costs={"p": 2, "f1": 9}).placement
    assert {(c.name, c.cost, str(c.expr)) for c in q.candidates if c.beside} == {("p'", 2.0, "2*e4")}
    assert q.sets == (("p'",),) and q.written(["p'"]) == [("p_2", "2*e4")]
    costs.write_text("{dQ: 1}\n", encoding="utf-8")
    refused = bgc_cli("analyse", dp, "--no-quantitative", "--place-sensors", "--costs", costs)
    assert refused.returncode != 0 and "'dQ', neither a bond variable nor a sensor of" in refused.stderr
    assert len(refused.stderr.strip().splitlines()) == 1, refused.stderr


def test_sensor_placement_refuses_what_it_cannot_do_in_one_line(tmp_path):
    costs = tmp_path / "costs.yaml"
    for args, what in ((("--write", tmp_path / "x.yaml"), "--write applies to --place-sensors"),
                       (("--place-sensors", "--write", TWO_TANK), "is the model file: it is never replaced"),
                       (("--place-sensors", "--costs", costs), "cannot be read")):
        p = bgc_cli("analyse", TWO_TANK, "--no-quantitative", *args)
        assert p.returncode != 0 and what in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
    costs.write_text("{e2: -1}\n", encoding="utf-8")
    p = bgc_cli("analyse", TWO_TANK, "--no-quantitative", "--place-sensors", "--costs", costs)
    assert p.returncode != 0 and "not a mapping of bond variables to costs >= 0" in p.stderr
    costs.write_text("{x99: 1}\n", encoding="utf-8")
    p = bgc_cli("analyse", TWO_TANK, "--no-quantitative", "--place-sensors", "--costs", costs)
    assert p.returncode != 0 and "costs names 'x99', neither a bond variable nor a sensor of two_tank" in p.stderr


@pytest.mark.slow
def test_an_input_test_is_proposed_for_a_damper_at_rest():
    """The mass-spring-damper of tests/data/models at rest (its force input
    0): the damper's force c v is 0 while nothing moves, so a change of c
    changes nothing the sensors read (P 0.5: a coin); a force that moves the
    mass shows it. The proposal's probability is what bgc distinguish gives
    with that input."""
    import yaml

    from bgc import api

    msd = ROOT / "tests" / "data" / "models" / "mass_spring_damper.yaml"
    r = analyse(msd, design_inputs=True, steps=100)
    (f, u, text, p, p0), = r.input_tests
    assert (f, u) == ("c", "F") and p0 < 0.6 and p > 0.99
    again = api.distinguishability(msd, inputs={u: yaml.safe_load(text)}, steps=100)
    assert max(d.detectability for d in again.distinctions if d.truth.startswith("c_")) == pytest.approx(p)
    with pytest.raises(ValueError, match="design_inputs=True needs the quantitative level"):
        analyse(msd, quantitative=False, design_inputs=True)


HYBRID = sorted(p for p in [*(ROOT / "models").glob("*.yaml"), *(ROOT / "docs" / "examples").glob("*.yaml")]
                if load.declares_modes(p))


@pytest.mark.parametrize("path", [pytest.param(p, marks=pytest.mark.slow) if p.stem == "ro_hybrid_valve" else p
                                  for p in HYBRID], ids=lambda p: p.stem)  # (the RO's three valve settings: 5 s)
@pytest.mark.long
def test_each_modes_structure_equals_the_fault_diagnosis_toolboxs(path):
    from bgc.pipeline import compile_model

    from bgc.api.analyse import _stuck_configs, _stuck_equations

    c = compile_model(path)
    stuck = c.model.modes.stuck  # a switch that may stick: a fault in the equations its configurations change
    faults = tuple(sorted({f.parameter for f in c.model.faults} | {f.junction for f in stuck}))
    sensors = {f.parameter: f.subject for f in c.model.faults if f.target == "sensor"}
    enters = _stuck_equations(c, _stuck_configs(c, stuck))
    for m in c.modes:
        level, model = isolability.structural(m.equations, faults, sensors, enters[m.name])
        tool = fdt_model(model)
        detected, _ = tool.DetectabilityAnalysis()
        assert set(detected) == {f for f, d in zip(faults, level.detectable) if d}, m.name
        im = tool.IsolabilityAnalysis()
        assert all(level.isolable[i][j] == (i != j and not im[i][j])
                   for i in range(len(faults)) for j in range(len(faults))), m.name


def test_a_relays_faults_across_its_modes_by_hand():
    """docs/examples/relay.yaml: the auxiliary load R_aux carries current only
    with the relay closed, where it sits beside the main load R_load (a
    change of either moves i_L and v_C alike: not told apart, structurally
    nor by the signatures); open, R_load alone is on the source. Across the
    modes: each is detected; R_load is told from R_aux (in the open mode,
    where R_aux is not in the circuit), R_aux not from R_load."""
    r = analyse(ROOT / "docs" / "examples" / "relay.yaml", quantitative=False)
    assert list(r.by_mode) == ["open", "closed", "unpowered"]
    aux, load_ = r.faults.index("R_aux"), r.faults.index("R_load")
    for name in ("structural", "qualitative"):
        lv = r.get(name)
        assert lv.detectable[aux] and lv.detectable[load_]
        assert lv.isolable[load_][aux] and not lv.isolable[aux][load_]
        assert "in closed: " in lv.why[aux, load_]
        open_, closed = (dict(zip(("structural", "qualitative"), r.by_mode[m]))[name] for m in ("open", "closed"))
        assert not open_.detectable[aux] and closed.detectable[aux] and not closed.isolable[aux][load_]


@pytest.mark.slow
def test_a_relays_stuck_switches_across_its_modes_by_hand():
    """The relay's switches that may stick (K: stuck_on, stuck_off; S:
    stuck_off) are faults of the analysis too. By hand (i the coil's
    current, v the capacitor's voltage; open: S on, K off; closed: both on;
    unpowered: both off, i no state): K stuck ON in open or unpowered, or
    OFF in closed, changes C dv/dt (R_aux on or off the capacitor), so K is
    in v's dynamic equation in every mode, where R_load is too: neither is
    told from the other structurally, in any mode; K is told from R_aux (in
    open, where R_aux is in no equation), R_aux not from K (closed: the same
    equation). S stuck OFF cuts the supply in open and closed (i no state:
    i's and v's equations change) and leaves unpowered as it is (not
    detected there). Its signatures are "?" where it acts (either way), so
    qualitatively K is told from nothing and nothing from K (it acts in
    every mode), S from nothing, and only what moves a sensor in unpowered
    (R_load and v_C's offset; R_aux is off the circuit there) is told from
    S, by the mode S leaves as it is; the quantitative level (bgc
    distinguish through the guards' run) tells K from R_load, which neither
    other level can."""
    r = analyse(ROOT / "docs" / "examples" / "relay.yaml", steps=1000)
    assert r.faults == ("K", "R_aux", "R_load", "S", "v_C_offset")
    assert r.targets[0] == r.targets[3] == "switch" and r.subjects[0] == "K"
    k, aux, load_, s, off = range(5)
    for mode in ("open", "closed", "unpowered"):
        structural = r.by_mode[mode][0]
        assert structural.detectable[k] and not structural.isolable[k][load_] and not structural.isolable[load_][k]
    assert r.by_mode["unpowered"][0].detectable[s] is False and r.by_mode["open"][0].detectable[s]
    S, Q, N = (r.get(name) for name in ("structural", "qualitative", "quantitative"))
    assert S.isolable[k][aux] and not S.isolable[aux][k] and S.isolable[k][s] and S.isolable[s][k]
    assert not any(Q.isolable[k]) and not any(Q.isolable[i][k] for i in range(5))
    assert not any(Q.isolable[s]) and [Q.isolable[i][s] for i in range(5)] == [False, False, True, False, True]
    assert N.detectable[k] and N.detectable[s] and N.isolable[k][load_]
    assert ("K", "R_load") in r.more("quantitative", "structural")


@pytest.mark.slow
def test_a_sensor_placed_across_the_relays_modes_reads_its_stuck_contact(tmp_path):
    """Placement on a model with modes (docs/examples/relay.yaml): a sensor
    reads its bond variable in every mode where it reads something, or where
    a switch stuck there changes it, and a set is enough when, across the
    modes, it detects and tells apart what every candidate does. By hand: K
    (the relay's contact, stuck either way) and R_load are both in the
    capacitor's equation in every mode (C dv/dt = i - v/R_load [- v/R_aux
    with K closed]; unpowered, no i), so no structure of the two sensors (v
    and i) tells them apart: of the 20 ordered pairs of the 5 faults, K from
    R_load, R_load from K, R_aux from K and R_aux from R_load are not told
    now (16). A sensor on R_aux's current f9 (v/R_aux with K closed, else 0;
    K stuck ON makes it read in open and unpowered, K stuck OFF silences it
    in closed: its reading holds K's fault in every mode) gives all four:
    the one sensor enough, of cost 1. A sensor on R_load's current f7 =
    v/R_load gives three (not R_aux from K, both then only in C's equation
    and f9's absent). R_aux from K is a structural separation: both move f9
    the same way, so the data may tell them apart only by the change's size.
    The model written with f9, compiled afresh in every mode with its stuck
    configurations, tells every pair apart structurally."""
    relay = ROOT / "docs" / "examples" / "relay.yaml"
    r = analyse(relay, quantitative=False, place_sensors=True)
    p = r.placement
    assert p.sets == (("f9",),) and p.cost == 1.0
    assert len(p.now[1]) == 16 and len(p.reachable[1]) == 20  # 5 faults: 20 ordered pairs, 4 untold now
    assert str(next(c.expr for c in p.candidates if c.name == "f9")) == \
        "0 in open; e6/R_aux in closed; 0 in unpowered"  # read in every mode: 0 but for K stuck
    from conftest import bgc_cli

    out = tmp_path / "relay_f9.yaml"
    done = bgc_cli("analyse", str(relay), "--no-quantitative", "--place-sensors", "--write", str(out))
    assert done.returncode == 0, done.stderr
    again = analyse(out, quantitative=False).get("structural")
    assert all(again.detectable) and len(again.pairs()) == 20


def test_a_reading_whose_terms_cancel_is_sized_by_its_largest_term():
    """A sensor on tank 1's net flow f2 = f_in - (e2 - e7)/R12 - e2/R10 reads 0 at the two tanks'
    steady state (P1 = 20/9, P2 = 4/3): its noise, a fraction of its size, is a fraction of its largest
    term, e2/R12 = 10/9, not of the rounding left of the cancellation (the sensor
    `bgc analyse --place-sensors` proposed had a std of 1e-10)."""
    text = (ROOT / "models" / "two_tank.yaml").read_text().replace(
        "measurements:\n", "measurements:\n  net1: {expr: f2, noise: 0.02}\n")
    c = compile_model("two_tank_net.yaml", text=text)
    j = c.equations.outputs.index("net1")
    assert abs(c.numerics.y0[j]) < 1e-6
    assert c.numerics.y_scale[j] == pytest.approx(2.2222222 / 2.0, rel=1e-12)
    assert c.numerics.noise.measurement[j] == pytest.approx(0.02 * 2.2222222 / 2.0, rel=1e-12)
    others = [k for k in range(len(c.equations.outputs)) if k != j]
    whole = compile_model(ROOT / "models" / "two_tank.yaml")
    assert [c.numerics.y_scale[k] for k in others] == list(whole.numerics.y_scale)


def test_placed_sets_are_ordered_by_what_the_quantitative_level_tells():
    """placement.checked orders the cheapest sets (equal in cost and
    structure) by the quantitative level's count of ordered pairs told
    apart, then of faults detected, a tie keeping the order found."""
    from bgc.analysis.placement import Placement, checked

    p = Placement((("a",), ("b",), ("c",), ("d",)), 1.0, (), (frozenset(), frozenset()),
                  (frozenset(), frozenset()), ())
    q = checked(p, [(3, 5), (4, 6), (4, 5), (3, 6)], (2, 2))
    assert q.sets == (("b",), ("d",), ("c",), ("a",)) and q.checked == ((4, 6), (3, 6), (4, 5), (3, 5))
    assert q.checked_now == (2, 2)


def test_the_sets_placed_are_checked_by_bgc_distinguish():
    """The DC motor (tests/data/models/dc_motor.yaml): b and k are not told
    apart by their signatures; one sensor on the motor's torque (e5 = k i)
    or on the friction's (e7 = b w) splits them. With the quantitative
    level, each set is checked by bgc distinguish of the model with it: the
    three faults detected and all six ordered pairs told apart (the most
    three faults allow), as the model as it is already does at a 30 %
    change; with --no-quantitative nothing is checked."""
    r = analyse(ROOT / "tests" / "data" / "models" / "dc_motor.yaml", place_sensors=True)
    p = r.placement
    assert set(p.sets) == {("e5",), ("e7",)} and p.checked == ((3, 6), (3, 6)) and p.checked_now == (3, 6)
    assert "checked by bgc distinguish" in render.analysis_text(r)
    assert r.to_dict()["placement"]["quantitative"] == {"now": {"detected": 3, "pairs": 6},
                                                         "sets": [{"detected": 3, "pairs": 6}] * 2}
    assert analyse(ROOT / "tests" / "data" / "models" / "dc_motor.yaml", quantitative=False,
                   place_sensors=True).placement.checked is None
