"""A run's times as people read them (bgc/data/clock.py): a run of
absolute times (ISO 8601 timestamps, a logger's Unix seconds) has them
written back as ISO 8601 UTC timestamps by the command line, the monitor and
the report, by the one rule the plots' time axis follows; a run counted from
its start keeps its numbers. Every expected timestamp is derived here with
Python's datetime, from a known instant or from the data file's own cells,
not read back from bgc."""

from __future__ import annotations

import csv
import datetime as dt
import json
import math
import re

import numpy as np
import pytest

import bgc
from bgc import events as ev
from bgc.data.clock import Clock
from bgc.output import plots
from bgc.output.events import fault_sentence, sentence
from bgc.output.labels import Labels

from conftest import ROOT, bgc_cli, session

UTC = dt.timezone.utc
EPOCH = dt.datetime(1970, 1, 1, tzinfo=UTC)
LOGGER = ROOT / "docs" / "examples" / "tank_logger.csv"
LOGGER_MAP = ROOT / "docs" / "examples" / "tank_logger.yaml"
#: Seconds in one unit of the model's time, as docs/format.md section 9 lists them (None: seconds).
UNIT_SECONDS = {None: 1.0, "s": 1.0, "ms": 1e-3, "min": 60.0, "h": 3600.0, "day": 86400.0}
#: An ISO 8601 UTC timestamp as bgc writes it: the fraction of a second without trailing zeros.
ISO = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d*[1-9])?Z")
#: A Unix time as a number: ten digits (seconds) to thirteen (milliseconds), not inside a longer number nor
#: after a decimal point, or written short with an exponent (``1.77243e+09``).
UNIX = re.compile(r"(?<![\d.])\d{10,13}(?!\d)|\d\.\d+e\+0?(9|1[0-2])\b")


def _iso(when: dt.datetime) -> str:
    """``when`` as an ISO 8601 UTC timestamp, by datetime's own isoformat:
    to the microsecond, then the fraction's trailing zeros (and a bare
    point) dropped, ``Z`` for UTC."""
    text = when.astimezone(UTC).replace(tzinfo=None).isoformat(timespec="microseconds")
    return text.rstrip("0").rstrip(".") + "Z"


def _instant(stamp: str) -> dt.datetime:
    """An ISO 8601 timestamp (``Z`` or an offset) as an aware datetime."""
    return dt.datetime.fromisoformat(stamp.replace("Z", "+00:00"))


def _in_unit(when: dt.datetime, unit: str | None) -> float:
    """``when`` as bgc reads a timestamp: time since 1970-01-01 UTC in ``unit``."""
    return ((when - EPOCH) / dt.timedelta(microseconds=1)) / 1e6 / UNIT_SECONDS[unit]


def _logger_stamps() -> list[str]:
    """The timestamp column of docs/examples/tank_logger.csv, as written."""
    with LOGGER.open(encoding="utf-8") as f:
        rows = [r for r in csv.reader(line for line in f if not line.startswith("#"))]
    return [r[0] for r in rows[1:]]


# -- the rule ------------------------------------------------------------------------------------------------

INSTANTS = [dt.datetime(2026, 3, 2, 6, 31, 0, 500000, tzinfo=UTC),  # a logger's half second
            dt.datetime(2026, 3, 2, 6, 31, 0, tzinfo=UTC),  # a whole second: no fraction
            dt.datetime(2025, 11, 21, 0, 55, 20, 123456, tzinfo=UTC),  # to the microsecond
            dt.datetime(2026, 3, 2, 6, 31, 10, 250000, tzinfo=UTC),  # 10 s: the zero before the point stays
            dt.datetime(1999, 12, 31, 23, 59, 59, 999999, tzinfo=UTC),
            dt.datetime(2026, 3, 2, 6, 31, 0, 1, tzinfo=UTC)]


@pytest.mark.parametrize("unit", [None, "s", "ms", "min", "h", "day"])
@pytest.mark.parametrize("when", INSTANTS, ids=lambda w: w.isoformat())
def test_an_absolute_time_is_written_as_its_iso_timestamp_in_any_unit(unit, when):
    """A known instant, read as bgc reads a timestamp (time since 1970 in
    the model's unit), is written back as that instant, to the microsecond."""
    start = _in_unit(dt.datetime(2026, 3, 2, 6, 30, 0, 500000, tzinfo=UTC), unit)
    clock = Clock.of([start, start + 1.0], unit)
    assert clock.absolute
    assert clock.text(_in_unit(when, unit)) == _iso(when)
    assert ISO.fullmatch(clock.text(_in_unit(when, unit)))


def test_the_fraction_keeps_its_digits_as_far_as_they_are_not_zero():
    """The fraction of a second to the microsecond, its trailing zeros dropped; none for a whole second."""
    clock = Clock.of([1.0e9], "s")
    base = dt.datetime(2026, 3, 2, 6, 31, 0, tzinfo=UTC)
    for micro, tail in ((500000, ".5"), (120000, ".12"), (123456, ".123456"), (1, ".000001"), (0, "")):
        assert clock.text(_in_unit(base + dt.timedelta(microseconds=micro), "s")) == f"2026-03-02T06:31:00{tail}Z"


@pytest.mark.parametrize("first, unit, absolute", [
    (0.0, "s", False),
    (99_999_999.0, "s", False),  # 1973-03-03 less a second
    (1e8, "s", True),
    (1.7724330605e9, "s", True),
    (1.7724330605e9, None, True),  # no unit: seconds, as a timestamp is read
    (1.7724330605e12, "ms", True),
    (1.7724330605e9, "ms", False),  # 20 days after 1970
    (29540550.0, "min", True),
    (1.7724330605e9, "min", False),  # past the year 5000
    (99_999_999_999.0, "s", True),
    (1e11, "s", False),
    (math.nan, "s", False),
    (1.7724330605e9, "fortnight", False),  # a unit bgc does not convert
])
def test_which_runs_are_absolute_the_messages_and_the_plots_agree(first, unit, absolute):
    """The one rule: the first time, in seconds, from 1e8 (1973-03-03) to
    below 1e11; the plots' time axis and the messages' clock decide alike."""
    clock = Clock.of([first, first + 1.0], unit)
    axis = plots.time_axis(np.array([first, first + 1.0]), Labels(unit))
    assert clock.absolute == absolute
    assert ("since" in axis.label) == absolute and (axis.origin != 0.0) == absolute


def test_times_not_absolute_stay_numbers_of_12_significant_digits():
    """A run counted from its start, or no clock: numbers, 12 significant digits."""
    clock = Clock.of([0.5, 1.0], "s")
    assert not clock.absolute
    assert [clock.text(t) for t in (60.5, 60.0, 0.1 + 0.2, 1.0 / 3.0, 1772433060.5)] == \
        ["60.5", "60", "0.3", "0.333333333333", "1772433060.5"]
    assert Clock().text(1772433060.5) == "1772433060.5"  # no clock said: a number


def test_a_sentence_writes_times_by_its_clock_and_durations_as_numbers():
    """An event's sentence and a fault's words write a run's times as the
    clock says (the same sentence without one: numbers); a gap's steps stay
    a number."""
    start = dt.datetime(2026, 3, 2, 6, 30, 0, 500000, tzinfo=UTC)
    times = [_in_unit(start + dt.timedelta(seconds=0.5 * k), "s") for k in range(40)]
    clock = Clock.of(times, "s")
    said = sentence(ev.Gap(step=10, steps=20), lambda k: times[k], clock=clock)
    assert said == (f"no sample for 20 steps from t = {_iso(start + dt.timedelta(seconds=5))} to t = "
                    f"{_iso(start + dt.timedelta(seconds=14.5))}: the filters predict across the gap")
    assert sentence(ev.Gap(step=10, steps=20), lambda k: 0.5 * k) == \
        "no sample for 20 steps from t = 5 to t = 14.5: the filters predict across the gap"
    from bgc.diagnosis.values import Estimate

    e = Estimate("R12", "abrupt", "bias", 1.0, 0.01, 0.98, 1.02, 0.95, 3.0, 2.0, subject="R12")
    assert fault_sentence(e, times[21], clock=clock).endswith(f"since t = {_iso(start + dt.timedelta(seconds=10.5))}")


# -- the commands ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def logger_diagnosis(tmp_path_factory):
    """``bgc diagnose`` of docs/examples/tank_logger.csv through its column
    map, as docs/format.md section 9 runs it: (what it printed, its folder)."""
    folder = tmp_path_factory.mktemp("iso") / "rig-b"
    out = bgc_cli("diagnose", "models/two_tank.yaml", "--data", LOGGER, "--columns", LOGGER_MAP, "-o", folder)
    assert out.returncode == 0, out.stderr
    return out.stdout, folder


@pytest.mark.slow
def test_a_loggers_iso_times_are_printed_as_the_files_own_timestamps(logger_diagnosis):
    """The detection, the onset and the fault's "since" are printed as ISO
    timestamps that are instants of the file's own time column (the grid
    starts at its first row, every step a row of it), no Unix number in the
    lines or report.md; report.json keeps the numbers and says they are
    absolute."""
    stdout, folder = logger_diagnosis
    stamps = {_instant(s) for s in _logger_stamps()}
    detected = re.search(r"detected at t = (\S+) \(\w+\), onset t = (\S+)\n", stdout)
    since = re.search(r"since t = (\S+)\n", stdout)
    assert detected and since, stdout
    printed = [*detected.groups(), since.group(1)]
    for stamp in printed:  # each an ISO timestamp, and an instant of the file's own time column
        assert ISO.fullmatch(stamp) and _instant(stamp) in stamps, (stamp, stdout)
    assert not UNIX.search(stdout), stdout
    report = (folder / "report.md").read_text(encoding="utf-8")
    assert not UNIX.search(report) and f"alarm at t = {detected.group(1)}:" in report
    # report.json keeps numbers: seconds since 1970 (the model's unit), and says they are absolute
    data = json.loads((folder / "report.json").read_text(encoding="utf-8"))
    assert data["settings"]["absolute_times"] is True
    assert data["detection"]["time"] == pytest.approx(_in_unit(_instant(detected.group(1)), "s"), abs=1e-6)
    assert data["onset"] == pytest.approx(_in_unit(_instant(detected.group(2)), "s"), abs=1e-6)


@pytest.mark.slow
def test_a_run_of_plain_numbers_prints_numbers(tmp_path):
    """A simulated run, its times counted from 0: the detection line prints
    numbers, each a time of the run's own (run.csv), and no timestamp."""
    out = bgc_cli("diagnose", "models/two_tank.yaml", "--scenario", "R12:abrupt:1.0@20", "--steps", "80",
                  "--particles", "200", "-o", tmp_path / "d")
    assert out.returncode == 0, out.stderr
    detected = re.search(r"detected at t = (\S+) \(\w+\), onset t = (\S+)\n", out.stdout)
    assert detected, out.stdout
    with (tmp_path / "d" / "run.csv").open(encoding="utf-8") as f:
        times = {float(r[0]) for r in csv.reader(line for line in f if not line.startswith("#")) if r[0] != "time"}
    for printed in detected.groups():  # a number, and a time of the run's own
        assert re.fullmatch(r"\d+(\.\d+)?", printed), out.stdout
        assert min(abs(float(printed) - t) for t in times) < 1e-9, (printed, out.stdout)
    assert not ISO.search(out.stdout), out.stdout
    data = json.loads((tmp_path / "d" / "report.json").read_text(encoding="utf-8"))
    assert data["settings"]["absolute_times"] is False


@pytest.mark.slow
def test_the_monitor_writes_a_loggers_unix_seconds_as_timestamps():
    """A logger that writes Unix seconds (numbers): the monitor's lines, its
    diagnosis's repr and the report's events write them as timestamps; a
    hole in the rows is said with its times as dates, its steps a number."""
    stamps = _logger_stamps()
    with LOGGER.open(encoding="utf-8") as f:
        rows = [r for r in csv.reader(line for line in f if not line.startswith("#"))][1:]
    hole = range(20, 35)  # 15 rows of 0.5 s missing: more than the 10 steps of the gap limit
    m = bgc.Monitor(session("two_tank"), ["time", "u:f_in", "y:F10", "y:F12", "y:F20"], particles=200)
    lines = []
    for k, r in enumerate(rows[:150]):
        if k in hole:
            continue
        t = _in_unit(_instant(stamps[k]), "s")
        lines += m.feed([t, *(0.001 * float(v) for v in r[1:5])])
    report = m.report()
    gap = next(line for line in lines if "no sample for" in line)
    first, last = (_iso(_instant(stamps[k])) for k in (hole[0], hole[-1]))
    assert gap == (f"t = {first}: no sample for {len(hole)} steps from t = {first} to t = {last}: the filters "
                   "predict across the gap")
    alarm = next(line for line in lines if "alarm on" in line)
    assert ISO.fullmatch(alarm.split(": ")[0].removeprefix("t = "))
    assert not any(UNIX.search(line) for line in lines), lines
    d = report.diagnosis
    onset = EPOCH + dt.timedelta(seconds=d.onset)
    assert onset in {_instant(s) for s in stamps} and f"onset t = {_iso(onset)}," in repr(d)
    sentences = report.table("events").column("sentence")
    assert sentences and not any(UNIX.search(text) for text in sentences), sentences


def test_bgc_filter_says_when_its_estimate_is_as_a_timestamp():
    """``bgc filter`` on the logger's file: its estimate at the last row, that row's timestamp."""
    out = bgc_cli("filter", "models/two_tank.yaml", LOGGER, "--columns", LOGGER_MAP, "--fault", "R12:abrupt",
                  "--filter", "gpf", "--particles", "50", "--generated", "generated")
    assert out.returncode == 0, out.stderr
    last = _iso(_instant(_logger_stamps()[-1]))
    assert re.search(rf"estimate of R12\b.* at t = {re.escape(last)}: ", out.stdout), out.stdout


def test_report_json_keeps_an_events_own_time_in_full():
    """An event that holds a time itself (a sensor taken out, a sample
    skipped, an episode's alarm and onset) keeps it in report.json with 12
    significant digits, as every time there is, not a value's 6: a logger's
    Unix seconds and their fraction."""
    from bgc import events as ev
    from bgc.output.events import record

    t = 1772433061.5
    clock = Clock.of([t], "s")
    out = record(ev.SensorExcluded("F12", "frozen", t), lambda k: None, clock=clock)
    assert out["time"] == t and "2026-03-02T06:31:01.5Z" in out["text"]
    assert not UNIX.search(out["text"])


# -- errors about the file's own rows --------------------------------------------------------------------------

def _logger_lines() -> list[str]:
    return LOGGER.read_text(encoding="utf-8").splitlines(keepends=True)


def test_a_row_out_of_order_in_an_iso_file_is_named_by_its_own_timestamps(tmp_path):
    """Two rows swapped in the logger's ISO file: the error names the later
    line, and its time and the row before's as the file writes them (the
    instants of its own cells, by datetime), from `bgc diagnose` and from
    `bgc monitor` reading the same rows through a pipe."""
    lines = _logger_lines()
    data = [i for i, line in enumerate(lines) if line[:1].isdigit()]
    a, b = data[9], data[10]
    lines[a], lines[b] = lines[b], lines[a]
    path = tmp_path / "swapped.csv"
    path.write_text("".join(lines), encoding="utf-8")
    early, late = (_iso(_instant(lines[i].split(",")[0])) for i in (b, a))
    said = f"swapped.csv:{b + 1}: time {early} does not increase (the row before has {late})"
    out = bgc_cli("diagnose", "models/two_tank.yaml", "--data", path, "--columns", LOGGER_MAP, "-o", tmp_path / "d")
    assert out.returncode != 0 and said in out.stderr and "Traceback" not in out.stderr, out.stderr
    out = bgc_cli("monitor", "models/two_tank.yaml", "--data", "-", "--columns", LOGGER_MAP, "--particles", "100",
                  "-o", tmp_path / "m", input="".join(lines))
    assert f"<stdin>:{b + 1}: time {early} does not increase (the row before has {late})" in out.stderr, out.stderr
    assert not UNIX.search(out.stderr), out.stderr


def test_a_clock_that_jumps_past_the_monitors_memory_is_bridged_and_said_in_the_files_own_times(tmp_path):
    """The logger's clock jumps three hours (21,600 steps of 0.5 s, more than
    a diagnosis of the two tanks holds in memory) and the rows go on, while
    the monitor watches: it bridges the gap (tests/test_bridge.py) and says
    so in one line dated by the file's own timestamps; its report's record
    starts at the row after the jump (no step of the gap in it)."""
    lines = _logger_lines()
    data = [i for i, line in enumerate(lines) if line[:1].isdigit()]
    jump = data[30]
    for i in data[30:]:
        stamp = lines[i].split(",")[0]
        later = _instant(stamp) + dt.timedelta(hours=3)
        lines[i] = lines[i].replace(stamp, later.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z", 1)
    out = bgc_cli("monitor", "models/two_tank.yaml", "--data", "-", "--columns", LOGGER_MAP, "-o", tmp_path / "m",
                  input="".join(lines))
    before, first = (_instant(lines[i].split(",")[0]) for i in (data[29], jump))
    steps = round((first - before) / dt.timedelta(seconds=0.5)) - 1
    assert out.returncode == 0 and out.stderr == "", out.stderr
    said = [line for line in out.stdout.splitlines() if "no data from" in line]
    assert said == [f"t = {_iso(first)}: no data from t = {_iso(before)} to t = {_iso(first)} ({steps} steps, more "
                    f"than the diagnosis holds): " + said[0].split("holds): ", 1)[1]] and steps == 21600, out.stdout
    report = json.loads((tmp_path / "m" / "report.json").read_text(encoding="utf-8"))
    assert report["data"]["steps"] == len(data) - 30
    assert report["data"]["t_first"] == pytest.approx(_in_unit(first, "s"), abs=1e-6)
    bridged = [e for e in report["events"] if e["event"] == "Bridged"]
    assert len(bridged) == 1 and bridged[0]["began"] == pytest.approx(_in_unit(before, "s"), abs=1e-6)


def test_a_folders_bad_row_is_named_by_its_own_file_and_line(tmp_path):
    """A folder of a logger's two files whose second starts before the first
    ends: `bgc monitor` reads them one after the other and names the bad row
    by its own file and line (the second file's first row, line 3: a comment
    and the column names before it), not by the folder and a count over
    both."""
    lines = _logger_lines()
    head = [line for line in lines if not line[:1].isdigit()]
    data = [line for line in lines if line[:1].isdigit()]
    folder = tmp_path / "logs"
    folder.mkdir()
    (folder / "d1.csv").write_text("".join(head + data[:60]), encoding="utf-8")
    (folder / "d2.csv").write_text("".join(head + data[50:100]), encoding="utf-8")
    out = bgc_cli("monitor", "models/two_tank.yaml", "--data", folder, "--columns", LOGGER_MAP, "--particles",
                  "100", "-o", tmp_path / "m")
    early, late = (_iso(_instant(row.split(",")[0])) for row in (data[50], data[59]))
    bad = f"{folder / 'd2.csv'}:{len(head) + 1}: time {early} does not increase (the row before has {late})"
    assert out.returncode != 0 and bad in out.stderr, out.stderr


def test_a_clock_two_days_ahead_is_refused_as_a_jump_before_the_memory_rule(tmp_path):
    """`bgc diagnose` of the logger's file with its clock two days ahead from
    its 41st row: the refusal of a clock that jumped (its data row and time,
    the steps of the gap, derived here), not the memory rule's."""
    lines = _logger_lines()
    data = [i for i, line in enumerate(lines) if line[:1].isdigit()]
    for i in data[40:]:
        stamp = lines[i].split(",")[0]
        later = _instant(stamp) + dt.timedelta(days=2)
        lines[i] = lines[i].replace(stamp, later.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z", 1)
    path = tmp_path / "jumped.csv"
    path.write_text("".join(lines), encoding="utf-8")
    out = bgc_cli("diagnose", "models/two_tank.yaml", "--data", path, "--columns", LOGGER_MAP, "-o", tmp_path / "d")
    after, before = (_instant(lines[i].split(",")[0]) for i in (data[40], data[39]))
    steps = round((after - before) / dt.timedelta(seconds=0.5)) - 1
    said = (f"jumped.csv, data row 41: time {_iso(after)} is {steps} steps of dt = 0.5 after the row before it, more "
            "than 100000")
    assert out.returncode != 0 and said in out.stderr and "GB" not in out.stderr, out.stderr


def test_report_json_keeps_the_streams_first_time_in_full(tmp_path):
    """report.json's ``data.stream.t_first_read`` (the first row the monitor
    read) is the logger's first timestamp to the half second, as
    ``data.t_first`` is (it was rounded to 6 digits: 50 minutes early)."""
    lines = _logger_lines()
    first = next(line for line in lines if line[:1].isdigit()).split(",")[0]
    head = [line for line in lines if not line[:1].isdigit()]
    rows = [line for line in lines if line[:1].isdigit()][:60]
    out = bgc_cli("monitor", "models/two_tank.yaml", "--data", "-", "--columns", LOGGER_MAP, "--particles", "100",
                  "-o", tmp_path / "m", input="".join(head + rows))
    assert out.returncode == 0, out.stderr
    data = json.loads((tmp_path / "m" / "report.json").read_text(encoding="utf-8"))["data"]
    assert data["stream"]["t_first_read"] == pytest.approx(_in_unit(_instant(first), "s"), abs=1e-6)
    assert data["stream"]["rows_read"] == 60
