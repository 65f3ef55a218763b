"""A whole RO diagnosis on the NumPy and the compiled (numba) backend, side by side in one run.

    .venv/bin/python bench/diagnosis_speed.py [--seeds 3] [--rounds 2] [--quick]

The runs: the RO plant (models/ro.yaml) at the model's noise, 300 steps, a
fault of R_pipe from t = 165, a step (``R_pipe:abrupt:24@165``) and a drift
(``R_pipe:incipient:0.18@165``), about 35 % of the parameter, simulated with
seeds 1..S. Each run is diagnosed by ``bgc.diagnose(session, data=run,
options=...)`` with gpf N = 200, gpf N = 1000 and ckf, ``workers=1`` (one
process: the ratio is the backends', not the scheduler's), once per backend
per round, the backends taking turns; the table keeps the best round of each
(CPU seconds of the process, time.process_time: other processes on a busy
machine do not inflate it; wall-clock beside it). The static posterior's
share (``bgc.diagnosis.static_posterior.static_posterior``, the cubature Kalman filters'
banks that weigh and size every hypothesis) is timed by wrapping that
function.

Correctness first: for every run the two backends must give the same verdict
and candidates and the same estimate to 1e-8 (relative); the script prints
the count.

The compiled backend's first-call cost: a fresh process with an empty
numba cache (``BGC_CACHE_DIR`` a new folder) opens a session of the RO plant
and compiles every kernel (the report line bgc prints), then a second
process loads them from the cache.

Targets (the compiled-backend issue): a whole RO diagnosis (drift, N = 1000)
at least 4x faster on the compiled backend, the static posterior alone at
least 3x; the first call's compile under 20 s.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"  # before numpy is imported: one thread, as the workers of a diagnosis run

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402
from bgc.diagnosis import static_posterior
from bgc.data import runs
from bgc.analysis import simulate  # noqa: E402
from bgc.diagnosis.options import DiagnosisOptions

MODEL = ROOT / "models" / "ro.yaml"
SCENARIOS = (("step", "R_pipe:abrupt:24@165"), ("drift", "R_pipe:incipient:0.18@165"))
FILTERS = (("gpf N=200", DiagnosisOptions(method="gpf", particles=200, workers=1)),
           ("gpf N=1000", DiagnosisOptions(method="gpf", particles=1000, workers=1)),
           ("ckf", DiagnosisOptions(method="ckf", workers=1)))
BACKENDS = ("numpy", "numba")
#: CPU seconds spent in static_posterior.static_posterior since the last reset.
STATIC = [0.0]


def timed_static_posterior():
    """Wrap static_posterior.static_posterior to add its CPU seconds to STATIC."""
    inner = static_posterior.static_posterior

    def wrapper(*args, **kwargs):
        started = time.process_time()
        try:
            return inner(*args, **kwargs)
        finally:
            STATIC[0] += time.process_time() - started
    static_posterior.static_posterior = wrapper


def first_call() -> list[str]:
    """The compiled backend's cold compile and warm load of the RO kernels, in fresh processes."""
    probe = ("import time, bgc; t = time.perf_counter(); s = bgc.open('models/ro.yaml', backend='numba'); "
             "print(f'{time.perf_counter() - t:.1f} s to open the session; {s.backend_note()}')")
    lines = []
    with tempfile.TemporaryDirectory(prefix="bgc-cache-") as cache:
        env = {**os.environ, "BGC_CACHE_DIR": cache}
        for what in ("cold cache", "warm cache"):
            done = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, env=env, capture_output=True, text=True)
            lines.append(f"{what}: " + (done.stdout.strip() or done.stderr.strip().splitlines()[-1]))
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="simulated runs per scenario (default 3)")
    ap.add_argument("--rounds", type=int, default=2, help="timed diagnoses per backend and run (best kept)")
    ap.add_argument("--quick", action="store_true", help="1 seed, 1 round")
    args = ap.parse_args()
    seeds, rounds = (1, 1) if args.quick else (args.seeds, args.rounds)
    print("$ .venv/bin/python bench/diagnosis_speed.py " + " ".join(sys.argv[1:]))
    print(f"# {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the start; BLAS threads 1\n")
    print("## The compiled backend's first call (fresh processes, an empty numba cache)\n")
    for line in first_call():
        print(f"- {line}")
    print()
    timed_static_posterior()
    sessions = {b: bgc.open(MODEL, backend=b) for b in BACKENDS}
    num = sessions["numpy"].compiled.numerics
    warm = runs.parse_run(simulate.to_csv(simulate.simulate(num, simulate.SimulationOptions(
        seed=0, fault=simulate.parse_fault(SCENARIOS[0][1], num)))), "warm-up")
    for b in BACKENDS:  # first calls, untimed
        bgc.diagnose(sessions[b], data=warm, options=dataclasses.replace(FILTERS[0][1], seed=0))
    best: dict[tuple, dict] = {}
    same, total = 0, 0
    began = time.perf_counter()
    for label, scenario in SCENARIOS:
        for seed in range(1, seeds + 1):
            run = runs.parse_run(simulate.to_csv(simulate.simulate(num, simulate.SimulationOptions(
                seed=seed, fault=simulate.parse_fault(scenario, num)))), f"ro_{label}_seed{seed}.csv")
            for name, options in FILTERS:
                options = dataclasses.replace(options, seed=seed)
                out = {}
                for _ in range(rounds):
                    for b in BACKENDS:
                        STATIC[0] = 0.0
                        wall, cpu = time.perf_counter(), time.process_time()
                        d = bgc.diagnose(sessions[b], data=run, options=options).diagnosis
                        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
                        key = (label, name, seed, b)
                        r = best.setdefault(key, {"cpu": cpu, "wall": wall, "static": STATIC[0]})
                        if cpu < r["cpu"]:
                            r.update(cpu=cpu, wall=wall, static=STATIC[0])
                        out[b] = d
                a, c = out["numpy"], out["numba"]
                total += 1
                estimates = (a.estimate is None and c.estimate is None) or (
                    a.estimate is not None and c.estimate is not None
                    and abs(a.estimate.value - c.estimate.value) <= 1e-8 * max(abs(a.estimate.value), 1e-300))
                same += (a.verdict, a.candidates) == (c.verdict, c.candidates) and estimates
                print(f"# {label} seed {seed} {name}: numpy {best[(label, name, seed, 'numpy')]['cpu']:.2f} s, "
                      f"numba {best[(label, name, seed, 'numba')]['cpu']:.2f} s: {a.verdict} "
                      f"{', '.join(a.candidates)}", file=sys.stderr, flush=True)
    print(f"## RO diagnosis, {seeds} seed(s) per scenario, best of {rounds} round(s), workers=1 "
          f"({time.perf_counter() - began:.0f} s in all)\n")
    print(f"Same verdict, candidates and estimate (1e-8) on both backends: {same}/{total} runs\n")
    print("| scenario | filter | numpy CPU s | numba CPU s | numpy/numba | static posterior numpy s | numba s "
          "| numpy/numba | wall numpy / numba s |")
    print("|---|---|---|---|---|---|---|---|---|")
    ratios = {}
    for label, _ in SCENARIOS:
        for name, _ in FILTERS:
            def med(b, k):
                return statistics.median(best[(label, name, s, b)][k] for s in range(1, seeds + 1))
            whole, static = med("numpy", "cpu") / med("numba", "cpu"), None
            if med("numba", "static") > 0:
                static = med("numpy", "static") / med("numba", "static")
            ratios[(label, name)] = (whole, static)
            print(f"| {label} | {name} | {med('numpy', 'cpu'):.2f} | {med('numba', 'cpu'):.2f} | {whole:.2f} "
                  f"| {med('numpy', 'static'):.2f} | {med('numba', 'static'):.2f} "
                  f"| {'-' if static is None else format(static, '.2f')} "
                  f"| {med('numpy', 'wall'):.2f} / {med('numba', 'wall'):.2f} |")
    print("\nMedians over the seeds of each run's best round. Static posterior: the CPU seconds inside "
          "static_posterior.static_posterior (the cubature Kalman filters' banks).\n")
    whole, static = ratios[("drift", "gpf N=1000")]
    print("## Targets\n")
    print(f"- whole RO diagnosis, drift, gpf N = 1000, at least 4x faster: {whole:.2f}x -> "
          + ("met" if whole >= 4 else "NOT MET"))
    print(f"- its static posterior at least 3x faster: {static:.2f}x -> " + ("met" if static >= 3 else "NOT MET"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
