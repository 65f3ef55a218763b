"""A switch that moves by itself (``uncommanded_on``, ``uncommanded_off``): at
its onset the switch turns ON, or OFF, though its mode asks for the other
state, and stays so until a mode asks for it in that state (the controller's
next command of the switch), from when it follows the modes again. Its
truth simulator, its generated fault model, its DBN, and the diagnosis that
tells it from a stuck switch once the controller commands the switch again,
all against the plant of docs/examples/switched_rc.yaml derived by hand:

    S ON  (mode closed): C dv/dt = (V - v)/R_s - v/R_load,   i_s = (V - v)/R_s
    S OFF (mode open):   C dv/dt = -v/R_load,                i_s = 0

v = e5 the capacitor's voltage from rest, i_s = f2 the supply's current, so
that with the switch's state s constant from time a, v(t) = v_inf + (v(a) -
v_inf) exp(-(t - a)/tau): ON tau = C R_s R_load/(R_s + R_load) = 0.8 s and
v_inf = V R_load/(R_s + R_load) = 8 V; OFF tau = R_load C = 4 s and v_inf = 0.

The controller's schedule throughout: closed from 0, open at 5 s, closed at
15 s, open at 22 s (the run file's mode column says it). Where the switch
is, by hand, for each fault:

    no fault                 ON [0, 5)  OFF [5, 15)  ON [15, 22)  OFF [22, ...)
    S:uncommanded_off@2      ON [0, 2)  OFF [2, 15)  ON [15, 22)  OFF [22, ...)   (open at 5 asks OFF: it ends)
    S:stuck_off@2            ON [0, 2)  OFF [2, ...)
    S:uncommanded_on@2       as no fault (closed asks ON already: nothing moves)
    S:uncommanded_on@7       ON [0, 5)  OFF [5, 7)   ON [7, 22)   OFF [22, ...)   (closed at 15 asks ON: it ends)
    S:uncommanded_on@4.95    as no fault (closed still asks ON at 4.95)
    S:uncommanded_on@5       ON [0, 22)              OFF [22, ...)   (at the command's own sample: it stays ON)

The diagnoses read data from solve_ivp on the same equations, not from bgc's
simulator.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import bgc
from bgc.analysis import track
from bgc.compiler import modes
from bgc.compiler.hybrid_dbn import across_modes
from bgc.compiler.load import load
from bgc.compiler.validate import validate
from bgc.data import runs
from bgc.diagnosis.static_posterior import fault_start
from bgc.filters.cubature import nominal_track, run_bank
from bgc.model.protocol import PLACES, nominal_model, onset_transition

ROOT = Path(__file__).resolve().parent.parent
MODEL = ROOT / "docs" / "examples" / "switched_rc.yaml"
V, R_S, C, R_LOAD = 10.0, 1.0, 1.0, 4.0
DT, STEPS = 0.05, 600
#: The sensors' noise stds the model declares (``noise: 0.02`` of each reading's scale; the package's
#: MEASUREMENT_STD, checked below): the data are made at them.
NOISE = {"v_C": 0.16, "i_s": 0.2}
SCHEDULE = ((0.0, "closed"), (5.0, "open"), (15.0, "closed"), (22.0, "open"))
MODES = "open@5,closed@15,open@22"
NUMBER = {"closed": 1, "open": 2}
NOMINAL = ((0.0, True), (5.0, False), (15.0, True), (22.0, False))
#: Where the switch is, by hand (module docstring): (from time, ON) pieces.
BY_HAND = {
    "none": NOMINAL,
    "S:uncommanded_off@2": ((0.0, True), (2.0, False), (15.0, True), (22.0, False)),
    "S:stuck_off@2": ((0.0, True), (2.0, False)),
    "S:uncommanded_on@2": NOMINAL,
    "S:uncommanded_on@7": ((0.0, True), (5.0, False), (7.0, True), (22.0, False)),
    "S:uncommanded_on@4.95": NOMINAL,
    "S:uncommanded_on@5": ((0.0, True), (22.0, False)),
    "S:uncommanded_off@16.5": ((0.0, True), (5.0, False), (15.0, True), (16.5, False)),
    "S:stuck_off@16.5": ((0.0, True), (5.0, False), (15.0, True), (16.5, False)),
}


def _at(pieces, t: float):
    """The piece's value at time ``t`` (the last whose start is at or before it)."""
    return [value for start, value in pieces if start <= t + 1e-9][-1]


def exact(pieces, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """v and i_s at ``times`` from rest, the switch ON or OFF by ``pieces``,
    by the closed form of the module docstring (a sample at a change sees
    the switch's new state: its row holds the state after the changes due
    at its time)."""
    on_tau, on_inf = C * R_S * R_LOAD / (R_S + R_LOAD), V * R_LOAD / (R_S + R_LOAD)
    off_tau = R_LOAD * C
    v = np.empty(len(times))
    start, value = 0.0, 0.0
    edges = [a for a, _ in pieces[1:]] + [math.inf]
    k = 0
    for j, t in enumerate(times):
        while t > edges[k] + 1e-12:  # carry v to the next change
            on = _at(pieces, start)
            tau, inf = (on_tau, on_inf) if on else (off_tau, 0.0)
            value = inf + (value - inf) * math.exp(-(edges[k] - start) / tau)
            start = edges[k]
            k += 1
        on = _at(pieces, start)
        tau, inf = (on_tau, on_inf) if on else (off_tau, 0.0)
        v[j] = inf + (value - inf) * math.exp(-(t - start) / tau)
    current = np.array([(V - x) / R_S if _at(pieces, t) else 0.0 for t, x in zip(times, v)])
    return v, current


def solved(scenario: str, r_load: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """v and i_s at the samples, the switch as ``BY_HAND[scenario]`` says, by solve_ivp piece by piece;
    ``r_load``: (onset, size), R_load that much higher from the onset on (a step of the load)."""
    pieces = BY_HAND[scenario]
    times = DT * np.arange(1, STEPS + 1)
    cuts = sorted({a for a, _ in pieces} | ({r_load[0]} if r_load else set()) | {float(times[-1]) + DT})
    v = np.empty(STEPS)
    x = 0.0
    for a, b in zip(cuts[:-1], cuts[1:]):
        on = _at(pieces, a)
        r = R_LOAD + (r_load[1] if r_load and a >= r_load[0] - 1e-12 else 0.0)
        inside = (times >= a - 1e-9) & (times < b - 1e-9)
        sol = solve_ivp(lambda _, y, on=on, r=r: [((V - y[0]) / R_S if on else 0.0) / C - y[0] / (r * C)], (a, b),
                        [x], dense_output=True, rtol=1e-11, atol=1e-13)
        v[inside] = sol.sol(times[inside])[0]
        x = float(sol.sol(b)[0])
    return v, np.array([(V - x) / R_S if _at(pieces, t) else 0.0 for t, x in zip(times, v)])


def run_text(scenario: str, seed: int, r_load: tuple[float, float] | None = None, truth: bool = False) -> str:
    """A run file of the plant with the switch as ``BY_HAND[scenario]`` says (:func:`solved`, ``r_load``
    its step of the load), with the sensors' noise; ``truth``: the capacitor's voltage (the model's state
    e5) beside the readings."""
    times = DT * np.arange(1, STEPS + 1)
    v, i_s = solved(scenario, r_load)
    rng = np.random.default_rng(seed)
    lines = ["time,mode,u:V,y:v_C,y:i_s" + (",x:e5" if truth else "")]
    for t, a, b, x in zip(times, v + NOISE["v_C"] * rng.standard_normal(STEPS),
                          i_s + NOISE["i_s"] * rng.standard_normal(STEPS), v):
        lines.append(f"{t:.10g},{NUMBER[_at(SCHEDULE, t)]},{V},{float(a)!r},{float(b)!r}"
                     + (f",{float(x)!r}" if truth else ""))
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("scenario", sorted(BY_HAND))
def test_the_closed_form_is_solve_ivps(scenario):
    """The closed form the tests use, against solve_ivp on the equations (the reference's own check)."""
    times = DT * np.arange(1, STEPS + 1)
    for a, b in zip(exact(BY_HAND[scenario], times), solved(scenario)):
        assert np.max(np.abs(a - b)) < 1e-8


@pytest.mark.parametrize("scenario", ["S:uncommanded_off@2", "S:stuck_off@2", "S:uncommanded_on@2",
                                      "S:uncommanded_on@7", "S:uncommanded_on@4.95", "S:uncommanded_on@5"])
def test_the_truth_simulator_moves_the_switch_until_the_controller_asks_for_it_so(scenario):
    """bgc's truth simulator (no process noise) against the closed form for
    the switch's pieces by hand: v to 1e-6, and i_s (a sensor of no noise
    here) zero exactly where the switch is OFF."""
    sim = bgc.simulate(MODEL, scenario, steps=STEPS, process_noise=0.0, measurement_noise=1e-12, modes=MODES, seed=3)
    v, current = exact(BY_HAND[scenario], sim.time)
    assert np.max(np.abs(sim.run.states["e5"] - v)) < 1e-6
    y = sim.run.measurements["i_s"]
    assert np.max(np.abs(y - current)) < 1e-5
    assert [NUMBER[_at(SCHEDULE, t)] for t in sim.time] == list(sim.modes)


def test_an_onset_outside_the_run_is_refused_as_on_a_plant_of_one_mode():
    """30 s of data: a fault at 40 s (a switch's or a parameter's) is refused in one line, as a model
    of one mode refuses it (the simulator of a model with modes ran it as no fault)."""
    for scenario in ("S:uncommanded_off@40", "R_load:abrupt:1@40"):
        with pytest.raises(bgc.ArgumentValueError, match="onset 40 is outside the run"):
            bgc.simulate(MODEL, scenario, steps=STEPS, modes=MODES)


@pytest.fixture(scope="module")
def session():
    return bgc.open(MODEL, backend="numpy")


@pytest.mark.parametrize("name, onset, scenario, flagged", [
    ("S_uncommanded_off", 2.0, "S:uncommanded_off@2", (2.0, 5.0)),  # until the controller opens S at 5 s
    ("S_uncommanded_off", 7.0, "none", (7.0, 7.0 + DT)),  # open asks OFF already: the onset sample only
    ("S_uncommanded_on", 4.95, "none", (4.95, 5.0)),  # closed asks ON still
    ("S_uncommanded_on", 5.0, "S:uncommanded_on@5", (5.0, 15.0)),  # at the command's own sample
])
def test_the_generated_flag_clears_when_a_mode_asks_for_the_switch_so(session, name, onset, scenario, flagged):
    """A generated model stepped by hand on the data's mode column as the
    filters step it: the nominal cloud lifted into the fault model before
    the transition into the onset sample (``augment``), the switch's fault
    placed within that transition (``onset_transition``: a switch fails at
    any instant; its one particle at the first of the PLACES places, half a
    PLACES-th of the step before the sample), then the model's own steps.
    Its flag is set over ``flagged`` (by hand: until a mode asks for the
    switch where the fault put it; only the onset sample where the mode asks
    for it already) and its v_C follows the closed form of the switch's
    pieces by hand, the fault's piece from that place."""
    package = session.package
    m = package.MODELS[name]
    assert dict(zip(m.OUTPUTS, m.MEASUREMENT_STD)) == pytest.approx(NOISE)
    assert m.STATES[-1] == "S_uncommanded" and m.STATE_KINDS[-1] == "switch"
    nominal = nominal_model(package)
    times = DT * np.arange(1, STEPS + 1)
    theta = np.asarray(m.THETA, dtype=float)
    y_row = list(m.OUTPUTS).index("v_C")
    x = np.array(nominal.X0, dtype=float)[:, None].copy()
    x[nominal.STATES.index("e5")] = 0.0
    flags, readings = [], []
    model = nominal  # the fault model from the onset on
    for t in times:
        u = np.array([V, NUMBER[_at(SCHEDULE, t)]], dtype=float)
        if abs(t - onset) < 1e-9:
            model, x = m, m.augment(x, np.random.default_rng(0))
            onset_transition(m, x, u, theta)
        else:
            x = model.predict(x, u, theta, model.DT)
        flags.append(float(x[-1, 0]) if model is m else 0.0)
        readings.append(float(model.observe(x, u, theta)[y_row, 0]))
    place = onset - 0.5 / PLACES * DT
    pieces = tuple((place if scenario != "none" and abs(start - onset) < 1e-9 else start, on)
                   for start, on in BY_HAND[scenario])
    v, _ = exact(pieces, times)
    assert np.max(np.abs(np.array(readings) - v)) < 1e-4
    assert np.array_equal(np.array(flags) > 0.5, (times >= flagged[0] - 1e-9) & (times < flagged[1] - 1e-9))
    assert list(m._RELEASE) == ([False, True] if name.endswith("off") else [True, False])
    assert not hasattr(package.MODELS["S_stuck_off"], "_RELEASE")


def _bank(package, scenario: str, name: str, onsets_at):
    """Cubature Kalman filters of fault model ``name`` from the samples at times ``onsets_at`` on the
    data of ``scenario`` (seed 1): their log-likelihoods, and the nominal filter's."""
    run = runs.parse_run(run_text(scenario, 1), "switched_rc.csv")
    nominal = nominal_model(package)
    ys, us = track.run_arrays(run, package, "nominal")
    base = nominal_track(nominal, ys, us, len(ys))
    model = package.MODELS[name]
    onsets = [int(np.searchsorted(run.time, t - 1e-9)) for t in onsets_at]
    bank = run_bank(model, ys, us, base, onsets, np.ones(len(onsets)), fault_start(model, base, onsets[0]))
    return np.asarray(bank.loglik, dtype=float), float(base.loglik[len(ys)])


def test_the_cubature_banks_read_the_flag_back_from_each_step(session):
    """S turned ON by itself at 5 s, the sample of the controller's command
    to open it: a bank's cell from that onset explains the data far better
    than no fault; one from the sample before (4.95 s, the mode still
    closed: no change) is the nominal filter, to rounding; one from 2 s (the
    mode closed until 5 s: its flag cleared at once) too."""
    loglik, nominal = _bank(session.package, "S:uncommanded_on@5", "S_uncommanded_on", [2.0, 4.95, 5.0])
    assert loglik[0] == pytest.approx(nominal, rel=1e-9) and loglik[1] == pytest.approx(nominal, rel=1e-9)
    assert loglik[2] > nominal + 1000.0


@pytest.fixture(scope="module")
def compiled():
    model = validate(load(MODEL))
    return model, modes.compile_modes(model)


def test_its_dbn_is_the_stuck_switchs_with_the_mode_releasing_its_indicator(compiled):
    """By hand: S carries the supply's current, so OFF where the mode has it
    ON (closed) it changes v's equation and i_s's reading there, as S stuck
    OFF does; and mode open, which asks S OFF, ends it: an arc mode@t+1 ->
    D@t+1 (release) in open. A stuck switch has no such arc."""
    model, ordered = compiled
    g = across_modes(model, ordered, "S:uncommanded_off").graph
    stuck = across_modes(model, ordered, "S:stuck_off").graph
    faults = {(a, b): d.get("modes") for a, b, d in g.edges(data=True) if d["arc"] == "fault"}
    assert faults == {("D_S_uncommanded_off@t", "e5@t+1"): "closed", ("D_S_uncommanded_off@t+1", "i_s@t+1"): "closed"}
    assert {(a.replace("stuck", "uncommanded"), b): d.get("modes") for a, b, d in stuck.edges(data=True)
            if d["arc"] == "fault"} == faults
    assert g.edges["mode@t+1", "D_S_uncommanded_off@t+1"] == {"arc": "release", "modes": "open"}
    assert not [e for e in stuck.edges(data="arc") if e[2] == "release"]
    on = across_modes(model, ordered, "S:uncommanded_on").graph
    assert on.edges["mode@t+1", "D_S_uncommanded_on@t+1"]["modes"] == "closed"


def _diagnose(session, scenario: str, seed: int):
    return bgc.diagnose(session, runs.parse_run(run_text(scenario, seed), "switched_rc.csv"), seed=1).diagnosis


@pytest.mark.parametrize("scenario, named, seed", [
    ("S:uncommanded_off@2", "S_uncommanded_off", 1),
    ("S:stuck_off@2", "S_stuck_off", 2),
    ("S:uncommanded_on@7", "S_uncommanded_on", 3),
])
def test_the_diagnosis_tells_a_switch_that_moved_from_one_that_stuck_after_the_next_command(session, scenario,
                                                                                             named, seed):
    """Data from solve_ivp: the switch that moved by itself and followed the
    controller from its next command is isolated as such, the stuck one as
    stuck (they differ from the controller's command at 15 s on: closed,
    where the stuck switch stays OFF), each from its onset."""
    d = _diagnose(session, scenario, seed)
    assert d.verdict == "isolated" and d.candidates == (named,), (d.verdict, d.candidates)
    onset = float(scenario.rsplit("@", 1)[1])
    assert abs(d.time_of(d.onset_step) - onset) < DT + 1e-9
    e = d.best.estimate
    assert e.target == "switch" and e.kind == named.split("_", 1)[1]


@pytest.mark.long
@pytest.mark.slow
def test_before_the_next_command_the_two_are_one_and_the_diagnosis_says_ambiguous(session):
    """S OFF at 16.5 s, the controller opening it at 22 s and never closing
    it again in the run: a stuck switch and one that moved are the same
    plant here, so the diagnosis is ambiguous between them, at equal
    priors half and half, and bgc distinguish predicts it (its rival fits
    the truth exactly: E = 0); at 2 s (the command at 15 s to come) it
    predicts them told apart; at 4.95 s, S turned ON where the mode asks it
    ON, it predicts nothing to see."""
    d = _diagnose(session, "S:uncommanded_off@16.5", 4)
    assert d.verdict == "ambiguous" and set(d.candidates) == {"S_stuck_off", "S_uncommanded_off"}
    posterior = {h.name: h.posterior for h in d.hypotheses}
    assert posterior["S_stuck_off"] == pytest.approx(0.5, abs=0.01)
    late = bgc.distinguishability(session, "S:uncommanded_off@16.5", modes=MODES, steps=STEPS)
    rival = next(r for r in late.distinctions[0].rivals if r.name == "S_stuck_off")
    assert abs(rival.expected) < 1e-6 and "S_stuck_off" in late.distinctions[0].group
    early = bgc.distinguishability(session, "S:uncommanded_off@2", modes=MODES, steps=STEPS)
    assert early.distinctions[0].group == ()
    # S turned ON at 4.95 s, while closed still asks it ON: no change at all, nothing to tell from no fault
    none = bgc.distinguishability(session, "S:uncommanded_on@4.95", modes=MODES, steps=STEPS)
    assert abs(none.distinctions[0].divergence) < 1e-9


@pytest.mark.numba
def test_the_compiled_kernels_read_the_flag_back_as_numpy_does(session):
    """The compiled package's cubature step reads the flag back from its own
    layout of the points (point p of cell c in column p C + c): a bank's
    log-likelihoods from onsets before, at and after the controller's
    commands (the flag cleared at once, or at 15 s, or held) are the NumPy
    package's."""
    at = [2.0, 4.95, 5.0, 7.0, 14.95, 15.0, 16.5]
    mine, _ = _bank(session.package, "S:uncommanded_on@5", "S_uncommanded_on", at)
    compiled, _ = _bank(bgc.open(MODEL, backend="numba").package, "S:uncommanded_on@5", "S_uncommanded_on", at)
    np.testing.assert_allclose(compiled, mine, rtol=1e-9)
    assert len(set(np.round(mine, 3))) >= 3  # the onsets differ: the read-back decides
