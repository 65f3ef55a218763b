"""A fault that began after its alarm (issue 48: a false alarm before a real
fault dated the fault from the alarm; a step whose change point falls early
is never tried from its onset): `bgc.diagnosis.later`.

The onset posterior of a fault that persists once it appeared is checked
against one Kalman filter per onset (`run_bank`, another code path); the
diagnosis on the circuit's exact discretisation (tests/test_episodes.py's
plant, not bgc's simulator), a reading off once (a false alarm), the fault
six seconds later."""

from __future__ import annotations

import numpy as np
import pytest

import bgc
from bgc import events as ev
from bgc.diagnosis import intermittent as im
from bgc.diagnosis import later
from bgc.diagnosis.detect import Detector, DetectorOptions
from bgc.filters.cubature import run_bank
from bgc.output.events import sentence

from conftest import ROOT
from test_episodes import plant
import test_intermittent_node
from test_mismatch import NOMINAL

CIRCUIT = ROOT / "models" / "circuit.yaml"
#: A fixture: the circuit's package, R2 stepping up at t = 5 (bgc's simulator), the nominal filter's track.
circuit = test_intermittent_node.circuit


@pytest.mark.parametrize("c", [0.6, 1.2])
def test_the_onset_posterior_is_one_kalman_filter_per_onset_normalised(circuit, c):
    model, ys, us, track, fixed = circuit
    T, start = len(ys), 60
    got, evidence = later.onset_posterior(model, ys, us, track, start, [c, c + 0.1], fixed)
    onsets = np.arange(start, T)
    rows = [run_bank(model, ys, us, track, onsets, np.full(len(onsets), v), fixed).loglik for v in (c, c + 0.1)]
    # the two magnitudes weighed by their likelihood (summed over the onsets), the onsets then summed over them
    loglik = np.logaddexp(*rows)
    reference = np.exp(loglik - loglik.max())
    reference /= reference.sum()
    # the evidence: the magnitude's prior integrated by the same quadrature over the per-onset filters' sums
    lo, hi = (float(v) for v in model.FAULT_PRIOR)
    assert evidence == pytest.approx(im._evidence(np.array([c, c + 0.1]),
                                                  np.array([np.logaddexp.reduce(r) for r in rows]), lo, hi), abs=1e-3)
    assert got[:start].sum() == 0.0
    assert got.sum() == pytest.approx(1.0, abs=1e-9)
    assert np.max(np.abs(got[start:] - reference)) < 0.01
    assert int(np.argmax(got)) == int(onsets[np.argmax(reference)])


@pytest.mark.parametrize("tests", [("mean",), ("mean", "drift", "variance", "frozen")])
def test_a_detector_armed_anew_is_a_fresh_detector_from_there(tests):
    rng = np.random.default_rng(5)
    z = rng.standard_normal((300, 3))
    z[100] += 7.0  # an excursion before the re-arming, inside the longest windows after it
    z[200:] += 0.8  # a shift after it
    y = np.round(rng.normal(10.0, 0.1, (300, 3)), 3)
    options = DetectorOptions(0.01, (1, 8, 32), 300, tests)
    armed, fresh = Detector(("a", "b", "c"), options, np.full(3, 0.1)), Detector(("a", "b", "c"), options,
                                                                               np.full(3, 0.1))
    at, alarms = 120, ([], [])
    for k in range(300):
        if k == at:
            armed.rearm()
        found = armed.update(z[k], None, y[k], np.ones(3))
        if found is not None and k >= at:
            alarms[0].append((found.step - at, found.sensor, found.window, found.onset_step - at, found.test))
        if k >= at:
            again = fresh.update(z[k], None, y[k], np.ones(3))
            if again is not None:
                alarms[1].append((again.step, again.sensor, again.window, again.onset_step, again.test))
    assert alarms[0] == alarms[1] and alarms[0]  # the shift is alarmed, the same way, at the same steps
    # the same sums (the running sums go on from where they stood: equal to rounding)
    np.testing.assert_allclose(np.array(armed.statistics[at:]), np.array(fresh.statistics), rtol=1e-9, atol=1e-12)


def _reading_off(text: str, time: float, column: int, by: float) -> str:
    """The plant's CSV ``text`` with sensor column ``column`` (0: f2, 1: f6,
    2: e11) off by ``by`` in the row of ``time`` alone."""
    lines = text.splitlines()
    for i, line in enumerate(lines[1:], 1):
        cells = line.split(",")
        if abs(float(cells[0]) - time) < 1e-9:
            cells[2 + column] = f"{float(cells[2 + column]) + by:.6g}"
            lines[i] = ",".join(cells)
    return "\n".join(lines) + "\n"


@pytest.mark.slow
def test_a_fault_after_a_false_alarm_is_dated_from_its_onset(tmp_path):
    # f6 reads 0.5 A low at t = 2 alone (about 6 of its residual's stds: an alarm the budget allows), and R2
    # rises to 1.6 times its value (+1.2 ohm) from t = 8. Tried around the alarm, R2's model fails its fit test
    # (the verdict was "unexplained"); its bank puts its onset later, the data quiet between: the diagnosis is
    # made again with the detector armed anew after the false alarm.
    data = tmp_path / "run.csv"
    data.write_text(_reading_off(plant(400, [(8.0, {"R2": 1.6})], seed=4), 2.0, 1, -0.5), encoding="utf-8")
    d = bgc.diagnose(CIRCUIT, data).diagnosis
    (false,) = [e for e in d.events if isinstance(e, ev.FalseAlarm)]
    assert d.time_of(false.step) == pytest.approx(2.0) and false.sensor == "f6" and false.again == false.step + 1
    assert false.hypothesis == "R2_abrupt" and abs(d.time_of(false.until) - 8.0) <= 0.05 + 1e-9
    assert sentence(false, d.time_of) == (  # as docs/diagnosis.md section 6.2 prints it
        "the alarm at t = 2 on f6 (mean test) was a false one: the model's residuals stay within its noise from "
        "t = 2.05 to t = 8, R2_abrupt explaining them from there on; the diagnosis was made again, the detector "
        "armed anew after the alarm")
    assert d.detection is not None and d.time_of(d.detection.step) >= 8.0 - 1e-9  # the fault's own alarm
    assert (d.verdict, d.candidates) == ("isolated", ("R2_abrupt",))
    assert abs(d.time_of(d.onset_step) - 8.0) <= 0.05 + 1e-9  # within one sample (dt 0.05)
    assert d.estimate.low <= 0.6 * NOMINAL["R2"] <= d.estimate.high
