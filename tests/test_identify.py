"""Identification by marginal likelihood on a grid (``DiagnosisOptions.refine``)."""

import numpy as np
import pytest

import bgc
from bgc.diagnosis import identify
from bgc.diagnosis import options
from bgc.model import package as packages
from bgc.analysis import track
from bgc.diagnosis.options import DiagnosisOptions

from conftest import FAST, ROOT, bgc_cli, fast_session, numba_package, session

GENERATED = ROOT / "generated"


@pytest.mark.slow
def test_the_grid_posterior_finds_the_bias_and_splits_into_parts_without_changing_it():
    """R2 0.6 -> 2.6 at t = 5 in the circuit: the grid posterior of the bias,
    from the true onset, holds the truth; cutting the grid into two jobs gives
    the same likelihoods (the nominal path and each onset's random numbers do
    not depend on the part)."""
    # the run bgc.diagnose(..., scenario="R2:abrupt:0.6@5", seed=4) diagnoses (one simulator for both), not
    # diagnosed: the grid is given the true onset
    run = bgc.simulate(session("circuit", generated=GENERATED), "R2:abrupt:0.6@5", seed=4).run
    package = packages.load_package(GENERATED, "circuit")
    ys, us = track.run_arrays(run, package, "nominal")
    onset = int(np.searchsorted(run.time, 5.0))
    values = np.linspace(0.2, 1.0, 9)
    whole = identify.loglik_grid(package, "R2_abrupt", None, ys, us, 0, (onset, onset + 2), values, 300, [1])
    parts = [identify.loglik_grid(package, "R2_abrupt", None, ys, us, 0, (onset, onset + 2), v, 300, [1])
             for v in np.array_split(values, 2)]
    assert np.array_equal(whole, np.concatenate(parts, axis=1))
    g = identify.refine(package, "R2_abrupt", None, ys, us, (onset,), 0.3, 0.9, (0.0, 2.0), 0.95,
                        options.GridOptions(points=15, particles=300), [2])
    assert g.low <= 0.6 <= g.high and abs(g.mean - 0.6) < 0.1 and g.std > 0
    assert abs(g.posterior.sum() - 1.0) < 1e-12 and g.values[0] >= 0.0


@pytest.mark.slow
def test_refine_replaces_the_estimate_of_the_diagnosed_hypothesis():
    """On the FAST backend (conftest.fast_session; the slow tier only)."""
    a = bgc.diagnose(fast_session("circuit"), scenario="R2:abrupt:0.6@5", seed=4,
                     options=DiagnosisOptions(seed=4, refine=True, workers=1)).diagnosis
    assert a.candidates == ("R2_abrupt",) and a.estimate.method == "grid"
    assert abs(a.estimate.value - 0.6) < 4 * a.estimate.std and a.estimate.low < a.estimate.value < a.estimate.high
    assert abs(a.estimate.parameter_value - (2.0 + a.estimate.value)) < 1e-9


@pytest.mark.slow
def test_bgc_diagnose_refine_says_so_in_the_report(tmp_path):
    """On the FAST backend, --backend (conftest.fast_session's kernels; the
    slow tier only): the command's --refine reaches the grid as the option
    does above, and the report says which estimate it gives."""
    if FAST == "numba":
        numba_package("circuit")  # the kernels the command loads, compiled once per test run
    r = bgc_cli("diagnose", "models/circuit.yaml", "--scenario", "R2:abrupt:0.6@5", "--seed", "4", "--refine",
                "--backend", FAST, "-o", tmp_path / "d")
    assert r.returncode == 0, r.stderr
    assert "grid posterior of the particle filters' marginal likelihood" in (tmp_path / "d" / "report.md").read_text()


def test_the_static_evidence_integrates_the_grid_by_the_trapezoid_rule_over_the_prior():
    """A likelihood of 1 on a grid over [0.2, 0.7], prior uniform on [0, 2],
    two onsets weighing 1 and 3: the integral is (0.7 - 0.2) / 2 per onset,
    so the evidence is log((1 + 3) x 0.25) = 0; a likelihood of e^2 at one
    grid point of one onset adds e^2 - 1 times that point's share."""
    values = np.linspace(0.2, 0.7, 6)
    ll = np.zeros((2, 6))
    g = identify.GridPosterior(values, (10, 14), ll, np.full(6, 1 / 6), 0.45, 0.1, 0.2, 0.7, 0.95)
    assert abs(identify.log_evidence(g, (0.0, 2.0), [1.0, 3.0])) < 1e-12
    ll2 = ll.copy()
    ll2[1, 2] = 2.0  # an interior point: trapezoid weight 0.1, onset weight 3
    g2 = identify.GridPosterior(values, (10, 14), ll2, np.full(6, 1 / 6), 0.45, 0.1, 0.2, 0.7, 0.95)
    expected = np.log(1.0 + 3 * 0.1 * (np.exp(2.0) - 1.0) / 2.0)
    assert abs(identify.log_evidence(g2, (0.0, 2.0), [1.0, 3.0]) - expected) < 1e-12


@pytest.mark.slow
def test_rank_weighs_the_survivors_by_their_static_evidence():
    """``rank``: R2 drifting in the circuit at 1 % process and 5 % measurement
    noise (a run of the sweep that R1's drift explains about as well): both
    drifts survive the filters' Bayes factor, each gets the static evidence of
    its grid, the survivors' posteriors are in the ratio of their prior times
    that evidence, and all posteriors still sum to 1. On the FAST backend
    (conftest.fast_session; the slow tier only)."""
    import math

    model = fast_session("circuit", process_noise=0.01, measurement_noise=0.05)
    d = bgc.diagnose(model, scenario="R2:incipient:0.0649091@5.45", seed=3751515929,
                     options=DiagnosisOptions(seed=3751515929, rank=True, workers=1)).diagnosis
    ranked = {h.name: h for h in d.hypotheses if h.static_log_evidence is not None}
    assert {"R1_incipient", "R2_incipient"} <= set(ranked) and set(d.candidates) <= set(ranked)
    assert all(math.isfinite(h.static_log_evidence) for h in ranked.values())
    a, b = ranked["R1_incipient"], ranked["R2_incipient"]
    assert abs(math.log(a.posterior / b.posterior) - (a.static_log_evidence - b.static_log_evidence)) < 1e-6
    assert abs(sum(h.posterior for h in d.hypotheses) - 1.0) < 1e-9
