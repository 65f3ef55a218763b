"""The online diagnoser and real plant data: one sample in, a belief out; the
batch diagnosis is the loop over it; time stamps with gaps, inputs with holes,
a sensor missing, a detector per horizon, bad time stamps; ``bgc monitor``
through a real pipe."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import threading
import time
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

import bgc
import bgc.errors
from bgc.errors import DataError
from bgc import events
from bgc.data import runs
from bgc.analysis import simulate
from bgc.diagnosis.detect import DetectorOptions
from bgc.diagnosis.options import DiagnosisOptions

from conftest import FAST, bgc_cli, fast_session, numba_package, session

ROOT = Path(__file__).resolve().parents[1]
CIRCUIT = ROOT / "models" / "circuit.yaml"
OPTIONS = DiagnosisOptions(particles=300, seed=1, workers=1)


def simulated(model: Path, fault: str | None = None, steps: int | None = None, seed: int = 1) -> runs.Run:
    num = session(model).compiled.numerics
    injected = None if fault is None else simulate.parse_fault(fault, num)
    result = simulate.simulate(num, simulate.SimulationOptions(steps=steps, seed=seed, fault=injected))
    return runs.parse_run(simulate.to_csv(result), f"{model.stem}.csv")


def rows_of(run: runs.Run, keep) -> runs.Run:
    """The run with only the rows ``keep`` (a boolean mask or indices)."""
    return runs.Run(run.time[keep], {k: v[keep] for k, v in run.inputs.items()},
                    {k: v[keep] for k, v in run.measurements.items()}, {k: v[keep] for k, v in run.states.items()},
                    {k: v[keep] for k, v in run.parameters.items()}, run.header, run.source)


def with_columns(run: runs.Run, **change) -> runs.Run:
    fields = {f: getattr(run, f) for f in runs.Run.__slots__}
    fields.update(change)
    return runs.Run(**fields)


def kinds(d) -> list[str]:
    return [type(e).__name__ for e in d.events]


@lru_cache(maxsize=None)
def read_at_once() -> tuple[str, list[str]]:
    """The verdict and the candidates of the circuit's R2 step, 120 samples
    (6 s, the fault at t = 5), diagnosed read at once with 100 particles:
    what a monitor of the same rows in pieces (a rotated file, a folder of
    daily files) must end with. Diagnosed once per test process, in this
    process (the workers change no number)."""
    run = simulated(CIRCUIT, "R2:abrupt:0.6@5", steps=120)
    whole = bgc.diagnose(session(CIRCUIT), data=run, options=DiagnosisOptions(particles=100, workers=1)).diagnosis
    return whole.verdict, list(whole.candidates)


@pytest.mark.slow
def test_stepping_the_diagnoser_sample_by_sample_gives_the_batch_diagnosis():
    """The online loop (trackers stepped as samples arrive) and the batch
    one (the same loop, the hypotheses' filters run at the end) give the
    same diagnosis: each filter has its own random numbers and one loop body
    (on the FAST backend: conftest.fast_session, the slow tier only; 200
    samples, 10 s, the fault at t = 5: the loop reaches every phase)."""
    run = simulated(CIRCUIT, "R2:abrupt:0.6@5", steps=200)
    batch = bgc.diagnose(fast_session("circuit"), data=run, options=OPTIONS).diagnosis
    d = fast_session("circuit").diagnoser(OPTIONS)
    phases = []
    for i, t in enumerate(run.time):
        belief = d.step(float(t), {u: c[i] for u, c in run.inputs.items()},
                        [run.measurements[y][i] for y in ("e11", "f2", "f6")])
        phases.append(belief.phase)
    online = d.finish(run)
    assert (online.verdict, online.candidates, online.onset) == (batch.verdict, batch.candidates, batch.onset)
    assert online.verdict == "isolated" and online.candidates == ("R2_abrupt",)
    for h, g in zip(online.hypotheses, batch.hypotheses):
        assert (h.name, h.dropped_step) == (g.name, g.dropped_step)
        for f in ("value", "low", "high"):
            assert math.isclose(getattr(h.estimate, f), getattr(g.estimate, f), rel_tol=1e-9) or \
                (math.isnan(getattr(h.estimate, f)) and math.isnan(getattr(g.estimate, f)))
    # the phases in loop order, each reached
    firsts = [phases.index(p) for p in ("watching", "isolating", "tracking")]
    assert firsts == sorted(firsts) and phases[-1] == "tracking"
    alarm = next(e for e in online.events if isinstance(e, events.Alarmed))
    assert alarm.step == online.detection.step and phases[alarm.step] == "isolating"
    assert phases[alarm.step - 1] == "watching"
    assert isinstance(online.events[-1], events.Decided) and online.events[-1].candidates == ("R2_abrupt",)


def test_a_belief_while_tracking_names_the_live_hypotheses_with_a_running_estimate():
    run = simulated(CIRCUIT, "R2:abrupt:0.6@5")
    d = session(CIRCUIT).diagnoser(OPTIONS)
    for i, t in enumerate(run.time):
        belief = d.step(float(t), None, [run.measurements[y][i] for y in ("e11", "f2", "f6")])
    assert belief.phase == "tracking"
    assert belief.hypotheses[0].name == "R2_abrupt" and belief.hypotheses[0].posterior > 0.5
    best = belief.hypotheses[0]
    assert best.low <= 0.6 <= best.high and abs(best.value - 0.6) < 0.1
    assert abs(sum(h.posterior for h in belief.hypotheses) - 1.0) < 1e-9


def test_a_healthy_run_with_a_logging_gap_is_healthy_and_the_gap_is_an_event():
    """Rows of t = 5.2 to 7 removed from a fault-free circuit run: the grid
    keeps its steps (measurements missing there), the filters predict across
    the gap, and no alarm is raised. (Before: every row was one dt, the gap
    shifted the time, and the detector alarmed.)"""
    run = simulated(CIRCUIT)
    keep = ~((run.time > 5.15) & (run.time < 7.05))
    d = bgc.diagnose(session(CIRCUIT), data=rows_of(run, keep), options=OPTIONS).diagnosis
    assert d.verdict == "no fault"
    assert len(d.time) == len(run.time) and np.allclose(d.time, run.time)
    gaps = [e for e in d.events if isinstance(e, events.Gap)]
    assert len(gaps) == 1 and d.time_of(gaps[0].step) == pytest.approx(5.2) and gaps[0].steps == (~keep).sum()
    assert d.data.unsampled == (~keep).sum() and d.data.gaps == 1
    assert np.isnan(d.nominal_z[gaps[0].step:gaps[0].step + gaps[0].steps]).all()


def test_a_sensor_silent_for_a_stretch_is_an_event_when_it_stops_and_when_it_resumes():
    """A fault-free circuit run (dt 0.05, gap limit 10 steps) whose f2 cells
    are empty on rows 100 to 159 (3 s, 60 samples) while the other sensors
    go on, e11 empty on rows 200 to 205 (6 samples: under the limit), and
    every row of 230 to 249 missing (a gap: no sensor stops): f2 stops when
    its silence passes the limit, at row 110 (rows 100..110 are 11 steps
    without it, more than 10), and resumes at row 160 after 60 steps; the
    report counts one silence of 60 steps for f2 and none for e11."""
    from bgc.output.report import data_lines, report_data

    run = simulated(CIRCUIT)
    ys = {k: v.copy() for k, v in run.measurements.items()}
    ys["f2"][100:160] = np.nan
    ys["e11"][200:206] = np.nan
    keep = np.ones(len(run.time), bool)
    keep[230:250] = False
    quiet = rows_of(with_columns(run, measurements=ys), keep)
    r = bgc.diagnose(session(CIRCUIT), data=quiet, options=OPTIONS)
    d = r.diagnosis
    assert d.verdict == "no fault"
    stopped = [e for e in d.events if isinstance(e, events.SensorStopped)]
    resumed = [e for e in d.events if isinstance(e, events.SensorResumed)]
    assert stopped == [events.SensorStopped("f2", 100, 110)] and resumed == [events.SensorResumed("f2", 100, 160)]
    assert d.data.silences == (("f2", 1, 60),)
    assert "sensor y:f2: silent 1 time(s) for longer than the gap limit, the longest 60 step(s) (3 time units)" \
        in data_lines(d)
    assert "the longest 60 step(s) (3 s)" in " ".join(data_lines(d, labels=r.labels))  # circuit: time_unit s
    data = report_data(r)
    assert data["data_semantics"]["sensors_silent"] == [{"sensor": "f2", "silences": 1, "longest_steps": 60}]
    said = [e["text"] for e in data["events"] if e["event"] in ("SensorStopped", "SensorResumed")]
    assert said == ["sensor y:f2 has no sample since t = 5.05, longer than the gap limit: diagnosed with the other "
                    "sensors until it resumes", "sensor y:f2 gives samples again after 60 step(s) without one "
                    "(from t = 5.05)"]


@pytest.mark.slow
def test_every_fifth_row_dropped_keeps_the_time_and_the_diagnosis():
    """On the FAST backend (conftest.fast_session; the slow tier only)."""
    run = simulated(CIRCUIT, "R2:abrupt:0.6@5")
    keep = np.arange(len(run.time)) % 5 != 4
    keep[-1] = True  # the grid ends at the last sample
    d = bgc.diagnose(fast_session("circuit"), data=rows_of(run, keep), options=OPTIONS).diagnosis
    assert len(d.time) == len(run.time) and d.data.unsampled == (~keep).sum()
    assert not any(isinstance(e, events.Gap) for e in d.events)  # one step at a time: under the gap limit
    assert d.verdict == "isolated" and d.candidates == ("R2_abrupt",)
    assert d.onset == pytest.approx(5.0, abs=0.1)
    assert d.estimate.low <= 0.6 <= d.estimate.high


def test_a_gap_limit_in_time_units_and_samples_on_a_taken_step():
    run = simulated(CIRCUIT, steps=100)
    keep = ~((run.time > 2.0) & (run.time < 2.3))  # 5 steps missing
    options = DiagnosisOptions(particles=200, seed=1, workers=1, gap=0.2)
    d = bgc.diagnose(session(CIRCUIT), data=rows_of(run, keep), options=options).diagnosis
    assert [e.steps for e in d.events if isinstance(e, events.Gap)] == [5]
    # a second sample on a step already taken (jittered logging faster than dt) is skipped, once said
    jitter = with_columns(run, time=run.time + np.where(np.arange(len(run.time)) == 10, 0.0, 0.0))
    times = np.insert(jitter.time, 11, jitter.time[10] + 0.01)
    dense = runs.Run(times, {k: np.insert(v, 11, v[10]) for k, v in run.inputs.items()},
                     {k: np.insert(v, 11, v[10]) for k, v in run.measurements.items()}, {}, {}, run.header,
                     "dense.csv")
    d = bgc.diagnose(session(CIRCUIT), data=dense, options=DiagnosisOptions(particles=200, seed=1, workers=1)).diagnosis
    assert d.data.skipped == 1 and len(d.time) == len(run.time)
    assert [type(e) for e in d.events].count(events.SampleSkipped) == 1


def test_a_clock_that_jumps_is_refused_not_predicted_across_for_hours():
    """A file whose time jumps by 9e6 s (180,000,000 steps of 0.05 s, past
    the 100,000 of a clock that jumped): refused before any work, its data
    row named (not the memory rule its grid would also fail); in a stream,
    the row that jumps is refused with its line."""
    run = simulated(CIRCUIT, steps=40)
    jumped = with_columns(run, time=np.where(np.arange(40) < 20, run.time, run.time + 9e6))
    with pytest.raises(DataError, match=r"circuit.csv, data row 21: time 9000001.05 is 180000000 steps of dt = "
                                        r"0.05 after the row before it, more than 100000"):
        bgc.diagnose(session(CIRCUIT), data=jumped, options=OPTIONS)
    d = session(CIRCUIT).diagnoser(OPTIONS, source="log.csv")
    for i in range(20):
        d.step(float(jumped.time[i]), None, [jumped.measurements[y][i] for y in ("e11", "f2", "f6")], line=i + 3)
    with pytest.raises(DataError, match=r"log.csv:23: time 9000001.05 is 180000000 steps of dt = 0.05 after the "
                                        r"sample before it, more than 100000"):
        d.step(float(jumped.time[20]), None, [jumped.measurements[y][20] for y in ("e11", "f2", "f6")], line=23)


def ramp_run(folder: Path) -> runs.Run:
    """A fault-free circuit run whose recorded source voltage ramps from 10 V
    to 13 V (a model variant, written in ``folder``, that declares the ramp
    made it): the circuit's own model declares a constant 10 V."""
    text = CIRCUIT.read_text().replace("V: {signal: constant, value: 10.0,",
                                       "V: {signal: ramp, value: 10.0, slope: 0.2, start: 0.0,")
    assert "signal: ramp" in text
    variant = folder / "circuit.yaml"
    variant.write_text(text)
    return simulated(variant, seed=3)


@pytest.mark.slow
@pytest.mark.long
def test_a_recorded_input_is_used_and_a_blank_cell_holds_the_last_value(tmp_path):
    """The data's u:V (a ramp) is used, not the model's declared constant;
    one blank cell holds the last value with an event (before: the whole
    recorded input was dropped for the model's, with a false alarm); with
    no u:V column at all the model's input is used, and the report says so
    (diagnosed on the FAST backend: conftest.fast_session, the slow tier
    only)."""
    run = ramp_run(tmp_path)
    assert run.inputs["V"][-1] > 12.5
    circuit = fast_session("circuit")
    d = bgc.diagnose(circuit, data=run, options=OPTIONS).diagnosis
    assert d.verdict == "no fault" and d.data.inputs == (("V", "data"),)
    holed = run.inputs["V"].copy()
    holed[150] = np.nan
    d = bgc.diagnose(circuit, data=with_columns(run, inputs={"V": holed}), options=OPTIONS).diagnosis
    assert d.verdict == "no fault"
    held = [e for e in d.events if isinstance(e, events.InputHeld)]
    assert held == [events.InputHeld("V", 150, float(run.inputs["V"][149]))]
    assert d.data.holds == (("V", 1),)
    r = bgc.diagnose(circuit, data=with_columns(run, inputs={}), options=OPTIONS)
    assert r.diagnosis.data.inputs == (("V", "model"),)
    assert events.InputFromModel("V", "absent") in r.diagnosis.events
    from bgc.output import report
    assert "input u:V: from the model's declared input" in report.report_markdown(r)
    assert r.diagnosis.verdict != "no fault"  # the model's 10 V is not what the plant got


@pytest.mark.slow
def test_a_sensor_column_missing_from_the_data_is_diagnosed_with_the_others():
    """On the FAST backend (conftest.fast_session; the slow tier only)."""
    run = simulated(CIRCUIT, "R2:abrupt:0.6@5")
    without = with_columns(run, measurements={k: v for k, v in run.measurements.items() if k != "f6"})
    d = bgc.diagnose(fast_session("circuit"), data=without, options=OPTIONS).diagnosis
    assert events.SensorMissing("f6") in d.events and d.data.missing == ("f6",)
    assert d.detection is not None and d.detection.sensor != "f6"
    assert "R2_abrupt" in d.candidates
    assert np.isnan(d.statistics[:, 2]).all()
    # the detector counts the sensors present only: two sensors, not three
    assert d.threshold == pytest.approx(DetectorOptions(0.01, (1, 8, 32), 300).threshold(2))
    nothing = with_columns(run, measurements={})
    with pytest.raises(DataError, match="none of the model's sensors"):
        bgc.diagnose(fast_session("circuit"), data=nothing, options=OPTIONS)


def test_the_detector_is_the_same_for_a_short_and_a_long_file_and_a_stream():
    """The false-alarm rate is per horizon (default: the model's declared
    run length, 300 steps of 0.05), not per file: a 100-row and a 600-row
    file, and a stream, get the same threshold."""
    short = bgc.diagnose(session(CIRCUIT), data=simulated(CIRCUIT, steps=100), options=OPTIONS).diagnosis
    long = bgc.diagnose(session(CIRCUIT), data=simulated(CIRCUIT, steps=600), options=OPTIONS).diagnosis
    stream = session(CIRCUIT).diagnoser(OPTIONS)
    expected = DetectorOptions(0.01, (1, 8, 32), 300).threshold(3)
    assert short.threshold == long.threshold == stream.detector.threshold == pytest.approx(expected)
    assert short.options.horizon == pytest.approx(15.0)
    wider = bgc.diagnose(session(CIRCUIT), data=simulated(CIRCUIT, steps=100),
                         options=DiagnosisOptions(particles=300, seed=1, workers=1, horizon=150.0)).diagnosis
    assert wider.threshold == pytest.approx(DetectorOptions(0.01, (1, 8, 32), 3000).threshold(3))


@pytest.mark.parametrize("times, line, what", [
    ("0.05\n0.1\n0.08\n", 5, "time 0.08 does not increase"),
    ("0.05\n0.1\n0.1\n", 5, "time 0.1 does not increase"),
    ("0.05\nnan\n0.15\n", 4, "time nan is not a finite number"),
])
def test_bad_time_stamps_are_located_errors_in_a_file_and_in_a_stream(tmp_path, times, line, what):
    rows = "".join(f"{t},10.0,2.4,2.4,2.4\n" for t in times.split())
    text = "# model circuit: a hand-made log\ntime,u:V,y:e11,y:f2,y:f6\n" + rows
    path = tmp_path / "log.csv"
    path.write_text(text)
    with pytest.raises(DataError) as err:
        bgc.diagnose(session(CIRCUIT), data=path, options=OPTIONS)
    assert f"{path}:{line}" in str(err.value) and "time" in str(err.value)
    p = bgc_cli("monitor", CIRCUIT, "--data", "-", "--particles", "50", "-o", tmp_path / "mon", input=text)
    assert p.returncode == 1 and "Traceback" not in p.stderr
    assert f"<stdin>:{line}: {what}" in p.stderr, p.stderr


@pytest.mark.process
def test_bgc_monitor_prints_events_from_a_pipe_before_the_input_ends(tmp_path):
    """Rows through a real pipe with a pause after the fault: the alarm line
    comes out while the input is still open; at the end the report is
    written as bgc diagnose writes it. (A real process: the pipe must stay
    open while the test reads what came out. 200 rows, 10 s: the fault at
    t = 5, the pause at t = 7, some 60 rows after it.)"""
    run = simulated(CIRCUIT, "R2:abrupt:0.6@5", steps=200)
    lines = runs.run_csv(run).splitlines(keepends=True)
    head = next(i for i, line in enumerate(lines) if line.startswith("time,"))
    fault_row = head + 1 + int(np.searchsorted(run.time, 7.0))
    out = tmp_path / "mon"
    env = dict(os.environ, MPLBACKEND="Agg")
    p = subprocess.Popen([sys.executable, "-m", "bgc", "monitor", str(CIRCUIT), "--data", "-", "--particles", "300",
                          "--seed", "1", "-o", str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, bufsize=1, env=env)
    try:
        p.stdin.write("".join(lines[:fault_row]))
        p.stdin.flush()
        seen = []
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # the input stays open: the events must come now
            line = p.stdout.readline()
            assert line, p.stderr.read()
            seen.append(line)
            if "isolation from the symbols" in line:
                break
        assert any(line.startswith("t = 5: alarm on") for line in seen), seen
        assert p.poll() is None  # still waiting for input
        rest, err = p.communicate("".join(lines[fault_row:]), timeout=300)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    assert "decided: isolated: R2_abrupt" in rest and "circuit: isolated: R2_abrupt" in rest
    assert (out / "report.md").is_file() and '"command": "monitor"' in (out / "manifest.json").read_text()
    assert "Fault isolated: R2_abrupt." in (out / "report.html").read_text()


@pytest.mark.slow
def test_bgc_monitor_follows_a_file_another_program_appends_to(tmp_path):
    """--follow: the file grows, half a line at a time, while bgc monitor
    reads it. The command runs in this process (conftest.bgc_cli); the other
    program, the logger appending to the file, is a thread of the test."""
    run = simulated(CIRCUIT, steps=120)
    lines = runs.run_csv(run).splitlines(keepends=True)
    path = tmp_path / "live.csv"
    path.write_text("".join(lines[:40]))
    failed = []

    def logger():
        try:
            time.sleep(1.0)
            with open(path, "a") as f:
                for line in lines[40:]:
                    f.write(line[:10])  # half a line first: the reader waits for the rest
                    f.flush()
                    f.write(line[10:])
                    f.flush()
        except BaseException as exc:  # said by the test, not lost in the thread
            failed.append(exc)

    writer = threading.Thread(target=logger, daemon=True)
    writer.start()
    p = monitor_cli("--data", str(path), "--follow", "--idle", "2", "--particles", "100", "-o", str(tmp_path / "mon"))
    writer.join(timeout=60)
    assert not writer.is_alive() and not failed, failed
    assert p.returncode == 0, p.stderr
    assert "decided: no fault" in p.stdout
    report = (tmp_path / "mon" / "report.json").read_text()
    assert '"steps": 120' in report


def test_every_option_belongs_to_one_stage_of_the_loop():
    import dataclasses

    from bgc.diagnosis.options import STAGES

    grouped = [name for names in STAGES.values() for name in names]
    assert sorted(grouped) == sorted(f.name for f in dataclasses.fields(DiagnosisOptions))
    assert len(grouped) == len(set(grouped))


@pytest.mark.process
def test_ctrl_c_on_bgc_monitor_writes_the_report_of_the_data_so_far(tmp_path):
    """SIGINT to a real process while its input is still open."""
    import signal

    run = simulated(CIRCUIT, "R2:abrupt:0.6@5")
    lines = runs.run_csv(run).splitlines(keepends=True)
    head = next(i for i, line in enumerate(lines) if line.startswith("time,"))
    out = tmp_path / "mon"
    p = subprocess.Popen([sys.executable, "-m", "bgc", "monitor", str(CIRCUIT), "--data", "-", "--particles", "200",
                          "-o", str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, bufsize=1, env=dict(os.environ, MPLBACKEND="Agg"))
    try:
        p.stdin.write("".join(lines[:head + 1 + int(np.searchsorted(run.time, 8.0))]))
        p.stdin.flush()
        while "isolation from the symbols" not in (line := p.stdout.readline()):
            assert line, p.stderr.read()
        p.send_signal(signal.SIGINT)  # the stream is still open
        rest, err = p.communicate(timeout=300)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    assert "interrupted: finishing the diagnosis of the data so far" in rest
    assert "circuit: isolated: R2_abrupt" in rest and "Traceback" not in err
    import json

    data = json.loads((out / "report.json").read_text())["data"]
    assert 6.6 <= data["t_last"] <= 8.0  # the rows taken before the interrupt


# -- what a hostile review found (each was a silent wrong answer, a traceback or a lost report) --------------


def test_a_misspelt_or_bad_value_from_python_is_an_error_not_a_silent_no_fault():
    d = session(CIRCUIT).diagnoser(OPTIONS)
    with pytest.raises(bgc.errors.ArgumentValueError, match=r"y has 'E11', not one of the model's sensors"):
        d.step(0.05, None, {"E11": 2.4, "f2": 2.4, "f6": 2.4})
    with pytest.raises(bgc.errors.ArgumentValueError, match=r"y\[e11\]=inf is not a finite number"):
        d.step(0.05, None, {"e11": math.inf})
    with pytest.raises(bgc.errors.ArgumentValueError, match=r"y\[e11\]='x' is not a finite number"):
        d.step(0.05, None, {"e11": "x"})
    for row in ([2.4, -math.inf, 2.4], (2.4, math.inf, 2.4)):  # a row of floats in order, the usual form
        with pytest.raises(bgc.errors.ArgumentValueError, match=r"y\[f2\]=-?inf \(line 7\) is not a finite number"):
            d.step(0.05, None, row, line=7)
    for t in ("0.05", True, None, 1j):
        with pytest.raises(bgc.errors.ArgumentTypeError, match="is not a number"):
            d.step(t, None, [2.4, 2.4, 2.4])
    with pytest.raises(bgc.errors.ArgumentValueError, match="has 2 values"):
        d.step(0.05, None, [2.4, 2.4])
    assert d.step(0.05, {"V": 10.0}, [2.45, 2.49, 2.47]).phase == "watching"  # none of the above left a trace


def test_a_refused_row_leaves_the_stream_as_it_was_and_a_finished_diagnoser_takes_no_more():
    d = session(CIRCUIT).diagnoser(OPTIONS, source="log")
    d.step(0.05, None, [2.45, 2.49, 2.47])
    with pytest.raises(DataError, match="more than 100000"):
        d.step(1e6, None, [2.45, 2.49, 2.47])
    d.step(0.1, None, [2.45, 2.49, 2.47])  # the refused jump is not the last time
    d.finish()
    with pytest.raises(bgc.errors.TrackingError, match="this diagnoser has finished"):
        d.step(0.15, None, [2.45, 2.49, 2.47])


@pytest.mark.slow
@pytest.mark.long
def test_an_alarm_on_the_first_sample_is_not_called_a_degenerate_filter():
    """On the FAST backend (conftest.fast_session; the slow tier only)."""
    run = simulated(CIRCUIT)  # healthy: nothing after the first row alarms again (no diagnosis made again)
    first = dict(run.measurements)
    first["f6"] = first["f6"].copy()
    first["f6"][0] += 1.0  # far off on the first row
    d = bgc.diagnose(fast_session("circuit"), data=with_columns(run, measurements=first),
                     options=OPTIONS).diagnosis
    assert d.detection is not None and d.detection.step == 0
    assert not any(isinstance(e, (events.Degenerate, events.Switched, events.FalseAlarm)) for e in d.events)


@pytest.mark.slow
def test_after_a_switch_of_filter_the_report_still_says_how_the_data_met_the_model():
    """The drivetrain's generic filter degenerates (at sample 9) and the
    diagnosis switches to cubature Kalman filters; rows missing after the
    switch are still counted. (recheck off: weighing the fault models the
    symbols ruled out is two thirds of the run's time and says nothing of
    the data's rows.)"""
    model = ROOT / "tests" / "data" / "models" / "drivetrain.yaml"
    run = simulated(model, "g_m:abrupt:-0.3@4", steps=200, seed=1)
    keep = ~((np.arange(200) > 150) & (np.arange(200) % 10 == 5))  # rows missing after the switch
    d = bgc.diagnose(session(model), data=rows_of(run, keep),
                     options=DiagnosisOptions(particles=200, seed=1, workers=1, recheck=False)).diagnosis
    assert any(isinstance(e, events.Switched) for e in d.events)
    assert d.data.unsampled == (~keep).sum()


def monitor_cli(*args, stdin=None):
    """``bgc monitor`` of the circuit, in this process (conftest.bgc_cli), ``stdin`` its standard input."""
    return bgc_cli("monitor", CIRCUIT, *args, input=stdin)


def test_bgc_monitor_refuses_bad_options_and_outputs_before_reading_the_stream(tmp_path):
    for args, message in ((["--checkpoint", "0"], "--checkpoint 0: give a time above 0"),
                          (["--horizon", "nan"], "--horizon nan: give a time above 0"),
                          (["--idle", "5"], "--idle applies to --follow"),
                          (["--follow"], "--follow applies to a file"),
                          (["--follow", "--idle", "-1"], "--idle -1: give the seconds")):
        p = monitor_cli("--data", "-", *args, stdin="")
        assert p.returncode == 1 and p.stderr.startswith(message) and "Traceback" not in p.stderr, p.stderr
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "report.md").write_text("my notes\n")
    p = monitor_cli("--data", "-", "-o", str(foreign), stdin="time,y:e11\n")
    assert p.returncode == 1 and "holds no bgc manifest.json" in p.stderr
    assert (foreign / "report.md").read_text() == "my notes\n"
    p = monitor_cli("--data", "/dev/zero", stdin="")
    assert p.returncode == 1 and "/dev/zero is not a regular file or a pipe" in p.stderr
    run_file = tmp_path / "out" / "run.csv"
    run_file.parent.mkdir()
    run_file.write_text(runs.run_csv(simulated(CIRCUIT, steps=20)))
    p = monitor_cli("--data", str(run_file), "-o", str(run_file.parent))
    assert p.returncode == 1 and "is in the output folder" in p.stderr and run_file.exists()


@pytest.mark.slow
def test_a_bad_row_mid_stream_ends_the_stream_with_the_report_of_the_rows_before_it(tmp_path):
    """On the FAST backend, --backend (conftest.fast_session's kernels; the
    slow tier only)."""
    if FAST == "numba":
        numba_package("circuit")  # the kernels the command loads, compiled once per test run
    text = runs.run_csv(simulated(CIRCUIT, "R2:abrupt:0.6@5"))
    lines = text.splitlines(keepends=True)
    head = next(i for i, line in enumerate(lines) if line.startswith("time,"))
    bad = head + 1 + 200
    lines[bad] = lines[bad].replace(",", ",x", 1)
    p = monitor_cli("--data", "-", "--particles", "200", "--backend", FAST, "-o", str(tmp_path / "mon"),
                    stdin="".join(lines))
    assert p.returncode == 1 and "Traceback" not in p.stderr
    assert f"<stdin>:{bad + 1}:" in p.stderr and "is not a number" in p.stderr
    assert "circuit: isolated: R2_abrupt" in p.stdout
    assert '"t_last": 10' in (tmp_path / "mon" / "report.json").read_text()


def monitor_with_logger(logger, *args):
    """``bgc monitor`` of the circuit with ``args``, in this process (:func:`monitor_cli`), while
    ``logger()`` (the other program, writing the files the monitor follows) runs in a thread; what it
    raised is raised here."""
    failed = []

    def run():
        try:
            logger()
        except BaseException as exc:  # said by the test, not lost in the thread
            failed.append(exc)

    writer = threading.Thread(target=run, daemon=True)
    writer.start()
    p = monitor_cli(*args)
    writer.join(timeout=130)
    assert not writer.is_alive(), "the logger thread did not end"
    if failed:
        raise failed[0]
    return p


def read_to_the_end(pid: int, path: Path, timeout: float = 120) -> None:
    """Wait until process ``pid`` has read the file ``path`` to its end (its
    offset in /proc/PID/fdinfo), or two seconds where there is no /proc: a
    process slow to start on a busy machine must not open the file only
    after the test has changed it."""
    if not Path(f"/proc/{pid}/fdinfo").is_dir():
        time.sleep(2.0)
        return
    size = path.stat().st_size
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for fd in Path(f"/proc/{pid}/fd").iterdir():
            try:
                if os.readlink(fd) == str(path):
                    info = Path(f"/proc/{pid}/fdinfo/{fd.name}").read_text()
                    if int(info.split("pos:")[1].split()[0]) >= size:
                        return
            except (OSError, IndexError, ValueError):  # closed meanwhile
                pass
        time.sleep(0.05)
    raise AssertionError(f"process {pid} did not read {path} to its end in {timeout} s")


@pytest.mark.slow
def test_a_followed_file_rewritten_from_an_earlier_time_ends_the_stream_and_an_unfinished_line_is_not_read(
        tmp_path):
    """The second half truncates a file bgc monitor --follow reads and
    writes its first rows again, as a logger that restarts its clock: the
    truncation is followed (read again from the start, the header skipped),
    and the first row whose time goes back ends the stream. (The command in
    this process, the logger a thread: :func:`monitor_with_logger`.)"""
    lines = runs.run_csv(simulated(CIRCUIT, steps=120)).splitlines(keepends=True)
    path = tmp_path / "live.csv"
    path.write_text("".join(lines[:80]) + lines[80][:8])  # the logger stopped mid-line
    p = monitor_cli("--data", str(path), "--follow", "--idle", "1", "--particles", "50", "-o", str(tmp_path / "a"))
    assert p.returncode == 0, p.stderr
    assert "the input ended in the middle of a line" in p.stdout
    report = (tmp_path / "a" / "report.json").read_text()
    assert f'"steps": {80 - 6}' in report  # the header's 6 lines aside, the 74 whole rows
    path.write_text("".join(lines[:60]))

    def logger():
        read_to_the_end(os.getpid(), path)  # the monitor follows the file now
        path.write_text("".join(lines[:10]))  # truncated and rewritten, as a logger that restarts

    p = monitor_with_logger(logger, "--data", str(path), "--follow", "--idle", "5", "--particles", "50",
                            "-o", str(tmp_path / "b"))
    assert "was truncated (rotated by copy and truncate): reading it again from its start" in p.stdout, p.stdout
    assert p.returncode == 1 and "time 0.05 does not increase" in p.stderr, p.stderr
    assert '"steps": 54' in (tmp_path / "b" / "report.json").read_text()  # the rows before it, diagnosed


@pytest.mark.slow
def test_a_followed_file_rotated_both_ways_goes_on_as_one_stream(tmp_path):
    """bgc monitor --follow while the test rotates its file as logrotate
    does: renamed (the logger writing on into the old file a while) and
    recreated with its header, then copied and truncated (the logger writing
    on without a header). Every row is diagnosed once, in order: the report
    has the run's 120 steps, and the verdict is the one of the whole run
    read at once. (The command in this process, the logger and logrotate a
    thread: :func:`monitor_with_logger`; the thread closes each file it
    writes before it waits on the monitor's reading of it.)"""
    run = simulated(CIRCUIT, "R2:abrupt:0.6@5", steps=120)
    lines = runs.run_csv(run).splitlines(keepends=True)
    head = next(i for i, line in enumerate(lines) if line.startswith("time,")) + 1
    header, rows = lines[:head], lines[head:]
    path, old, copy = tmp_path / "live.csv", tmp_path / "live.csv.1", tmp_path / "live.csv.2"
    path.write_text("".join(header + rows[:40]))

    def logger():
        read_to_the_end(os.getpid(), path)
        path.rename(old)
        with open(old, "a") as f:  # the logger has not reopened yet
            f.write("".join(rows[40:50]))
        read_to_the_end(os.getpid(), old)
        path.write_text("".join(header + rows[50:80]))
        read_to_the_end(os.getpid(), path)
        shutil.copyfile(path, copy)
        with open(path, "r+") as f:
            f.truncate(0)
        time.sleep(1.0)  # the reader polls every 0.1 s: it sees the file shorter before it grows again
        with open(path, "a") as f:
            f.write("".join(rows[80:]))

    p = monitor_with_logger(logger, "--data", str(path), "--follow", "--idle", "3", "--particles", "100",
                            "-o", str(tmp_path / "mon"))
    assert p.returncode == 0, p.stderr
    assert "was rotated (renamed, and a new file made under its name)" in p.stdout
    assert "was truncated (rotated by copy and truncate)" in p.stdout
    followed = json.loads((tmp_path / "mon" / "report.json").read_text())
    assert followed["data"]["steps"] == 120
    assert (followed["verdict"], followed["diagnosis"]) == read_at_once()


def test_a_session_is_compiled_once_for_many_diagnoses_and_owns_its_package(tmp_path):
    """No compile cache between calls: a session holds its model's
    compilation and package, bgc.diagnose takes it for many runs, and two
    sessions of one model name (two texts) keep their own packages."""
    session = bgc.open(CIRCUIT)
    runs_ = [simulated(CIRCUIT, steps=60, seed=s) for s in (1, 2)]
    verdicts = [bgc.diagnose(session, data=r, options=DiagnosisOptions(particles=100, workers=1)).diagnosis.verdict
                for r in runs_]
    assert verdicts == ["no fault", "no fault"]
    with pytest.raises(bgc.errors.ArgumentValueError, match="with a Session: the session's apply"):
        bgc.diagnose(session, data=runs_[0], process_noise=0.5)
    variant = tmp_path / "circuit.yaml"
    variant.write_text(CIRCUIT.read_text().replace("value: 10.0", "value: 12.0"))
    other = bgc.open(variant)
    assert other.package.__name__ != session.package.__name__
    assert session.package.MODELS["nominal"].inputs(0.0)[0] == 10.0
    assert other.package.MODELS["nominal"].inputs(0.0)[0] == 12.0


def test_a_batch_diagnosis_counts_its_steps_in_its_seconds_and_a_session_simulates_at_its_noise():
    """The seconds are the steps' and the end's (the loop's steps run
    through take(), which a batch calls directly); a scenario diagnosed
    through a session is simulated at the session's noise levels."""
    circuit = session(CIRCUIT)  # compiled before the clock starts
    run = simulated(CIRCUIT)  # fault-free: the nominal observer's steps are nearly all the work
    started = time.perf_counter()
    d = bgc.diagnose(circuit, data=run, options=OPTIONS).diagnosis
    wall = time.perf_counter() - started
    assert d.verdict == "no fault" and 0.5 * wall <= d.seconds <= wall
    noisy = session(CIRCUIT, process_noise=0.05, measurement_noise=0.04)
    r = bgc.diagnose(noisy, scenario="none", steps=40, options=DiagnosisOptions(particles=50, workers=1))
    assert any(h.startswith("noise: process 0.05, measurement 0.04") for h in r.run.header), r.run.header


@pytest.mark.slow
def test_a_faulty_sensor_is_taken_out_and_monitoring_goes_on_through_a_pipe(tmp_path):
    """The two tanks: F12 reads 0.05 high from t = 60 (added to the recorded
    reading), and R10 steps up by 1.5 at t = 120. With --exclude-faulty-sensor
    a checkpoint isolates F12's bias, takes F12 out of the nominal observer,
    and the monitor, watching F10 and F20, finds the step of R10. (On the
    FAST backend, --backend: conftest.fast_session's kernels, the slow tier
    only.)"""
    if FAST == "numba":
        numba_package("two_tank")  # the kernels the command loads, compiled once per test run
    tanks = ROOT / "models" / "two_tank.yaml"
    run = simulated(tanks, "R10:abrupt:1.5@120", seed=2)
    biased = dict(run.measurements)
    biased["F12"] = np.where(run.time >= 60, run.measurements["F12"] + 0.05, run.measurements["F12"])
    text = runs.run_csv(runs.Run(run.time, run.inputs, biased, {}, {}, run.header, run.source))
    out = tmp_path / "mon"
    p = bgc_cli("monitor", tanks, "--data", "-", "--checkpoint", "10", "--exclude-faulty-sensor", "--particles",
                "500", "--backend", FAST, "-o", out, input=text)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    taken = next(i for i, line in enumerate(lines) if line.startswith("sensor F12 taken out of the nominal observer"))
    assert "(sensor F12 reads " in lines[taken] and " high since t = " in lines[taken]
    assert any(line.startswith("t = 120: alarm on F10") for line in lines[taken:]), lines[taken:]
    assert "two_tank: isolated: R10_abrupt" in p.stdout and "no column y:F12" not in p.stdout
    import json

    report = json.loads((out / "report.json").read_text())
    assert report["events"][0]["event"] == "SensorExcluded" and report["events"][0]["sensor"] == "F12"
    assert report["data_semantics"]["sensors"] == ["F10", "F20"] and report["data_semantics"]["sensors_missing"] == []


def test_exclude_faulty_sensor_needs_checkpoints():
    p = monitor_cli("--data", "-", "--exclude-faulty-sensor", stdin="")
    assert p.returncode == 1 and "--exclude-faulty-sensor acts at checkpoints" in p.stderr


@pytest.mark.slow
def test_bgc_diagnose_prints_a_loggers_unix_times_in_full(tmp_path):
    """A logger's Unix time stamps (1.76e9 s, the plant's own clock): the
    command line's detection line gives the alarm's and the onset's times
    to the sample (R2's step at 5 s after the start, at 1763686400 + 5), as
    ISO 8601 timestamps (tests/test_iso_times.py), not rounded to six digits
    (1.76369e+09). (On the FAST backend, --backend: conftest.fast_session's
    kernels, the slow tier only.)"""
    import datetime

    if FAST == "numba":
        numba_package("circuit")  # the kernels the command loads, compiled once per test run
    start = 1763686400.0
    run = simulated(CIRCUIT, "R2:abrupt:0.6@5")
    shifted = with_columns(run, time=run.time + start)
    data = tmp_path / "logger.csv"
    data.write_text(runs.run_csv(shifted), encoding="utf-8")
    r = bgc_cli("diagnose", CIRCUIT, "--data", data, "--particles", "300", "--seed", "1", "--backend", FAST,
                "-o", tmp_path / "d")
    assert r.returncode == 0, r.stderr
    line = next(l for l in r.stdout.splitlines() if "detected at t = " in l)
    stamps = [part.split("t = ")[1].split()[0].rstrip(",") for part in line.split(", onset")]
    detected, onset = (datetime.datetime.fromisoformat(t.replace("Z", "+00:00")).timestamp() for t in stamps)
    assert "e+09" not in line
    assert start + 4.5 <= onset <= detected <= start + 7.0, line


def _daily(folder: Path, run: runs.Run, cuts: tuple[int, ...]) -> None:
    """``run`` cut into a logger's daily files at rows ``cuts``, each with the run's header and column line."""
    lines = runs.run_csv(run).splitlines(keepends=True)
    head = next(i for i, line in enumerate(lines) if line.startswith("time,")) + 1
    edges = (0, *cuts, len(lines) - head)
    folder.mkdir()
    for day, (a, b) in enumerate(zip(edges, edges[1:]), start=1):
        (folder / f"day{day:02d}.csv").write_text("".join(lines[:head] + lines[head + a:head + b]))


@pytest.mark.slow
def test_bgc_monitor_reads_a_folder_of_daily_files_as_one_stream(tmp_path):
    """The run of :func:`read_at_once` in three daily files (50, 40 and 30
    rows): one stream, every row diagnosed once, the verdict that of the
    run read at once."""
    run = simulated(CIRCUIT, "R2:abrupt:0.6@5", steps=120)
    _daily(tmp_path / "logs", run, (50, 90))
    p = monitor_cli("--data", str(tmp_path / "logs" / "day*.csv"), "--particles", "100", "-o", str(tmp_path / "a"))
    assert p.returncode == 0, p.stderr
    assert f"{tmp_path / 'logs' / 'day01.csv'} read to its end: reading the next file" in p.stdout
    followed = json.loads((tmp_path / "a" / "report.json").read_text())
    assert followed["data"]["steps"] == 120
    assert (followed["verdict"], followed["diagnosis"]) == read_at_once()


@pytest.mark.slow
def test_a_followed_file_the_logger_creates_later_is_waited_for(tmp_path):
    """--follow on a file that does not exist yet (a logger that starts
    after the monitor): the monitor waits for it, then reads it as it
    grows; every row is diagnosed (the report's steps are the file's rows).
    A file that does not appear within --idle is refused as before, in one
    line naming it. (The command in this process, conftest.bgc_cli; the
    logger a thread that creates the file half a second after the start.)"""
    lines = runs.run_csv(simulated(CIRCUIT, steps=60)).splitlines(keepends=True)
    rows = sum(1 for line in lines if line[:1].isdigit())
    path = tmp_path / "later.csv"

    def logger():
        time.sleep(0.5)
        path.write_text("".join(lines))

    p = monitor_with_logger(logger, "--data", str(path), "--follow", "--idle", "1.5", "--particles", "50",
                            "-o", str(tmp_path / "mon"))
    assert p.returncode == 0, p.stderr
    assert f'"steps": {rows}' in (tmp_path / "mon" / "report.json").read_text()
    p = monitor_cli("--data", str(tmp_path / "never.csv"), "--follow", "--idle", "0.3", "-o", str(tmp_path / "b"))
    assert p.returncode == 1 and "never.csv: No such file or directory" in p.stderr and "Traceback" not in p.stderr, \
        p.stderr


@pytest.mark.slow
def test_a_followed_folder_takes_up_the_days_file_when_it_appears(tmp_path):
    """--follow on a folder: the last file there is followed, and a file
    that appears later (the next day's) is read when the one before ends.
    (100 particles: with 50 the observer raises a false alarm on these
    fault-free rows, and the monitor would weigh every fault model.) The
    command runs in this process (conftest.bgc_cli: the test is about the
    folder followed, not about a process); the other program, the logger
    that writes the next day's file once the monitor has read the first to
    its end (this process's /proc says where its reader is), is a thread."""
    run = simulated(CIRCUIT, steps=120)
    _daily(tmp_path / "logs", run, (60,))
    tomorrow = (tmp_path / "logs" / "day02.csv").read_text()
    (tmp_path / "logs" / "day02.csv").unlink()
    failed = []

    def logger():
        try:
            read_to_the_end(os.getpid(), tmp_path / "logs" / "day01.csv")
            (tmp_path / "logs" / "day02.csv").write_text(tomorrow)
        except BaseException as exc:  # said by the test, not lost in the thread
            failed.append(exc)

    writer = threading.Thread(target=logger, daemon=True)
    writer.start()
    p = monitor_cli("--data", str(tmp_path / "logs"), "--follow", "--idle", "3", "--particles", "100",
                    "-o", str(tmp_path / "mon"))
    writer.join(timeout=130)
    assert not writer.is_alive() and not failed, failed
    assert p.returncode == 0, p.stderr
    assert "day01.csv read to its end: reading the next file" in p.stdout
    assert json.loads((tmp_path / "mon" / "report.json").read_text())["data"]["steps"] == 120
