"""A fault that comes and goes as one fault node with two states
(bgc/diagnosis/intermittent.py; issue 47, point 3): the batch diagnosis of
a record in which a fault appeared, went away and came back names it
intermittent, with each appearance's and going away's time and its
magnitude while present.

The data come from the circuit simulated by the exact discretisation of its
equations (tests/test_mismatch.py, tests/test_episodes.py's ``plant``),
not from bgc's simulator; the expected spans and sizes are the changes the
test makes. The bank's likelihood is checked against two identities that
hold whatever the code: with no magnitude, every path of the fault's chain
is the nominal model's (the nominal filter's likelihood times the number
of samples the first appearance may fall on, its weight 1 per sample); and
a fault that never goes away is the persistent fault with its onset summed
over the samples (:func:`bgc.filters.cubature.run_bank`, one Kalman filter
per onset: a separate code path).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import bgc
from bgc import events as ev
from bgc.diagnosis import intermittent as im
from bgc.filters.cubature import nominal_track, run_bank
from bgc.model.protocol import state_rows

from conftest import ROOT, bgc_cli, fast_backend, fast_session
from test_episodes import plant
from test_mismatch import NOMINAL

CIRCUIT = ROOT / "models" / "circuit.yaml"


def _bias_over(text: str, column: int, value: float, spans) -> str:
    """The plant's CSV ``text`` with sensor column ``column`` (0: f2, 1: f6,
    2: e11) reading ``value`` high over each (on, off) span of ``spans``
    (off None: to the end), by the onset rule (a row at time t >= on and < off)."""
    lines = text.splitlines()
    out = [lines[0]]
    for line in lines[1:]:
        cells = line.split(",")
        t = float(cells[0])
        if any(t >= on - 1e-9 and (off is None or t < off - 1e-9) for on, off in spans):
            cells[2 + column] = f"{float(cells[2 + column]) + value:.6g}"
        out.append(",".join(cells))
    return "\n".join(out) + "\n"


@pytest.fixture(scope="module")
def circuit():
    """The circuit's package, a record of R2 stepping up at t = 5 (bgc's simulator: only the bank's
    identities are checked on it), and the nominal filter's track over it."""
    s = bgc.simulate(CIRCUIT, "R2:abrupt:1.2@5", seed=1, steps=200)
    package = bgc.open(CIRCUIT).package
    nominal = package.MODELS["nominal"]
    ys = np.column_stack([s.measurements[y] for y in nominal.OUTPUTS])
    us = np.column_stack([s.inputs[u] for u in nominal.INPUTS])
    model = package.MODELS["R2_abrupt"]
    track = nominal_track(nominal, ys, us, len(ys))
    _, extra = state_rows(model)
    fixed = model.augment(track.mean[0][:, None], np.random.default_rng(0))[extra, 0]
    return model, ys, us, track, fixed


def test_with_no_magnitude_every_path_is_the_nominal_model(circuit):
    model, ys, us, track, fixed = circuit
    T, start = len(ys), 80
    p = im._bank(model, ys, us, track, start, [0.0], [10.0], [10.0], fixed)
    assert p.loglik[0] == pytest.approx(track.loglik[T] + math.log(T - start), abs=1e-8)


@pytest.mark.parametrize("c", [0.6, 1.2])
def test_a_fault_that_never_goes_is_the_persistent_one_summed_over_its_onsets(circuit, c):
    model, ys, us, track, fixed = circuit
    T, start = len(ys), 80
    p = im._bank(model, ys, us, track, start, [c], [1e12], [1e12], fixed)
    onsets = np.arange(start, T)
    reference = np.logaddexp.reduce(run_bank(model, ys, us, track, onsets, np.full(len(onsets), c), fixed).loglik)
    assert p.loglik[0] == pytest.approx(reference, abs=1e-3)


def test_the_spans_are_read_where_the_presence_crosses_one_half():
    present = np.array([0, 0, 0.9, 0.95, 0.2, 0.1, 0.7, 0.8])
    appear = np.array([0, 0, 0.9, 0, 0, 0, 0.6, 0.1])
    vanish = np.array([0, 0, 0, 0.1, 0.8, 0, 0, 0])
    spans = im.spans_of(present, appear, vanish, 0, 0.95)
    assert [(s.on, s.off) for s in spans] == [(2, 4), (6, None)]
    assert spans[1].on_low == 6 and spans[1].on_high == 7  # 0.6 then 0.1: the 97.5 % point falls on 7


class _Static:
    """A stand-in of a static posterior: its best cell's residuals from ``best``'s onset."""

    def __init__(self, z, onset=0):
        self.residuals, self.best = z, (onset, 0.0)


class _Named:
    def __init__(self, z, onset=0):
        self.static = _Static(z, onset)


def test_white_residuals_do_not_wander_and_a_mean_that_comes_and_goes_does():
    rng = np.random.default_rng(7)
    white = [im._wanders(_Named(rng.standard_normal((600, 3)))) for _ in range(200)]
    assert sum(white) <= 3  # a level of 0.001: about 0.2 of 200 expected
    z = rng.standard_normal((600, 3))
    z[100:250, 0] += 0.6  # a stretch 0.6 std high, then low: what a persistent model leaves of a fault that went away
    z[250:400, 0] -= 0.6
    assert im._wanders(_Named(z))
    z = rng.standard_normal((600, 3))
    z[:50] += 3.0  # before the onset: not read
    assert not im._wanders(_Named(z, onset=50))
    # a plant noisier than its model and offset from it, throughout: that is a mismatch, nothing comes and goes
    assert sum(im._wanders(_Named(1.5 * rng.standard_normal((600, 3)) + 0.3)) for _ in range(100)) <= 2
    z = rng.standard_normal((600, 3))
    z[100:250, 1] *= 3.0  # a burst of noise over 150 samples
    assert im._wanders(_Named(z))


class _Row:
    """A stand-in of a bank's pass over a grid of magnitudes: a log density known in closed form."""

    def __init__(self, logd):
        self.logd, self.calls = logd, 0

    def __call__(self, values, full):
        self.calls += 1

        class Pass:
            loglik = np.zeros(len(values))

        return Pass(), self.logd(np.asarray(values))


#: Log densities of the magnitude: a Gaussian peak of std 0.02; a Laplace peak; and a Gaussian peak on a
#: plateau, what the bank gives far from the magnitude, where the fault node can stay absent (the parabola
#: through three coarse points then puts its vertex off the peak by many of its stds).
SHAPES = {"gaussian": lambda v, peak: -0.5 * ((v - peak) / 0.02) ** 2,
          "laplace": lambda v, peak: -50.0 * np.abs(v - peak),
          "plateau": lambda v, peak: np.maximum(-0.5 * ((v - peak) / 0.025) ** 2, -300.0)}


@pytest.mark.parametrize("peak", [1.013, -4.2, 0.3])
@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_the_magnitudes_grid_ends_around_the_peak_whatever_its_shape(peak, shape):
    """A prior of (-5, 5): the last grid holds the peak, resolved (the log density falls by less than
    SMOOTH between the best point and its neighbours: 2.4 stds apart at most for a Gaussian)."""
    row = _Row(lambda v: SHAPES[shape](v, peak))
    _, values, got, _ = im._searched(row, -5.0, 5.0)
    assert values[0] <= peak <= values[-1]
    best = int(np.argmax(got))
    assert abs(values[best] - peak) <= values[1] - values[0]
    assert np.max(np.abs(np.diff(got[max(best - 1, 0):best + 2]))) < im.SMOOTH
    assert row.calls <= im.REFINE + 1


#: R2 at 1.6 times its value over t = 6 to 12 and from t = 20 (a step of +1.2 ohm while present).
COMES_AND_GOES = [(6.0, {"R2": 1.6}), (12.0, {"R2": 1.0}), (20.0, {"R2": 1.6})]


@pytest.fixture(scope="module")
def comes_and_goes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("comes_and_goes")
    data = folder / "run.csv"
    data.write_text(plant(600, COMES_AND_GOES, seed=3), encoding="utf-8")
    return folder, data, bgc.diagnose(fast_session("circuit"), data)


@pytest.mark.slow
@pytest.mark.long
def test_a_fault_that_comes_and_goes_is_isolated_with_its_spans(comes_and_goes):
    _, _, report = comes_and_goes
    d = report.diagnosis
    assert (d.verdict, d.candidates) == ("isolated", ("R2_abrupt",))
    h = next(h for h in d.hypotheses if h.name == "R2_abrupt")
    i = h.intermittent
    assert i is not None and i.alarm is None
    truth = [(6.0, 12.0), (20.0, None)]
    assert len(i.spans) == 2
    for s, (on, off) in zip(i.spans, truth):
        assert d.time_of(s.on_low) <= on + 1e-9 and d.time_of(s.on_high) >= on - 1e-9
        assert abs(d.time_of(s.on) - on) <= 0.05 + 1e-9  # within one sample (dt 0.05)
        if off is None:
            assert s.off is None
        else:
            assert abs(d.time_of(s.off) - off) <= 0.05 + 1e-9
    assert i.low <= 0.6 * NOMINAL["R2"] <= i.high  # +1.2 ohm while present
    assert h.estimate.value == i.value
    assert report.intermittent["R2"]["spans"] == [(d.time_of(s.on), None if s.off is None else d.time_of(s.off))
                                                  for s in i.spans]
    said = [e for e in d.events if isinstance(e, ev.Intermittent)]
    assert [e.hypothesis for e in said] == ["R2_abrupt"]
    assert not [e for e in d.events if isinstance(e, ev.Redated)]  # its first appearance is its onset
    # between the spans the fault is absent: the presence probability says so
    t = d.time
    assert i.present[(t > 13) & (t < 19)].max() < 0.05 and i.present[(t > 7) & (t < 11)].min() > 0.95


@pytest.mark.slow
def test_the_report_says_it_comes_and_goes(comes_and_goes, tmp_path):
    folder, _, report = comes_and_goes
    report.write(tmp_path / "out")
    data = json.loads((tmp_path / "out" / "report.json").read_text(encoding="utf-8"))
    assert "comes and goes: present t = 6 to 12 and from t = 20" in data["in_words"][0]
    (h,) = [h for h in data["hypotheses"] if h["intermittent"]]
    assert [s["appeared"] for s in h["intermittent"]["spans"]] == [6.0, 20.0]
    assert "comes and goes" in (tmp_path / "out" / "report.md").read_text(encoding="utf-8")


@pytest.mark.slow
def test_a_persistent_fault_is_not_tried_as_one_that_comes_and_goes(tmp_path):
    data = tmp_path / "run.csv"
    data.write_text(plant(400, [(6.0, {"R2": 1.6})], seed=3), encoding="utf-8")
    d = bgc.diagnose(fast_session("circuit"), data).diagnosis
    assert (d.verdict, d.candidates) == ("isolated", ("R2_abrupt",))
    assert not [e for e in d.events if isinstance(e, (ev.IntermittentTried, ev.Intermittent))]
    assert all(h.intermittent is None for h in d.hypotheses)


@pytest.mark.slow
@pytest.mark.long
def test_a_sensors_bias_that_comes_and_goes_from_the_command_line(tmp_path):
    spans = [(6.0, 11.0), (17.0, None)]
    text = _bias_over(plant(500, [], seed=4), 1, 0.5, spans)  # f6 reads 0.5 A high over the spans
    (tmp_path / "run.csv").write_text(text, encoding="utf-8")
    p = bgc_cli("diagnose", CIRCUIT, "--data", tmp_path / "run.csv", *fast_backend("circuit"), "-o",
                tmp_path / "out")
    assert p.returncode == 0, p.stderr
    data = json.loads((tmp_path / "out" / "report.json").read_text(encoding="utf-8"))
    assert data["verdict"] == "isolated" and data["diagnosis"] == ["f6_offset_bias"], data["in_words"]
    (h,) = [h for h in data["hypotheses"] if h["intermittent"]]
    got = [(s["appeared"], s["went"]) for s in h["intermittent"]["spans"]]
    assert len(got) == 2
    for (on, off), (a, b) in zip(spans, got):
        assert abs(a - on) <= 0.05 + 1e-9 and (off is None) == (b is None)
        assert off is None or abs(b - off) <= 0.05 + 1e-9
    low, high = h["intermittent"]["interval"]
    assert low <= 0.5 <= high
    assert "sensor f6 reads" in p.stdout and "comes and goes" in p.stdout


def test_a_span_shorter_than_an_isolation_is_named_by_the_monitor(tmp_path):
    """R2 present over t = 6 to 6.6 only (12 samples, gone before the first checkpoint could isolate it),
    then from t = 14: the monitor's first episode names it gone (intermittent, present t = 6 to 6.6) and
    watches the healthy model; the second accommodates it back."""
    from test_episodes import run

    text = plant(500, [(6.0, {"R2": 1.6}), (6.6, {"R2": 1.0}), (14.0, {"R2": 1.6})], seed=5)
    _, report, log = run(tmp_path, text)
    closed = [e for e in log if e["event"] == "EpisodeClosed"]
    assert [(e["action"], e["parameter"]) for e in closed] == [("ended", "R2"), ("accommodated", "R2")]
    assert closed[0]["present"] == [[6.0, 6.6]]
    assert closed[1]["present"] == [[6.0, 6.6], [14.0, None]]
    assert closed[1]["value"] == pytest.approx(1.6 * NOMINAL["R2"], rel=0.05)


@pytest.mark.slow
@pytest.mark.long
def test_an_actuators_bias_that_comes_and_goes(tmp_path):
    """The source delivers 1 V more than the 10 V logged over t = 6 to 12 and from t = 20 (the plant's
    dynamics and readings see 11 V; the run file says 10): the actuator's bias, coming and going."""
    from test_mismatch import DT, START, V, circuit, readings

    rng = np.random.default_rng(11)
    e, process, sensor = circuit(dict(NOMINAL), 1.0)
    x, lines = np.array(START), ["time,u:V,y:f2,y:f6,y:e11"]
    for k in range(1, 601):
        t = k * DT
        v = V + (1.0 if (6.0 - 1e-9 <= t < 12.0 - 1e-9) or t >= 20.0 - 1e-9 else 0.0)
        # the sample at t sees the source of t; the step into it the source before it (the onset rule)
        before = V + (1.0 if (6.0 - 1e-9 <= t - DT < 12.0 - 1e-9) or t - DT >= 20.0 - 1e-9 else 0.0)
        x = e[:3, :3] @ x + e[:3, 3] * before + process * rng.standard_normal(3)
        y = readings(NOMINAL, x, v) + sensor * rng.standard_normal(3)
        lines.append(",".join(f"{val:.6g}" for val in (t, V, *y)))
    (tmp_path / "run.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    d = bgc.diagnose(fast_session("circuit"), tmp_path / "run.csv").diagnosis
    assert (d.verdict, d.candidates) == ("isolated", ("V_offset_bias",))
    i = next(h for h in d.hypotheses if h.name == "V_offset_bias").intermittent
    assert i is not None and i.low <= 1.0 <= i.high
    assert [(d.time_of(s.on), None if s.off is None else d.time_of(s.off)) for s in i.spans] == \
        [(pytest.approx(6.0), pytest.approx(12.0)), (pytest.approx(20.0), None)]


@pytest.mark.slow
@pytest.mark.long
def test_a_persistent_fault_forced_through_the_bank_loses_to_itself(tmp_path, monkeypatch):
    """The intermittent hypothesis's evidence and the persistent one's on one scale: a persistent sensor
    bias (f6 reading 0.2 high from t = 6), tried as one that comes and goes (the wander test forced),
    is less likely coming and going than persisting (the Occam factor of its unknown rates) and is
    named persistent; the static posterior's onset grid alone (t = 5.6, 5.8, 6) would have put it
    several nats below its exact sum over every onset."""
    monkeypatch.setattr(im, "_wanders", lambda h: True)
    data = tmp_path / "run.csv"
    data.write_text(plant(400, [], seed=0, bias=(6.0, 1, 0.2)), encoding="utf-8")
    d = bgc.diagnose(fast_session("circuit"), data).diagnosis
    assert (d.verdict, d.candidates) == ("isolated", ("f6_offset_bias",))
    (tried,) = [e for e in d.events if isinstance(e, ev.IntermittentTried)]
    assert tried.log_factor < 0
    assert all(h.intermittent is None for h in d.hypotheses)


def test_an_accommodated_fault_that_goes_away_briefly_stays_accommodated(tmp_path):
    """R2 1.6 times its value from t = 6, back to its value over t = 14 to 14.6, then 1.6 times again: the
    monitor's second episode names the absence and keeps the fault accommodated (its spans split), and the
    record ends with no fault, not a mismatch."""
    from test_episodes import run

    _, report, log = run(tmp_path, plant(800, [(6.0, {"R2": 1.6}), (14.0, {"R2": 1.0}), (14.6, {"R2": 1.6})],
                                         seed=5))
    closed = [e for e in log if e["event"] == "EpisodeClosed"]
    assert [(e["action"], e["parameter"]) for e in closed] == [("accommodated", "R2"), ("accommodated", "R2")]
    assert closed[1]["present"] == [[6.0, 14.0], [14.6, None]]
    assert report["verdict"] == "no fault"


@pytest.mark.slow
def test_a_fault_gone_before_its_first_checkpoint_is_in_the_reports_intermittent():
    """bgc.monitor on R2 present over t = 6 to 6.6 only: the fault log's one episode ends it, and the
    report's ``intermittent`` lists its span (no value while accommodated: it never was)."""
    text = plant(400, [(6.0, {"R2": 1.6}), (6.6, {"R2": 1.0})], seed=5)
    report = bgc.monitor(fast_session("circuit"), text.splitlines(keepends=True), checkpoint=1, episodes=True,
                         particles=300, seed=3)
    assert [(e.action, e.parameter) for e in report.fault_log] == [("ended", "R2")]
    got = report.intermittent["R2"]
    assert [tuple(round(t, 6) if t is not None else None for t in span) for span in got["spans"]] == [(6.0, 6.6)]
    assert got["values"] == [] and got["mean"] is None


@pytest.mark.slow
@pytest.mark.long
def test_a_burst_of_noise_that_comes_and_goes():
    """RO's permeate flow sensor five times as noisy over samples 100 to 150 and from 200 (bgc's simulator:
    the variance half of the wander test is what sees it)."""
    d = bgc.diagnose(fast_session("ro"), bgc.simulate(ROOT / "models" / "ro.yaml",
                                                            "F_perm:noise:4@100-150,200", seed=2, steps=300))
    r = d.diagnosis
    assert (r.verdict, r.candidates) == ("isolated", ("F_perm_noise_noise",))
    i = next(h for h in r.hypotheses if h.name == "F_perm_noise_noise").intermittent
    assert i is not None and i.low <= 4.0 <= i.high
    assert len(i.spans) == 2 and i.spans[1].off is None
    assert abs(r.time_of(i.spans[0].off) - 150.0) <= 5.0 and abs(r.time_of(i.spans[1].on) - 200.0) <= 5.0


@pytest.mark.long
def test_a_record_finished_again_tracks_its_hypotheses_once(monkeypatch):
    """A record finished twice, faults that come and go not tried and then
    tried (a hidden-mode diagnosis whose first diagnosis stands), tracks its
    hypotheses once: steps 4 to 6b do not read that choice, and the second
    finish gives what a loop finishing afresh gives (bgc's simulator: the
    two finishes are compared with each other). A record that took a sample
    since tracks them anew."""
    from bgc.diagnosis import finish as steps
    from bgc.diagnosis.options import DiagnosisOptions

    calls = []
    original = steps.tracked
    monkeypatch.setattr(steps, "tracked", lambda *a: calls.append(1) or original(*a))
    s = bgc.simulate(CIRCUIT, "R2:abrupt:1.2@5", seed=1, steps=160)
    session = bgc.open(CIRCUIT)

    def fed(n):
        d = session.diagnoser(DiagnosisOptions(particles=100, seed=2, workers=1), inputs=["V"])
        for k in range(n):
            d.step(float(s.time[k]), {"V": float(s.inputs["V"][k])}, {y: float(s.measurements[y][k]) for y in
                                                                     ("f2", "f6", "e11")})
        return d

    d = fed(150)
    first = d.loop.finish(None, None, False)
    again = d.loop.finish(None, None, True)
    assert first.detection is not None and len(calls) == 1, (first.verdict, calls)
    fresh = fed(150).loop.finish(None, None, True)
    assert len(calls) == 2
    assert (again.verdict, again.candidates, again.onset_step) == (fresh.verdict, fresh.candidates, fresh.onset_step)
    assert [(h.name, h.posterior, h.log_evidence, h.estimate) for h in again.hypotheses] == \
        [(h.name, h.posterior, h.log_evidence, h.estimate) for h in fresh.hypotheses]
    d.step(float(s.time[150]), {"V": float(s.inputs["V"][150])}, {y: float(s.measurements[y][150]) for y in
                                                                   ("f2", "f6", "e11")})
    d.loop.finish(None, None, True)
    assert len(calls) == 3
