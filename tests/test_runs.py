"""Run files (bgc/data/runs.py): the streaming reader's limits on hostile
files (comment floods, blank floods, endless lines, unterminated quotes,
infinite numbers), the memory it takes, and the one check a run from a file
and a run built in Python both go through (``check_run``)."""

import os

import numpy as np
import pytest

from bgc.errors import DataError
from bgc.data import runs

from conftest import peak_memory

HEAD = "# model rc: 3 steps\n"
BODY = "time,u:V,y:e3,x:q\n0.5,1,2.5,0.1\n1.0,1,2.25,0.2\n1.5,1,,0.3\n"


def error(text: str, name: str = "bad.csv") -> str:
    with pytest.raises(DataError) as info:
        runs.parse_run(text, name)
    return info.value.line()


def file_error(path) -> str:
    with pytest.raises(DataError) as info:
        runs.read_run(path)
    return info.value.line()


# ------------------------------------------------------------ what a good file gives
def test_a_run_reads_with_its_source_header_and_missing_samples():
    run = runs.parse_run(HEAD + BODY, "rc.csv")
    assert run.source == "rc.csv" and run.model == "rc" and run.header == ("model rc: 3 steps",)
    assert run.time.tolist() == [0.5, 1.0, 1.5]
    assert run.measurements["e3"][:2].tolist() == [2.5, 2.25] and np.isnan(run.measurements["e3"][2])
    assert run.inputs["V"].dtype == np.float64 and run.states["q"].tolist() == [0.1, 0.2, 0.3]
    again = runs.parse_run(runs.run_csv(run), "again.csv")
    assert np.array_equal(again.measurements["e3"], run.measurements["e3"], equal_nan=True)
    assert again.header == run.header


def test_nan_and_an_empty_cell_are_not_measured_but_infinity_is_an_error():
    run = runs.parse_run("time,y:a,y:b\n1,nan,\n2, NaN ,  \n", "f.csv")
    assert np.isnan(run.measurements["a"]).all() and np.isnan(run.measurements["b"]).all()
    for cell in ("inf", "-inf", "Infinity", "1e400", "-1e999"):
        line = error(f"time,y:a,y:f2\n1,0,0\n2,0,{cell}\n", "run.csv")
        assert line.startswith("run.csv:3: ") and "in column y:f2 is not a finite number" in line, line
    for column in ("u:V", "x:q", "theta:R"):  # every data column, not the sensors only
        line = error(f"time,{column}\n1,0\n2,-inf\n", "run.csv")
        assert line.startswith(f"run.csv:3: -inf in column {column} is not a finite number"), line


def test_the_issue_case_minus_inf_in_every_sample_of_one_sensor(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text(HEAD + "time,y:e3,y:f2\n" + "".join(f"{k},1.0,-inf\n" for k in range(1, 50)))
    assert file_error(path).startswith(f"{path}:3: -inf in column y:f2 is not a finite number")


def test_a_byte_order_mark_and_crlf_line_ends_read_as_the_plain_file(tmp_path):
    plain = runs.parse_run(HEAD + BODY, "x")
    path = tmp_path / "excel.csv"
    path.write_bytes(b"\xef\xbb\xbf" + (HEAD + BODY).replace("\n", "\r\n").encode())
    run = runs.read_run(path)
    assert run.header == plain.header and np.array_equal(run.time, plain.time)
    assert np.array_equal(run.measurements["e3"], plain.measurements["e3"], equal_nan=True)


# ------------------------------------------------------------ bounded header and blank lines
def test_comment_lines_are_bounded_in_number_and_length():
    header = "".join(f"# note {k}\n" for k in range(runs.MAX_COMMENT_LINES))
    assert len(runs.parse_run(header + BODY).header) == runs.MAX_COMMENT_LINES
    line = error(header + "#\n" + BODY)
    assert line.startswith(f"bad.csv:{runs.MAX_COMMENT_LINES + 1}: more than {runs.MAX_COMMENT_LINES} comment "
                           "lines"), line
    assert error("#" * 3 + "x" * runs.MAX_COMMENT + "\n" + BODY).startswith(
        f"bad.csv:1: a comment line of {runs.MAX_COMMENT + 3} characters")
    # comments after the column names count too (a flood between the rows)
    rows = BODY.splitlines(keepends=True)
    flood = rows[0] + rows[1] + "# x\n" * (runs.MAX_COMMENT_LINES + 1) + "".join(rows[2:])
    assert error(flood).startswith(f"bad.csv:{runs.MAX_COMMENT_LINES + 3}: more than")


def test_blank_and_whitespace_lines_are_bounded():
    ok = "\n" * runs.MAX_BLANK_LINES + BODY
    assert len(runs.parse_run(ok).time) == 3
    for blank in ("\n", "   \n", "\t\r\n"):
        line = error(HEAD + blank * (runs.MAX_BLANK_LINES + 1) + BODY)
        assert line.startswith(f"bad.csv:{runs.MAX_BLANK_LINES + 2}: more than {runs.MAX_BLANK_LINES} blank lines")


def test_hostile_floods_are_refused_at_once_and_in_little_memory(tmp_path):
    """The issue's files, scaled down to 20 MB: comment lines (took 1 GB and
    5 s at 200 MB), blank lines (2 GB and 28 s), both refused within the
    first few hundred lines, the rest of the file never read."""
    for name, flood in (("comments.csv", "# " + "x" * 98 + "\n"), ("blanks.csv", "\n"), ("hashes.csv", "#\n")):
        path = tmp_path / name
        with open(path, "w") as f:
            f.write(flood * (20_000_000 // len(flood)))
            f.write(BODY)
        line, peak = peak_memory(lambda: file_error(path))
        assert "more than" in line and peak < 2_000_000, (line, peak)


def test_an_endless_line_is_counted_not_kept(tmp_path):
    path = tmp_path / "long.csv"
    with open(path, "w") as f:
        f.write("time,y:e3\n1.0,")
        f.write("9" * 30_000_000)
        f.write("\n2.0,1\n")
    line, peak = peak_memory(lambda: file_error(path))
    assert line.startswith(f"{path}:2: line is 30000004 characters long"), line
    assert peak < 8 * runs.MAX_LINE < 30_000_000, peak  # blocks of MAX_LINE, never the whole line
    # a long comment line too, and the count is in characters (2 bytes each here)
    path.write_text("# " + "é" * (runs.MAX_LINE + 5) + "\n" + BODY, encoding="utf-8")
    assert file_error(path).startswith(f"{path}:1: line is {runs.MAX_LINE + 7} characters long")


def test_an_unterminated_quote_stops_at_the_csv_field_limit():
    line = error('time,y:a\n1,"' + "1\n" * 200_000)
    assert line.startswith("bad.csv:") and "not CSV: field larger than field limit" in line, line


# ------------------------------------------------------------ streamed into arrays
@pytest.mark.slow
def test_reading_a_large_run_takes_memory_near_its_numbers(tmp_path):
    rows, cols = 80_000, 6  # 4.5 MB of numbers (measured: the peak 1.23 times them; 1.33 at 200,000 rows)
    path = tmp_path / "big.csv"
    with open(path, "w") as f:
        f.write(HEAD + "time," + ",".join(f"y:s{j}" for j in range(cols - 1)) + "\n")
        for k in range(rows):
            f.write(f"{0.05 * (k + 1)!r},1.2345678901234567,2.5,-3.25e-05,4.0,5.5\n")
    size = os.path.getsize(path)
    numbers = rows * (cols + 1) * 8  # the columns and each row's line number
    run, peak = peak_memory(lambda: runs.read_run(path))
    assert len(run.time) == rows and run.measurements["s0"][-1] == 1.2345678901234567
    # the numbers (growing in place) and little else: the text of the file (as large) is never held whole
    assert peak < 1.6 * numbers and peak < 1.6 * size, (peak, numbers, size)


def test_the_numbers_of_a_run_are_bounded(monkeypatch):
    monkeypatch.setattr(runs, "MAX_VALUES", 3000)
    body = "time,y:a,y:b\n" + "".join(f"{k},1,2\n" for k in range(1, 2000))
    line = error(body)
    assert line.startswith("bad.csv:752: more than 750 rows of 3 columns (3000 numbers)"), line
    monkeypatch.setattr(runs, "MAX_COLUMNS", 4)
    assert error("time,y:a,y:b,y:c,y:d\n1,2,3,4,5\n").startswith("bad.csv:1: 5 columns, more than 4")


def test_a_file_past_the_byte_limit_while_read_is_refused(monkeypatch, tmp_path):
    monkeypatch.setattr(runs, "MAX_RUN_BYTES", 100)
    text = "time,y:a\n" + "".join(f"{k},1\n" for k in range(1, 100))
    assert error(text).startswith("bad.csv: more than 100 bytes")
    path = tmp_path / "big.csv"
    path.write_text(text)
    assert file_error(path).startswith(f"{path}: file is {len(text)} bytes, more than 100")


def test_not_utf8_is_located_by_line_and_byte(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_bytes(b"# x\ntime,y:a\n1,2\n2,\xff\n")
    assert file_error(path) == f"{path}:4: not UTF-8 text (byte 19 is 0xff) (give a CSV written by bgc simulate)"


def test_a_folder_without_run_files_or_a_missing_file_is_one_line(tmp_path):
    assert file_error(tmp_path).startswith(f"{tmp_path}: no run file in the folder (*.csv)")  # a folder: its files
    assert file_error(tmp_path / "none.csv").startswith(f"{tmp_path / 'none.csv'}: no such file")


@pytest.mark.parametrize("text, what", [
    ("time,y:a\n1,2\n,3\n", "bad.csv:3: time nan is not a finite number"),
    ("time,y:a\n1,2\ninf,3\n", "bad.csv:3: time inf is not a finite number"),
    ("time,y:a\n1,2\n\n1,3\n", "bad.csv:4: time 1 does not increase (the row before has 1)"),
    ("time,y:a\n2,2\n1,3\n", "bad.csv:3: time 1 does not increase (the row before has 2)"),
    # a logger's Unix seconds, a quarter of a second apart: written as the diagnosis writes absolute times,
    # ISO 8601 UTC (datetime.fromtimestamp(1777881601.25, UTC) is 2026-05-04 08:00:01.25)
    ("time,y:a\n1777881601.5,2\n1777881601.25,3\n",
     "bad.csv:3: time 2026-05-04T08:00:01.25Z does not increase (the row before has 2026-05-04T08:00:01.5Z)"),
    ("time,y:a\n1,2\n2,x\n", "bad.csv:3: 'x' in column y:a is not a number"),
    ("time\n", "bad.csv: the run has no data rows, only column names"),
    ("\n\n# only comments\n", "bad.csv: no data"),
    # a spreadsheet's export with semicolons (or tabs): one column of it all, said so
    ("# x\ntime;y:a\n1;2\n", "bad.csv:2: the column names are separated by ';', not by commas"),
    ("time\ty:a\n1\t2\n", "bad.csv:1: the column names are separated by '\\t', not by commas"),
    # a logger that restarted and wrote its header again within the file
    ("time,y:a\n1,2\ntime,y:a\n2,3\n", "bad.csv:3: the column names again, within the file"),
    # the last line without its end of line (still being written), and a short row that is not the last
    ("time,y:a\n1,2\n2", "bad.csv:3: 1 fields, expected 2: the file's last line, without its end of line"),
    ("time,y:a\n1,2\n2\n3,4\n", "bad.csv:3: 1 fields, expected 2 (give every row one value per column)"),
])
def test_times_and_cells_are_located(text, what):
    assert error(text).startswith(what), error(text)


# ------------------------------------------------------------ a Run built in Python
def python_run(**change) -> runs.Run:
    fields = dict(time=np.array([0.1, 0.2, 0.3]), inputs={}, measurements={"f2": np.array([1.0, 2.0, 3.0])},
                  states={}, parameters={}, header=())
    fields.update(change)
    return runs.Run(**fields)


def test_a_python_run_is_checked_and_given_float_arrays():
    run = runs.check_run(python_run(time=[1, 2, 3], measurements={"f2": np.array([1, 2, 3], dtype=np.int32)}))
    assert run.source == runs.PYTHON_SOURCE and run.time.dtype == np.float64
    assert run.measurements["f2"].dtype == np.float64 and run.measurements["f2"].tolist() == [1.0, 2.0, 3.0]
    same = python_run()
    assert runs.check_run(same).measurements["f2"] is same.measurements["f2"]  # no copy of a float64 array


@pytest.mark.parametrize("change, what", [
    (dict(time=np.array([])), "<Run from Python>: the run has no data rows"),
    (dict(time=np.array([0.1, np.nan, 0.3])), "<Run from Python>, index 1: time nan is not a finite number"),
    (dict(time=np.array([0.1, 0.3, 0.2])), "<Run from Python>, index 2: time 0.2 does not increase"),
    (dict(time=np.array([0.1, 0.1, 0.2])), "<Run from Python>, index 1: time 0.1 does not increase"),
    (dict(time=np.array([[0.1, 0.2, 0.3]])), "<Run from Python>: column time has shape (1, 3)"),
    (dict(time=np.array([True, False, True])), "<Run from Python>: column time holds bool values, not numbers"),
    (dict(measurements={"f2": np.ones(4)}), "<Run from Python>: column y:f2 has 4 values, the time 3"),
    (dict(measurements={"f2": np.ones((3, 1))}), "<Run from Python>: column y:f2 has shape (3, 1)"),
    (dict(measurements={"f2": np.array(["1", "2", "3"])}), "<Run from Python>: column y:f2 holds <U1 values"),
    (dict(measurements={"f2": np.array([1, 2, 3], dtype=object)}), "<Run from Python>: column y:f2 holds object"),
    (dict(measurements={"f2": np.array([1j, 2, 3])}), "<Run from Python>: column y:f2 holds complex128"),
    (dict(measurements={"f2": [[1], [2, 3], 4]}), "<Run from Python>: column y:f2 is not an array of numbers"),
    (dict(measurements={"f2": np.array([1.0, -np.inf, 3.0])}),
     "<Run from Python>, index 1: -inf in column y:f2 is not a finite number"),
    (dict(inputs={"V": np.array([1.0, 1.0, np.inf])}), "<Run from Python>, index 2: inf in column u:V"),
    (dict(measurements=[("f2", np.ones(3))]), "<Run from Python>: the y:* columns are a list, not a dict"),
    (dict(measurements={2: np.ones(3)}), "<Run from Python>: column name 2 under y:* is not a non-empty text"),
    (dict(states={"": np.ones(3)}), "<Run from Python>: column name '' under x:* is not a non-empty text"),
    (dict(header="model rc: x"), "<Run from Python>: the header is not a tuple of text lines"),
    (dict(header=("x",) * (runs.MAX_COMMENT_LINES + 1)), "<Run from Python>: the header has more than"),
    (dict(source="lab run 7", time=np.array([0.3, 0.2, 0.1])), "lab run 7, index 1: time 0.2 does not increase"),
])
def test_a_python_run_goes_through_the_checks_of_a_file(change, what):
    with pytest.raises(DataError) as info:
        runs.check_run(python_run(**change))
    assert info.value.line().startswith(what), info.value.line()


def test_check_run_refuses_what_is_not_a_run():
    with pytest.raises(DataError, match="a dict, not a bgc.data.runs.Run"):
        runs.check_run({"time": [1.0]})


# ------------------------------------------------------------ a logger's daily files
DAY = "# model circuit: a day of the logger\ntime,u:V,y:f2\n"


def _days(folder, *days: str) -> None:
    folder.mkdir(exist_ok=True)
    for i, rows in enumerate(days, start=1):
        (folder / f"2026-03-0{i}.csv").write_text(DAY + rows, encoding="utf-8")


def test_a_folder_or_a_pattern_of_daily_files_reads_as_one_run_in_the_order_of_their_names(tmp_path):
    _days(tmp_path / "logs", "1,10,2.0\n2,10,2.1\n", "3,10,2.2\n", "4,11,,\n5,11,2.4\n".replace(",,", ","))
    (tmp_path / "logs" / "notes.txt").write_text("not a run")
    for path in (tmp_path / "logs", str(tmp_path / "logs" / "2026-03-*.csv")):
        run = runs.read_run(path)
        assert run.time.tolist() == [1.0, 2.0, 3.0, 4.0, 5.0]
        assert run.inputs["V"].tolist() == [10.0, 10.0, 10.0, 11.0, 11.0]
        assert np.array_equal(run.measurements["f2"], [2.0, 2.1, 2.2, np.nan, 2.4], equal_nan=True)
        assert run.model == "circuit" and run.source == str(path)
    assert runs.run_files(tmp_path / "logs" / "2026-03-01.csv") is None  # one file


@pytest.mark.parametrize("days, message", [
    (("1,10,2.0\n2,10,2.1\n", "2,10,2.2\n"), "2026-03-02.csv: its first time 2 does not go on from the last time "
                                             "of {folder}/2026-03-01.csv (2)"),
    (("1,10,2.0\n", "time,y:f2\n"), None),
])
def test_daily_files_that_overlap_or_differ_are_refused_naming_the_file(tmp_path, days, message):
    folder = tmp_path / "logs"
    _days(folder, *days)
    if message is None:  # the second file's columns differ
        (folder / "2026-03-02.csv").write_text("# model circuit\ntime,y:f2\n2,2.5\n")
        message = "2026-03-02.csv: its columns differ from {folder}/2026-03-01.csv's"
    with pytest.raises(DataError) as caught:
        runs.read_run(folder)
    assert message.format(folder=folder) in str(caught.value) and "\n" not in str(caught.value)
    with pytest.raises(DataError, match="no run file matches the pattern"):
        runs.read_run(str(tmp_path / "nothing-*.csv"))


def test_daily_files_whose_names_do_not_sort_in_time_are_read_in_time_order(tmp_path):
    """logrotate's numbering: log.csv.2 is the oldest."""
    folder = tmp_path / "logs"
    folder.mkdir()
    for name, rows in (("log.2.csv", "1,10,2.0\n"), ("log.1.csv", "2,10,2.1\n"), ("log.csv", "3,10,2.2\n")):
        (folder / name).write_text(DAY + rows)
    assert runs.read_run(folder).time.tolist() == [1.0, 2.0, 3.0]


def test_a_stream_read_row_by_row_has_no_byte_bound_and_bounds_its_comment_lines_between_rows(monkeypatch):
    """A monitor's stream (RowReader) goes on past MAX_RUN_BYTES, holds the
    comment lines since the row before the last one only (those before it
    were read with it), and bounds the comment and blank lines between two
    rows, not over the stream: by hand, 40 rows each after two comment lines
    and a blank line, the bounds set to 3 comment lines (before the first
    row the file's header counts with them), one blank line and 300 bytes."""
    import io

    monkeypatch.setattr(runs, "MAX_COMMENT_LINES", 3)
    monkeypatch.setattr(runs, "MAX_BLANK_LINES", 1)
    monkeypatch.setattr(runs, "MAX_RUN_BYTES", 300)
    text = "# header\ntime,y:a\n" + "".join(f"# note {k}a\n# note {k}b\n\n{k},1\n" for k in range(1, 41))
    reader = runs.RowReader(io.BytesIO(text.encode()), "s.csv")
    assert reader.header == ("header",)
    held = []
    for values, line in reader:
        held.append(len(reader.lines.header))
        k = int(values[0])
        assert reader.lines.comments == 1 + 2 * k  # every comment line counted, those forgotten too
        assert reader.lines.since(1 + 2 * (k - 1)) == [f"note {k}a", f"note {k}b"]  # the ones before this row
        assert line == 2 + 4 * k
    assert len(held) == 40 and max(held) <= 1 + 2 * 2  # this row's two, the last row's two (and the header's)
    assert len(text) > 300
    for flood, what in (("# w\n# x\n# y\n# z\n", "more than 3 comment lines"), ("\n\n", "more than 1 blank lines")):
        bad = "time,y:a\n1,1\n" + flood + "2,1\n"
        with pytest.raises(DataError) as info:
            list(runs.RowReader(io.BytesIO(bad.encode()), "s.csv"))
        assert what in info.value.line(), info.value.line()
    # a file is bounded as a whole, as before
    assert error("time,y:a\n" + "".join(f"{k},1\n" for k in range(1, 100))).startswith("bad.csv: more than 300 bytes")


def test_what_loggers_write_for_a_reading_not_taken_is_an_empty_cell():
    text = "time,y:a,y:b\n1,NA,2\n2,n/a,#N/A\n3, null ,---\n4,None,-\n5,4,--\n"
    run = runs.parse_run(text, "logger.csv")
    assert np.isnan(run.measurements["a"][:4]).all() and run.measurements["a"][4] == 4.0
    assert run.measurements["b"][0] == 2.0 and np.isnan(run.measurements["b"][1:]).all()
    with pytest.raises(DataError, match=r"^logger\.csv:2: 'NAN!' in column y:a is not a number"):
        runs.parse_run("time,y:a\n1,NAN!\n", "logger.csv")
