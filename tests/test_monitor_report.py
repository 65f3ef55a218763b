"""A monitor's report says what it read, not only what it kept: its record
is the last ``keep`` of a stream that may run for months (bgc.service.monitor,
DiagnosisReport.stream), also across a restart from its state."""

from __future__ import annotations

import json

import pytest

import bgc

from conftest import session
from test_episodes import DT, plant

ROWS = 1200  # healthy rows of the circuit (its exact solution), 0.05 s apart: t = 0.05 to 60
KEEP = 100 * DT


def _monitor(lines, **more):
    return bgc.monitor(session("circuit"), lines, keep=KEEP, particles=100, seed=3, **more)


@pytest.mark.slow
@pytest.mark.long
def test_the_report_counts_the_rows_read_beside_the_record_kept(tmp_path):
    lines = plant(ROWS, []).splitlines(keepends=True)
    report = _monitor(lines)
    assert report.stream == (ROWS, pytest.approx(DT))
    # the record kept: at most twice --keep, which is never less than the onsets' reach back (256 steps) and
    # the detector's longest window (32): docs/commands.md
    assert len(report.run.time) <= 2 * (256 + 32) < ROWS
    folder = tmp_path / "out"
    report.write(folder)
    data = json.loads((folder / "report.json").read_text(encoding="utf-8"))["data"]
    assert data["stream"] == {"rows_read": ROWS, "t_first_read": pytest.approx(DT)}
    first = (folder / "report.md").read_text(encoding="utf-8").splitlines()[2]
    assert first.endswith(f"the record the monitor kept of the {ROWS} rows it read from t = 0.05 on.")
    # killed (stopped) after 700 rows, then given only the rows after its state: the count is the state's
    # plus the rows read since, as if it never stopped
    state = tmp_path / "state"
    _monitor(lines[:701], state=state, state_every=50)
    again = _monitor(lines[:1] + lines[701:], state=state, state_every=50)
    assert again.stream == (ROWS, pytest.approx(DT))
    # given the whole input again: the rows it passed over are not counted twice
    state2 = tmp_path / "state2"
    _monitor(lines[:701], state=state2, state_every=50)
    assert _monitor(lines, state=state2, state_every=50).stream == (ROWS, pytest.approx(DT))


def test_a_report_of_a_whole_run_says_nothing_of_a_stream():
    s = bgc.simulate("models/circuit.yaml", "none", seed=1, steps=50)
    assert bgc.diagnose(session("circuit"), s, particles=50).stream is None
