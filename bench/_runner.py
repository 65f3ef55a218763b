"""Time one filter implementation at one N, in a fresh process; print one JSON line.

Started by bench/filter_speed.py, once per (implementation, N, round), with the
interpreter of the venv the implementation needs:

  gpf, apf, numpy   the project's .venv (generated package, hand-written NumPy)
  compiled          the project's .venv (the generated compiled package, numba_model)
  numba             bench/.venvs/numba
  particles         bench/.venvs/particles

Steps: import, load the data (.npz), one warm-up run (T = 3 steps, N = min(N,
200): imports, numba compilation), then ``repeats`` timed runs on the full
record (seeds 1..repeats; a run = filter construction + all T steps; both
wall-clock seconds and the process's CPU seconds, user + system, which other
processes on a busy machine do not inflate). With --tracemalloc, one more
untimed run under tracemalloc comes first, before the timed runs, so that it
also sees the buffers a filter makes once and keeps (the generated kernel's
per-thread scratch). It prints the weighted state mean and std at every step
of the last timed run, for the correctness check.

Memory, two measures:
  rss_mb     peak resident set during the timed runs minus the resident set
             before them: /proc/self/status VmHWM, reset to the current RSS by
             writing 5 to /proc/self/clear_refs, minus VmRSS (Linux). Not
             ru_maxrss: a child inherits its parent's peak through fork and exec,
             so the driver's own size would hide the runner's. Covers every
             allocator, numba's included; pages, not bytes;
  traced_mb  tracemalloc peak over one untimed run (every NumPy array buffer,
             exact; blind to numba's allocator, so not used for numba).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
IMPLEMENTATIONS = ("gpf", "compiled", "apf", "numpy", "numba", "particles")


def load(path):
    with np.load(path) as d:
        data = {k: d[k] for k in d.files}
    model = {"x0": data["x0"], "x0_std": data["x0_std"], "process_std": data["process_std"],
             "measurement_std": data["measurement_std"], "dt": float(data["dt"]), "substeps": int(data["substeps"])}
    return data, model


def check_names(data, states, outputs):
    if tuple(data["state_names"]) != tuple(states) or tuple(data["output_names"]) != tuple(outputs):
        raise SystemExit(f"state/output order of the data {tuple(data['state_names'])}, "
                         f"{tuple(data['output_names'])} is not the implementation's {states}, {outputs}")


def make(impl, data, model):
    """A function run(ys, us, n, seed) -> (mean (T, n_x), std (T, n_x)): the weighted moments at every step."""
    if impl == "compiled":
        sys.path.insert(0, str(ROOT / "generated" / "ro"))
        from numba_model import filters, nominal

        check_names(data, nominal.STATES, nominal.OUTPUTS)

        def run(ys, us, n, seed):
            out = filters.GenericParticleFilter(nominal, n, np.random.default_rng(seed)).run(ys, us)
            return out.mean, out.std
        return run
    if impl in ("gpf", "apf"):
        sys.path.insert(0, str(ROOT / "generated" / "ro"))
        from numpy_model import filters, nominal

        check_names(data, nominal.STATES, nominal.OUTPUTS)
        cls = filters.GenericParticleFilter if impl == "gpf" else filters.AuxiliaryParticleFilter

        def run(ys, us, n, seed):
            out = cls(nominal, n, np.random.default_rng(seed)).run(ys, us)
            return out.mean, out.std
        return run

    import _handwritten_numpy as hand

    check_names(data, hand.STATES, hand.OUTPUTS)
    theta = dict(zip(data["parameter_names"], data["parameter_values"]))
    if theta != hand.PARAMETERS:
        raise SystemExit(f"hand-written parameters {hand.PARAMETERS} differ from the model's {theta}")
    if impl in ("numpy", "numba"):
        module = hand
        if impl == "numba":
            import _handwritten_numba as module

        def run(ys, us, n, seed):
            out = module.run(ys, us, n, seed, model)
            return out["mean"], out["std"]
        return run

    if impl == "particles":
        import particles
        from particles import collectors
        from particles import state_space_models as ssms

        from _particles_model import RO

        def run(ys, us, n, seed):
            np.random.seed(seed)
            ssm = RO(us=us, **model)
            pf = particles.SMC(fk=ssms.Bootstrap(ssm=ssm, data=list(ys)), N=n, resampling="systematic",
                               ESSrmin=0.5, collect=[collectors.Moments()])
            pf.run()
            moments = pf.summaries.moments  # weighted mean and var of X_t given y_0..y_t, every t
            return (np.array([m["mean"] for m in moments]),
                    np.sqrt(np.maximum(np.array([m["var"] for m in moments]), 0.0)))
        return run
    raise SystemExit(f"unknown implementation {impl}; choose from {', '.join(IMPLEMENTATIONS)}")


def _status_mb(field):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0  # kB
    raise RuntimeError(f"no {field} in /proc/self/status")


def reset_peak_rss():
    """Reset VmHWM to the current RSS; return the current RSS in MB."""
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")
    return _status_mb("VmRSS")


def peak_rss():
    return _status_mb("VmHWM")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("impl", choices=IMPLEMENTATIONS)
    ap.add_argument("data")
    ap.add_argument("--n", type=int, required=True)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--tracemalloc", action="store_true")
    args = ap.parse_args()
    data, model = load(args.data)
    ys, us = data["ys"], data["us"]
    run = make(args.impl, data, model)
    run(ys[:3], us[:3], min(args.n, 200), 0)  # warm-up: imports, numba compilation
    traced = None
    if args.tracemalloc:  # before the timed runs: buffers made once and kept (scratch) count too
        tracemalloc.start()
        run(ys, us, args.n, 1)
        traced = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
    before = reset_peak_rss()
    seconds, cpu_seconds = [], []
    for seed in range(1, args.repeats + 1):
        t0, c0 = time.perf_counter(), time.process_time()
        mean, std = run(ys, us, args.n, seed)
        cpu_seconds.append(time.process_time() - c0)
        seconds.append(time.perf_counter() - t0)
    rss = peak_rss() - before
    print(json.dumps({"impl": args.impl, "n": args.n, "seconds": seconds, "cpu_seconds": cpu_seconds,
                      "mean": np.asarray(mean).tolist(), "std": np.asarray(std).tolist(), "rss_mb": rss,
                      "traced_mb": traced, "numpy": np.__version__}))


if __name__ == "__main__":
    main()
