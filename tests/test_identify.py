"""Identification by marginal likelihood on a grid (``DiagnosisOptions.refine``)."""

import numpy as np

import bgc
from bgc.runtime import identify, track
from bgc.runtime.diagnose import DiagnosisOptions

from conftest import ROOT

GENERATED = ROOT / "generated"


def test_the_grid_posterior_finds_the_bias_and_splits_into_parts_without_changing_it():
    """R2 0.6 -> 2.6 at t = 5 in the circuit: the grid posterior of the bias,
    from the true onset, holds the truth; cutting the grid into two jobs gives
    the same likelihoods (the nominal path and each onset's random numbers do
    not depend on the part)."""
    report = bgc.diagnose(ROOT / "models" / "circuit.yaml", scenario="R2:abrupt:0.6@5", seed=4, generated=GENERATED)
    package = track.load_package(GENERATED, "circuit")
    ys, us = track.run_arrays(report.run, package, "nominal")
    onset = int(np.searchsorted(report.run.time, 5.0))
    values = np.linspace(0.2, 1.0, 9)
    whole = identify.loglik_grid(package, "R2_abrupt", None, ys, us, 0, (onset, onset + 2), values, 300, [1])
    parts = [identify.loglik_grid(package, "R2_abrupt", None, ys, us, 0, (onset, onset + 2), v, 300, [1])
             for v in np.array_split(values, 2)]
    assert np.array_equal(whole, np.concatenate(parts, axis=1))
    g = identify.refine(package, "R2_abrupt", None, ys, us, (onset,), 0.3, 0.9, (0.0, 2.0), 0.95,
                        identify.GridOptions(points=15, particles=300), [2])
    assert g.low <= 0.6 <= g.high and abs(g.mean - 0.6) < 0.1 and g.std > 0
    assert abs(g.posterior.sum() - 1.0) < 1e-12 and g.values[0] >= 0.0


def test_refine_replaces_the_estimate_of_the_diagnosed_hypothesis():
    model = ROOT / "models" / "circuit.yaml"
    a = bgc.diagnose(model, scenario="R2:abrupt:0.6@5", seed=4, generated=GENERATED,
                     options=DiagnosisOptions(seed=4, refine=True)).diagnosis
    assert a.candidates == ("R2_abrupt",) and a.estimate.method == "grid"
    assert a.estimate.low <= 0.6 <= a.estimate.high
    assert abs(a.estimate.parameter_value - (2.0 + a.estimate.value)) < 1e-9


def test_bgc_diagnose_refine_says_so_in_the_report(tmp_path):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "bgc", "diagnose", "models/circuit.yaml", "--scenario", "R2:abrupt:0.6@5",
                        "--seed", "4", "--refine", "--generated", "generated", "-o", str(tmp_path / "d")],
                       cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "grid posterior of the marginal likelihood" in (tmp_path / "d" / "report.md").read_text()
