"""``bgc.monitor``: the monitor from Python (its doctest runs the fault log of
an intermittent fault). A generator's rows are diagnosed as it yields them,
a malformed row ends the stream with the report of the rows before it, and
the arguments are checked before any work."""

from __future__ import annotations

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
