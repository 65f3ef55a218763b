"""A logger's outage longer than the diagnosis holds, bridged by a monitor
that is watching (issue 47, point 5: "a clock that jumps (refused or
bridged as a gap, documented)"; bgc.diagnosis.bridge).

The plants are simulated here, not by bgc: the circuit of models/circuit.yaml
by the exact solution of its linear equations (tests/test_mismatch.py, the
matrix exponential over each sample period), the two tanks by scipy's
solve_ivp on the hand-derived equations (tests/two_tank_reference.py). The
plant goes on through the gap at another input (the source or the inflow
moved while nobody logged), so the state after the gap is not the one
before; the expectations are the simulator's truth: no fault, or the fault
put in after the gap, at its time and size. The steps the model is run on
across the gap are derived here from the circuit's matrix, not read from bgc.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import bgc
from bgc import events as ev
from bgc.diagnosis import bridge

from conftest import ROOT, bgc_cli
from test_mismatch import DT, NOMINAL, START, circuit, readings
import two_tank_reference as tanks

CIRCUIT = ROOT / "models" / "circuit.yaml"
TWO_TANK = ROOT / "models" / "two_tank.yaml"
#: Three hours with no row: 216,000 steps of the circuit's 0.05 s, past a clock jump's 100,000.
HOURS3 = 3 * 3600.0


def circuit_rows(seed: int, v_after: float, fault_after: tuple | None = None, before: int = 400,
                 after: int = 400, gap: float = HOURS3, fault_before: float | None = None) -> list[str]:
    """The circuit's rows as a logger's CSV lines: ``before`` rows at V = 10
    from its steady state, no row for ``gap``, then ``after`` rows at V =
    ``v_after`` from where the plant settled at that source (400 unlogged
    steps from its steady state: 20 s, 17 of its slowest time constants);
    ``fault_after`` (seconds after the gap, parameter, factor): that fault
    from then on; ``fault_before`` (a time): R2 at 1.6 times its value from
    then on, through the gap too."""
    rng = np.random.default_rng(seed)
    lines = ["time,u:V,y:f2,y:f6,y:e11"]
    nominal = dict(NOMINAL)

    def run(x, v, t0, n, changes, write):
        for k in range(1, n + 1):
            t = t0 + k * DT
            p = dict(nominal)
            for since, name, factor in changes:
                if t >= since - 1e-9:
                    p[name] = factor * NOMINAL[name]
            e, process, sensor = circuit(p, 1.0)
            x = e[:3, :3] @ x + e[:3, 3] * v + process * rng.standard_normal(3)
            if write:
                y = readings(p, x, v) + sensor * rng.standard_normal(3)
                lines.append(f"{t:.12g}," + ",".join(f"{w:.9g}" for w in (v, *y)))
        return x

    early = [] if fault_before is None else [(fault_before, "R2", 1.6)]
    run(np.array(START), 10.0, 0.0, before, early, True)
    settled = run(np.array(START) * v_after / 10.0, v_after, -1e9, 400, [(-1e10, "R2", 1.6)] if early else [], False)
    t1 = before * DT + gap
    late = list(early) if fault_after is None else [(t1 + fault_after[0], fault_after[1], fault_after[2])]
    run(settled, v_after, t1 - DT, after, [(-1e10, n, f) for _, n, f in early] or late, True)
    return lines


def test_the_model_is_run_on_ten_of_its_slowest_time_constants():
    """168 steps: 10 / 1.1933 / 0.05, the slowest eigenvalue of the circuit's
    matrix (derived here from its parameters) 1.1933 in real part."""
    p = NOMINAL
    a = np.array([[-(1 / p["R2"] + 1 / p["R1"]) / p["C1"], 1 / (p["R2"] * p["C1"]), 0.0],
                  [1 / (p["R2"] * p["C2"]), -1 / (p["R2"] * p["C2"]), -1 / p["C2"]],
                  [0.0, 1 / p["L"], -p["R3"] / p["L"]]])
    slowest = min(-np.linalg.eigvals(a).real)
    expected = math.ceil(10.0 / slowest / DT)
    assert expected == 168
    nominal = bgc.open(CIRCUIT).package.MODELS["nominal"]
    assert bridge.settle_steps(nominal) == expected
    assert bridge.settle_steps(type("M", (), {"EIGENVALUES": ((0.0, 0.0), (1e-3, 0.0)), "DT": 1.0})) == 0


def _monitor(lines, **kw):
    said: list[str] = []
    report = bgc.monitor(CIRCUIT, iter(lines), seed=3, particles=500, events=said.append, **kw)
    return report, said


@pytest.mark.parametrize("v_after", [10.0, 12.0, 7.0])
def test_a_three_hour_outage_while_watching_is_bridged_and_a_healthy_plant_stays_no_fault(v_after):
    report, said = _monitor(circuit_rows(1, v_after))
    d = report.diagnosis
    assert d.verdict == "no fault" and d.detection is None, said
    assert [e for e in d.events if isinstance(e, ev.Bridged)] == [ev.Bridged(20.0, 20.0 + HOURS3, 215999, 168)]
    assert report.run.time[0] == pytest.approx(20.0 + HOURS3)  # the report's record: the rows after the gap
    assert any(line.startswith("t = 10820: no data from t = 20 to t = 10820 (215999 steps") for line in said)


@pytest.mark.slow
@pytest.mark.long
def test_without_running_the_model_on_a_moved_input_would_alarm(monkeypatch):
    """The control: the observer started where it was before the gap, its
    spread widened by the model's initial spread only (no run on), alarms
    or calls the model off at the moved source. The run on is what the
    previous test's verdicts rest on."""
    monkeypatch.setattr(bridge, "SETTLE", 0.0)
    report, said = _monitor(circuit_rows(2, 7.0))
    assert report.diagnosis.verdict != "no fault" or report.diagnosis.detection is not None


@pytest.mark.slow
@pytest.mark.long
def test_a_fault_after_the_outage_is_isolated_at_its_time_and_size():
    """R1 at 1.5 times its value 10 s after the gap, the source moved to 12:
    R1 isolated from t = 10830, +0.5 ohm."""
    report, said = _monitor(circuit_rows(3, 12.0, fault_after=(10.0, "R1", 1.5), after=600))
    d = report.diagnosis
    assert d.verdict == "isolated" and d.candidates[0].startswith("R1_"), said
    assert d.onset == pytest.approx(20.0 + HOURS3 + 10.0, abs=3 * DT)
    e = d.estimate
    assert e.low <= 0.5 <= e.high or abs(e.value - 0.5) < 0.05 * 0.5, e


@pytest.mark.slow
@pytest.mark.long
def test_the_two_tanks_after_a_gap_past_the_memory_with_the_inflow_moved_name_the_fault(tmp_path):
    """40,000 steps with no row (beyond the 18,951 the diagnosis holds, under
    a clock jump's 100,000), the inflow from 1 to 1.3 meanwhile, R12 up by
    0.6 50 s after the gap (solve_ivp): R12 isolated, its onset the first
    sample after the step the fault starts in, its size 0.6."""
    t1 = 200.0 + 20000.0
    rows = tanks.run(5, steps=400) + tanks.run(6, ("R12", 0.6, t1 + 50.0), steps=600, inflow=1.3,
                                               start=tanks.P0 * 1.3, t0=t1 - 0.5)
    data = tanks.write(tmp_path / "tanks.csv", rows, [1.0] * 400 + [1.3] * 600)
    said: list[str] = []
    report = bgc.monitor(TWO_TANK, data, seed=3, particles=500, events=said.append)
    d = report.diagnosis
    bridged = [e for e in d.events if isinstance(e, ev.Bridged)]
    assert len(bridged) == 1 and bridged[0].steps == 39999 and bridged[0].began == 200.0
    assert d.verdict == "isolated" and d.candidates == ("R12_abrupt",), said
    assert d.onset == pytest.approx(t1 + 50.5)
    assert abs(d.estimate.value - 0.6) < 0.06


@pytest.mark.slow
@pytest.mark.long
def test_an_episode_open_at_the_gap_is_closed_on_the_rows_before_it_then_the_gap_bridged():
    """R2 up from t = 19.3, 0.7 s before a three-hour gap: the alarm comes,
    no checkpoint decides it before the gap; the episode closes there (its
    reason the gap), and the monitor watches again after it."""
    lines = circuit_rows(1, 10.0, fault_before=19.3, after=60)
    report, said = _monitor(lines, checkpoint=1.0, episodes=True)
    log = report.fault_log
    assert len(log) >= 1 and log[0].alarm == pytest.approx(19.3, abs=2 * DT), said
    assert log[0].time == pytest.approx(20.0) and log[0].action in ("re-armed", "accommodated")
    if log[0].action == "re-armed":
        assert log[0].reason == "gap"
    assert any("no data from t = 20 to t = 10820" in line for line in said)


@pytest.mark.slow
@pytest.mark.long
def test_without_episodes_an_alarm_open_at_the_gap_stops_with_the_rows_before_it(tmp_path):
    """No episodes: one diagnosis of one record; the gap comes during the
    alarm, so the monitor stops there (exit 1, one line, no traceback), its
    report the diagnosis of the rows before the gap."""
    path = tmp_path / "plant.csv"
    path.write_text("\n".join(circuit_rows(1, 10.0, fault_before=18.0)) + "\n", encoding="utf-8")
    p = bgc_cli("monitor", CIRCUIT, "--data", path, "--seed", "3", "-o", tmp_path / "out")
    assert p.returncode == 1 and "Traceback" not in p.stderr
    assert "plant.csv:402: time 10820 is 215999 steps" in p.stderr.strip().splitlines()[-1]
    assert "an alarm was in progress" in p.stderr
    assert "isolated: R2_abrupt" in p.stdout


@pytest.mark.slow
@pytest.mark.long
def test_a_restart_across_the_gap_gives_the_uninterrupted_runs_report(tmp_path):
    """The state saved before the gap (the input cut there, as a kill would),
    then the whole input again: the same events and verdict as one run."""
    lines = circuit_rows(4, 12.0, fault_after=(3.0, "R2", 1.6), after=160)
    whole, _ = _monitor(lines)
    state = tmp_path / "state"
    _monitor(lines[:401], state=state, state_every=7)
    again, said = _monitor(lines, state=state, state_every=7)
    assert said[0].startswith("resumed from")
    assert again.diagnosis.verdict == whole.diagnosis.verdict == "isolated"
    assert again.diagnosis.events == whole.diagnosis.events
    assert again.diagnosis.estimate == whole.diagnosis.estimate


def test_row_inputs_read_a_row_without_moving_the_sampler():
    from bgc.data.sampler import Sampler

    session = bgc.open(CIRCUIT)
    s = Sampler(session.package.MODELS["nominal"], ("V",), ("f2", "f6", "e11"), "plant.csv")
    s.push(0.05, {"V": 9.0}, {"f2": 1.0, "f6": 1.0, "e11": 1.0})
    held = dict(s.held)
    assert s.row_inputs(10.0, {"V": 11.0}).tolist() == [11.0]
    assert s.row_inputs(10.0, {"V": math.nan}).tolist() == [9.0]  # an empty cell: the input held
    assert s.held == held


#: The shipped example of an outage (docs/commands.md, "A logger that was down"): made by :func:`outage_lines`.
OUTAGE = ROOT / "docs" / "examples" / "tank_outage.csv"


def outage_lines() -> str:
    """docs/examples/tank_outage.csv: the two tanks by solve_ivp, 300 rows
    of 0.5 s at f_in = 1, no row for six hours while the inflow moved to
    1.3, then 300 rows with R12 up by 0.6 from t = 21800."""
    t1 = 150.0 + 6 * 3600.0
    rows = tanks.run(11, steps=300) + tanks.run(12, ("R12", 0.6, t1 + 50.0), steps=300, inflow=1.3,
                                                start=tanks.P0 * 1.3, t0=t1 - 0.5)
    text = ["# two tanks of models/two_tank.yaml, by scipy's solve_ivp on its hand-derived equations",
            "# (tests/two_tank_reference.py, seeds 11 and 12): f_in = 1 to t = 150, no row for six hours",
            "# while f_in moved to 1.3, R12 up by 0.6 from t = 21800 (tests/test_bridge.py makes this file)",
            "time,u:f_in,y:F10,y:F12,y:F20"]
    for (t, a, b, c), u in zip(rows, [1.0] * 300 + [1.3] * 300):
        text.append(f"{t:.12g},{u:g},{a:.9g},{b:.9g},{c:.9g}")
    return "\n".join(text) + "\n"


def test_the_shipped_outage_example_is_this_simulators_run():
    assert OUTAGE.read_text(encoding="utf-8") == outage_lines()


#: The level plant's slowest time constant, by hand: draining, C_t p' = -p/R_out, 1/(R_out C_t) = 1/3 per
#: second, which its generated mode module writes to 10 digits (-0.3333333333): ten of them, in steps of 0.05 s,
#: ceil(10 / 0.3333333333 / 0.05) = ceil(600.00000006) = 601.
LEVEL_SETTLE = 601


def _level_lines(times, y_p, y_q) -> list[str]:
    import hybrid_reference as hybrid

    return ["time,u:E,y:p,y:q_out"] + [f"{t:.12g},{hybrid.LEVEL_E},{float(a)!r},{float(b)!r}"
                                       for t, a, b in zip(times, y_p, y_q)]


@pytest.mark.slow
@pytest.mark.long
def test_a_plant_whose_mode_is_read_from_the_data_is_bridged_from_its_settled_course():
    """The level plant of docs/examples/level.yaml (its pump switched by the
    tank's level; the data have no mode column), by solve_ivp
    (tests/hybrid_reference.py), its clock 10^5 s ahead from its 301st row,
    the pump's mode another there than at the row before: no fault; the
    observer started anywhere on the course the model settles into (its
    slowest time constant ten times over, LEVEL_SETTLE steps), the mode one
    of the two (its cycle, of about 3 s, visits both in the course's second
    half); "the data have no mode column" said once."""
    import hybrid_reference as hybrid

    times, modes, y_p, y_q, _ = hybrid.level_run(0)
    assert modes[299] != modes[300]
    shift = np.where(np.arange(len(times)) >= 300, 1e5, 0.0)
    said: list[str] = []
    report = bgc.monitor(ROOT / "docs" / "examples" / "level.yaml", iter(_level_lines(times + shift, y_p, y_q)),
                         seed=3, events=said.append)
    d = report.diagnosis
    assert d.verdict == "no fault" and d.detection is None, said
    assert [e for e in d.events if isinstance(e, ev.Bridged)] == [
        ev.Bridged(15.0, 1e5 + 15.05, 2000000, LEVEL_SETTLE, True, ("filling", "draining"))]
    assert sum("the data have no mode column" in line for line in said) == 1, said
    assert sum("the mode one of filling, draining" in line for line in said) == 1, said


def _cycling_lines(seed: int) -> list[str]:
    """The level plant's rows: 300 of one run, no row for 10^5 s, then those of
    another run from a point of its cycle where the mode is another and the
    level a quarter of the band or more away (the test below)."""
    import hybrid_reference as hybrid

    times, modes, y_p, y_q, _ = hybrid.level_run(seed)
    _, after_modes, after_p, after_q, _ = hybrid.level_run(seed + 10)
    start = next(k for k in range(300, 600) if after_modes[k] != modes[299] and abs(after_p[k] - y_p[299]) > 0.1)
    later = 1e5 + hybrid.LEVEL_DT * np.arange(600 - start)
    return _level_lines(np.concatenate([times[:300], later]), np.concatenate([y_p[:300], after_p[start:]]),
                        np.concatenate([y_q[:300], after_q[start:]]))


@pytest.mark.slow
@pytest.mark.long
@pytest.mark.parametrize("seed", [1, 2])
def test_a_cycling_plant_found_elsewhere_in_its_cycle_after_an_outage_is_watched_without_an_alarm(seed):
    """The level plant by solve_ivp, 300 rows, then nothing for 10^5 s, then
    rows of another run of it (its own noise) from another point of its cycle
    (the mode other than at the last row, the level a quarter of the band
    or more away): the plant cycles between p = 0.4 and 0.8 all the while,
    and where in its cycle it is after the outage nothing before it says.
    Started from its last estimate, the observer met the first row 25
    standard deviations off and the monitor said a mismatch; started
    anywhere on its settled course, in either mode, no fault."""
    said: list[str] = []
    report = bgc.monitor(ROOT / "docs" / "examples" / "level.yaml", iter(_cycling_lines(seed)), seed=3,
                         events=said.append)
    d = report.diagnosis
    assert d.verdict == "no fault" and d.detection is None, said
    assert [(e.ran, e.settled) for e in d.events if isinstance(e, ev.Bridged)] == [(LEVEL_SETTLE, True)]
    # the mode before the outage is not known: the first mode read after it is no change of mode
    assert not [e for e in d.events if isinstance(e, ev.ModeRead) and e.step == 0], said


def _thermostat_lines(seed: int) -> list[str]:
    """The thermostat's rows: 300 of one run, the clock 10^6 s ahead, then those of
    another run from a sample whose valve is the other way (the test below)."""
    import hybrid_reference as hybrid

    times, modes, readings = hybrid.thermostat_run(seed)
    _, after_modes, after_readings = hybrid.thermostat_run(seed + 20)
    start = next(k for k in range(300, 600) if after_modes[k] != modes[299])
    later = 1e6 + hybrid.THERMO_DT * np.arange(600 - start)
    lines = ["time,u:T_s," + ",".join(f"y:{y}" for y in hybrid.THERMO_SENSORS)]
    return lines + [f"{t:.12g},{hybrid.THERMO_T_S:g}," + ",".join(f"{v:.9g}" for v in r)
                    for t, r in zip(np.concatenate([times[:300], later]),
                                    np.concatenate([readings[:300], after_readings[start:]]))]


@pytest.mark.slow
@pytest.mark.long
@pytest.mark.parametrize("seed", [1, 2])
def test_a_thermostat_found_in_its_other_mode_after_an_outage_is_watched_without_an_alarm(seed):
    """The thermostat of tests/data/hybrid/thermostat.yaml (a radiator's valve
    opened under 18 and shut over 21 by the room's temperature, each
    threshold drawn anew at each visit; no mode column) by solve_ivp: 300
    rows, the clock 10^6 s ahead, then rows of another run from a sample
    whose valve is the other way. Started from its last estimate, the first
    row after the gap alarmed on T_room and the verdict was a mismatch
    (seed 1: "mismatch: T_room_offset_bias"); started anywhere on its
    settled course, the valve either way, no fault."""
    import hybrid_reference as hybrid

    said: list[str] = []
    d = bgc.monitor(hybrid.THERMO_MODEL, iter(_thermostat_lines(seed)), seed=3, events=said.append).diagnosis
    assert d.verdict == "no fault" and d.detection is None, said
    assert [(e.settled, e.modes) for e in d.events if isinstance(e, ev.Bridged)] == [(True, ("heating", "idle"))]
    assert not [e for e in d.events if isinstance(e, ev.ModeRead) and e.step == 0], said


def _supply_cycling(steps: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The supply of docs/examples/switched_rc.yaml, its controller closing
    the contactor for 2 s and opening it for 2 s, over and over, by the exact
    solution of its equations (its header, by hand): closed, C v' = (V -
    v)/R_s - v/R_load, v = 8 + (v0 - 8) exp(-1.25 t); open, C v' = -v/R_load,
    v = v0 exp(-0.25 t). A row's mode is the one from its time on (the step
    that ends at it in the mode before, as bgc reads a mode column); the
    sensors read v and the supply's current (V - v)/R_s closed, 0 open, each
    with noise of std 0.02 (the model's). Returns the modes (1 closed, 2
    open, the file's order), v and the readings (steps x 2), from v = 0."""
    rng = np.random.default_rng(seed)
    dt = 0.05
    modes = np.where(np.arange(steps) % 80 < 40, 1, 2)
    v, values = 0.0, []
    for k in range(steps):
        if k:
            v = 8.0 + (v - 8.0) * np.exp(-1.25 * dt) if modes[k - 1] == 1 else v * np.exp(-0.25 * dt)
        values.append(v)
    values = np.array(values)
    current = np.where(modes == 1, (10.0 - values) / 1.0, 0.0)
    readings = np.column_stack([values, current]) + 0.02 * rng.standard_normal((steps, 2))
    return modes, values, readings


def _supply_lines(seed: int) -> list[str]:
    """The cycling supply's rows: 300 from its start, the clock 10^5 s ahead, then
    the same cycle from a point where the contactor is the other way and the
    voltage 1.5 V or more away (the test below)."""
    steps = 3000
    modes, values, readings = _supply_cycling(steps, seed)
    start = next(k for k in range(2000, steps) if modes[k] != modes[299] and abs(values[k] - values[299]) > 1.5)
    times = np.concatenate([0.05 * np.arange(300), 1e5 + 0.05 * np.arange(steps - start)])
    return ["time,mode,u:V,y:v_C,y:i_s"] + [f"{t:.12g},{modes[k]},10,{readings[k, 0]:.9g},{readings[k, 1]:.9g}"
                                            for t, k in zip(times, np.r_[0:300, start:steps])]


@pytest.mark.slow
@pytest.mark.long
@pytest.mark.parametrize("seed", [1, 2])
def test_a_plant_whose_modes_the_data_set_is_started_where_the_record_saw_it_in_the_rows_mode(seed):
    """The supply cycling through its contactor's two settings (its mode in
    the data), 300 rows, the clock 10^5 s ahead, then rows of the same
    cycle at a point where the contactor is the other way and the
    capacitor's voltage 1.5 V or more away: what the controller did in the
    gap is not known, and the plant is somewhere its cycle takes it. Started
    from its last estimate the first row alarmed; started where the
    record's estimates were in the row's mode, with their spread: no fault,
    no run on (a mode held alone need not settle where the cycle keeps the
    plant)."""
    said: list[str] = []
    d = bgc.monitor(ROOT / "docs" / "examples" / "switched_rc.yaml", iter(_supply_lines(seed)), seed=3,
                    events=said.append).diagnosis
    assert d.verdict == "no fault" and d.detection is None, said
    assert [(e.ran, e.settled, e.modes) for e in d.events if isinstance(e, ev.Bridged)] == [(0, True, ())]


@pytest.mark.slow
@pytest.mark.long
@pytest.mark.parametrize("cut", [300, 340])
def test_a_restart_of_a_cycling_plants_monitor_across_its_outage_gives_the_uninterrupted_report(tmp_path, cut):
    """The cycling level plant's outage, its monitor's state saved before the
    gap (``cut`` 300 rows) or after it (340: its branches over the modes
    taken and the gap's event in the state), then the whole input again: the
    same events (the gap's, whose mode reader started among the modes) and
    verdict as one run."""
    model, lines = ROOT / "docs" / "examples" / "level.yaml", _cycling_lines(1)
    whole = bgc.monitor(model, iter(lines), seed=3)
    state = tmp_path / "state"
    bgc.monitor(model, iter(lines[:cut + 1]), seed=3, state=state, state_every=7)
    said: list[str] = []
    again = bgc.monitor(model, iter(lines), seed=3, state=state, state_every=7, events=said.append)
    assert said[0].startswith("resumed from")
    assert again.diagnosis.verdict == whole.diagnosis.verdict == "no fault"
    assert again.diagnosis.events == whole.diagnosis.events
    assert [e.modes for e in again.diagnosis.events if isinstance(e, ev.Bridged)] == [("filling", "draining")]


@pytest.mark.slow
@pytest.mark.long
def test_a_step_whose_change_point_fell_before_every_onset_its_filters_took_is_tested_again():
    """bench/outage.py's circuit seed 9 (docs/results.md section 77): R2 at
    1.5 times its value from 10 s after the gap, the source moved to 7 V.
    The alarm comes on the fault's first sample (t = 10830, one reading of
    f6), the detector's change point 13 samples before it; R2's particle
    filters, from the change point -4 to +2, all stop. Before, a step whose
    every filter stopped was not tested again: "unexplained". Its static
    posterior, whose onsets reach the alarm, names it."""
    report, said = _monitor(circuit_rows(9, 7.0, fault_after=(10.0, "R2", 1.5)))
    d = report.diagnosis
    assert any(isinstance(e, ev.Rescued) and e.hypothesis == "R2_abrupt" for e in d.events), said
    assert d.verdict == "isolated" and d.candidates == ("R2_abrupt",), said
    assert d.onset == pytest.approx(20.0 + HOURS3 + 10.0, abs=1.5 * DT)
    assert abs(d.estimate.value - 1.0) < 0.1


@pytest.mark.slow
@pytest.mark.long
def test_a_repair_said_during_the_outage_still_bridges_the_gap():
    """R2 up from t = 6 (accommodated by an episode), then the logger goes
    down at t = 20 and a `# repaired` line comes before its first row back,
    three hours later, the source moved to 7 V and R2 mended. The repair's
    new diagnoser has taken no row: it bridges the gap too (no alarm after
    it, no fault), not started unwidened where the plant was."""
    lines = circuit_rows(5, 7.0, fault_before=6.0, after=200)
    healthy = circuit_rows(5, 7.0, after=200)  # the same noise; R2 as in the file after the gap
    lines = lines[:401] + ["# repaired"] + healthy[401:]
    report, said = _monitor(lines, checkpoint=1.0, episodes=True)
    kinds = [type(e).__name__ for e in report.fault_log]
    assert kinds[0] == "EpisodeClosed" and report.fault_log[0].parameter == "R2", said
    assert "Repaired" in kinds, said
    d = report.diagnosis
    assert [e.began for e in d.events if isinstance(e, ev.Bridged)] == [20.0], said
    assert d.verdict == "no fault" and d.detection is None, said


@pytest.mark.slow
@pytest.mark.long
def test_a_kill_after_an_episode_closed_at_the_gap_resumes_to_the_uninterrupted_report(tmp_path):
    """The episode open at the gap is closed (and its state saved) while the
    row after the gap is taken; killed before the next save, the restart
    takes up the closing diagnoser, which meets the gap itself: it bridges it
    as the uninterrupted run did (the same events, fault log and estimate)."""
    from bgc.service import monitor as service
    from bgc.diagnosis.options import DiagnosisOptions

    lines = circuit_rows(1, 12.0, fault_before=19.3, after=80)
    whole, _ = _monitor(lines, checkpoint=1.0, episodes=True)
    session = bgc.open(CIRCUIT)
    options = DiagnosisOptions(particles=500, seed=3)
    stream = iter([line + "\n" for line in lines])

    class Lines:
        def readline(self, limit=-1):
            return next(stream, "").encode()

    state = tmp_path / "state"
    run = service._Monitor(session, Lines(), "plant", options, lambda line: None, 1.0, None, False, None, state,
                           10000, None, True)
    guard = service._Guard()
    try:
        for values, line in run.reader:
            run.row(values, line, guard)
            if values[0] > 1000.0:  # the row after the gap taken; the process killed here, no save after it
                break
    finally:
        guard.close()
    saved = service.resume.load(state, run.keep.ident)
    assert saved is not None and saved.last_time == pytest.approx(20.0) and len(saved.rows) == 0
    again, said = _monitor(lines, checkpoint=1.0, episodes=True, state=state, state_every=10000)
    assert said[0].startswith("resumed from")
    assert again.fault_log == whole.fault_log
    assert again.diagnosis.events == whole.diagnosis.events
    assert again.diagnosis.verdict == whole.diagnosis.verdict


def test_the_spread_is_widened_by_the_model_files_initial_spread_after_the_record_forgot():
    """A diagnoser that watched long enough to forget its record's older half
    runs on a started package whose initial spread is the observer's at the
    cut; the bridge widens by the model file's X0_STD all the same:
    std^2 = s^2 + s0^2 + d^2 per state (s the observer's last std, d how far
    the run on moved the mean, both read here from the diagnoser)."""
    from bgc.diagnosis.options import DiagnosisOptions
    from bgc.model.protocol import nominal_model

    session = bgc.open(CIRCUIT)
    d = session.diagnoser(DiagnosisOptions(particles=200, seed=1, keep=20 * DT), inputs=["V"])
    n = 2 * d.keep + 10  # past twice the record kept: its older half forgotten
    lines = circuit_rows(6, 10.0, before=n, after=1)
    for line in lines[1:n + 1]:
        t, v, f2, f6, e11 = map(float, line.split(","))
        d.step(t, {"V": v}, {"f2": f2, "f6": f6, "e11": e11})
    assert d.offset > 0  # the record forgot its older half: a started package
    started = nominal_model(d.config.package)
    file_std = np.asarray(session.package.MODELS["nominal"].X0_STD, dtype=float)
    assert not np.allclose(np.asarray(started.X0_STD, dtype=float), file_std)
    last_mean, last_std = np.asarray(d.loop.x_mean[-1]), np.asarray(d.loop.x_std[-1])
    new, said = bridge.bridged(d, n * DT + HOURS3, {"V": 12.0}, n * DT, 215999)
    m = nominal_model(new.config.package)
    moved = np.asarray(m.X0, dtype=float) - last_mean
    assert said.ran == 168 and np.all(np.abs(moved) > 0)
    assert np.allclose(np.asarray(m.X0_STD, dtype=float), np.sqrt(last_std ** 2 + file_std ** 2 + moved ** 2))


def test_a_diagnoser_that_took_no_row_yet_bridges_a_hidden_mode_from_its_settled_course_too():
    """A diagnoser that took no row yet (an episode's or a repair's, the
    monitor's next one) meets the gap: its reader of the mode is made at the
    first row, so whether the mode is hidden is the row's columns' (no
    ``mode``): the level plant is run on with its guards from its start and
    the reader starts among both modes; the rows of a run of the plant
    from another point of its cycle then raise no alarm."""
    import hybrid_reference as hybrid
    from bgc.diagnosis.options import DiagnosisOptions

    session = bgc.open(ROOT / "docs" / "examples" / "level.yaml")
    d = session.diagnoser(DiagnosisOptions(particles=200, seed=1))
    new, said = bridge.bridged(d, 1e5, {"E": hybrid.LEVEL_E}, 0.0, 2_000_000)
    assert (said.ran, said.settled, said.modes) == (LEVEL_SETTLE, True, ("filling", "draining"))
    _, _, y_p, y_q, _ = hybrid.level_run(4)
    for k in range(337, 537):
        belief = new.step(1e5 + (k - 337) * hybrid.LEVEL_DT, {"E": hybrid.LEVEL_E}, {"p": y_p[k], "q_out": y_q[k]})
    assert belief.alarm is None and new.finish().verdict == "no fault"


def test_a_bridged_diagnosers_state_before_its_first_row_keeps_where_its_mode_reader_starts():
    """A diagnoser of the API bridged before it took a row (its reader of the
    mode made at the first row), its state taken then and taken up again:
    the same branches, and the same numbers over the rows after as the
    diagnoser that never stopped."""
    import hybrid_reference as hybrid
    from bgc.diagnosis.diagnoser import Diagnoser
    from bgc.diagnosis.options import DiagnosisOptions
    from bgc.diagnosis.state import DiagnoserState

    session = bgc.open(ROOT / "docs" / "examples" / "level.yaml")
    d = session.diagnoser(DiagnosisOptions(particles=100, seed=1))
    new, _ = bridge.bridged(d, 1e5, {"E": hybrid.LEVEL_E}, 0.0, 2_000_000)
    again = Diagnoser.from_state(new.config, DiagnoserState.from_bytes(new.to_state().to_bytes()))
    assert all(np.array_equal(a, b) for a, b in zip(again.branches, new.branches))
    _, _, y_p, y_q, _ = hybrid.level_run(4)
    for k in range(337, 377):
        row = (1e5 + (k - 337) * hybrid.LEVEL_DT, {"E": hybrid.LEVEL_E}, {"p": y_p[k], "q_out": y_q[k]})
        new.step(*row)
        again.step(*row)
    for name, value in new.arrays().items():
        assert np.array_equal(np.asarray(again.arrays()[name]), np.asarray(value), equal_nan=True), name
