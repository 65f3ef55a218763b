"""Speed and memory of the generated particle filters of the RO model, side by side in one run.

Run: .venv/bin/python bench/filter_speed.py [--quick] [--profile]

On one record of the RO plant (``bgc simulate``'s simulator, seed 1, T = 300
steps, made in-process and handed to every column as one .npz), for
N = 200, 1 000, 10 000, 100 000 particles (--quick: up to 10 000, fewer rounds)
it times:

  GPF        generated/ro/numpy_model: GenericParticleFilter on ``nominal``
  GPF numba  generated/ro/numba_model: the same filter on the compiled backend
             (bgc compile's numba package; its kernels compiled in the warm-up)
  APF        the same package's AuxiliaryParticleFilter
  hand       a hand-written NumPy bootstrap filter of the same equations and
             discretisation, written the natural first way ((N, n_x) particles,
             ``np.stack`` derivative): bench/_handwritten_numpy.py
  numba      the same filter with ``@njit`` loops over particles, one thread:
             bench/_handwritten_numba.py, in bench/.venvs/numba (made here)
  particles  N. Chopin's ``particles`` bootstrap filter (SMC, systematic
             resampling, ESSrmin = 0.5) of the same model:
             bench/_particles_model.py, in bench/.venvs/particles (made here:
             particles pins numpy < 2)

Every column does the same work per step: RK4 with the generated SUBSTEPS,
the same process and measurement noise, systematic resampling when
ESS < 0.5 N, and the weighted state mean and std (the generated and hand-written
filters also the predicted measurement; `particles` its ESS and log-likelihood
summaries). The NumPy columns and numba draw from the same np.random.Generator
(PCG64); `particles` from NumPy's global generator.

Every timed run is a fresh subprocess with BLAS pinned to one thread
(bench/_runner.py: imports, a short warm-up that also compiles numba, one timed
run = filter construction + T steps, seed 1). The columns take turns in rounds
(N, round, column), and the table reports the best round of each column in CPU
seconds (user + system of the process, time.process_time): on a shared machine
wall-clock time also counts the time the process waits for a CPU, CPU time does
not (both are printed; on an idle machine they agree for these one-thread
runs). Particle-steps/s is N * T / CPU seconds.

Peak memory, measured in round 1: the tracemalloc peak over one extra untimed
run before the timed ones, from before the filter is built (every NumPy buffer
the filter allocates, its particle array and the generated kernel's scratch
included; blind to numba's allocator), and the growth of the
resident set over the timed run (peak RSS from /proc/self/status VmHWM after a
reset through /proc/self/clear_refs, minus the RSS before; Linux; pages rather
than bytes, so coarse, but it sees numba's allocations too). The memory target
uses the tracemalloc peak.

Correctness first: at N = 10 000 all columns must estimate the same posterior,
within loose Monte Carlo tolerances: final means within 1 posterior std (the
GPF's) of each other, final stds within a factor 1.5, and, over the whole record,
the mean |m_column(t) - m_GPF(t)| / std_GPF(t) at most 0.5 for every state. The
script prints the spread and the verdict before the speed tables.

Targets (the filter-speed issue): the generated GPF no slower than hand-written
at N = 200; at N >= 10 000 at least 1.5x faster than hand-written and within 2x
of numba; at least 2.5x faster than `particles` at every N; peak memory at
N = 100 000 within 2x of the particle array itself (n_x * N * 8 bytes).

The venvs under bench/.venvs are reused when they import; delete one to rebuild it.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"  # before numpy is imported, inherited by every subprocess

import argparse  # noqa: E402
import cProfile  # noqa: E402
import hashlib  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import pstats  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from _venvs import VENV_SPECS, ensure_venv, progress  # noqa: E402

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "generated" / "ro"))

T = 300
SEED = 1
FULL = {200: 5, 1_000: 5, 10_000: 3, 100_000: 2}    # N -> rounds (timed runs per column)
QUICK = {200: 3, 1_000: 2, 10_000: 1}
CHECK_N = 10_000
COLUMNS = ("gpf", "compiled", "apf", "numpy", "numba", "particles")
TITLES = {"gpf": "GPF", "compiled": "GPF numba", "apf": "APF", "numpy": "hand", "numba": "numba",
          "particles": "particles"}


def generated_digest() -> str:
    """sha256 of the generated package's sources: the bench warns when they change during the run."""
    h = hashlib.sha256()
    for path in sorted([*(ROOT / "generated" / "ro" / "numpy_model").glob("*.py"),
                        *(ROOT / "generated" / "ro" / "numba_model").glob("*.py")]):
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()[:12]


def make_data(directory: Path) -> Path:
    """Simulate the RO plant (seed 1, T steps) and write what every column needs to one .npz."""
    from bgc import pipeline
    from bgc.analysis import simulate as sim
    from numpy_model import nominal

    import _handwritten_numpy as hand

    worst = hand.mismatch(nominal, np.random.default_rng(0))
    if not worst <= 1e-9:
        raise SystemExit(f"bench/_handwritten_numpy.py's equations differ from generated/ro/numpy_model "
                         f"(largest relative difference {worst:.3g}): type them in again from generated/ro/equations.txt")
    compiled = pipeline.compile_model(ROOT / "models" / "ro.yaml")
    ssm = compiled.equations
    result = sim.simulate(compiled.numerics, sim.SimulationOptions(steps=T, seed=SEED))
    ys = result.measurements[:, [result.output_names.index(n) for n in nominal.OUTPUTS]]
    us = result.inputs[:, [result.input_names.index(n) for n in nominal.INPUTS]]
    states = result.states[:, [result.state_names.index(n) for n in nominal.STATES]]
    path = directory / "ro_seed1.npz"
    # noise levels, prior and substeps: the generated tables' numbers, so every column uses the same ones
    np.savez(path, ys=ys, us=us, states=states, x0=nominal.X0, x0_std=nominal.X0_STD,
             process_std=nominal.PROCESS_STD, measurement_std=nominal.MEASUREMENT_STD, dt=nominal.DT,
             substeps=nominal.SUBSTEPS, state_names=np.array(nominal.STATES), output_names=np.array(nominal.OUTPUTS),
             parameter_names=np.array(ssm.parameters), parameter_values=np.array(ssm.parameter_values, dtype=float))
    return path


def run_column(python: str, column: str, data: Path, n: int, memory: bool) -> dict:
    """One timed run of one column in a fresh process (with memory: also the tracemalloc run)."""
    cmd = [python, str(BENCH / "_runner.py"), column, str(data), "--n", str(n), "--repeats", "1"]
    if memory and column != "numba":
        cmd.append("--tracemalloc")
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=BENCH)
    if done.returncode != 0:
        tail = done.stderr.strip().splitlines()[-3:]
        return {"error": " | ".join(tail) or f"exit code {done.returncode}"}
    return json.loads(done.stdout.strip().splitlines()[-1])


def fmt(v: float | None, spec: str, width: int) -> str:
    return f"{'n/a':>{width}}" if v is None else f"{v:>{width}{spec}}"


def seconds(results: dict, column: str, n: int, key: str = "cpu_seconds") -> float | None:
    """Best (smallest) CPU seconds per run over the rounds; key="seconds" for wall-clock."""
    r = results.get((column, n))
    return min(r[key]) if r and key in r else None


def ratio(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a / b


def print_tables(results: dict, sizes: dict, n_x: int) -> None:
    print(f"\nRO model, T = {T} steps; CPU seconds per run (user + system), best of the rounds; 1 thread")
    head = (f"{'N':>7} {'rnds':>4} {'GPF s':>8} {'GPFnb s':>8} {'APF s':>8} {'hand s':>8} {'numba s':>8}"
            f" {'partcl s':>8} {'GPF p-st/s':>10} {'GPF MB':>7} {'x MB':>6} {'hand/GPF':>8} {'GPF/numba':>9}"
            f" {'GPFnb/numba':>11} {'GPF/GPFnb':>9} {'partcl/GPF':>10} {'APF/GPF':>7}")
    print(head)
    print("-" * len(head))
    for n, reps in sizes.items():
        t = {c: seconds(results, c, n) for c in COLUMNS}
        gpf = results.get(("gpf", n), {})
        print(f"{n:>7} {reps:>4} " + " ".join(fmt(t[c], ".3f", 8) for c in COLUMNS)
              + " " + fmt(None if t["gpf"] is None else n * T / t["gpf"], ".3g", 10)
              + " " + fmt(gpf.get("traced_mb"), ".1f", 7) + " " + fmt(n_x * n * 8 / 2**20, ".2f", 6)
              + " " + fmt(ratio(t["numpy"], t["gpf"]), ".2f", 8) + " " + fmt(ratio(t["gpf"], t["numba"]), ".2f", 9)
              + " " + fmt(ratio(t["compiled"], t["numba"]), ".2f", 11)
              + " " + fmt(ratio(t["gpf"], t["compiled"]), ".2f", 9)
              + " " + fmt(ratio(t["particles"], t["gpf"]), ".2f", 10) + " " + fmt(ratio(t["apf"], t["gpf"]), ".2f", 7))
    print("GPF p-st/s: particle-steps per second, N * T / GPF s; GPF MB: tracemalloc peak of one run; "
          "x MB: the particle array, n_x * N * 8 bytes; GPFnb: the generated GPF on the compiled backend")
    print("\nWall-clock seconds per run, best of the rounds (inflated when other processes load the machine)")
    print(f"{'N':>7} " + " ".join(f"{TITLES[c]:>9}" for c in COLUMNS))
    for n in sizes:
        print(f"{n:>7} " + " ".join(fmt(seconds(results, c, n, "seconds"), ".3f", 9) for c in COLUMNS))
    print("\nPeak memory, MB: tracemalloc peak of one run / peak RSS growth over one timed run")
    print(f"{'N':>7} " + " ".join(f"{TITLES[c]:>17}" for c in COLUMNS))
    for n in sizes:
        cells = []
        for c in COLUMNS:
            r = results.get((c, n), {})
            if "rss_mb" not in r:
                cells.append(f"{'n/a':>17}")
                continue
            traced = "-" if r.get("traced_mb") is None else f"{r['traced_mb']:.1f}"
            cells.append(f"{traced + ' / ' + format(r['rss_mb'], '.1f'):>17}")
        print(f"{n:>7} " + " ".join(cells))


def check_agreement(results: dict, truth: np.ndarray, names: tuple[str, ...]) -> bool:
    """All columns estimate the same posterior: compare their weighted means at N = CHECK_N.

    Loose tolerances, for Monte Carlo error (the slow conductivity state e27
    carries the largest): final means within 1 GPF posterior std of each other,
    final stds within a factor 1.5, and over the whole record the mean
    |m_column(t) - m_GPF(t)| / std_GPF(t) at most 0.5 for every state.
    """
    have = [c for c in COLUMNS if "mean" in results.get((c, CHECK_N), {})]
    print(f"\nCorrectness at N = {CHECK_N}: final-state weighted means (t = {T})")
    if "gpf" not in have or len(have) < 2:
        print("  not enough columns ran at this N to compare")
        return False
    traj = {c: np.array(results[(c, CHECK_N)]["mean"]) for c in have}
    sds = {c: np.array(results[(c, CHECK_N)]["std"]) for c in have}
    means = np.array([traj[c][-1] for c in have])
    stds = np.array([sds[c][-1] for c in have])
    scale = sds["gpf"][-1]
    print(f"{'':>11} " + " ".join(f"{n:>11}" for n in names))
    for c, m in zip(have, means):
        print(f"{TITLES[c]:>11} " + " ".join(f"{v:>11.5g}" for v in m))
    print(f"{'truth':>11} " + " ".join(f"{v:>11.5g}" for v in truth))
    print(f"{'GPF std':>11} " + " ".join(f"{v:>11.4g}" for v in scale))
    spread = (means.max(axis=0) - means.min(axis=0)) / scale
    std_ratio = stds.max(axis=0) / stds.min(axis=0)
    print(f"{'spread/std':>11} " + " ".join(f"{v:>11.3f}" for v in spread)
          + "   max - min of the final means, in GPF posterior stds (tolerance 1)")
    print(f"{'std max/min':>11} " + " ".join(f"{v:>11.3f}" for v in std_ratio) + "   final stds (tolerance 1.5)")
    print("mean over t of |mean - GPF mean| / GPF std (tolerance 0.5):")
    worst = 0.0
    for c in have:
        if c == "gpf":
            continue
        d = np.mean(np.abs(traj[c] - traj["gpf"]) / sds["gpf"], axis=0)
        worst = max(worst, float(d.max()))
        print(f"{TITLES[c]:>11} " + " ".join(f"{v:>11.3f}" for v in d))
    ok = bool(np.all(spread <= 1.0) and np.all(std_ratio <= 1.5) and worst <= 0.5)
    print(f"  agreement over {', '.join(TITLES[c] for c in have)}: "
          + ("OK" if ok else "FAILED: the speed numbers below compare filters that do not agree"))
    return ok


def print_targets(results: dict, sizes: dict, n_x: int, missing: dict, agree: bool) -> None:
    def verdict(ok: bool | None, why: str = "") -> str:
        return f"not evaluated{': ' + why if why else ''}" if ok is None else ("met" if ok else "NOT MET")

    print("\nTargets" + ("" if agree else " (VOID: the filters do not agree, see the correctness check)"))
    t = {(c, n): seconds(results, c, n) for c in COLUMNS for n in sizes}
    r = ratio(t[("numpy", 200)], t[("gpf", 200)]) if 200 in sizes else None
    print(f"  GPF no slower than hand-written at N = 200: hand/GPF = {fmt(r, '.2f', 0)} -> "
          + verdict(None if r is None else r >= 1.0))
    for n in (n for n in sizes if n >= 10_000):
        r = ratio(t[("numpy", n)], t[("gpf", n)])
        print(f"  N = {n}: GPF >= 1.5x faster than hand-written: hand/GPF = {fmt(r, '.2f', 0)} -> "
              + verdict(None if r is None else r >= 1.5))
        r = ratio(t[("gpf", n)], t[("numba", n)])
        print(f"  N = {n}: GPF within 2x of numba: GPF/numba = {fmt(r, '.2f', 0)} -> "
              + verdict(None if r is None else r <= 2.0, missing.get("numba", "")))
    rs = [ratio(t[("particles", n)], t[("gpf", n)]) for n in sizes]
    if any(v is None for v in rs):
        print("  GPF >= 2.5x faster than particles at every N -> " + verdict(None, missing.get("particles", "")))
    else:
        print("  GPF >= 2.5x faster than particles at every N: particles/GPF = "
              + ", ".join(f"{v:.2f}" for v in rs) + " -> " + verdict(min(rs) >= 2.5))
    print("  Compiled backend (GPF numba against the hand-written numba filter):")
    for n in sizes:
        r = ratio(t[("compiled", n)], t[("numba", n)])
        limit = 1.5 if n < 10_000 else 1.2
        print(f"    N = {n}: GPF numba within {limit}x of numba: GPF numba/numba = {fmt(r, '.2f', 0)} -> "
              + verdict(None if r is None else r <= limit, missing.get("numba", "")))
    n = 100_000
    for column in ("compiled",):
        r = results.get((column, n), {})
        if r.get("traced_mb") is not None:
            limit = 2 * n_x * n * 8 / 2**20
            print(f"    GPF numba peak memory at N = {n} within 2x of n_x * N * 8 bytes: {r['traced_mb']:.1f} MB traced "
                  f"(NumPy's buffers; RSS growth {r.get('rss_mb', float('nan')):.1f} MB) (limit {limit:.1f} MB) -> "
                  + verdict(r["traced_mb"] <= limit and r.get("rss_mb", 0.0) <= limit))
    traced = results.get(("gpf", n), {}).get("traced_mb")
    if traced is None:
        print(f"  GPF peak memory at N = {n} within 2x of n_x * N * 8 bytes -> "
              + verdict(None, "N = 100000 not run (--quick)" if n not in sizes else "no measurement"))
    else:
        limit = 2 * n_x * n * 8 / 2**20
        print(f"  GPF peak memory at N = {n} within 2x of n_x * N * 8 bytes: {traced:.1f} MB traced "
              f"(limit {limit:.1f} MB, {traced / (limit / 2):.1f}x the array) -> " + verdict(traced <= limit))


def profile_gpf(data: Path, sizes: list[int]) -> None:
    """cProfile of the generated GPF (in this process, BLAS pinned, CPU time): the top functions by own time."""
    from numpy_model import filters, nominal

    with np.load(data) as d:
        ys, us = d["ys"], d["us"]
    for n in sizes:
        progress(f"profiling the GPF at N = {n} ...")
        profiler = cProfile.Profile(time.process_time)
        profiler.enable()
        filters.GenericParticleFilter(nominal, n, np.random.default_rng(SEED)).run(ys, us)
        profiler.disable()
        out = io.StringIO()
        pstats.Stats(profiler, stream=out).sort_stats("tottime").print_stats(12)
        lines = [l for l in out.getvalue().splitlines() if l.strip()]
        print(f"\ncProfile, generated GPF, N = {n}, T = {T} (CPU seconds; top 12 by own time)")
        print("\n".join(l.replace(str(ROOT) + "/", "") for l in lines[2:]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="N up to 10 000, fewer rounds")
    ap.add_argument("--profile", action="store_true", help="also cProfile the GPF at the smallest and largest N")
    args = ap.parse_args()
    sizes = QUICK if args.quick else FULL
    start = time.perf_counter()
    load_start = os.getloadavg()[0]
    digest = generated_digest()
    pythons = {c: sys.executable for c in ("gpf", "compiled", "apf", "numpy")}
    missing = {}
    for name in VENV_SPECS:
        python, why = ensure_venv(name)
        progress(f"venv {name}: {why if python else 'NOT AVAILABLE: ' + why}")
        if python:
            pythons[name] = python
        else:
            missing[name] = f"{name} not available ({why})"
    results: dict = {}
    with tempfile.TemporaryDirectory(prefix="bgc-filter-speed-") as tmp:
        progress("simulating the RO plant (bgc.simulate, seed 1) ...")
        data = make_data(Path(tmp))
        with np.load(data) as d:
            truth, names = d["states"][-1], tuple(str(s) for s in d["state_names"])
        # rounds: every column once per round, so load from other processes hits all columns alike
        cells = [(n, k, c) for n in sizes for k in range(sizes[n]) for c in COLUMNS]
        for i, (n, k, column) in enumerate(cells, 1):
            if column not in pythons:
                results[(column, n)] = {"error": missing[column]}
                continue
            progress(f"[{i}/{len(cells)}] N = {n:>6} round {k + 1}/{sizes[n]} {TITLES[column]:<9} ...")
            t0 = time.perf_counter()
            r = run_column(pythons[column], column, data, n, memory=(k == 0))
            if "error" in r:
                progress(f"    FAILED: {r['error']}")
                results.setdefault((column, n), r)
                continue
            progress(f"    {r['cpu_seconds'][0]:.3f} CPU s/run, {r['seconds'][0]:.3f} wall s/run "
                     f"({time.perf_counter() - t0:.0f} s with start-up)")
            if k == 0:
                results[(column, n)] = r
            elif "seconds" in results.get((column, n), {}):
                results[(column, n)]["seconds"] += r["seconds"]
                results[(column, n)]["cpu_seconds"] += r["cpu_seconds"]
        n_x = len(names)
        print(f"bench/filter_speed.py{' --quick' if args.quick else ''}: python {sys.version.split()[0]}, "
              f"numpy {np.__version__} (particles venv: numpy "
              f"{results.get(('particles', 200), {}).get('numpy', 'n/a')}), "
              f"{os.cpu_count()} CPUs, BLAS/OpenMP threads pinned to 1")
        changed = generated_digest() != digest
        print(f"generated/ro/numpy_model and numba_model sources sha256 {digest}"
              + (" -- WARNING: CHANGED DURING THE RUN, the columns mix versions; run again" if changed else
                 ", unchanged during the run"))
        print(f"load average (1 min) at start {load_start:.2f}, at end {os.getloadavg()[0]:.2f} "
              f"(other processes compete for the {os.cpu_count()} CPUs when it exceeds 1)")
        for name, why in missing.items():
            print(f"column {name}: {why}")
        agree = check_agreement(results, truth, names)
        for n in sizes:  # the same filter, seed and random numbers: the backends' numbers agree to rounding
            a, b = results.get(("gpf", n), {}), results.get(("compiled", n), {})
            if "mean" in a and "mean" in b:
                ma, mb = np.array(a["mean"]), np.array(b["mean"])
                worst = float(np.max(np.abs(ma - mb) / np.maximum(np.abs(ma).max(axis=0), 1e-300)))
                print(f"  N = {n}: GPF numba's state means against GPF's (same seed): largest relative "
                      f"difference {worst:.2g} -> " + ("equal to 1e-10" if worst <= 1e-10 else "DIFFERENT"))
        print_tables(results, sizes, n_x)
        print_targets(results, sizes, n_x, missing, agree)
        if args.profile:
            profile_gpf(data, [min(sizes), max(sizes)])
    progress(f"done in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
