"""Distinguishability of a model with modes (bgc/analysis/distinguish.py), across
its switches: the relay of tests/data/hybrid/relay_rl.yaml."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import bgc
from bgc.model import linear
from bgc.errors import ArgumentValueError
from bgc.model.protocol import nominal_model
from bgc.output import render

ROOT = Path(__file__).resolve().parent.parent
RELAY = ROOT / "tests" / "data" / "hybrid" / "relay_rl.yaml"
#: The same relay switched by an operator (controlled transitions between open and closed).
SWITCHED = ROOT / "docs" / "examples" / "relay_switched.yaml"


def rival(report, name):
    (d,) = report.distinctions
    return next(x for x in d.rivals if x.name == name)


@pytest.mark.slow
def test_two_loads_in_parallel_are_told_apart_only_by_a_switch():
    """By hand: with the relay closed, R_load and R_aux load C in parallel (C dv/dt = i - v G,
    G = 1/R_load + 1/R_aux), so a rise of R_aux from 0.5 to 0.51 (G falls by 0.0392) is the rise of
    R_load that lowers G as much: to first order dG = -dR/R^2, 0.04 / 0.01 = 4 ohms. Closed
    throughout, no data can separate them (the expected log Bayes factor 0, P = 1/2); once the
    relay opens R_aux carries nothing while R_load still shows its change, and the data can."""
    closed = bgc.distinguishability(SWITCHED, "R_aux:abrupt:0.01@1", steps=1000, modes="closed@0.5")
    load = rival(closed, "R_load_abrupt")
    assert abs(load.expected) < 1e-3 * closed.distinctions[0].divergence and abs(load.probability - 0.5) < 0.01
    assert 3.8 < load.magnitude < 4.1
    assert "# modes: closed@0.5 (the controlled changes; from the first mode)" in \
        render.distinguishability_text(closed)
    switching = bgc.distinguishability(SWITCHED, "R_aux:abrupt:0.01@1", steps=1000,
                                       modes="closed@0.5,open@3,closed@4,open@6,closed@7,open@9")
    load = rival(switching, "R_load_abrupt")
    assert load.expected > 1.0 and load.probability > 0.75


def test_the_mode_column_of_a_prediction_is_the_noise_free_plants_run_through_its_automaton():
    """The schedule's controlled changes at their samples (sample k at (k + 1) dt), and the
    relay's own closings above 6 V between them, as the truth simulator runs it."""
    from bgc.api.distinguish import _automaton_modes

    switched = bgc.open(SWITCHED, backend="numpy").view
    modes = _automaton_modes("f", switched, 300, ((0.5, "closed"), (2.0, "open")), ())
    assert np.all(modes[:49] == 1) and np.all(modes[49:199] == 2) and np.all(modes[199:] == 1)
    relay = bgc.open(RELAY, backend="numpy")
    own = _automaton_modes("f", relay.view, 300, (), ())  # no schedule: the guards alone
    sim = bgc.simulate(RELAY, steps=300, process_noise=0.0)  # the guards read the noise-free values
    np.testing.assert_array_equal(own, sim.modes)
    assert set(np.unique(own)) == {1.0, 2.0}
    package = relay.package  # the generated model's own guards give the same column, to a sample at a switch
    guards = linear.scenario_inputs(package, 300)[:, nominal_model(package).MODE_INPUT]
    assert np.mean(guards != own) < 0.02


def test_a_schedule_is_refused_in_one_line_where_it_does_not_apply():
    with pytest.raises(ArgumentValueError, match="'shut' is no mode of the model"):
        bgc.distinguishability(RELAY, "R_aux:abrupt:0.01@1", steps=200, modes="shut@0.5")
    with pytest.raises(ArgumentValueError, match="closed"):  # open -> closed only by the relay's guard
        bgc.distinguishability(RELAY, "R_aux:abrupt:0.01@1", steps=200, modes="closed@0.5")
    with pytest.raises(ArgumentValueError, match="has no modes"):
        bgc.distinguishability(ROOT / "models" / "circuit.yaml", "R2:abrupt:0.6@5", modes="on@1")


@pytest.mark.slow
def test_the_detectors_runs_go_through_the_schedule_and_read_the_mode_the_run_records():
    """bgc's detector on simulated runs of the valve RO through a schedule of
    its three settings (the truth simulator's automaton; the diagnoser takes
    each sample's mode from the run's mode column): a pipe clogged by 24 at
    t = 120, between two switches, is alarmed in every run within a sample
    of its onset (the median delay at most 1 s), and none before it; the
    rate's seeds are the runs' (0, 1, 2). Before, such a model's detector
    runs were refused."""
    r = bgc.distinguishability(ROOT / "models" / "ro_hybrid_valve.yaml", "R_pipe:abrupt:24@120",
                               modes="secondary@100,purge@160,primary@200", detector_runs=3)
    rate = r.detector
    assert (rate.runs, rate.detected, rate.false_alarms, rate.first_seed) == (3, 3, 0, 0), rate
    assert rate.median_delay is not None and rate.median_delay <= 1.0, rate


@pytest.mark.process
def test_bgc_distinguish_takes_the_modes():
    done = subprocess.run([sys.executable, "-m", "bgc", "distinguish", str(SWITCHED), "--scenario",
                           "R_aux:abrupt:0.01@1", "--steps", "1000", "--modes", "closed@0.5"],
                          capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert "# modes: closed@0.5" in done.stdout and "R_load_abrupt" in done.stdout
