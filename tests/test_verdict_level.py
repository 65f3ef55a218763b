"""What a verdict promises: its candidates hold a posterior of at least
``isolation_level`` together, and a fault model the symbols ruled out is
weighed before a verdict names another (step 6b, ``recheck``).

The level rule is checked on hypotheses built by hand (the posteriors are
the test's own numbers, the expected groups summed by hand); the recheck on
a run where the symbols mislead: the two tanks at 3 % process / 10 %
measurement noise, R12 drifting at 0.01 per unit time from t = 75 (seed 6 of
experiments/step_or_drift.yaml). The drift is so slow that the detector
alarms at t = 273 of 300; the symbols, read on the open-loop prediction from
a change point far after the true onset, see F20's slope rise, which rules
out R12's drift (its signature predicts it falling) and leaves R20's step
alone. Without step 6b that run was "isolated: R20_abrupt", a fault that
was not there.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import bgc
from bgc.diagnosis import weigh
from bgc.diagnosis.options import DiagnosisOptions
from bgc import events as ev
from bgc.diagnosis.values import Drop, Estimate, Hypothesis

from conftest import fast_session


def hypothesis(name: str, posterior: float, dropped: int | None = None, code: str = "bayes-factor") -> Hypothesis:
    e = Estimate("P", "abrupt", "bias", 0.0, 0.0, 0.0, 0.0, 0.95, 1.0, 1.0, None)
    empty = np.zeros((0, 1))
    return Hypothesis(name=name, parameter="P", kind="abrupt", signatures=(), start_step=0, onset_steps=(0,),
                      onset_posterior=(1.0,), y_mean=empty, y_std=empty, z=empty, x_mean=empty, x_std=empty,
                      magnitude=np.zeros(0), magnitude_band=np.zeros((0, 2)),
                      drop=None if dropped is None else Drop(code, dropped, code), log_evidence=0.0,
                      posterior=posterior, estimate=e, seconds=0.0)


def test_a_lone_survivor_under_the_level_keeps_the_most_probable_outvoted_rivals():
    """A at 0.90 survives; B, C, D (0.05, 0.03, 0.02) were dropped by the
    Bayes factor. A alone holds 0.90 < 0.95 of the 1.00 in the running;
    A + B hold 0.95: B is kept, C and D stay dropped. E, dropped by its
    consistency test, is out of the running whatever its posterior."""
    hs = (hypothesis("A", 0.90), hypothesis("B", 0.05, 9), hypothesis("C", 0.03, 9),
          hypothesis("D", 0.02, 9), hypothesis("E", 0.5, 3, "inconsistent"))
    out, events = weigh.credible(hs, 0.95, 10)
    assert [h.name for h in out if h.dropped_step is None] == ["A", "B"]
    assert weigh.verdict(out) == ("ambiguous", ("A", "B"))
    (e,) = events
    assert isinstance(e, ev.Uncertain)
    assert e.candidates == ("A",) and e.kept == ("B",)
    assert e.mass == pytest.approx(0.90) and e.posteriors == pytest.approx((0.05,))
    drops = {h.name: h.drop for h in out}
    assert drops["B"] is None and drops["C"].code == "bayes-factor" and drops["E"].code == "inconsistent"


def test_survivors_at_the_level_are_left_as_they_are():
    """A at 0.96 of the running 1.00: isolated, no event; a level of 0.99
    keeps B (0.96 + 0.03 = 0.99), not C."""
    hs = (hypothesis("A", 0.96), hypothesis("B", 0.03, 9), hypothesis("C", 0.01, 9))
    out, events = weigh.credible(hs, 0.95, 10)
    assert out is hs and not events
    out, events = weigh.credible(hs, 0.99, 10)
    assert weigh.verdict(out) == ("ambiguous", ("A", "B"))


def test_many_rivals_each_under_the_bayes_factor_make_a_verdict_ambiguous():
    """20 rivals at 1/150 of the best each pass the Bayes factor of 100 one
    by one, but together hold 20/170 = 0.118: the best alone is 0.882."""
    best = 1.0 / (1.0 + 20 / 150)
    hs = (hypothesis("A", best),) + tuple(hypothesis(f"R{i:02d}", best / 150, 9) for i in range(20))
    out, _ = weigh.credible(hs, 0.95, 10)
    kept = [h.name for h in out if h.dropped_step is None]
    # the best plus k rivals reach 0.95 when (1 + k/150) / (1 + 20/150) >= 0.95: k >= 11.5
    assert len(kept) == 1 + 12


@pytest.fixture(scope="module")
def noisy_tanks():
    """The two tanks at 3 % / 10 % noise on the FAST backend (conftest.fast_session; the slow tier only)."""
    return fast_session("two_tank", process_noise=0.03, measurement_noise=0.1)


@pytest.mark.slow
def test_a_fault_model_the_symbols_ruled_out_is_weighed_before_another_is_named(noisy_tanks):
    options = DiagnosisOptions(filter="gpf", particles=500, seed=6, workers=1, switch=False)
    d = bgc.diagnose(noisy_tanks, scenario="R12:incipient:0.01@75", seed=6, options=options).diagnosis
    ruled_out = {h.name for h in d.hypotheses if h.ruled_out}
    assert "R12_incipient" in ruled_out, "the symbols rule the truth out on this run"
    assert d.verdict == "ambiguous" and "R12_incipient" in d.candidates
    overruled = {e.hypothesis for e in d.events if isinstance(e, ev.Overruled)}
    assert "R12_incipient" in overruled
    truth = next(h for h in d.hypotheses if h.name == "R12_incipient")
    assert truth.estimate.low <= 0.01 <= truth.estimate.high
    # without step 6b the symbols alone decide: a step of R20, which is not there
    alone = replace(options, recheck=False)
    d0 = bgc.diagnose(noisy_tanks, scenario="R12:incipient:0.01@75", seed=6, options=alone).diagnosis
    assert (d0.verdict, d0.candidates) == ("isolated", ("R20_abrupt",))
    assert not any(h.ruled_out for h in d0.hypotheses)


def test_the_command_line_says_the_overruled_hypotheses_in_one_note():
    """Two or more fault models overruled: one sentence naming them, where
    the first stood; the other notable events keep their own sentences and
    order; events the command line does not print (Started) are left out."""
    from bgc.output.events import notes, sentence

    time_of = lambda step: float(step)  # noqa: E731
    gap = ev.Gap(step=3, steps=12)
    a, b = ev.Overruled("R12_incipient", "F20: +", 9), ev.Overruled("R20_abrupt", "F12: -", 9)
    lines = notes([ev.Started(1, "R10_abrupt", (1, 2)), a, gap, b], time_of)
    assert len(lines) == 2 and lines[1] == sentence(gap, time_of)
    assert lines[0].startswith("R12_incipient, R20_abrupt: ruled out by the symbols")
    assert notes([gap, a], time_of) == [sentence(gap, time_of), sentence(a, time_of)]
