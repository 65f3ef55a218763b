"""Sensor and actuator faults, and the priors of fault sizes.

The two tanks (tests/test_signatures.py has their relations): f1 = f_in is
imposed by the source Sf_in, de2/dt = (f1 - f3 - f4)/C1, F10 = f3 = e2/R10,
F12 = f5 = (e2 - e7)/R12, de7/dt = (f5 - f8)/C2, F20 = f8 = e7/R20.

Derived by hand for its shipped faults:

* a sensor bias of F12 adds b to F12's reading and to nothing else: F12 jumps
  (order 0, the sign of b), F10 and F20 stay (0 at every order); a drift adds
  c (t - t_f): F12 bends (order 1). In the DBN the offset node is a parent of
  the F12 measurement only (both slices), of no state.
* an actuator bias b of the inflow (the plant receives f_in + b) enters
  de2/dt only: e2 moves at order 1, so F10 = e2/R10 (0, +) and F12 (0, +);
  the rising F10 and F12 slow e2 (order 2: F10 -), e7 moves at order 2 (F20
  (0, 0, +)) and F12 = (e2 - e7)/R12 falls at order 2 (0, +, -). In the DBN
  the offset node is a parent of e2@t+1 only.

Prior: R12 = 2, direction increase, default step prior 0 to +100 % of R12,
i.e. a bias in [0, 2].
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import bgc
from bgc.diagnosis.options import DiagnosisOptions
from bgc.compiler.load import loads
from bgc.compiler.validate import validate
from bgc.errors import BgcError
from bgc.pipeline import compile_model
from bgc import events as ev
from bgc.analysis import simulate as sim

from conftest import ROOT as REPO, bgc_cli, fast_session, session

TWO_TANK = "models/two_tank.yaml"


def one_process(particles: int, seed: int) -> DiagnosisOptions:
    """The options of ``particles=..., seed=...``, the filters in this process."""
    return DiagnosisOptions(particles=particles, seed=seed, workers=1)


@pytest.fixture(scope="module")
def tanks():
    return compile_model(TWO_TANK)


def test_sensor_fault_signatures_of_the_two_tanks_by_hand(tanks):
    s = tanks.signatures
    assert s.measurements == ("F10", "F12", "F20")
    depth = len(s.get("R12+:abrupt").symbols[0])
    zero = "0" * depth
    assert ["".join(m) for m in s.get("F12_offset+:bias").symbols] == [zero, "+" + "0" * (depth - 1), zero]
    assert ["".join(m) for m in s.get("F12_offset-:bias").symbols] == [zero, "-" + "0" * (depth - 1), zero]
    assert ["".join(m) for m in s.get("F12_offset+:drift").symbols] == [zero, "0+" + "0" * (depth - 2), zero]
    assert s.get("F12_offset+:bias").first == ("F12",)


def test_actuator_fault_signature_of_the_two_tanks_by_hand(tanks):
    symbols = ["".join(m)[:3] for m in tanks.signatures.get("f_in_offset+:bias").symbols]
    assert symbols == ["0+-", "0+-", "00+"]
    assert ["".join(m)[:3] for m in tanks.signatures.get("f_in_offset-:bias").symbols] == ["0-+", "0-+", "00-"]


def _arcs(d, kind):
    return {(u, v) for u, v, a in d.graph.edges(data=True) if a["arc"] == kind}


def test_sensor_and_actuator_dbn_nodes_of_the_two_tanks_by_hand(tanks):
    bias = tanks.dbn.get("F12_offset:bias")
    assert _arcs(bias, "fault") == {("delta_F12_offset@t", "F12@t"), ("delta_F12_offset@t+1", "F12@t+1")}
    roles = {n: a["role"] for n, a in bias.graph.nodes(data=True)}
    assert roles["D_F12_offset@t"] == "fault_indicator" and roles["delta_F12_offset@t+1"] == "fault_bias"
    drift = tanks.dbn.get("F12_offset:drift")
    assert _arcs(drift, "fault") == {("F12_offset@t", "F12@t"), ("F12_offset@t+1", "F12@t+1")}
    assert _arcs(drift, "drift") == {("delta_F12_offset@t", "F12_offset@t+1")}
    actuator = tanks.dbn.get("f_in_offset:bias")
    assert _arcs(actuator, "fault") == {("delta_f_in_offset@t", "e2@t+1")}


def test_the_fault_symbols_enter_the_equations_where_they_act(tanks):
    import sympy

    ssm = tanks.equations
    # models/two_tank.yaml: its parameters, then one offset per declared sensor (F10, F12, F20)
    # and the inflow's, sorted by name, each at 0
    assert ssm.parameters == ("C1", "C2", "R10", "R12", "R20", "F10_offset", "F12_offset", "F20_offset",
                              "f_in_offset")
    values = dict(zip(ssm.parameters, ssm.parameter_values))
    assert all(values[p] == 0.0 for p in ssm.parameters[5:])
    y = dict(zip(ssm.outputs, ssm.output_exprs))
    e2, e7, R12, off = sympy.symbols("e2 e7 R12 F12_offset")
    assert sympy.simplify(y["F12"] - ((e2 - e7) / R12 + off)) == 0
    assert all(sympy.Symbol("F12_offset") not in e.free_symbols for e in (y["F10"], y["F20"], *ssm.rhs))
    rhs = dict(zip(ssm.states, ssm.rhs))
    # the inflow's offset acts exactly as the inflow does (de2/dt = (f_in + f_in_offset - ...)/C1), and only there
    assert sympy.simplify(sympy.diff(rhs["e2"], sympy.Symbol("f_in_offset")) - 1 / sympy.Symbol("C1")) == 0
    assert sympy.simplify(sympy.diff(rhs["e2"], sympy.Symbol("f_in")) - 1 / sympy.Symbol("C1")) == 0
    assert sympy.Symbol("f_in_offset") not in rhs["e7"].free_symbols


def test_simulated_sensor_bias_and_drift_add_their_offset_to_their_sensor_only(tanks):
    num = tanks.numerics
    base = sim.simulate(num, sim.SimulationOptions(seed=4))
    for text, offset in (("F12:bias:0.05@60", lambda t: np.where(t >= 60, 0.05, 0.0)),
                         ("F12:drift:0.002@60", lambda t: np.where(t > 60, 0.002 * (t - 60), 0.0))):
        run = sim.simulate(num, sim.SimulationOptions(seed=4, fault=sim.parse_fault(text, num)))
        assert np.array_equal(run.states, base.states)
        assert np.allclose(run.measurements[:, 1] - base.measurements[:, 1], offset(run.time), atol=1e-12)
        assert np.array_equal(run.measurements[:, [0, 2]], base.measurements[:, [0, 2]])
        assert np.allclose(run.parameter, offset(run.time), atol=1e-15)


def test_an_inflow_bias_from_the_start_is_the_plant_fed_that_much_more(tmp_path, tanks):
    text = (REPO / TWO_TANK).read_text()
    assert "f_in: {signal: constant, value: 1.0," in text
    fed = tmp_path / "two_tank.yaml"
    fed.write_text(text.replace("f_in: {signal: constant, value: 1.0,", "f_in: {signal: constant, value: 1.5,"))
    more = compile_model(fed)
    a = sim.simulate(tanks.numerics, sim.SimulationOptions(seed=2, fault=sim.parse_fault("f_in:bias:0.5@0",
                                                                                          tanks.numerics)))
    b = sim.simulate(more.numerics, sim.SimulationOptions(seed=2))
    assert np.allclose(a.states, b.states, rtol=1e-12, atol=1e-12)
    assert np.allclose(a.measurements, b.measurements, rtol=1e-12, atol=1e-12)
    assert np.all(a.inputs == 1.0)  # the run records the command, not what the actuator delivered


@pytest.mark.parametrize("faults, message", [
    ("F12: [abrupt]", "fault kind 'abrupt' does not apply to sensor F12 (a sensor takes: bias, drift, stuck, noise)"),
    ("f_in: [gain, stuck]", "fault kind 'stuck' does not apply to actuator f_in (an actuator takes: bias, drift, gain)"),
    ("f_in: [gain, sudden]", "'sudden' is not valid"),
    ("R12: [bias]", "fault kind 'bias' does not apply to parameter R12"),
    ("R12: {kinds: [abrupt], size: [1.0, 0.5]}", "its low bound is not below its high bound"),
    ("R12: {kinds: [abrupt], direction: increase, size: [-0.5, 1.0]}", "allows changes against the fault's direction"),
    ("R12: {kinds: [abrupt], size: [0.5]}", "must list two numbers [low, high]"),
    ("Q7: [abrupt]", "fault names 'Q7', which is no parameter, measurement or input"),
])
def test_bad_fault_declarations_are_located_errors(faults, message):
    text = (REPO / TWO_TANK).read_text()
    head = text[:text.index("faults:")]
    tail = text[text.index("simulation:"):]
    with pytest.raises(BgcError) as info:
        validate(loads(head + "faults:\n  " + faults + "\n\n" + tail, "two_tank.yaml"))
    assert message in str(info.value)


def test_a_name_the_fault_symbol_needs_is_refused():
    text = (REPO / TWO_TANK).read_text().replace("  R20: {value: 3.0,", "  F12_offset: {value: 1.0}\n  R20: {value: 3.0,")
    with pytest.raises(BgcError) as info:
        validate(loads(text, "two_tank.yaml"))
    assert "'F12_offset' is already declared" in str(info.value)


def test_declared_sizes_and_rates_set_the_prior_in_units_of_the_scale():
    text = (REPO / TWO_TANK).read_text()
    text = text.replace("  R12: {kinds: [abrupt, incipient], direction: increase, prior: 0.02}",
                        "  R12: {kinds: [abrupt, incipient], size: [0, 3.0], rate: [0, 0.01], prior: 0.02}")
    text = text.replace("  F12: {kinds: [bias, drift], prior: 0.02}", "  F12: {kinds: [bias, drift], size: [-0.2, 0.1]}")
    c = compile_model_text(text)
    num = c.numerics
    assert num.fault("R12:abrupt").prior == pytest.approx((0.0, 3.0 * 2.0))
    assert num.fault("R12:incipient").prior == pytest.approx((0.0, 0.01 * 2.0))
    y0 = num.y0[list(c.equations.outputs).index("F12")]
    assert num.fault("F12_offset:bias").prior == pytest.approx((-0.2 * y0, 0.1 * y0))
    assert num.fault("F12_offset:bias").scale == pytest.approx(y0)


def compile_model_text(text: str):
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "two_tank.yaml"
        path.write_text(text)
        return compile_model(path)


def test_prior_scale_widens_and_a_decrease_stays_above_minus_95_percent(tanks):
    wide = compile_model(TWO_TANK, prior_scale=3.0)
    assert wide.numerics.fault("R12:abrupt").prior == pytest.approx((0.0, 3 * 2.0))
    assert tanks.numerics.fault("C1:abrupt").prior == pytest.approx((-1.0, 2.0))  # -50 % to +100 % of C1 = 2
    assert wide.numerics.fault("C1:abrupt").prior == pytest.approx((-0.95 * 2.0, 6.0))


def test_check_and_show_signatures_show_the_priors():
    r = bgc_cli("check", TWO_TANK, cwd=REPO)
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "parameter R12 abrupt: bias 0 to 2 Pa*s/m^3, +0 % to +100 % of |R12| = 2 (default)" in out
    assert "sensor F12 bias: bias" in out and "of F12's nominal reading" in out
    r = bgc_cli("show", "signatures", TWO_TANK, cwd=REPO)
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "priors of the fault magnitudes" in out and "actuator f_in bias: bias" in out


def test_simulate_warns_outside_the_prior_and_outside_the_candidates(tmp_path):
    def run(fault):
        return bgc_cli("simulate", TWO_TANK, "--fault", fault, "-o", tmp_path / "run.csv", cwd=REPO)

    r = run("R12:abrupt:3@60")
    assert r.returncode == 0 and "warning: bias 3 is outside the prior of R12:abrupt in the model (0 to 2)" in r.stderr
    r = run("R12:abrupt:-0.5@60")
    assert r.returncode == 0 and "outside the prior" in r.stderr
    r = run("C1:incipient:0.001@60")
    assert r.returncode == 0 and "lists no fault C1:incipient among its candidates" in r.stderr
    r = run("R12:abrupt:1@60")
    assert r.returncode == 0 and r.stderr == ""


@pytest.fixture(scope="module")
def tank_session():
    return bgc.open(TWO_TANK)


@pytest.mark.slow
def test_a_step_past_the_prior_says_so_and_a_wider_prior_sizes_it():
    """R12 from 2 to 4 (+100 %, the default prior's edge), seed 3; at the
    model's prior on the FAST backend (conftest.fast_session; the slow tier
    only), at the wider prior on NumPy (its package is another, whose kernels
    no other test compiles)."""
    r = bgc.diagnose(fast_session("two_tank"), scenario="R12:abrupt:2@60", seed=3, options=one_process(500, 3))
    d = r.diagnosis
    bounds = [e for e in d.events if isinstance(e, ev.AtPriorBound)]
    assert any(e.hypothesis == "R12_abrupt" and e.side == "high" and e.bound == pytest.approx(2.0) for e in bounds)
    h = next(h for h in d.hypotheses if h.name == "R12_abrupt")
    assert h.estimate.bound == "high"
    from bgc.output import report

    assert any("or more: the model's prior ends there" in line for line in report.plain_words(d))
    wide = bgc.diagnose(session(TWO_TANK, prior_scale=2.0), scenario="R12:abrupt:2@60", seed=3,
                        options=one_process(500, 3))
    w = wide.diagnosis
    assert w.verdict == "isolated" and w.candidates == ("R12_abrupt",)
    assert not any(isinstance(e, ev.AtPriorBound) for e in w.events)
    e = w.estimate
    assert e.low <= 2.0 <= e.high and abs(e.value - 2.0) < 0.05


@pytest.mark.slow
@pytest.mark.parametrize("model, scenario, sensor", [
    ("models/two_tank.yaml", "F12:bias:0.05@75", "F12"),
    ("models/circuit.yaml", "f2:bias:0.6@7", "f2"),
])
def test_a_biased_sensor_is_named_a_sensor_fault_on_the_shipped_plants(model, scenario, sensor):
    """On the FAST backend (conftest.fast_session; the slow tier only). The RO's
    P_memb biased by 30 at t = 165 is docs/commands.md's transcript (tests/test_docs.py
    runs it: the verdict, "sensor P_memb reads ... high since t = 165" and the
    interval holding the truth, as printed there)."""
    r = bgc.diagnose(fast_session(Path(model).stem), scenario=scenario, seed=0, options=one_process(500, 0))
    d = r.diagnosis
    assert d.verdict == "isolated", d.candidates
    e = d.estimate
    assert (e.target, e.subject, e.kind) == ("sensor", sensor, "bias")
    from bgc.output import report

    words = report.plain_words(d)
    assert words and words[0].startswith(f"sensor {sensor} reads ") and " high since t = " in words[0]
    assert e.low <= e.truth <= e.high


@pytest.mark.slow
def test_an_actuator_bias_is_named_an_actuator_fault():
    """On the FAST backend (conftest.fast_session; the slow tier only)."""
    d = bgc.diagnose(fast_session("two_tank"), scenario="f_in:bias:0.4@75", seed=0,
                     options=one_process(500, 0)).diagnosis
    assert d.verdict == "isolated"
    e = d.estimate
    assert (e.target, e.subject) == ("actuator", "f_in") and e.low <= 0.4 <= e.high
    assert math.isclose(e.truth, 0.4)


@pytest.fixture(scope="module")
def stuck_model(tmp_path_factory):
    """The two tanks with F12 also declared ``stuck``."""
    text = (REPO / TWO_TANK).read_text()
    old = "  F12: {kinds: [bias, drift], prior: 0.02}"
    assert old in text
    path = tmp_path_factory.mktemp("stuck") / "two_tank.yaml"
    path.write_text(text.replace(old, "  F12: {kinds: [bias, drift, stuck], prior: 0.02}"))
    return path


def test_a_stuck_sensor_reads_its_value_and_nothing_of_the_plant(stuck_model):
    """By hand: a stuck F12 reads v whatever e2 and e7 do: its fault model's
    F12 has the stuck value as its only parent, F10 and F20 keep theirs; its
    signature is F12 '?' (off the plant in either direction, or not at all
    at rest) and nothing elsewhere; its prior is centred on F12's nominal
    reading 4/9 (-150 % to +150 % of it around it)."""
    c = compile_model(stuck_model)
    d = c.dbn.get("F12:stuck")
    parents = {m: set(d.graph.predecessors(m)) for m in ("F12@t", "F12@t+1", "F10@t")}
    assert parents["F12@t"] == {"delta_F12_stuck@t"} and parents["F12@t+1"] == {"delta_F12_stuck@t+1"}
    assert parents["F10@t"] == {"e2@t"}
    sig = c.signatures.get("F12_stuck+:stuck")
    assert ["".join(m)[0] for m in sig.symbols] == ["0", "?", "0"] and "F12_stuck-:stuck" not in \
        {s.name for s in c.signatures.signatures}
    lo, hi = c.numerics.fault("F12_stuck:stuck").prior
    assert (lo, hi) == pytest.approx((4 / 9 - 1.5 * 4 / 9, 4 / 9 + 1.5 * 4 / 9), rel=1e-6)
    module = {name: text for name, text in c.package.files}["F12_stuck_stuck.py"]
    assert "_y[1] = " in module and "x[2]" in module.split("def observe", 1)[1].split("def ", 1)[0]


@pytest.mark.slow
def test_a_dead_sensor_is_named_stuck_at_zero(stuck_model):
    num = compile_model(stuck_model).numerics
    run = sim.simulate(num, sim.SimulationOptions(seed=1, fault=sim.parse_fault("F12:stuck:0@60", num)))
    after = run.time >= 60
    assert np.all(run.measurements[after, 1] == 0.0) and np.all(run.measurements[~after, 1] != 0.0)
    r = bgc.diagnose(stuck_model, scenario="F12:stuck:0@60", seed=1, options=one_process(500, 1))
    d = r.diagnosis
    assert d.verdict == "isolated" and d.candidates == ("F12_stuck_stuck",)
    from bgc.experiment import metrics

    m = metrics.measure(d, r.run, metrics.Truth("F12_stuck", "stuck", 0.0, 60.0))
    assert m.right and m.covers and m.error is None  # no relative error of a truth of 0 (it divided by zero)
    from bgc.output import report

    assert report.plain_words(d)[0].startswith("sensor F12 is stuck at ")
    assert d.estimate.low <= 0.0 <= d.estimate.high


@pytest.mark.slow
def test_a_fault_the_model_does_not_list_ends_unexplained():
    """R12 falls by 30 % where only its rise is a candidate: the candidate
    that mimics it best (a step of R10 at seed 1) fails the goodness-of-fit
    test and is dropped; so is every other: unexplained. On the FAST backend
    (conftest.fast_session; the slow tier only)."""
    d = bgc.diagnose(fast_session("two_tank"), scenario="R12:abrupt:-0.6@75", seed=1,
                     options=one_process(500, 1)).diagnosis
    assert d.verdict == "unexplained"
    reasons = {e.reason for e in d.events if isinstance(e, ev.Dropped)}
    assert reasons & {"static-test", "wrong-direction"}
    from bgc.output import report

    assert report.plain_words(d)[0].startswith("closest, but not explaining the data: ")


def test_distinguish_says_when_its_scenario_is_outside_the_prior_or_the_candidates(tank_session):
    with pytest.warns(bgc.ScenarioWarning, match="bias 3 is outside the prior of R12:abrupt"):  # Python's, too
        r = bgc.distinguishability(tank_session, "R12:abrupt:3@60", steps=160)
    assert r.warning.startswith("bias 3 is outside the prior of R12:abrupt in the model (0 to 2)")
    from bgc.output import render

    assert "warning: bias 3 is outside the prior" in render.distinguishability_text(r)
    assert bgc.distinguishability(tank_session, "R12:abrupt:1@60", steps=160).warning is None
    with pytest.raises(BgcError) as info, pytest.warns(bgc.ScenarioWarning, match="no fault F12:stuck"):
        bgc.distinguishability(tank_session, "F12:stuck:0@60", steps=160)
    assert "F12:stuck is not a fault candidate of two_tank" in str(info.value)
