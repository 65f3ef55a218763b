"""Data as loggers write them (bgc/data/columns.py): a column map from a
logger's names to bgc's with scales and offsets, ISO 8601 timestamps, and
errors that list what the model reads and the map line that would fix them.
Every expected number is derived here by hand (a scale times a logged value
plus an offset; a timestamp's seconds by calendar.timegm), not read back
from bgc."""

import calendar
import io

import numpy as np
import pytest

import bgc
from bgc.data import runs
from bgc.diagnosis.options import DiagnosisOptions
from bgc.data.columns import ColumnMap, Entry, Reading, iso_seconds, parse_map, read_map
from bgc.errors import ArgumentValueError, DataError

from conftest import bgc_cli, session

TANKS_COLUMNS = ("u:f_in", "y:F10", "y:F12", "y:F20")
MAP = """\
# the logger of tank rig 2
time: stamp
columns:
  pump_flow: u:f_in
  flow10_lps: y:F10
  flow12_mlps: {name: y:F12, scale: 0.001}
  flow20_lps: {name: y:F20, scale: 2, offset: -0.5}
  temp_C: skip
"""


def _logger(rows: list[tuple]) -> str:
    """A logger's file: its own names, a text column, times as written."""
    lines = ["stamp,temp_C,pump_flow,flow10_lps,flow12_mlps,flow20_lps"]
    lines += [",".join(str(v) for v in r) for r in rows]
    return "\n".join(lines) + "\n"


ROWS = [("2026-03-01T08:00:00.5Z", "ok", 1.0, 0.57, 517.0, 0.75),
        ("2026-03-01T08:00:01Z", "ok", 1.0, 0.58, "", 0.80),
        ("2026-03-01T09:00:01.5+01:00", "hot", 1.0, "", 520.0, 0.85)]


def test_a_logger_file_is_read_through_its_map():
    m = parse_map(MAP, "rig2.yaml")
    run = runs.parse_run(_logger(ROWS), "rig2.csv", Reading(m, TANKS_COLUMNS))
    start = calendar.timegm((2026, 3, 1, 8, 0, 0))  # seconds of 2026-03-01 08:00:00 UTC
    assert run.time.tolist() == [start + 0.5, start + 1.0, start + 1.5]  # 09:00:01.5+01:00 is 08:00:01.5 UTC
    assert run.inputs["f_in"].tolist() == [1.0, 1.0, 1.0]
    assert run.measurements["F10"][:2].tolist() == [0.57, 0.58] and np.isnan(run.measurements["F10"][2])
    f12 = run.measurements["F12"]
    assert f12[0] == pytest.approx(0.517, rel=1e-15) and np.isnan(f12[1]) and f12[2] == pytest.approx(0.52)
    assert run.measurements["F20"].tolist() == pytest.approx([2 * 0.75 - 0.5, 2 * 0.80 - 0.5, 2 * 0.85 - 0.5])
    assert set(run.measurements) == {"F10", "F12", "F20"} and not run.states  # temp_C left out


def test_a_stream_is_read_through_the_map_row_by_row():
    m = parse_map(MAP, "rig2.yaml")
    reader = runs.RowReader(io.StringIO(_logger(ROWS)), "rig2.csv", Reading(m))
    assert reader.columns == ["time", "u:f_in", "y:F10", "y:F12", "y:F20"]
    rows = list(reader)
    start = calendar.timegm((2026, 3, 1, 8, 0, 0))
    assert [r[0][0] for r in rows] == [start + 0.5, start + 1.0, start + 1.5]
    assert rows[0][0][3] == pytest.approx(0.517) and rows[2][0][4] == pytest.approx(2 * 0.85 - 0.5)
    assert [r[1] for r in rows] == [2, 3, 4]  # the file's line numbers


def test_iso_times_without_a_zone_are_utc_and_take_the_models_unit():
    base = calendar.timegm((2025, 12, 31, 23, 59, 0))
    assert iso_seconds("2025-12-31T23:59:00") == base
    assert iso_seconds("2025-12-31 23:59:00.25") == base + 0.25
    assert iso_seconds("2026-01-01T00:59:00+01:00") == base
    assert iso_seconds("12.5") is None and iso_seconds("yesterday") is None
    text = "time,y:F10\n2025-12-31T23:59:00Z,1\n2026-01-01T00:01:00Z,2\n"
    minutes = runs.parse_run(text, "r.csv", Reading(None, (), 60.0, "min"))
    assert minutes.time.tolist() == [base / 60, base / 60 + 2]
    with pytest.raises(DataError, match=r"r\.csv:2: an ISO time, and the model's time unit 'fortnight'"):
        runs.parse_run(text, "r.csv", Reading(None, (), None, "fortnight"))


def test_an_unknown_column_lists_what_the_model_reads_and_the_map_line_that_fixes_it():
    text = "time,force_N,y:F10\n0.5,1.0,0.2\n"
    with pytest.raises(DataError) as e:
        runs.parse_run(text, "log.csv", Reading(None, TANKS_COLUMNS))
    line = str(e.value)
    assert line.startswith("log.csv:1: column 'force_N' is not time, u:NAME")
    assert "the model reads time, u:f_in, y:F10, y:F12, y:F20" in line
    assert "'force_N: u:f_in'" in line and "'force_N: skip'" in line  # u:f_in: the first column not yet there
    with pytest.raises(DataError, match=r"log\.csv:1: the first column must be 'time', not 'stamp' \(.*time: names"):
        runs.parse_run("stamp,y:F10\n0.5,0.2\n", "log.csv")
    with pytest.raises(DataError) as e:  # a logger's file as it is: every column its own
        runs.parse_run(_logger(ROWS), "rig2.csv", Reading(None, TANKS_COLUMNS))
    assert str(e.value) == (
        "rig2.csv:1: 6 columns are not bgc's (stamp, temp_C, pump_flow, flow10_lps, flow12_mlps, flow20_lps); "
        "the model reads time, u:f_in, y:F10, y:F12, y:F20 (give a column map with columns=FILE "
        "(docs/format.md, section 9): 'time: stamp' and under columns: a line per column, e.g. "
        "'temp_C: u:f_in' or 'temp_C: skip')")


@pytest.mark.parametrize("text, message", [
    ("columns:\n  a: u:f_in\n  a: y:F10\n", r"m\.yaml:3: column 'a' is mapped twice \(line 2\)"),
    ("columns:\n  a: y:F10\n  b: y:F10\n", r"m\.yaml:3: two columns map to y:F10 \(line 2\)"),
    ("columns:\n  a: F10\n", r"m\.yaml:2: 'F10' is not u:NAME, y:NAME or skip"),
    ("columns:\n  a: {name: y:F10, scale: 0}\n", r"m\.yaml:2: scale of 'a' is 0"),
    ("columns:\n  a: {name: y:F10, scale: big}\n", r"m\.yaml:2: scale of 'a' is not a finite number"),
    ("columns:\n  a: {name: y:F10, gain: 2}\n", r"m\.yaml:2: unknown key 'gain' of column 'a'"),
    ("columns:\n  a: {scale: 2}\n", r"m\.yaml:2: column 'a' has no name:"),
    ("time: stamp\nrows: 3\n", r"m\.yaml:2: unknown key 'rows'"),
    ("columns: [a, b]\n", r"m\.yaml:1: columns: maps each logger column"),
    ("columns:\n  a: y:F10\n b: 3\n", r"m\.yaml:3: YAML syntax error"),
    ("", r"m\.yaml: the column map is empty"),
    ("time: stamp\ncolumns:\n  stamp: y:F10\n", r"m\.yaml:3: column 'stamp' is mapped twice \(it is the time column\)"),
])
def test_a_wrong_map_is_one_line_naming_its_file_and_line(text, message):
    with pytest.raises(DataError, match=message):
        parse_map(text, "m.yaml")


def test_a_map_naming_a_column_the_file_lacks_says_which_columns_there_are(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text("columns:\n  pump: u:f_in\n  flow10: y:F10\n", encoding="utf-8")
    m = read_map(path)
    assert m == ColumnMap("time", (Entry("pump", "u:f_in", line=2), Entry("flow10", "y:F10", line=3)), str(path))
    with pytest.raises(DataError, match=r"m\.yaml:3: column 'flow10' is not in log\.csv:1 .*its columns are time, "
                                        r"pump, flow_10"):
        runs.parse_run("time,pump,flow_10\n0.5,1,2\n", "log.csv", Reading(m))
    with pytest.raises(DataError, match=r"no such file"):
        read_map(tmp_path / "missing.yaml")


def test_a_map_naming_a_sensor_or_input_the_model_lacks_is_refused_at_its_line():
    # a typo in a target (y:F21 for y:F20) would leave the column unread and the sensor missing
    typo = parse_map(MAP.replace("name: y:F20", "name: y:F21"), "rig2.yaml")
    with pytest.raises(DataError, match=r"^rig2\.yaml:7: column 'flow20_lps' is mapped to y:F21, and the model has no "
                                        r"sensor F21 \(did you mean y:F20\? map it to one of u:f_in, y:F10"):
        runs.parse_run(_logger(ROWS), "rig2.csv", Reading(typo, TANKS_COLUMNS))
    pump = parse_map(MAP.replace("pump_flow: u:f_in", "pump_flow: u:pump"), "rig2.yaml")
    with pytest.raises(DataError, match=r"^rig2\.yaml:4: .* the model has no input pump "):
        runs.parse_run(_logger(ROWS), "rig2.csv", Reading(pump, TANKS_COLUMNS))
    assert runs.parse_run(_logger(ROWS), "rig2.csv", Reading(pump))  # a reader told nothing of the model: as before


def test_a_mode_beyond_the_models_is_refused_at_its_line():
    text = "time,mode,y:v\n0.5,1,0.1\n1.0,2,0.1\n1.5,3,0.1\n"
    reading = Reading(expected=("y:v",), modes=("open", "closed"), model="relay")
    with pytest.raises(DataError, match=r"^m\.csv:4: mode 3 is no mode of relay \(1 to 2: open, closed\)"):
        runs.parse_run(text, "m.csv", reading)
    assert runs.parse_run(text.replace(",3,", ",2,"), "m.csv", reading).modes.tolist() == [1, 2, 2]


@pytest.mark.slow
def test_a_diagnosis_of_the_loggers_file_is_the_diagnosis_of_bgcs_own(tmp_path):
    """The two tanks' scenario run written as a logger would (its names, ISO
    times from an hour of the day, F12 in millilitres, a text column) and
    read through the map: the same verdict, candidates and estimate as the
    run itself, the onset shifted by the clock's start."""
    tanks = session("two_tank")
    simulated = bgc.diagnose(tanks, scenario="R12:abrupt:1.0@60", seed=4, steps=180,
                             options=DiagnosisOptions(particles=150, seed=4, workers=1))
    run = simulated.run
    start = calendar.timegm((2026, 3, 1, 8, 0, 0))
    rows = []
    for k, t in enumerate(run.time):
        stamp = _iso(start + float(t))
        rows.append((stamp, "ok", repr(float(run.inputs["f_in"][k])), repr(float(run.measurements["F10"][k])),
                     repr(float(run.measurements["F12"][k]) * 1000),
                     repr((float(run.measurements["F20"][k]) + 0.5) / 2)))
    (tmp_path / "rig2.csv").write_text(_logger(rows), encoding="utf-8")
    (tmp_path / "rig2.yaml").write_text(MAP, encoding="utf-8")
    logged = bgc.diagnose(tanks, data=tmp_path / "rig2.csv", columns=tmp_path / "rig2.yaml",
                          options=simulated.options)
    own = bgc.diagnose(tanks, data=run, options=simulated.options)
    a, b = own.diagnosis, logged.diagnosis
    assert (a.verdict, a.candidates) == (b.verdict, b.candidates) and a.candidates == ("R12_abrupt",)
    assert b.onset_step == a.onset_step and b.onset == a.onset + start  # a step of the grid, and its time
    assert b.estimate.value == pytest.approx(a.estimate.value, rel=1e-6)
    with pytest.raises(ArgumentValueError, match="columns= with a Run"):
        bgc.diagnose(tanks, data=run, columns=tmp_path / "rig2.yaml")


def _iso(seconds: float) -> str:
    whole = int(seconds // 1)
    y, mo, d, h, mi, s = __import__("time").gmtime(whole)[:6]
    return f"{y:04d}-{mo:02d}-{d:02d}T{h:02d}:{mi:02d}:{s:02d}.{round((seconds - whole) * 1e6):06d}Z"


@pytest.mark.slow
@pytest.mark.long
def test_the_commands_take_a_column_map(tmp_path):
    """``--columns`` on diagnose, monitor (through a stream), filter and
    calibrate; a map that does not fit is one line with its file and line."""
    text = "stamp,pump,flow10,flow12,flow20\n" + "".join(f"{0.5 * k},1.0,{0.5 + 0.001 * k},0.1,0.4\n"
                                                         for k in range(1, 41))
    (tmp_path / "log.csv").write_text(text, encoding="utf-8")
    (tmp_path / "m.yaml").write_text("time: stamp\ncolumns:\n  pump: u:f_in\n  flow10: y:F10\n  flow12: y:F12\n"
                                     "  flow20: y:F20\n", encoding="utf-8")
    (tmp_path / "bad.yaml").write_text("time: stamp\ncolumns:\n  pump: u:f_in\n  flow_10: y:F10\n", encoding="utf-8")
    model = "models/two_tank.yaml"
    out = bgc_cli("diagnose", model, "--data", tmp_path / "log.csv", "--columns", tmp_path / "m.yaml",
                  "--particles", "100", "-o", tmp_path / "d")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("two_tank: ")
    out = bgc_cli("monitor", model, "--data", "-", "--columns", tmp_path / "m.yaml", "--particles", "100",
                  "-o", tmp_path / "m", input=text)
    assert out.returncode == 0, out.stderr
    out = bgc_cli("filter", model, tmp_path / "log.csv", "--columns", tmp_path / "m.yaml", "--filter", "gpf",
                  "--generated", "generated", "--particles", "50")
    assert out.returncode == 0, out.stderr
    for command in (["diagnose", model, "--data"], ["calibrate", model, "-o", tmp_path / "c.yaml", "--data"]):
        out = bgc_cli(*command, tmp_path / "log.csv", "--columns", tmp_path / "bad.yaml")
        assert out.returncode != 0 and "Traceback" not in out.stderr
        assert out.stderr.strip().splitlines()[-1].startswith(f"{tmp_path / 'bad.yaml'}:4: column 'flow_10' is not in ")
    out = bgc_cli("diagnose", model, "--scenario", "none", "--columns", tmp_path / "m.yaml")
    assert out.returncode != 0 and "--columns applies to --data" in out.stderr


def test_an_input_a_logger_writes_when_it_changes_is_one_note_not_one_per_change():
    from bgc import events
    from bgc.output.events import notes

    held = [events.InputHeld("Q", k, v) for k, v in ((3, 250.0), (203, 150.0), (403, 250.0))]
    lines = notes([*held, events.InputHeld("T_amb", 9, 20.0)], lambda k: k * 1.0)
    assert lines == ["input u:Q is empty 3 times, from t = 3 to t = 403: each time its last value is held until a "
                     "value arrives (a logger that writes it when it changes; the report lists each)",
                     "input u:T_amb is empty: its last value 20 is held until a value arrives"]
