"""Distinguishability of a model with modes (bgc/analysis/distinguish.py), across
its switches: the relay of tests/data/hybrid/relay_rl.yaml."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import bgc
from bgc.analysis import distinguish
from bgc.errors import ArgumentValueError, SimulationError
from bgc.model.protocol import nominal_model
from bgc.output import render

ROOT = Path(__file__).resolve().parent.parent
RELAY = ROOT / "tests" / "data" / "hybrid" / "relay_rl.yaml"


def rival(report, name):
    (d,) = report.distinctions
    return next(x for x in d.rivals if x.name == name)


def test_two_loads_in_parallel_are_told_apart_only_by_a_switch():
    """By hand: with the relay closed, R_load and R_aux load C in parallel (C dv/dt = i - v G,
    G = 1/R_load + 1/R_aux), so a rise of R_aux from 0.5 to 0.51 (G falls by 0.0392) is the rise of
    R_load that lowers G as much: to first order dG = -dR/R^2, 0.04 / 0.01 = 4 ohms. Closed
    throughout, no data can separate them (the expected log Bayes factor 0, P = 1/2); once the
    relay opens R_aux carries nothing while R_load still shows its change, and the data can."""
    closed = bgc.distinguishability(RELAY, "R_aux:abrupt:0.01@1", steps=1000, modes="closed@0.5")
    load = rival(closed, "R_load_abrupt")
    assert abs(load.expected) < 1e-3 * closed.distinctions[0].divergence and abs(load.probability - 0.5) < 0.01
    assert 3.8 < load.magnitude < 4.1
    assert "# modes: closed@0.5 (the controlled changes; from the first mode)" in \
        render.distinguishability_text(closed)
    switching = bgc.distinguishability(RELAY, "R_aux:abrupt:0.01@1", steps=1000,
                                       modes="closed@0.5,open@3,closed@4,open@6,closed@7,open@9")
    load = rival(switching, "R_load_abrupt")
    assert load.expected > 1.0 and load.probability > 0.75


def test_the_mode_column_of_a_prediction_follows_the_schedule_or_the_guards():
    package = bgc.open(RELAY, backend="numpy").package
    nominal = nominal_model(package)
    us = distinguish.scenario_inputs(package, 300, schedule=((0.5, "closed"), (2.0, "open")))
    modes = us[:, nominal.MODE_INPUT]  # sample k at (k + 1) dt = 0.01 (k + 1)
    assert np.all(modes[:49] == 1) and np.all(modes[49:199] == 2) and np.all(modes[199:] == 1)
    own = distinguish.scenario_inputs(package, 300)[:, nominal.MODE_INPUT]  # the guards: closes above 6 V
    first = int(np.argmax(own == 2))
    assert own[0] == 1 and first > 0 and set(np.unique(own)) <= {1.0, 2.0}


def test_a_schedule_is_refused_in_one_line_where_it_does_not_apply():
    with pytest.raises(SimulationError, match="'shut' is no mode of the model"):
        bgc.distinguishability(RELAY, "R_aux:abrupt:0.01@1", steps=200, modes="shut@0.5")
    with pytest.raises(ArgumentValueError, match="has no modes"):
        bgc.distinguishability(ROOT / "models" / "circuit.yaml", "R2:abrupt:0.6@5", modes="on@1")
    with pytest.raises(ArgumentValueError, match="detector_runs=5 is not built yet for a model with modes"):
        bgc.distinguishability(RELAY, "R_aux:abrupt:0.01@1", steps=200, detector_runs=5)


@pytest.mark.process
def test_bgc_distinguish_takes_the_modes():
    done = subprocess.run([sys.executable, "-m", "bgc", "distinguish", str(RELAY), "--scenario",
                           "R_aux:abrupt:0.01@1", "--steps", "1000", "--modes", "closed@0.5"],
                          capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert "# modes: closed@0.5" in done.stdout and "R_load_abrupt" in done.stdout
