"""The full parametrisations of tests that now keep representatives: what a
test checked on every case (every model module, every case of a sweep,
every filter with every option on), moved out of tests/ ("long runs are
benchmarks"); each test keeps the cases that cover its code paths, named in
each claim below. Each claim runs the test's own check on all the cases, as
the test ran them before, prints its table and says "holds" or "FAILS".

    .venv/bin/python bench/full_cases.py [CLAIM ...]

CLAIM (default: all of them):

- ``backend-modules`` (tests/test_backend.py): every model module of each
  shipped model (circuit, two tanks, RO: 20, 16 and 21 modules), every
  particle filter and the cubature Kalman filter, over the test's faulty run
  of 60 steps: the compiled package's outputs equal the NumPy package's to
  1e-10 (the test runs the nominal module and one module of each kind of
  fault, ``representatives``).
- ``grid-cases`` (tests/test_kalman.py): the adaptive grid against a fine
  brute-force grid on the test's two cases and ``MORE_GRID_CASES`` (R12's
  drift over onsets 88 to 148, the drift's path again on a narrower window).
- ``state-cases`` (tests/test_state.py): the eight (model, filter) round
  trips of ``CASES`` at 200 particles with ``recheck`` on (the test: 100
  particles, 200 on the RO plant, recheck on the fast tier's case only):
  cut while tracking, every belief after the cut and the whole diagnosis bit
  for bit, the fault isolated.

The models run on the backends the tests pick (numba when installed) with
the suite's caches (tests/conftest.py, the root conftest.py). Exits 1 when a
claim fails.
"""

from __future__ import annotations

import sys
import time

from _claims import run  # noqa: E402  (first: the suite's set-up before NumPy loads)


def backend_modules():
    import test_backend as t

    rows, checks = [], []
    for name in t.MODELS:
        ys, us = t.record(name, steps=60)
        numpy_pkg, numba_pkg = t.packages(name)
        modules = list(numpy_pkg.MODELS)
        worst = t.filter_differences(numpy_pkg, numba_pkg, modules, ys, us)
        top = max(worst.values())
        bad = sorted(k for k, v in worst.items() if not v <= t.TOLERANCE)
        rows.append(f"  {name}: {len(modules)} modules x 4 filters, the largest difference {top:.2e}"
                    + (f", over 1e-10: {bad}" if bad else ""))
        checks.append((f"{name}: every module within {t.TOLERANCE:g}", not bad))
    return rows, checks


def grid_cases():
    import test_kalman as t

    marks = t.test_the_adaptive_grid_integrates_like_a_fine_brute_force_grid.pytestmark
    kept = next(m.args[1] for m in marks if m.name == "parametrize")
    rows, checks = [], []
    for case in [*kept, *t.MORE_GRID_CASES]:
        case = case.values if hasattr(case, "values") else case
        label = f"{case[1]} ({case[0]}), onsets {case[2][0]} to {case[2][-1]}"
        try:
            t.test_the_adaptive_grid_integrates_like_a_fine_brute_force_grid(*case)
            passed, text = True, "the adaptive grid's mean, std, interval and evidence: the fine grid's"
        except AssertionError as exc:
            passed, text = False, f"differs: {exc}"
        rows.append(f"  {label}: {text}")
        checks.append((label, passed))
    return rows, checks


def state_cases():
    import test_state as t
    from conftest import MODELS, fast_session
    from conftest import session as session_of

    rows, checks = [], []
    for name, method in t.CASES:
        session = fast_session(name) if t._fast(name, method) else session_of(MODELS / f"{name}.yaml")
        table, run = t._rows(session, t.SCENARIOS[name], steps=t.STEPS[name])
        start = time.perf_counter()
        (beliefs, whole), (later, resumed), at_cut = t._round_trip(session, table, run, 0.8, filter=method,
                                                                   particles=200, seed=3)
        try:
            t._equal(beliefs, later, "beliefs")
            t._equal(whole, resumed, "diagnosis")
            same = True
        except AssertionError:
            same = False
        ok = same and at_cut.loop.phase == "tracking" and whole.verdict == "isolated"
        rows.append(f"  {name} {method} ({session.backend}, {time.perf_counter() - start:.0f} s): cut while "
                    f"{at_cut.loop.phase}, {whole.verdict} {', '.join(whole.candidates)}, resumed "
                    + ("bit for bit" if same else "DIFFERS"))
        checks.append((f"{name} {method}: tracked at the cut, isolated, the same bit for bit", ok))
    return rows, checks


CLAIMS = {
    "backend-modules": backend_modules,
    "grid-cases": grid_cases,
    "state-cases": state_cases,
}


def main(argv=None) -> int:
    return run(CLAIMS, __doc__, argv)


if __name__ == "__main__":
    sys.exit(main())
