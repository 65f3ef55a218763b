"""The seeded statistics of the test suite: claims that need many seeded
runs (a rate, a coverage, a mean error), moved out of tests/ ("long runs are
benchmarks"); each test file keeps a short deterministic check of the same
code path, named in each claim below. Each claim runs as its test ran (the
same seeds, runs and thresholds), prints its table and says "holds" or
"FAILS".

    .venv/bin/python bench/seeded_statistics.py [CLAIM ...]

CLAIM (default: all of them, about 3 minutes on one core):

- ``ro-incipient`` (tests/test_diagnose.py): the RO's R_pipe drifting at 0.5
  per unit time from t = 165, seeds 1 to 5 (1000 particles, gpf): the mean
  |onset error| at most 8 samples, the mean relative slope error under 15 %,
  and the 95 % interval holding the slope in at least 4 of the 5 runs.
- ``coverage`` (tests/test_diagnose.py): the circuit's R2 up by 0.6 at t = 5
  at process and sensor noise 0.01, seeds 200 to 219, ``recheck`` off: the
  95 % interval of R2's step holds 0.6 in at least 16 of 20 runs (with a
  true coverage of 90 % that passes with probability 0.96, with 70 % only
  0.24).
- ``first-hour`` (tests/test_first_hour.py): the new plant of issue 44 (two
  masses), b1 up by 0.12 at 3 s: bgc distinguish's "bgc's detector"
  probability over 50 runs of bgc's simulator (seeds 100...) and the
  detector's rate on 50 runs of the hand-derived plant (its exact solution,
  seeds 10000...): the first away from 0 and 1 (0.05 to 0.95), the two not
  told apart by a two-sided two-sample test at 99.9 % (|z| < 3.29), and the
  second within the first's 95 % interval.
- ``distinguish-rate`` (tests/test_distinguish.py): the two tanks' R12 up by
  0.15 at t = 75: "bgc's detector" over 50 runs (seed 1000) against the
  detector's rate on 50 runs of the plant integrated by solve_ivp (seeds
  5000...): within a two-sample test at 99.9 %, and the ideal detector's
  probability above the first's interval.
- ``hidden-modes`` (tests/test_hidden_mode.py): the level plant of
  docs/examples/level.yaml (solve_ivp's runs, tests/hybrid_reference.py),
  seeds 0 to 4, its mode read from the data by the mode decoder: the plant's
  at all but at most 1 sample in 200, each of those within 2 samples of a
  switch.
- ``relay-thresholds`` (tests/test_hybrid_tracking.py): the relay of
  tests/data/hybrid/relay_rl.yaml with a tolerance of 0.2 V on its closing
  guard (v_C > 6), noise-free runs of bgc's truth simulator, seeds 0 to 3:
  at least 24 closings, each its own draw, their mean within 4 standard
  errors of 6 and their std within 0.6 to 1.4 times 0.2.

The models run on the backend the tests' ``fast_session`` picks (numba when
installed) with the suite's caches (tests/conftest.py, the root
conftest.py): the numbers are the tests' own. Exits 1 when a claim fails.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

from _claims import run  # noqa: E402  (first: the suite's set-up before NumPy loads)

import numpy as np  # noqa: E402


def ro_incipient():
    import test_diagnose as t

    rows, onset_errors, slope_errors, covered = [], [], [], 0
    for seed in range(1, 6):
        d = t.run("ro", "R_pipe:incipient:0.5@165", seed=seed)
        e = d.estimate
        onset_errors.append(abs(d.onset - 165))
        slope_errors.append(abs(e.value - 0.5) / 0.5)
        covered += e.low <= 0.5 <= e.high
        rows.append(f"  seed {seed}: {d.verdict:<10} {d.candidates[0]:<18} onset {d.onset:g} "
                    f"slope {e.value:.4f} [{e.low:.4f}, {e.high:.4f}]")
    checks = [(f"mean |onset error| {np.mean(onset_errors):.1f} <= 8", np.mean(onset_errors) <= 8),
              (f"mean slope error {100 * np.mean(slope_errors):.1f} % < 15 %", np.mean(slope_errors) < 0.15),
              (f"interval holds the slope in {covered} of 5 >= 4", covered >= 4)]
    return rows, checks


def coverage():
    import bgc
    from bgc.diagnosis.options import DiagnosisOptions
    from conftest import fast_session

    model = fast_session("circuit", process_noise=0.01, measurement_noise=0.01)
    rows, covered = [], 0
    for seed in range(200, 220):
        d = bgc.diagnose(model, scenario="R2:abrupt:0.6@5", seed=seed,
                         options=DiagnosisOptions(seed=seed, workers=1, recheck=False)).diagnosis
        h = next((h for h in d.hypotheses if h.name == "R2_abrupt"), None)
        hit = h is not None and h.estimate.low <= 0.6 <= h.estimate.high
        covered += hit
        rows.append(f"  seed {seed}: " + ("no R2_abrupt hypothesis" if h is None else
                                         f"{h.estimate.value:.4f} [{h.estimate.low:.4f}, {h.estimate.high:.4f}]"
                                         f"{'' if hit else '  misses 0.6'}"))
    return rows, [(f"interval holds 0.6 in {covered} of 20 >= 16", covered >= 16)]


def two_sample(a: int, b: int, n: int) -> float:
    """The z of two binomial counts of ``n`` runs each under one pooled probability."""
    p = (a + b) / (2 * n)
    return (a / n - b / n) / math.sqrt(p * (1 - p) * (2 / n)) if 0 < p < 1 else 0.0


def first_hour():
    import tempfile

    import bgc
    from bgc.analysis import simulate
    from bgc.api.detection import detector_rate, wilson
    import test_first_hour as t

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "two_mass.yaml"
        path.write_text(t.MODEL, encoding="utf-8")
        session = bgc.open(path)
        scenario = simulate.parse_scenario("b1:abrupt:0.12@3", session.view.numerics)
        rate = detector_rate(session, scenario, t.STEPS, runs=50, seed=100)
        hits = t.hand_plant_hits(session, t.B1 + 0.12, 3.0, range(10_000, 10_050))
    z = two_sample(rate.detected, hits, 50)
    low, high = wilson(hits, 50)
    rows = [f"  bgc's simulator: {rate.detected} of 50 alarmed after the onset, in [{rate.low:.2f}, {rate.high:.2f}]",
            f"  hand-derived plant: {hits} of 50, in [{low:.2f}, {high:.2f}]"]
    checks = [(f"bgc's probability {rate.probability:.2f} in (0.05, 0.95)", 0.05 < rate.probability < 0.95),
              (f"two-sample |z| {abs(z):.2f} < 3.29", abs(z) < 3.29),
              (f"the plant's rate {hits / 50:.2f} in bgc's interval", rate.low <= hits / 50 <= rate.high)]
    return rows, checks


def distinguish_rate():
    import bgc
    from bgc.api.detection import wilson
    from conftest import fast_session
    import test_distinguish as t

    s = fast_session("two_tank")
    r = bgc.distinguishability(s, "R12:abrupt:0.15@75", detector_runs=50, seed=1000)
    rate = r.detector
    detected = t.solve_ivp_tank_hits(s, 0.15, range(5000, 5050))
    z = two_sample(detected, rate.detected, 50)
    low, high = wilson(detected, 50)
    ideal = r.distinctions[0].detectability
    rows = [f"  bgc's simulator: {rate.detected} of 50, in [{rate.low:.2f}, {rate.high:.2f}]",
            f"  solve_ivp's plant: {detected} of 50, in [{low:.2f}, {high:.2f}]",
            f"  the ideal detector (knows the fault's shape): {ideal:.2f}"]
    checks = [(f"two-sample |z| {abs(z):.2f} < 3.29", abs(z) < 3.29),
              (f"ideal {ideal:.2f} > bgc's interval's top {rate.high:.2f}", ideal > rate.high),
              ("bgc's interval holds its rate", rate.low <= rate.probability <= rate.high)]
    return rows, checks


def hidden_modes():
    import test_hidden_mode as t
    from conftest import session

    level = session(t.LEVEL)
    rows, wrong, far = [], 0, 0
    for seed in range(5):
        times, modes, got, switches = t.modes_read(level, seed)
        off = np.flatnonzero(got != modes)
        near = [min(abs(times[k] - s) for s in switches) for k in off]
        far += sum(d > 2 * t.DT for d in near)
        wrong += len(off)
        rows.append(f"  seed {seed}: {len(switches)} switches, {len(off)} of {t.STEPS} samples read in another mode")
    total = 5 * t.STEPS
    return rows, [(f"{wrong} of {total} samples off <= 1 in 200", wrong <= total / 200),
                  (f"{far} of them more than 2 samples from a switch: none", far == 0)]


def relay_thresholds():
    import tempfile

    import test_hybrid_tracking as t

    with tempfile.TemporaryDirectory() as folder:
        path = t.relay_with(Path(folder), f'  - {{from: open, to: closed, when: "v_C > 6", tolerance: {t.SPREAD}}}')
        drawn = t.closing_levels(path, range(4))
    n, mean, std = len(drawn), float(np.mean(drawn)), float(np.std(drawn))
    rows = [f"  {n} closings over seeds 0 to 3: mean {mean:.4f}, std {std:.4f} (the guard: 6, std {t.SPREAD})"]
    return rows, [(f"{n} draws >= 24, each its own", n >= 24 and len(np.unique(np.round(drawn, 6))) == n),
                  (f"|mean - 6| {abs(mean - 6):.4f} < 4 standard errors {4 * t.SPREAD / math.sqrt(n):.4f}",
                   abs(mean - 6.0) < 4 * t.SPREAD / math.sqrt(n)),
                  (f"std {std:.3f} within 0.6 to 1.4 times {t.SPREAD}", 0.6 * t.SPREAD < std < 1.4 * t.SPREAD)]


CLAIMS = {
    "ro-incipient": ro_incipient,
    "coverage": coverage,
    "first-hour": first_hour,
    "distinguish-rate": distinguish_rate,
    "hidden-modes": hidden_modes,
    "relay-thresholds": relay_thresholds,
}


def main(argv=None) -> int:
    return run(CLAIMS, __doc__, argv)


if __name__ == "__main__":
    sys.exit(main())
