"""The RO plant with its three valve settings (models/ro_hybrid.yaml, the
guards; models/ro_hybrid_valve.yaml, the valve in the data): each setting's
equations against what the bond graph gives by hand, and a simulated cycle."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import sympy

import bgc
from bgc import pipeline
from bgc.analysis import hybrid
from bgc.analysis.simulate import SimulationOptions

from conftest import session

#: Simulated cycles of the RO: the full suite's (make test), not make check's.
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
VALVE = ROOT / "models" / "ro_hybrid_valve.yaml"
e6, e13, f3, f22, e27 = sympy.symbols("e6 e13 f3 f22 e27")
R_pipe, R_back, R_aes, R_brine, m2 = sympy.symbols("R_pipe R_back R_aes R_brine m2")


@pytest.fixture(scope="module")
def ro():
    h = pipeline.check_model(ROOT / "models" / "ro_hybrid.yaml")
    return h, {m.name: m.equations for m in h.modes}


def test_setting_1_is_the_shipped_primary_mode(ro):
    """models/ro.yaml is setting 1: the same states and the same equations
    (the back-flow pipe's flow f31, which also drives the conductivity, is 0
    with its junction OFF)."""
    _, eq = ro
    single = pipeline.compile_model(ROOT / "models" / "ro.yaml").equations
    primary = eq["primary"]
    assert primary.states == single.states
    for a, b in zip(primary.rhs, single.rhs):
        assert sympy.simplify(a - b) == 0
    assert [sympy.simplify(a - b) for a, b in zip(primary.output_exprs, single.output_exprs)] == [0] * 4


def test_each_setting_returns_the_brine_its_own_way(ro):
    """By hand: the loop flow f10 is (e6 + m2 f22 - e13)/R_pipe with the pump
    on (the gyrator's boost) and (e6 - e13)/R_pipe with it off (purge: f22 is
    0 and no state); the brine leaves the membrane through R_brine in
    setting 1, through R_back in setting 2 (both into the reservoir) and
    through R_aes to the AES (zero pressure) in purge."""
    _, eq = ro
    v = {name: dict(e.variables) for name, e in eq.items()}
    on, off = (e6 + m2 * f22 - e13) / R_pipe, (e6 - e13) / R_pipe
    assert sympy.simplify(v["primary"]["f10"] - on) == 0 and sympy.simplify(v["secondary"]["f10"] - on) == 0
    assert sympy.simplify(v["purge"]["f10"] - off) == 0
    assert eq["purge"].states == ("f3", "e6", "e13", "e27") and v["purge"]["f22"] == 0
    assert sympy.simplify(v["primary"]["f18"] - (e13 - e6) / R_brine) == 0 and v["primary"]["f31"] == 0
    assert sympy.simplify(v["secondary"]["f31"] - (e13 - e6) / R_back) == 0 and v["secondary"]["f18"] == 0
    assert sympy.simplify(v["purge"]["f34"] - e13 / R_aes) == 0 and v["purge"]["f18"] == v["purge"]["f31"] == 0


def test_the_plant_cycles_through_its_settings_by_its_guards(ro):
    h, _ = ro
    nums = h.numerics()
    run = hybrid.simulate(h, nums, SimulationOptions(steps=400, seed=2))
    order = [(w.source, w.target, w.kind) for w in run.switches]
    assert order[:3] == [("primary", "secondary", "autonomous"), ("secondary", "purge", "timed"),
                         ("purge", "primary", "autonomous")]
    assert len(order) >= 6 and all(a[1] == b[0] for a, b in zip(order, order[1:]))
    back = [w for w in run.switches if w.target == "primary"]
    k = np.searchsorted(run.result.time, back[0].time)  # the row at the switch: K reset to K0
    assert run.result.states[k, run.result.state_names.index("e27")] == pytest.approx(12000.0, abs=50.0)
    timed = [w for w in run.switches if w.kind == "timed"]
    entered = [w.time for w in run.switches if w.target == "secondary"]
    assert [round(w.time - t0, 9) for w, t0 in zip(timed, entered)] == [30.0] * len(timed)


def test_the_valve_variant_follows_the_schedule_it_is_given():
    h = pipeline.check_model(ROOT / "models" / "ro_hybrid_valve.yaml")
    nums = h.numerics()
    schedule = hybrid.parse_schedule("secondary@50,purge@80,primary@90", h.model.modes.names)
    run = hybrid.simulate(h, nums, SimulationOptions(steps=120, seed=1), schedule)
    assert [(w.time, w.target) for w in run.switches] == [(50.0, "secondary"), (80.0, "purge"), (90.0, "primary")]
    assert list(np.unique(run.modes[49:79])) == [2] and list(np.unique(run.modes[79:89])) == [3]


def test_bgc_simulate_from_python_takes_a_model_with_modes():
    import bgc

    sim = bgc.simulate("models/ro_hybrid_valve.yaml", "R_pipe:abrupt:20@100", seed=1, steps=200,
                       modes="secondary@50,purge@80,primary@90")
    assert sim.mode_names == ("primary", "secondary", "purge")
    assert [(w.time, w.source, w.target, w.kind) for w in sim.switches] == [
        (50.0, "primary", "secondary", "controlled"), (80.0, "secondary", "purge", "controlled"),
        (90.0, "purge", "primary", "controlled")]
    assert sim.modes[48:51].tolist() == [1.0, 2.0, 2.0] and sim.truth["hypothesis"] == "R_pipe_abrupt"
    assert bgc.simulate("models/two_tank.yaml", seed=1, steps=10).modes is None
    with pytest.raises(bgc.Error, match=r"modes='a@1', and the model has no modes \(drop modes=\)"):
        bgc.simulate("models/two_tank.yaml", seed=1, steps=10, modes="a@1")
    with pytest.raises(ValueError, match=r"bgc.simulate: modes 'closed' is no mode of the model"):
        bgc.simulate("models/ro_hybrid_valve.yaml", seed=1, steps=10, modes="closed@1")


#: The valve RO cycled twice through its three settings (controlled: the valve in the data).
CYCLES = "secondary@60,purge@100,primary@120,secondary@180,purge@220,primary@240"


@pytest.fixture(scope="module")
def valve():
    """The valve RO's session on NumPy, opened once for the simulations and
    diagnoses below, which are not about opening the model:
    ``bgc.simulate(valve, ...)`` and ``bgc.diagnose(valve, ...)`` give what
    they give of the model file (the session's noise levels are the
    model's), its check and each mode's numerics made once, not per call."""
    return session(VALVE, backend="numpy")


def test_the_cycling_valve_ro_raises_no_alarm_at_its_switches(valve):
    """One fault-free run (seed 11; a second seed ran the same path): the rate over 100 runs at two
    noise levels is bench/hybrid_false_alarms.py's."""
    sim = bgc.simulate(valve, seed=11, steps=300, modes=CYCLES)
    assert len(sim.switches) == 6
    report = bgc.diagnose(valve, data=sim)
    assert report.diagnosis.verdict == "no fault", report.diagnosis.candidates


@pytest.mark.long
def test_a_pipe_clogging_in_the_second_cycle_is_named(valve):
    """R_pipe clogs from t = 140 (the second cycle's primary setting) and is
    named. The record ends at 250, ten samples past the second cycle's
    return to primary at 240 (the whole second cycle, its switches at 180,
    220 and 240 after the onset, is in it); the samples of the third cycle
    after that are not needed to name the fault."""
    sim = bgc.simulate(valve, "R_pipe:incipient:0.5@140", seed=4, steps=250, modes=CYCLES)
    assert [w.time for w in sim.switches] == [60.0, 100.0, 120.0, 180.0, 220.0, 240.0]
    d = bgc.diagnose(valve, data=sim).diagnosis
    assert d.verdict == "isolated" and d.candidates == ("R_pipe_incipient",), (d.verdict, d.candidates)
    assert d.detection.step > 140
