"""A monitor that survives a restart (issue 47, point 4): ``bgc monitor
--state DIR`` saves its state, and a monitor started again with the same
folder goes on where the state left it, as if it had never stopped.

The plant is the circuit of models/circuit.yaml simulated by the exact
solution of its equations (tests/test_mismatch.py: the matrix exponential
over each sample period), its R2 stepping to 1.6 times its value at
t = 6; the rows reach the monitor through a file and through a real pipe,
the process killed (SIGKILL) part way through. The monitors of the slow tests
run on the FAST backend (conftest.fast_backend: numba when installed; the
diagnosis does not depend on it, tests/test_backend.py), the others on NumPy.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bgc.service import resume

from conftest import ROOT, bgc_cli, fast_backend
from test_mismatch import DT, NOMINAL, START, V, circuit, readings

CIRCUIT = ROOT / "models" / "circuit.yaml"
STEPS, ONSET = 240, 6.0
#: The monitor's options in every run here (a state is valid for them only).
OPTIONS = ("--particles", "200", "--seed", "3")


def plant_lines(seed: int = 2, r2: float = 1.6, f2_bias: float = 0.0) -> list[str]:
    """The circuit's run as a logger's CSV lines: from t = ONSET, R2 is
    ``r2`` times its value and sensor f2 reads ``f2_bias`` high; noise as the
    model declares."""
    rng = np.random.default_rng(seed)
    healthy, faulty = circuit(NOMINAL, 1.0), circuit(dict(NOMINAL, R2=r2 * NOMINAL["R2"]), 1.0)
    x, lines = np.array(START), ["time,u:V,y:f2,y:f6,y:e11"]
    for k in range(1, STEPS + 1):
        p, (e, process, sensor) = (NOMINAL, healthy) if k * DT < ONSET else \
            (dict(NOMINAL, R2=r2 * NOMINAL["R2"]), faulty)
        x = e[:3, :3] @ x + e[:3, 3] * V + process * rng.standard_normal(3)
        y = readings(p, x, V) + sensor * rng.standard_normal(3) + [f2_bias * (k * DT >= ONSET), 0, 0]
        lines.append(",".join(f"{v:.6g}" for v in (k * DT, V, *y)))
    return [line + "\n" for line in lines]


def report(folder: Path) -> dict:
    """report.json without the seconds the diagnosis took (a clock's, not the data's)."""
    return _no_seconds(json.loads((folder / "report.json").read_text(encoding="utf-8")))


def _no_seconds(value):
    if isinstance(value, dict):
        return {k: _no_seconds(v) for k, v in value.items() if k != "seconds"}
    if isinstance(value, list):
        return [_no_seconds(v) for v in value]
    return value


def saved_rows(state: Path) -> int:
    """The rows the state file in folder ``state`` was saved after (0: none yet)."""
    f = state / resume.NAME
    return json.loads(f.read_bytes().split(b"\n")[1])["rows"] if f.is_file() else 0


def monitor(tmp: Path, lines: list[str], out: str, *more):
    return bgc_cli("monitor", CIRCUIT, "--data", "-", *OPTIONS, "-o", tmp / out, *more, input="".join(lines))


def fast_monitor(tmp: Path, lines: list[str], out: str, *more):
    """:func:`monitor` on the FAST backend (the slow tests')."""
    return monitor(tmp, lines, out, *fast_backend("circuit"), *more)


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """The uninterrupted monitor's run: what it printed, and its report."""
    tmp = tmp_path_factory.mktemp("whole")
    p = fast_monitor(tmp, plant_lines(), "whole")
    assert p.returncode == 0, p.stderr
    assert "circuit: isolated: R2_abrupt" in p.stdout
    return p.stdout, report(tmp / "whole")


@pytest.mark.slow
@pytest.mark.long
def test_a_monitor_started_again_on_its_state_gives_the_uninterrupted_diagnosis(tmp_path, whole):
    lines = plant_lines()
    # The first 100 rows, then the input ends (the state saved every 30 rows, and at the end).
    first = fast_monitor(tmp_path, lines[:101], "first", "--state", tmp_path / "state", "--state-every", "30")
    assert first.returncode == 0, first.stderr
    assert (tmp_path / "state" / resume.NAME).is_file() and not (tmp_path / "state" / resume.PARTIAL).exists()
    # Started again with the whole input from its start: the rows to t = 5 are passed over. On two
    # processes where the first ran on one (the suite's BGC_WORKERS): the state holds to no count of them.
    again = fast_monitor(tmp_path, lines, "again", "--state", tmp_path / "state", "--state-every", "30",
                         "--workers", "2")
    assert again.returncode == 0, again.stderr
    said = again.stdout.splitlines()
    assert said[0] == "resumed from " + str(tmp_path / "state") + \
        ": 100 rows read, to t = 5 (the record the diagnosis keeps: the last 100); the input's rows after it are read on"
    assert report(tmp_path / "again") == whole[1]
    assert said[1:-1] == whole[0].splitlines()[:-1]  # every event: none was said before t = 5
    assert said[-1].startswith("wrote ")


def test_a_state_that_is_not_this_monitors_is_refused_in_one_line_and_kept(tmp_path):
    lines = plant_lines()[:41]
    state = tmp_path / "state"
    assert monitor(tmp_path, lines, "a", "--state", state).returncode == 0
    saved = (state / resume.NAME).read_bytes()

    def refused(*more, model=CIRCUIT, what):
        p = bgc_cli("monitor", model, "--data", "-", *more, "-o", tmp_path / "b", "--state", state,
                    input="".join(lines))
        assert p.returncode != 0 and "Traceback" not in p.stderr, p.stderr
        assert len(p.stderr.strip().splitlines()) == 1 and what in p.stderr, p.stderr
        assert (state / resume.NAME).read_bytes() == saved  # never replaced

    refused("--particles", "300", "--seed", "3", what="saved with another options")
    edited = tmp_path / "circuit.yaml"
    edited.write_text(CIRCUIT.read_text(encoding="utf-8").replace("value: 2.0", "value: 2.1", 1), encoding="utf-8")
    refused(*OPTIONS, model=edited, what="saved with another model file")
    refused(*OPTIONS, "--checkpoint", "1", what="saved with another --checkpoint")
    changed = bytearray(saved)
    changed[-1000] ^= 1  # one bit of the diagnoser's state
    (state / resume.NAME).write_bytes(bytes(changed))
    saved = (state / resume.NAME).read_bytes()
    refused(*OPTIONS, what="the state is not whole (its checksum differs)")
    (state / resume.NAME).write_bytes(saved[: len(saved) // 2])
    saved = (state / resume.NAME).read_bytes()
    refused(*OPTIONS, what="the state is not whole")
    (state / resume.NAME).write_bytes(b"a file of someone else\n")
    saved = (state / resume.NAME).read_bytes()
    refused(*OPTIONS, what="is not a state bgc wrote")
    (state / resume.NAME).unlink()
    (tmp_path / "theirs").write_text("", encoding="utf-8")
    (state / resume.PARTIAL).symlink_to(tmp_path / "theirs")  # bgc writes through no link
    p = bgc_cli("monitor", CIRCUIT, "--data", "-", *OPTIONS, "-o", tmp_path / "d", "--state", state,
                input="".join(lines))
    assert p.returncode != 0 and "is not a state bgc wrote" in p.stderr
    assert (tmp_path / "theirs").read_text(encoding="utf-8") == ""


@pytest.mark.slow
def test_a_restart_on_other_rows_than_the_state_was_saved_with_is_refused(tmp_path):
    lines = plant_lines()
    assert fast_monitor(tmp_path, lines[:61], "a", "--state", tmp_path / "s").returncode == 0
    other = lines[:30] + [lines[30].replace(",10,", ",10.5,", 1)] + lines[31:]
    p = fast_monitor(tmp_path, other, "b", "--state", tmp_path / "s")
    assert p.returncode != 0 and "<stdin>:31: the row of t = 1.5 differs from the one the state" in p.stderr, p.stderr


def test_the_state_options_are_checked_before_the_input_is_read(tmp_path):
    for args, what in ((("--state-every", "5"), "--state-every applies to --state"),
                       (("--state", tmp_path / "c" / "state"), "is inside the report folder"),
                       (("--state", tmp_path / "s", "--state-every", "0"), "--state-every 0")):
        p = monitor(tmp_path, plant_lines()[:5], "c", *args)
        assert p.returncode != 0 and what in p.stderr and "Traceback" not in p.stderr, p.stderr
    (tmp_path / "file").write_text("x", encoding="utf-8")
    p = monitor(tmp_path, plant_lines()[:5], "c", "--state", tmp_path / "file")
    assert p.returncode != 0 and "not a folder" in p.stderr
    assert (tmp_path / "file").read_text(encoding="utf-8") == "x"


@pytest.mark.process
@pytest.mark.slow
def test_a_monitor_killed_mid_stream_goes_on_from_its_last_state(tmp_path, whole):
    """SIGKILL to a real ``bgc monitor`` reading a pipe, after its state was
    saved; started again with the logger's whole file on its standard input,
    it gives the uninterrupted diagnosis."""
    lines = plant_lines()
    state = tmp_path / "state"

    def cmd(out: str) -> list[str]:
        return [sys.executable, "-m", "bgc", "monitor", str(CIRCUIT), "--data", "-", *OPTIONS,
                *fast_backend("circuit"), "-o", str(tmp_path / out), "--state", str(state), "--state-every", "20"]

    p = subprocess.Popen(cmd("killed"), stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                         env=dict(os.environ, MPLBACKEND="Agg"))
    try:
        p.stdin.write("".join(lines[:151]))
        p.stdin.flush()
        deadline = time.monotonic() + 120
        while saved_rows(state) < 100 and time.monotonic() < deadline:
            time.sleep(0.05)
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert not (tmp_path / "killed" / "report.json").exists()  # killed: no report
    rows = saved_rows(state)
    assert 100 <= rows <= 140
    again = subprocess.run(cmd("again"), input="".join(lines), capture_output=True, text=True, timeout=300,
                           env=dict(os.environ, MPLBACKEND="Agg"))
    assert again.returncode == 0, again.stderr
    assert again.stdout.startswith(f"resumed from {state}: ") and f"(the record the diagnosis keeps: the last {rows})" \
        in again.stdout.splitlines()[0]
    assert report(tmp_path / "again") == whole[1]


@pytest.mark.slow
@pytest.mark.long
def test_a_restart_after_a_sensor_was_taken_out_goes_on_without_it(tmp_path):
    """f2 reads 0.5 high from t = 6: a checkpoint every time unit isolates
    it and the monitor takes it out (--exclude-faulty-sensor); stopped
    after that and started again, the monitor watches without f2 and ends
    as the uninterrupted one, checkpoints at the same times."""
    lines = plant_lines(r2=1.0, f2_bias=0.5)
    more = ("--checkpoint", "1", "--exclude-faulty-sensor")
    whole = fast_monitor(tmp_path, lines, "whole", *more)
    assert whole.returncode == 0 and "sensor f2 taken out" in whole.stdout, whole.stdout
    first = fast_monitor(tmp_path, lines[:231], "first", *more, "--state", tmp_path / "s", "--state-every", "7")
    assert first.returncode == 0 and "sensor f2 taken out" in first.stdout
    again = fast_monitor(tmp_path, lines, "again", *more, "--state", tmp_path / "s", "--state-every", "7")
    assert again.returncode == 0, again.stderr
    assert report(tmp_path / "again") == report(tmp_path / "whole")
    said = again.stdout.splitlines()
    assert said[0].startswith("resumed from ") and said[1:-1] == \
        [x for x in whole.stdout.splitlines()[:-1] if x not in first.stdout.splitlines()[:-2]]


@pytest.mark.slow
def test_a_restart_from_the_state_saved_as_an_episode_closed_gives_the_uninterrupted_report(tmp_path):
    """--episodes: the state saved as an episode closes holds no row (the
    next diagnoser, on the model with the fault accommodated, took none yet):
    what a kill right after the close leaves, and a stream that ends on the
    close row (its end saves nothing more). Started again on it, the monitor
    ends as the uninterrupted one (bench/restart_kills.py kills at 20 points
    of a longer stream)."""
    from test_episodes import OPTIONS as EPISODES, plant

    lines = plant(180, [(6.0, {"R2": 1.6})]).splitlines(keepends=True)  # R2 up from t = 6, to t = 9
    fast = ("--particles", "100", "--no-recheck")  # over EPISODES', the same in every run (a state is for them)

    def run(out: str, rows: int, *more):
        p = bgc_cli("monitor", CIRCUIT, "--data", "-", *EPISODES, *fast, *fast_backend("circuit"), "-o", tmp_path / out,
                    *more, input="".join(lines[:rows + 1]))
        assert p.returncode == 0, p.stderr
        return p

    run("whole", 180)
    closed = report(tmp_path / "whole")["events"][0]
    assert closed["event"] == "EpisodeClosed" and closed["action"] == "accommodated"
    state = tmp_path / "state"
    first = run("first", round(closed["time"] / DT), "--state", state)  # up to the row it closed on
    assert "episode 1 closed" in first.stdout and (state / resume.NAME).is_file() and saved_rows(state) == 0
    again = run("again", 180, "--state", state)
    read = round(closed["time"] / DT)  # every row up to the one the episode closed on, none kept
    assert again.stdout.startswith(f"resumed from {state}: {read} rows read, to t = {closed['time']:g} (the record "
                                   "the diagnosis keeps: the last 0);")
    assert report(tmp_path / "again") == report(tmp_path / "whole")


@pytest.mark.slow
def test_a_restart_on_a_pipe_of_the_new_rows_takes_the_repair_said_in_it(tmp_path):
    """A repair said before the first row of a restarted input that holds
    only the rows after the state (a pipe of what the logger writes from now
    on): it is taken there, as the uninterrupted stream takes it, although
    the state counted the first input's comment lines (a ``# repaired`` at
    t = 2, before the fault). The fault log of the two readings is the
    uninterrupted one's: R2 accommodated, then repaired at t = 12 (the first
    row of the second input), the restarted report holding the whole log."""
    from test_episodes import OPTIONS as EPISODES, plant

    lines = plant(400, [(6.0, {"R2": 1.6}), (12.0, {"R2": 1.0})]).splitlines(keepends=True)
    head, rows = lines[0], lines[1:]
    cut = next(i for i, line in enumerate(rows) if float(line.split(",")[0]) > 12.0 - 1e-9)  # the row of t = 12
    early = next(i for i, line in enumerate(rows) if float(line.split(",")[0]) > 2.0 - 1e-9)
    first = [head] + rows[:early] + ["# repaired\n"] + rows[early:cut]
    then = [head, "# repaired: R2\n"] + rows[cut:]

    def run(out: str, text: list[str], *more):
        p = bgc_cli("monitor", CIRCUIT, "--data", "-", *EPISODES, *fast_backend("circuit"), "-o", tmp_path / out,
                    *more, input="".join(text))
        assert p.returncode == 0, p.stderr
        return [e for e in report(tmp_path / out)["events"] if e["event"] in ("EpisodeClosed", "Repaired")]

    whole = run("whole", first + then[1:])
    assert [e["event"] for e in whole] == ["Repaired", "EpisodeClosed", "Repaired"], whole
    assert whole[-1]["parameters"] == ["R2"] and whole[-1]["time"] == pytest.approx(float(rows[cut].split(",")[0]))
    state = tmp_path / "state"
    before = run("before", first, "--state", state)
    assert before == whole[:2]
    after = run("after", then, "--state", state)
    assert after == whole, after


@pytest.mark.slow
def test_a_state_is_for_what_the_column_map_does_not_for_its_comments(tmp_path):
    """A logger's file monitored with its column map and a state, then again
    with the map moved, a comment added and a scale written 0.00100: the
    state is taken up (the same map); with one scale changed it is refused
    in one line naming the column map."""
    logger = ROOT / "docs" / "examples" / "tank_logger.csv"
    text = (ROOT / "docs" / "examples" / "tank_logger.yaml").read_text(encoding="utf-8")
    lines = logger.read_text(encoding="utf-8").splitlines(keepends=True)
    first = "".join(lines[:62])
    (tmp_path / "map.yaml").write_text(text, encoding="utf-8")
    (tmp_path / "other").mkdir()
    same = (tmp_path / "other" / "map.yaml")
    same.write_text("# the same map, with a comment\n" + text.replace("drain1_Lps: {name: y:F10, scale: 0.001}",
                                                                      "drain1_Lps: {name: y:F10, scale: 0.00100}"),
                    encoding="utf-8")
    changed = tmp_path / "changed.yaml"
    changed.write_text(text.replace("drain1_Lps: {name: y:F10, scale: 0.001}",
                                    "drain1_Lps: {name: y:F10, scale: 0.0011}"), encoding="utf-8")

    def monitor(columns, out, data):
        return bgc_cli("monitor", "models/two_tank.yaml", "--data", "-", "--columns", columns, "--particles", "100",
                       "--state", tmp_path / "s", "-o", tmp_path / out, input=data)

    assert monitor(tmp_path / "map.yaml", "a", first).returncode == 0
    again = monitor(same, "b", "".join(lines))
    assert again.returncode == 0 and again.stdout.startswith(f"resumed from {tmp_path / 's'}: 60 rows read"), \
        again.stdout + again.stderr
    refused = monitor(changed, "c", "".join(lines))
    assert refused.returncode != 0 and "another column map" in refused.stderr, refused.stderr
