"""A campaign never runs away and never loses a user's file: worker and run
limits, a scheduler that is not there, a resumed runs.csv that a spreadsheet,
an editor or a kill left damaged, text that would be a formula or Markdown,
and workers whose campaign was killed."""

import inspect
import math
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bgc.experiment import campaign

from bgc.experiment import campaign_file, dispatch, runs_csv
from bgc.errors import ArgumentTypeError, ArgumentValueError, BgcError, ExperimentError, printable
from bgc.model import DEFAULT_BACKEND
from bgc.output import tables

from conftest import ROOT, bgc_cli

CIRCUIT = ROOT / "models" / "circuit.yaml"

# two quick runs (a fault-free one and a step), a second or two on one core
TINY = """\
campaign: tiny
defaults:
  steps: 40
  particles: [50]
groups:
  - name: g
    model: {model}
    scenarios: [none, "R2:abrupt:0.6@1.0"]
"""


def write(folder: Path, text: str, name: str = "c.yaml") -> Path:
    p = folder / name
    p.write_text(textwrap.dedent(text), encoding="utf-8")
    return p


def bgc(*args: str) -> subprocess.CompletedProcess:
    """``bgc ARGS`` in this process (conftest.bgc_cli)."""
    return bgc_cli(*args)


def bgc_process(*args: str, timeout: float) -> subprocess.CompletedProcess:
    """``python -m bgc ARGS``, a real process: for a test whose failure would
    be a command that never ends, which only a process can be timed out of."""
    return subprocess.run([sys.executable, "-m", "bgc", *args], capture_output=True, text=True, timeout=timeout)


def one_line_error(r: subprocess.CompletedProcess) -> str:
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The tiny campaign run once: (campaign, result, its folder's runs.csv bytes).
    It forks one worker process: a local campaign runs there."""
    folder = tmp_path_factory.mktemp("tiny")
    c = campaign_file.load_campaign(write(folder, TINY.format(model=CIRCUIT)))
    r = campaign.run_campaign(c, folder / "out", workers=1, progress=False)
    assert r.failed == 0 and r.ran == 2
    return c, r, (folder / "out" / "runs.csv").read_bytes()


def copy_of(tiny, folder: Path) -> Path:
    """A finished tiny campaign's folder (a copy: each test damages its own)."""
    out = folder / "out"
    shutil.copytree(tiny[1].folder, out)
    return out


def unused_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now: a connection is refused
    return port


# ------------------------------------------------------------------ item 3: how many workers
def test_workers_beyond_the_limit_are_refused_with_the_limit_before_anything_is_compiled(tmp_path):
    limit = dispatch.worker_limit()
    assert limit == dispatch.WORKERS_PER_CORE * dispatch.cores() and dispatch.cores() >= 1
    config = write(tmp_path, TINY.format(model=tmp_path / "not-there.yaml"))  # would fail to load
    for n in (limit + 1, 600, 100000):
        t = time.perf_counter()
        line = one_line_error(bgc("experiment", str(config), "-o", str(tmp_path / "o"), "--workers", str(n)))
        assert time.perf_counter() - t < 30
        assert f"--workers {n}" in line and f"limit of {limit} local processes" in line
        assert "not-there" not in line  # refused before the campaign file was read
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("kwargs, error", [
    ({"workers": 0}, ArgumentValueError), ({"workers": -3}, ArgumentValueError),
    ({"workers": "limit+1"}, ArgumentValueError), ({"workers": 10**9}, ArgumentValueError),
    ({"workers": 2.0}, ArgumentTypeError), ({"workers": "2"}, ArgumentTypeError), ({"workers": True}, ArgumentTypeError),
    ({"progress": "yes"}, ArgumentTypeError), ({"progress": 1}, ArgumentTypeError),
    ({"scheduler": 8786}, ArgumentTypeError), ({"scheduler": ""}, ArgumentTypeError),
    ({"connect_timeout": 0}, ArgumentValueError), ({"connect_timeout": -1.0}, ArgumentValueError),
    ({"connect_timeout": math.inf}, ArgumentValueError), ({"connect_timeout": math.nan}, ArgumentValueError),
    ({"connect_timeout": "10"}, ArgumentTypeError), ({"outputs": None}, ArgumentTypeError),
    ({"on_start": "print"}, ArgumentTypeError), ({"backend": "cuda"}, ArgumentValueError),
    ({"backend": 1}, ArgumentTypeError),
])
def test_run_campaign_refuses_bad_arguments_before_touching_the_folder(tiny, tmp_path, kwargs, error):
    c = tiny[0]
    if kwargs.get("workers") == "limit+1":
        kwargs = {"workers": dispatch.worker_limit() + 1}
    out = tmp_path / "o"
    with pytest.raises(error) as err:
        campaign.run_campaign(c, out, **kwargs)
    # a BgcError (one line for the CLI) and Python's own kind (ValueError, TypeError)
    assert isinstance(err.value, BgcError)
    assert isinstance(err.value, ValueError if error is ArgumentValueError else TypeError)
    assert "\n" not in str(err.value)
    if "workers" in kwargs and error is ArgumentValueError and kwargs["workers"] > 0:
        assert f"limit of {dispatch.worker_limit()}" in str(err.value)
    assert not out.exists()
    with pytest.raises(ArgumentTypeError):
        campaign.run_campaign("c.yaml", out)
    with pytest.raises(ArgumentTypeError):
        campaign.run_campaign(c, None)


def test_no_more_workers_start_than_runs_to_do_or_memory_holds(monkeypatch):
    monkeypatch.setattr(dispatch, "_available_memory", lambda: 10**15)
    assert dispatch.local_workers(8, 2) == (2, "runs")
    assert dispatch.local_workers(2, 2) == (2, None)
    assert dispatch.local_workers(1, 1000) == (1, None)
    assert dispatch.local_workers(5, 0) == (0, None)  # nothing to run: no process
    assert dispatch.local_workers(None, 1) == (1, "runs" if dispatch.cores() > 1 else None)
    assert dispatch.local_workers(None, 10**6) == (dispatch.cores(), None)
    monkeypatch.setattr(dispatch, "_available_memory", lambda: 3 * dispatch.WORKER_MEMORY + 1)
    assert dispatch.local_workers(8, 100) == (3, "memory")
    monkeypatch.setattr(dispatch, "_available_memory", lambda: 0)  # at least one, whatever the memory
    assert dispatch.local_workers(8, 100) == (1, "memory")
    monkeypatch.setattr(dispatch, "_available_memory", lambda: None)  # unknown: not limited by it
    assert dispatch.local_workers(3, 100) == (3, None)


@pytest.mark.process  # two campaigns on forked worker processes: what it tests
def test_a_request_for_more_workers_than_runs_starts_one_per_run_and_says_so(tiny, tmp_path):
    c = tiny[0]
    events = []
    r = campaign.run_campaign(c, tmp_path / "o", workers=dispatch.worker_limit(), progress=False, outputs=False,
                              on_start=events.append)
    assert len(events) == 1
    start = events[0]
    assert (start.total, start.todo, start.reused, start.workers, start.requested) == \
        (2, 2, 0, 2, dispatch.worker_limit())
    assert r.workers == 2
    if dispatch.worker_limit() > 2:
        assert start.limited_by in ("runs", "memory")
    # the command line says it on stderr
    config = write(tmp_path, TINY.format(model=CIRCUIT))
    n = dispatch.worker_limit()
    p = bgc("experiment", str(config), "-o", str(tmp_path / "cli"), "--workers", str(n), "--no-progress", "-v")
    assert p.returncode == 0, p.stderr
    assert f"--workers {n}: starting 2 local processes, one per run to do" in p.stderr
    assert "2 runs on 2 local processes" in p.stderr
    quiet = bgc("experiment", str(config), "-o", str(tmp_path / "cli"), "--workers", str(n), "--no-progress")
    assert quiet.returncode == 0 and quiet.stderr == ""  # status lines with -v only


# ------------------------------------------------------------------ item 4: how many runs
def test_a_huge_grid_is_refused_from_its_count_before_anything_is_expanded(tmp_path):
    # 100000 scenarios would be a large file: the grid multiplies out instead
    particles = ", ".join(str(10 + i) for i in range(100))
    noise = ", ".join(f"{{name: n{i}, process: 0.01, measurement: 0.01}}" for i in range(100))
    text = f"""\
    campaign: huge
    groups:
      - name: small
        model: {CIRCUIT}
        scenarios: [none]
      - name: big
        model: {tmp_path / 'never-compiled.yaml'}
        scenarios: [none, "R2:abrupt:0.6@1.0"]
        filters: [gpf, apf, opf, ckf]
        particles: [{particles}]
        noise: [{noise}]
        refine: [false, true]
        seeds: 100000
    """
    path = write(tmp_path, text)
    total = 1 + 2 * 4 * 100 * 100 * 2 * 100000  # 16 000 000 001 runs
    t = time.perf_counter()
    with pytest.raises(ExperimentError) as err:
        campaign_file.load_campaign(path)
    assert time.perf_counter() - t < 10
    line = str(err.value)
    assert f"{total:,} runs" in line and "limit of 100,000" in line and "group 'big'" in line
    assert line.startswith(f"{path}:6:5: ")  # the big group's place in the file
    assert "--max-runs" in line
    # the command line: one line, quickly
    t = time.perf_counter()
    r = bgc("experiment", str(path), "-o", str(tmp_path / "o"))
    assert time.perf_counter() - t < 30
    assert f"{total:,} runs" in one_line_error(r) and not (tmp_path / "o").exists()


def test_draws_and_seed_lists_count_and_groups_add_up(tmp_path):
    seeds = list(range(1000))
    text = f"""\
    campaign: many
    defaults:
      seeds: {seeds}
    groups:
      - name: a
        model: {CIRCUIT}
        draws: {{count: 60, change: [0.2, 0.5], onset: [0.3, 0.6]}}
      - name: b
        model: {CIRCUIT}
        draws: {{count: 50, change: [0.2, 0.5], onset: [0.3, 0.6]}}
    """
    path = write(tmp_path, text)
    with pytest.raises(ExperimentError, match=r"plans 110,000 runs.*group 'a' alone: 60,000"):
        campaign_file.load_campaign(path)
    assert campaign_file.group_size({"draws": {"count": 60}}, {"noise": ["model"], "filters": ["gpf"],
                                                            "particles": [1000], "refine": [False],
                                                            "seeds": seeds}) == 60_000


def test_the_run_limit_can_be_raised_or_lowered_and_is_exact(tmp_path):
    path = write(tmp_path, TINY.format(model=CIRCUIT))
    assert len(campaign_file.load_campaign(path, max_runs=2).specs) == 2  # exactly at the limit
    with pytest.raises(ExperimentError, match=r"plans 2 runs, more than the limit of 1 "):
        campaign_file.load_campaign(path, max_runs=1)
    for bad, error in ((0, ArgumentValueError), (-5, ArgumentValueError), ("10", ArgumentTypeError),
                       (True, ArgumentTypeError), (2.5, ArgumentTypeError), (None, ArgumentTypeError)):
        with pytest.raises(error):
            campaign_file.load_campaign(path, max_runs=bad)
    r = bgc("experiment", str(path), "-o", str(tmp_path / "o"), "--max-runs", "1")
    assert "plans 2 runs, more than the limit of 1 " in one_line_error(r)
    r = bgc("experiment", str(path), "-o", str(tmp_path / "o"), "--max-runs", "0")
    assert r.returncode == 2 and "Traceback" not in r.stderr  # argparse's usage error


def test_the_command_line_defaults_are_the_documented_limits():
    from bgc.cli import build_parser

    args = build_parser().parse_args(["experiment", "c.yaml"])
    assert (args.max_runs, args.connect_timeout, args.workers) == (campaign_file.MAX_RUNS, dispatch.CONNECT_TIMEOUT, None)
    assert campaign_file.MAX_RUNS == 100_000 and dispatch.WORKERS_PER_CORE == 4  # as docs/experiments.md says
    docs = (ROOT / "docs" / "experiments.md").read_text(encoding="utf-8")
    assert "100 000 runs" in docs and "4 per core" in docs and "default 10" in docs
    # one default backend for every door: the command line's and run_campaign's
    assert args.backend == DEFAULT_BACKEND == inspect.signature(campaign.run_campaign).parameters["backend"].default
    assert DEFAULT_BACKEND == "auto" and "--backend" in docs and "run_campaign(backend=" in docs


# ------------------------------------------------------------------ item 7: the scheduler
def test_a_refused_scheduler_fails_in_seconds_with_one_line(tmp_path):
    config = write(tmp_path, TINY.format(model=CIRCUIT))
    port = unused_port()
    for address in (f"tcp://127.0.0.1:{port}", f"127.0.0.1:{port}", f"tls://127.0.0.1:{port}"):
        t = time.perf_counter()
        r = bgc("experiment", str(config), "-o", str(tmp_path / "o"), "--scheduler", address)
        assert time.perf_counter() - t < 5, address
        line = one_line_error(r)
        assert "Dask scheduler" in line and "connection refused" in line, line
    assert not (tmp_path / "o").exists()
    c = campaign_file.load_campaign(config)
    t = time.perf_counter()
    with pytest.raises(ExperimentError, match="connection refused"):
        campaign.run_campaign(c, tmp_path / "api", scheduler=f"tcp://127.0.0.1:{port}")
    assert time.perf_counter() - t < 5


def test_a_silent_host_fails_after_the_connect_timeout(tmp_path):
    # a listener whose queue is full drops new connections' SYNs, as a blackholed address does
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(0)
    port = server.getsockname()[1]
    held = []
    try:
        for _ in range(3):
            s = socket.socket()
            s.settimeout(0.5)
            try:
                s.connect(("127.0.0.1", port))
                held.append(s)
            except OSError:
                s.close()
                break
        else:
            pytest.skip("this system accepts every connection to a full queue")
        t = time.perf_counter()
        with pytest.raises(ExperimentError, match=r"no answer within 1\.5 s"):
            dispatch.check_scheduler(f"tcp://127.0.0.1:{port}", 1.5)
        assert 1.4 < time.perf_counter() - t < 4
    finally:
        for s in held:
            s.close()
        server.close()


@pytest.mark.process
@pytest.mark.parametrize("answer", [None, b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n", b"\xff" * 64])
def test_a_server_that_is_no_scheduler_fails_in_one_line(tmp_path, answer):
    """A server that takes the connection and never answers held Dask's client
    forever (its handshake has no timeout); one that answers HTTP made it
    allocate exabytes ('out of memory'). A real process: held forever or out
    of memory, it is ended by its timeout, and the test fails."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    port = server.getsockname()[1]
    stop = threading.Event()
    conns = []

    def serve():
        server.settimeout(0.2)
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            conns.append(conn)
            if answer is not None:
                conn.sendall(answer)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        config = write(tmp_path, TINY.format(model=CIRCUIT))
        t = time.perf_counter()
        r = bgc_process("experiment", str(config), "-o", str(tmp_path / "o"), "--scheduler",
                        f"tcp://127.0.0.1:{port}", "--connect-timeout", "1.5", timeout=60)
        assert time.perf_counter() - t < 15
        line = one_line_error(r)
        assert "Dask scheduler" in line and "out of memory" not in line
        if answer is None:
            assert "does not answer within 1.5 s" in line
    finally:
        stop.set()
        thread.join()
        for conn in conns:
            conn.close()
        server.close()


@pytest.mark.parametrize("address, words", [
    ("tcp://h:99999", "not a number from 1 to 65535"), ("tcp://:8786", "names no host"),
    ("tcp://h", "names no port"), ("h:port", "not a number"), ("[::1]", "names no port"),
])
def test_a_malformed_scheduler_address_is_one_line(address, words):
    with pytest.raises(ExperimentError, match=re.escape(words)):
        dispatch.check_scheduler(address, 1.0)


def test_scheduler_addresses_are_read_as_dask_writes_them():
    assert dispatch.scheduler_endpoint("tcp://10.0.0.5:8786") == ("10.0.0.5", 8786)
    assert dispatch.scheduler_endpoint("TLS://host.example:1") == ("host.example", 1)
    assert dispatch.scheduler_endpoint("127.0.0.1:9000") == ("127.0.0.1", 9000)
    assert dispatch.scheduler_endpoint("tcp://[::1]:8786") == ("::1", 8786)
    assert dispatch.scheduler_endpoint("inproc://10.0.0.5/1/2") is None  # left to Dask


# ------------------------------------------------------------------ item 8 and 9: reading runs.csv
#: The comment line an earlier bgc wrote first in runs.csv: a file that has it is read all the same.
OLD_COMMENT = b"# generated by bgc experiment from c.yaml: campaign tiny, one row per run\n"


def tiny_lines(tiny) -> list[bytes]:
    """The finished tiny campaign's runs.csv: header, two rows (no comment line before the header)."""
    lines = tiny[2].splitlines(keepends=True)
    assert len(lines) == 3 and lines[0].startswith(b"id,index,")
    return lines


def test_every_intact_row_is_read_and_every_other_line_kept_exactly(tiny, tmp_path):
    header, row0, row1 = tiny_lines(tiny)
    comment = OLD_COMMENT  # an earlier bgc's first line: skipped
    bad = [b'"broken,row\n',                       # an unclosed quote: swallowed every row after it
           b"x" * 200_000 + b"\n",                 # over the csv module's field limit: a traceback
           b"\xff\xfe not utf-8\n",                # not UTF-8
           b"a,b,c\n",                             # too few cells
           row0.replace(b",0,g,", b",zero,g,", 1),  # 'index' not an integer
           b"# a note of mine\n"]                   # a comment that is not bgc's
    cut = row1[:-30]                                # a last line cut short by a kill
    path = tmp_path / "runs.csv"
    path.write_bytes(b"\xef\xbb\xbf" + comment + header + bad[0] + row0 + bad[1] + bad[2] + b"\n" + bad[3]
                     + bad[4] + bad[5] + row1 + b"  \n" + cut)
    found = runs_csv.read_runs(path)
    assert [r["index"] for r in found.rows] == [0, 1]
    expected = runs_csv.read_runs(_file(tmp_path, tiny[2])).rows
    assert found.rows == expected
    assert found.unread == b"".join(bad) + cut and found.unread_lines == len(bad) + 1


def _file(folder: Path, data: bytes) -> Path:
    p = folder / "clean.csv"
    p.write_bytes(data)
    return p


def test_a_spreadsheet_save_is_read(tiny, tmp_path):
    """BOM, CRLF, every cell quoted, TRUE/FALSE, the comment line padded with commas."""
    import csv as csvmod
    import io

    rows = list(csvmod.reader(io.StringIO(tiny[2].decode())))
    buf = io.StringIO()
    w = csvmod.writer(buf, quoting=csvmod.QUOTE_ALL, lineterminator="\r\n")
    w.writerow([OLD_COMMENT.decode().strip()] + [""] * (len(rows[0]) - 1))  # an earlier bgc's file
    for values in rows:
        w.writerow([v.upper() if v in ("true", "false") else v for v in values])
    saved = tmp_path / "runs.csv"
    saved.write_bytes(b"\xef\xbb\xbf" + buf.getvalue().encode())
    found = runs_csv.read_runs(saved)
    assert found.unread_lines == 0
    assert found.rows == runs_csv.read_runs(_file(tmp_path, tiny[2])).rows


def test_a_foreign_header_keeps_every_line(tmp_path):
    data = b"name,value\nx,1\ny,2\n"
    (tmp_path / "runs.csv").write_bytes(data)
    found = runs_csv.read_runs(tmp_path / "runs.csv")
    assert found.rows == () and found.unread == data
    assert runs_csv.read_runs(tmp_path / "missing.csv") == runs_csv.RunsFile((), b"", 0)


def test_a_resumed_campaign_keeps_every_intact_row_and_sets_aside_the_rest(tiny, tmp_path):
    c = tiny[0]
    out = copy_of(tiny, tmp_path)
    header, row0, row1 = tiny_lines(tiny)
    damaged = b"\xef\xbb\xbf" + OLD_COMMENT + header + b'"broken,row\n' + row0 + b"y" * 140_000 + b"\n" + row1 + b"cut"
    (out / "runs.csv").write_bytes(damaged)
    mine = b"my own notes, not bgc's\n"
    (out / "runs.unread-1.csv").write_bytes(mine)  # a file of that name exists: never overwritten
    events = []
    r = campaign.run_campaign(c, out, progress=False, on_start=events.append)
    assert (r.reused, r.ran, r.quarantined) == (2, 0, 3)
    assert r.quarantine == out / "runs.unread-2.csv" and events[0].quarantine == r.quarantine
    assert (out / "runs.unread-2.csv").read_bytes() == b'"broken,row\n' + b"y" * 140_000 + b"\n" + b"cut"
    assert (out / "runs.unread-1.csv").read_bytes() == mine
    assert [row["index"] for row in runs_csv.read_rows(out / "runs.csv")] == [0, 1]
    # once more, damaged again: a third file, the first two untouched
    (out / "runs.csv").write_bytes((out / "runs.csv").read_bytes() + b'"again\n')
    again = campaign.run_campaign(c, out, progress=False, outputs=False)
    assert again.quarantine == out / "runs.unread-3.csv" and again.quarantined == 1
    assert (out / "runs.unread-3.csv").read_bytes() == b'"again\n'
    assert (out / "runs.unread-2.csv").read_bytes().startswith(b'"broken,row\n')
    # a clean folder sets nothing aside
    clean = campaign.run_campaign(c, out, progress=False, outputs=False)
    assert (clean.quarantined, clean.quarantine, clean.reused) == (0, None, 2)
    assert sorted(p.name for p in out.glob("runs.unread-*")) == [f"runs.unread-{i}.csv" for i in (1, 2, 3)]


def test_a_link_in_the_way_of_the_side_file_is_left_alone(tiny, tmp_path):
    out = copy_of(tiny, tmp_path)
    target = tmp_path / "elsewhere.txt"
    target.write_text("keep me")
    (out / "runs.unread-1.csv").symlink_to(target)
    (out / "runs.csv").write_bytes(tiny[2] + b'"broken\n')
    r = campaign.run_campaign(tiny[0], out, progress=False, outputs=False)
    assert r.quarantine == out / "runs.unread-2.csv" and target.read_text() == "keep me"


def test_the_command_line_says_where_the_unread_lines_are(tiny, tmp_path):
    out = copy_of(tiny, tmp_path)
    header, row0, row1 = tiny_lines(tiny)
    (out / "runs.csv").write_bytes(header + b"z" * 200_000 + b"\n" + row0 + b'"broken,row\n' + row1)
    config = write(tmp_path, TINY.format(model=CIRCUIT))
    # the copied folder's source was another file: the campaign's name is what must match
    r = bgc("experiment", str(config), "-o", str(out), "--no-progress", "-v")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "field larger" not in r.stderr
    assert f"2 lines of {out}/runs.csv could not be read: kept as they were in {out}/runs.unread-1.csv" in r.stderr
    assert "2 runs (2 done before, 0 to run)" in r.stderr
    assert "0 runs done, 2 reused" in r.stdout and "2 unreadable lines of runs.csv kept in" in r.stdout


# ------------------------------------------------------------------ item 10: text that would be code
#: The columns of an earlier bgc's runs.csv: every state's MSE in one text cell, no estimate_method.
OLD_COLUMNS = (
    "id", "index", "group", "model", "scenario", "fault", "kind", "magnitude", "onset", "ambiguous", "filter",
    "particles", "noise", "process_noise", "measurement_noise", "seed", "steps", "status", "failure", "rt",
    "mse", "nmse", "mse_states", "ct", "detected", "detection_time", "delay", "false_alarm", "verdict",
    "diagnosed", "candidates", "right", "in_candidates", "estimate", "low", "high", "est_error", "parameter",
    "parameter_truth", "param_error", "covers", "refine", "separable", "rivals", "separation", "detectability",
    "target", "diagnosed_target", "expected",
)


def test_runs_csv_loads_in_pandas_as_it_is(tiny):
    """runs.csv is a plain CSV: pandas reads it with no option, the header
    first, every numeric column a number (a state's MSE a column of its own),
    a list cell split on its separator, and where the estimate comes from."""
    pd = pytest.importorskip("pandas")
    c, r, _ = tiny
    df = pd.read_csv(r.folder / "runs.csv")
    assert c.states == ("e4", "e8", "f10")  # the circuit's
    assert tuple(df.columns) == runs_csv.columns(c.states) and len(df) == 2
    numeric = [k for k in df.columns if k in runs_csv._INT | runs_csv._FLOAT or runs_csv.is_state_column(k)]
    assert {"index", "rt", "mse", "mse_e4", "mse_e8", "mse_f10", "estimate", "detectability"} <= set(numeric)
    for k in numeric:
        assert pd.api.types.is_numeric_dtype(df[k]), (k, df[k].dtype)
    for i, row in enumerate(r.rows):
        assert [df[f"mse_{s}"][i] for s in c.states] == [row[f"mse_{s}"] for s in c.states]
        assert df["mse"][i] == pytest.approx(sum(row[f"mse_{s}"] for s in c.states) / 3)
    faulty = df[df["fault"] == "R2"].iloc[0]
    assert faulty["candidates"].split(runs_csv.SEPARATOR)[0] == faulty["diagnosed"] == "R2_abrupt"
    assert faulty["estimate_method"] in ("filter", "kalman", "grid")
    assert pd.isna(df[df["scenario"] == "none"].iloc[0]["estimate_method"])  # no fault diagnosed: no estimate


def test_a_runs_csv_of_an_earlier_bgc_resumes_and_is_written_plain(tiny, tmp_path):
    """An earlier bgc's runs.csv (its '# generated by bgc' line first, the
    states' MSEs in one text cell 'e4=0.00197 ...'): every row is reused, no
    line set aside, and the file written again has the header first and a
    column per state."""
    import csv as csvmod
    import io

    c, r, _ = tiny
    out = copy_of(tiny, tmp_path)
    buf = io.StringIO()
    w = csvmod.writer(buf, lineterminator="\n")
    w.writerow(OLD_COLUMNS)
    for row in r.rows:
        w.writerow([" ".join(f"{s}={row[f'mse_{s}']:.6g}" for s in c.states) if k == "mse_states"
                    else runs_csv.format_cell(k, row[k]) for k in OLD_COLUMNS])
    (out / "runs.csv").write_bytes(OLD_COMMENT + buf.getvalue().encode())
    again = campaign.run_campaign(c, out, progress=False)
    assert (again.reused, again.ran, again.quarantined) == (2, 0, 0)
    text = (out / "runs.csv").read_text(encoding="utf-8")
    assert text.splitlines()[0] == ",".join(runs_csv.columns(c.states))
    for old, new in zip(r.rows, runs_csv.read_rows(out / "runs.csv")):
        assert [new[f"mse_{s}"] for s in c.states] == pytest.approx([old[f"mse_{s}"] for s in c.states], rel=1e-5)
        assert new["estimate_method"] is None and new["verdict"] == old["verdict"]  # not in the earlier file


HOSTILE = ["=cmd|' -C calc'!A0", "+1+1", "-2+3", "@SUM(A1)", "\t=1", "\r=1", "'quoted", "''", "a\nb\r\nc",
           "x,\"y\"", "ok", "# heading", "é ü 中", "\x1b[31mred"]


@pytest.mark.parametrize("text", HOSTILE)
def test_text_cells_are_one_line_safe_in_a_spreadsheet_and_read_back_exactly(tmp_path, text):
    row = dict.fromkeys(runs_csv.COLUMNS)
    row.update(id="abc", index=3, status="failed", model=text, scenario=text, failure=text, group=text,
               magnitude=-0.5, onset=-1e-300, seed=7, detected=False)
    line = runs_csv.csv_row(row)
    assert line.count("\n") == 1 and line.endswith("\n") and "\r" not in line
    import csv as csvmod

    cells = dict(zip(runs_csv.COLUMNS, next(csvmod.reader([line]))))
    for column in ("model", "scenario", "failure", "group"):
        assert not cells[column].startswith(("=", "+", "-", "@", "\t", "\r")), cells[column]
    assert cells["magnitude"] == "-0.5" and cells["onset"] == "-1e-300"  # numbers untouched
    path = tmp_path / "runs.csv"
    path.write_text("# generated by bgc\n" + ",".join(runs_csv.COLUMNS) + "\n" + line, encoding="utf-8")
    found = runs_csv.read_runs(path)
    assert found.unread_lines == 0
    back = found.rows[0]
    assert back["model"] == back["failure"] == printable(text)  # exact for a one-line text
    assert (back["magnitude"], back["onset"], back["index"], back["detected"]) == (-0.5, -1e-300, 3, False)


@given(st.text(max_size=40))
def test_any_text_cell_reads_back_as_its_printable_line(text):
    line = runs_csv.format_cell("model", text)
    assert "\n" not in line and "\r" not in line
    assert not line.startswith(("=", "+", "-", "@", "\t", "\r"))
    assert runs_csv.parse_value("model", line) == (printable(text) or None)


def unescape(md: str) -> str:
    """CommonMark's backslash escapes read back: '\\' before ASCII punctuation is that character."""
    return re.sub(r"\\([!-/:-@\[-`{-~])", r"\1", md)


def markup_left(md: str) -> list[str]:
    """Markdown-significant characters not escaped, with what a line start makes of the text."""
    bare = re.sub(r"\\[!-/:-@\[-`{-~]", "\0", md)  # an escaped character is inert
    left = [ch for ch in bare if ch in "\\`*[]<>|~$&#"]
    for m in re.finditer("_", bare):
        i = m.start()
        if not (0 < i < len(bare) - 1 and bare[i - 1].isalnum() and bare[i + 1].isalnum()):
            left.append("_")
    if re.match(r"[-+=]|\d{1,9}[.)]( |$)| {4}", bare):
        left.append("line start")
    return left


@given(st.text(max_size=60))
def test_escaped_text_renders_as_written_and_holds_no_markup(text):
    md = tables.escape(text)
    assert "\n" not in md and "\r" not in md
    assert markup_left(md) == []
    assert unescape(md) == printable(text).strip()


@pytest.mark.parametrize("text", HOSTILE + ["a | b", "[x](http://e.vil)", "<script>x</script>", "*b* _i_", "1. x",
                                            "- item", "> quote", "`code`", "$x$", "&amp;", "~~s~~", "a\\|b"])
def test_hostile_names_are_plain_text_in_markdown(text):
    md = tables.escape(text)
    assert markup_left(md) == [] and unescape(md) == printable(text).strip()
    assert tables.escape("R_pipe_incipient") == "R_pipe_incipient"  # identifiers stay readable
    assert tables.escape("R2:abrupt:-0.6@1.5") == "R2:abrupt:-0.6@1.5"


def unescaped_pipes(line: str) -> int:
    return len(re.findall(r"(?<!\\)\|", re.sub(r"\\\\", "", line)))


def test_tables_md_cannot_be_forged_by_names_paths_and_messages(tmp_path, monkeypatch):
    """A model file named like a formula, a description and titles that try
    to make headings, rows, links and HTML: tables.md keeps its structure and
    runs.csv holds no formula."""
    monkeypatch.chdir(tmp_path)  # the model's path is shown relative to here: it starts with '='
    model = tmp_path / "=cmd|' -C calc'!A0 [x](y) <b>_z_.yaml"
    shutil.copy(CIRCUIT, model)
    text = f"""\
    campaign: _forged_
    description: "ok\\n# Forged heading\\n| a | b |\\n<img src=x onerror=alert(1)>"
    defaults:
      steps: 40
      particles: [50]
    groups:
      - name: g
        model: "{model.name}"
        scenarios: [none]
    tables:
      - title: "T\\n## Injected | x |"
        groups: [g]
        metrics: [rt]
        reference:
          source: "[click](http://e.vil) <script>"
          values: [{{row: none, filter: gpf, rt: 1}}]
    """
    write(tmp_path, text, "--> x.yaml")
    c = campaign_file.load_campaign(Path("--> x.yaml"))
    r = campaign.run_campaign(c, tmp_path / "o", workers=1, progress=False)
    failed = dict(r.rows[0], status="failed", failure="boom | x\n# h <i>", scenario="[a](b)")
    md = tables.campaign_markdown(c, (failed,) + r.rows)
    lines = md.splitlines()
    headings = [ln for ln in lines if ln.startswith("#")]
    assert headings == ["# Campaign \\_forged\\_", "### T\\\\n\\#\\# Injected \\| x \\|", "## Summary",
                        "## Reliability of the verdicts",
                        f"## Isolation confusion matrix: {tables.escape(r.rows[0]['model'])}", "## Failed runs"]
    assert lines[0].startswith("<!-- generated by bgc experiment from ") and lines[0].count("-->") == 1
    for ln in lines[1:]:  # the first line is bgc's own HTML comment
        # no tag and no link (bgc's own '[1]', published numbers, is no link: nothing can define one)
        assert not re.search(r"(?<!\\)<|(?<!\\)\]\(", ln), ln
    # every table row has as many cell bounds as its header
    bounds = None
    for ln in lines:
        if ln.startswith("|"):
            bounds = bounds if bounds is not None else unescaped_pipes(ln)
            assert unescaped_pipes(ln) == bounds, ln
        else:
            bounds = None
    # the description is one paragraph, its characters kept
    desc = lines[lines.index("# Campaign \\_forged\\_") + 2]
    assert unescape(desc) == "ok # Forged heading | a | b | <img src=x onerror=alert(1)>"
    # runs.csv: the model's name is not a formula to a spreadsheet, and reads back as it was
    runs = (tmp_path / "o" / "runs.csv").read_text(encoding="utf-8")
    assert ",'=cmd|' -C calc'!A0" in runs
    assert runs_csv.read_rows(tmp_path / "o" / "runs.csv")[0]["model"] == r.rows[0]["model"]
    assert Path(r.rows[0]["model"]).name == model.name


# ------------------------------------------------------------------ item 15: workers of a killed campaign
def _children(pid: int) -> set[int]:
    out = set()
    for f in Path(f"/proc/{pid}/task").glob("*/children"):
        try:
            out |= {int(x) for x in f.read_text().split()}
        except OSError:
            pass
    return out


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")  # a zombie has ended


@pytest.mark.process  # the campaign's process is killed (SIGKILL), its workers must end with it
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads /proc")
def test_the_workers_of_a_killed_campaign_end_with_it(tmp_path):
    config = write(tmp_path, f"""\
    campaign: long
    defaults:
      steps: 300
      particles: [2000]
      seeds: 40
    groups:
      - name: g
        model: {CIRCUIT}
        scenarios: [none]
    """)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = dict(os.environ, TMPDIR=str(tmp))
    p = subprocess.Popen([sys.executable, "-m", "bgc", "experiment", str(config), "-o", str(tmp_path / "o"),
                          "--workers", "2", "--no-progress"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         env=env)
    workers: set[int] = set()
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and len(workers) < 2:
            workers = _children(p.pid)
            assert p.poll() is None, "the campaign ended before its workers could be seen"
            time.sleep(0.05)
        assert len(workers) >= 2, workers
        time.sleep(1.0)  # at work
        workers = _children(p.pid)
        os.kill(p.pid, signal.SIGKILL)
        p.wait(timeout=10)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and any(_alive(w) for w in workers):
            time.sleep(0.05)
        assert not [w for w in workers if _alive(w)], "workers outlived their campaign"
        # and removed their private folders on the way out
        assert not [d.name for d in tmp.iterdir() if d.name.startswith("bgc-campaign-")]
    finally:
        if p.poll() is None:
            p.kill()
        for w in workers:
            if _alive(w):
                os.kill(w, signal.SIGKILL)


# ------------------------------------------------------------------ found by the review of this issue
@pytest.mark.parametrize("line, words", [
    ("  seeds: 3.0", "integer"), ("  seeds: 1.0e+5", "integer"), ("  particles: [50.0]", "integer"),
    ("  noise: [{name: x, process: .nan, measurement: 0.02}]", "number"),
    ("  noise: [{name: x, process: 0.01, measurement: .inf}]", "number"),
])
def test_integral_floats_and_non_finite_numbers_are_located_schema_errors(tmp_path, line, words):
    text = TINY.format(model=CIRCUIT).replace("  particles: [50]", line if "particles" in line else
                                               "  particles: [50]\n" + line)
    r = bgc("experiment", str(write(tmp_path, text)), "-o", str(tmp_path / "out"))
    error = one_line_error(r)
    assert error.startswith(f"{tmp_path / 'c.yaml'}:") and words in error, error
    assert not (tmp_path / "out").exists()


@pytest.mark.process
def test_a_runs_csv_that_is_a_fifo_or_a_folder_is_refused_at_once(tiny, tmp_path):
    """A real process: a command that blocked reading the FIFO is ended by its timeout."""
    out = copy_of(tiny, tmp_path)
    (out / "runs.csv").unlink()
    os.mkfifo(out / "runs.csv")
    before = sorted(p.name for p in out.iterdir())
    start = time.monotonic()
    error = one_line_error(bgc_process("experiment", str(tiny[0].source), "-o", str(out), timeout=30))
    assert time.monotonic() - start < 20 and "runs.csv" in error
    assert sorted(p.name for p in out.iterdir()) == before
    (out / "runs.csv").unlink()
    (out / "runs.csv").mkdir()
    one_line_error(bgc("experiment", str(tiny[0].source), "-o", str(out)))
    assert sorted(p.name for p in out.iterdir()) == before


def test_an_edited_table_stops_a_resumed_campaign_before_any_run(tiny, tmp_path):
    out = copy_of(tiny, tmp_path)
    (out / "tables.md").write_text((out / "tables.md").read_text() + "my remark\n")
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    bigger = write(tmp_path, Path(tiny[0].source).read_text().replace("particles: [50]", "particles: [50]\n  seeds: 3"))
    start = time.monotonic()
    error = one_line_error(bgc("experiment", str(bigger), "-o", str(out)))
    assert error == f"{out / 'tables.md'} was changed after bgc wrote it (move it away to keep it, or choose another " \
                    "output folder with -o)"
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert time.monotonic() - start < 30
