"""``bgc.monitor``: the monitor from Python (its doctest runs the fault log of
an intermittent fault). A generator's rows are diagnosed as it yields them,
a malformed row ends the stream with the report of the rows before it, and
the arguments are checked before any work."""

from __future__ import annotations

import numpy as np
import pytest

import bgc
from bgc.errors import ArgumentTypeError, ArgumentValueError, DataError

from conftest import ROOT, session
from test_episodes import plant

CIRCUIT = ROOT / "models" / "circuit.yaml"


@pytest.mark.slow
def test_a_generators_rows_are_diagnosed_as_it_yields_them():
    lines = plant(200, [(4.0, {"R2": 1.6})]).splitlines()
    given, heard = [], []

    def rows():
        for line in lines:
            given.append(line)
            yield line

    report = bgc.monitor(session("circuit"), rows(), particles=200,
                         events=lambda line: heard.append((len(given), line)))
    first, said = next((n, line) for n, line in heard if "alarm" in line)
    # the alarm is heard when the row it was raised on was given, not at the end: the row of the time it names
    when = float(said.split(":")[0].removeprefix("t = "))
    row = next(i for i, line in enumerate(lines) if i and float(line.split(",")[0]) == when)
    assert first == row + 1 < len(lines)
    assert when >= 4.0  # no alarm before the fault
    assert report.diagnosis.verdict == "isolated" and report.diagnosis.candidates[0] == "R2_abrupt"
    assert report.fault_log == () and report.intermittent == {}


def test_a_malformed_row_ends_the_stream_with_the_report_of_the_rows_before_it():
    lines = plant(120, []).splitlines()
    lines.insert(101, "5.05,10,not a number,2.5,2.5")
    with pytest.raises(DataError) as caught:
        bgc.monitor(session("circuit"), iter(lines), particles=100)
    assert len(caught.value.report.run.time) == 100 and caught.value.report.diagnosis.verdict == "no fault"


@pytest.mark.parametrize("kwargs, error, said", [
    (dict(episodes=True), ArgumentValueError, "episodes=True without a checkpoint"),
    (dict(checkpoint=0), ArgumentValueError, "checkpoint=0 is out of range"),
    (dict(rearm=5, checkpoint=1), ArgumentValueError, "rearm applies to episodes"),
    (dict(particles=0), ArgumentValueError, "particles=0 is below 1"),
    (dict(state_every=0), ArgumentValueError, "state_every=0 is below 1"),
    (dict(state_every=10), ArgumentValueError, "state_every without a state folder"),
    (dict(options=bgc.DiagnosisOptions(), particles=50), ArgumentValueError, "particles beside options"),
])
def test_the_arguments_are_checked_before_any_work(kwargs, error, said):
    with pytest.raises(error, match=said):
        bgc.monitor(CIRCUIT, ["time,u:V,y:f2,y:f6,y:e11"], **kwargs)


def test_data_of_another_type_is_refused_in_one_line():
    with pytest.raises(ArgumentTypeError, match="bgc.monitor: data is int"):
        bgc.monitor(CIRCUIT, 3)


def test_keep_beside_options_is_the_monitors_record():
    lines = ["time,u:V,y:f2,y:f6,y:e11"] + [f"{0.05 * k:.2f},10,2.5,2.5,2.5" for k in range(1, 301)]
    report = bgc.monitor(session("circuit"), lines, options=bgc.DiagnosisOptions(particles=50), keep=300 * 0.05)
    assert report.options.keep == pytest.approx(15.0) and report.stream == (300, pytest.approx(0.05))


# ------------------------------------------------------------------ bgc.Monitor: the monitor stepped
def _lines(scenario: str, steps: int) -> list[str]:
    """The circuit with ``scenario`` (bgc's simulator), the run file's lines from the column names on."""
    from bgc.data.runs import run_csv

    lines = run_csv(bgc.simulate(CIRCUIT, scenario, seed=2, steps=steps).run).splitlines()
    return lines[next(i for i, line in enumerate(lines) if line.startswith("time")):]


@pytest.mark.slow
@pytest.mark.long
def test_a_monitor_stepped_row_by_row_says_what_bgc_monitor_says_row_for_row():
    """The rows fed one at a time (as CSV lines, as lists of numbers and as
    mappings, in turn): the fault log follows the plant (R2 accommodated
    when it steps, named gone when it returns, accommodated again), and each
    row returns the event lines bgc.monitor says while that row is the last
    one its generator gave; the report is bgc.monitor's (its events, its
    verdict, the rows read)."""
    lines = _lines("R2:abrupt:1.2@2-8,12", 340)  # R2 up at 2 s, back at 8 s, up again at 12 s
    given, heard = [], []

    def rows():
        for line in lines:
            given.append(line)
            yield line

    report = bgc.monitor(session("circuit"), rows(), checkpoint=1, episodes=True, particles=300,
                         events=lambda line: heard.append((len(given) - 1, line)))
    m = bgc.Monitor(session("circuit"), lines[0], checkpoint=1, episodes=True, particles=300)
    columns = m.columns
    returned = []
    for i, line in enumerate(lines[1:], start=1):
        numbers = [float(v) for v in line.split(",")]
        row = (line, numbers, dict(zip(columns, numbers)))[i % 3]
        returned += [(i, said) for said in m.feed(row)]
    mine = m.report()
    assert [(e.action, e.parameter) for e in m.fault_log] == [("accommodated", "R2"), ("ended", "R2"),
                                                             ("accommodated", "R2")]
    assert returned == [(i, said) for i, said in heard if i < len(lines)][:len(returned)]
    assert len(returned) > 10 and m.events == tuple(said for _, said in heard)
    assert mine.fault_log == report.fault_log and mine.diagnosis.events == report.diagnosis.events
    assert mine.diagnosis.verdict == report.diagnosis.verdict and mine.stream == report.stream
    assert m.report() is mine
    with pytest.raises(ArgumentValueError, match="has made its report"):
        m.feed(lines[-1])


@pytest.mark.slow
def test_a_repair_said_from_python_is_the_streams_repair_line():
    """R2 up from 2 s to 6 s, the operator saying it was repaired before the row of t = 6:
    ``Monitor.repaired('R2')`` does what a ``# repaired: R2`` line of the stream there does (the
    same fault log: R2 accommodated, then repaired at that row's time), and the repaired plant
    raises no alarm after it."""
    lines = _lines("R2:abrupt:1.2@2-6", 200)
    at = next(i for i, line in enumerate(lines) if i and float(line.split(",")[0]) >= 6.0 - 1e-9)
    m = bgc.Monitor(session("circuit"), lines[0], checkpoint=1, episodes=True, particles=300)
    after = []
    for i, line in enumerate(lines[1:], start=1):
        if i == at:
            m.repaired("R2")
        said = m.feed(line)
        if i >= at:
            after += said
    streamed = bgc.monitor(session("circuit"), lines[:at] + ["# repaired: R2"] + lines[at:], checkpoint=1,
                           episodes=True, particles=300)
    assert m.fault_log == streamed.fault_log
    assert [(type(e).__name__, getattr(e, "action", None)) for e in m.fault_log] == [
        ("EpisodeClosed", "accommodated"), ("Repaired", None)]
    done = m.fault_log[-1]
    assert done.parameters == ("R2",) and done.time == pytest.approx(float(lines[at].split(",")[0]))
    assert not [line for line in after if "alarm" in line], after


def test_a_stepped_monitors_arguments_and_rows_are_checked():
    """One-line errors for what a program gets wrong; a refused row leaves
    the monitor as it was (the next row is taken, a repair said before it
    still waits), and a report needs a row."""
    with pytest.raises(ArgumentTypeError, match="columns is int"):
        bgc.Monitor(CIRCUIT, 5)
    with pytest.raises(ArgumentValueError, match="episodes=True without a checkpoint"):
        bgc.Monitor(CIRCUIT, "time,u:V,y:f2,y:f6,y:e11", episodes=True)
    plain = bgc.Monitor(session("circuit"), "time,u:V,y:f2,y:f6,y:e11", particles=50)
    with pytest.raises(ArgumentValueError, match="a monitor without episodes accommodates no fault"):
        plain.repaired()
    with pytest.raises(DataError, match="no data row arrived"):
        plain.report()
    m = bgc.Monitor(session("circuit"), ["time", "u:V", "y:f2", "y:f6", "y:e11"], particles=50, checkpoint=1,
                    episodes=True)
    assert m.columns == ("time", "u:V", "y:f2", "y:f6", "y:e11")
    with pytest.raises(ArgumentValueError, match="no column 'y:f9'"):
        m.feed({"time": 0.05, "y:f9": 1.0})
    with pytest.raises(ArgumentValueError, match="the row has no time"):
        m.feed({"y:f2": 1.0})
    with pytest.raises(ArgumentTypeError, match="not a number"):
        m.feed([0.05, None, 2.0, 2.0, 2.0])
    with pytest.raises(ArgumentTypeError, match="row is bytes"):
        m.feed(b"0.05,10,2,2,2")
    with pytest.raises(ArgumentValueError, match="a comment or blank line is no row"):
        m.feed("# repaired")
    with pytest.raises(ArgumentValueError, match="parameters are the model's names"):
        m.repaired("R2 and R1")
    with pytest.raises(DataError, match="3 fields, expected 5"):
        m.feed([0.05, 10.0, 2.0])
    m.feed({"time": 0.05, "u:V": 10.0, "y:f2": 2.5, "y:f6": 2.5})  # e11 not measured
    assert np.isnan(m._run.rows[-1][4]) and m._run.rows[-1][:4] == [0.05, 10.0, 2.5, 2.5]
    m.repaired("R2")
    with pytest.raises(DataError, match="time 0.05 is not after the last row's"):
        m.feed([0.05, 10.0, 2.5, 2.5, 2.5])
    with pytest.raises(ArgumentValueError, match="a repair was said after the last row"):
        m.report()
    m.feed([0.1, 10.0, 2.5, 2.5, 2.5])  # the repair taken here: nothing accommodated, nothing to take out
    assert [type(e).__name__ for e in m.fault_log] == ["Repaired"] and m.fault_log[0].time == 0.1
    report = m.report()  # the record of the diagnoser watching since the repair; the rows read in all
    assert list(report.run.time) == [0.1] and report.stream == (2, 0.05)


def test_a_stepped_monitor_keeps_the_last_event_lines_only(monkeypatch):
    """A monitor that runs for months keeps a bounded memory: ``events`` holds
    the last ``EVENTS_KEPT`` lines, and each row still returns its own."""
    from bgc.service import public

    monkeypatch.setattr(public, "EVENTS_KEPT", 2)
    lines = _lines("R2:abrupt:1.2@2-6", 200)
    m = bgc.Monitor(session("circuit"), lines[0], checkpoint=1, episodes=True, particles=300)
    returned = [said for line in lines[1:] for said in m.feed(line)]
    assert len(returned) > 2 and m.events == tuple(returned[-2:])


def test_a_monitor_takes_more_repairs_and_bytes_than_a_run_file_may_hold(monkeypatch):
    """A monitor runs for months: its stream has no bound on its bytes, and
    a repair line may come as often as the plant is repaired. With a run
    file's bounds set to 6 comment lines and 3000 bytes, a fault-free stream
    of 200 rows (some 9000 bytes) with a ``# repaired`` line after every
    tenth row (20 of them) is read to its end, each repair taken at the row
    after it, where a run file of these lines is refused (as it was, the
    stream too, at its seventh comment line)."""
    from bgc.data import runs

    monkeypatch.setattr(runs, "MAX_COMMENT_LINES", 6)
    monkeypatch.setattr(runs, "MAX_RUN_BYTES", 3000)
    lines = plant(200, []).splitlines(keepends=True)
    out, repaired_before = [], []
    for line in lines:
        out.append(line)
        if line[:1].isdigit() and round(float(line.split(",")[0]) / 0.05) % 10 == 5:
            out.append("# repaired\n")
            repaired_before.append(len([x for x in out if x[:1].isdigit()]))  # the row the repair comes before
    rows = [line for line in lines if line[:1].isdigit()]
    assert len(repaired_before) == 20 and sum(map(len, out)) > 3000
    said = []
    report = bgc.monitor(session("circuit"), out, checkpoint=3.0, episodes=True, particles=200, seed=1,
                         events=said.append)
    times = [float(rows[k].split(",")[0]) for k in repaired_before]
    assert [line for line in said if line.startswith("repaired at t = ")] == [
        f"repaired at t = {t:g}: watching on the model as it was" for t in times]
    assert report.diagnosis.time[-1] == pytest.approx(float(rows[-1].split(",")[0]))
    with pytest.raises(DataError):
        runs.parse_run("".join(out), "plant.csv")


@pytest.mark.slow
def test_the_monitors_lines_never_go_back_in_time_and_a_late_drop_says_its_own_time():
    """A hypothesis dropped while its filters caught up on past samples, or by
    the weighing at the end, is learnt after lines dated later: its line is
    dated by the latest time said, and ends with the drop's own time (at
    the end: the step of its event in the report)."""
    from bgc.events import Dropped

    heard = []
    report = bgc.monitor(session("circuit"), _lines("R2:abrupt:0.6@5", 300), particles=300, events=heard.append)
    dated = [(float(line.split(":")[0].removeprefix("t = ")), line) for line in heard if line.startswith("t = ")]
    assert [t for t, _ in dated] == sorted(t for t, _ in dated)
    late = [(t, line.split(": ", 1)[1].split(" dropped")[0], float(line.rsplit(", at t = ", 1)[1]))
            for t, line in dated if " dropped " in line and ", at t = " in line]
    assert late and all(own < t for t, _, own in late)
    assert any(t < dated[-1][0] for t, _, _ in late)  # while the stream ran too, not only at its end
    end = report.diagnosis.time_of(len(report.diagnosis.time) - 1)
    drops = {e.hypothesis: report.diagnosis.time_of(e.step) for e in report.diagnosis.events
             if isinstance(e, Dropped)}
    at_end = [(name, own) for t, name, own in late if t == end]
    assert at_end and all(drops[name] == pytest.approx(own) for name, own in at_end)
