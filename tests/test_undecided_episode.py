"""An episode never decided does not stop a monitor that runs for months
(bgc.service.monitor, FULL_ROOM): without ``--rearm``, a fault no fault
model explains keeps the record growing from its alarm, until the most the
diagnosis may hold in memory (bgc.api.limits); before that the episode is
closed ``re-armed`` for that reason, and the monitor watches on."""

from __future__ import annotations

import pytest

import bgc
from bgc.api import session as session_module
from bgc.service import monitor as monitor_module

from conftest import fast_session
from test_episodes import DT, plant

#: The most steps the diagnosis may hold, made small for the test (RO's real one is about 15,500).
MOST = 300


@pytest.mark.slow
@pytest.mark.long
def test_an_episode_never_decided_is_closed_before_the_memory_rule_and_the_monitor_goes_on(monkeypatch):
    monkeypatch.setattr(session_module, "most_steps", lambda numerics, options: MOST)
    # R2 falls to 0.6 of its value at t = 6 and stays there: outside the prior of every fault model (R2_abrupt
    # only rises, tests/test_episodes.py), never isolated, and no --rearm
    text = plant(600, [(6.0, {"R2": 0.6})])
    said = []
    report = bgc.monitor(fast_session("circuit"), text.splitlines(keepends=True), checkpoint=3.0, episodes=True,
                         keep=100 * DT, particles=300, seed=3, events=said.append)
    log = report.fault_log
    assert log, said
    assert all(e.action == "re-armed" and e.reason == "memory" and e.verdict != "isolated" for e in log)
    start = 0.0  # where each diagnoser's record began: the stream's start, then the last episode's close
    for e in log:  # closed once its record (from its start, not only since the alarm) is within the room of the most
        assert start < e.alarm < e.time
        assert MOST - monitor_module.FULL_ROOM <= round((e.time - start) / DT) <= MOST
        start = e.time
    assert report.diagnosis.time[-1] == pytest.approx(600 * DT)  # the stream read to its end: no error
    assert not any(line.startswith("stopped: ") for line in said)
    assert any("not decided before its record reached the most this diagnosis holds in memory" in line
               for line in said)


def test_the_room_is_kept_below_the_most():
    class Loop:
        samples = range(0)

    class Config:
        most = 1000

    class D:
        loop, config = Loop(), Config()

    d = D()
    for n, full in ((0, False), (1000 - monitor_module.FULL_ROOM - 1, False), (1000 - monitor_module.FULL_ROOM, True)):
        d.loop.samples = range(n)
        assert monitor_module._nearly_full(d) is full
    d.config.most = None
    assert monitor_module._nearly_full(d) is False
