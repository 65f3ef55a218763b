"""Time one filter implementation at one N, in a fresh process; print one JSON line.

Started by bench/filter_speed.py, once per (implementation, N), with the
interpreter of the venv the implementation needs:

  gpf, apf, numpy   the project's .venv (generated package, hand-written NumPy)
  numba             bench/.venvs/numba
  particles         bench/.venvs/particles

Steps: import, load the data (.npz), one warm-up run (T = 3 steps, N = min(N,
200): imports, numba compilation), then ``repeats`` timed runs on the full
record (seeds 1..repeats; seconds per run = filter construction + all T
steps), then, with --tracemalloc, one more untimed run under tracemalloc.

Memory, two measures:
  rss_mb     ru_maxrss after the timed runs minus ru_maxrss before them: the
             growth of the process's peak resident set caused by the runs
             (coarse: it can only under-count, e.g. when freed import-time memory
             is reused; covers numba's own allocations);
  traced_mb  tracemalloc peak over one untimed run (every NumPy array buffer,
             exact; blind to numba's allocator, so not used for numba).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
IMPLEMENTATIONS = ("gpf", "apf", "numpy", "numba", "particles")


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
    """A function run(ys, us, n, seed) -> (final mean, final std, number of resampling steps)."""
    if impl in ("gpf", "apf"):
        sys.path.insert(0, str(ROOT / "generated" / "ro"))
        from numpy_model import filters, nominal

        check_names(data, nominal.STATES, nominal.OUTPUTS)
        cls = filters.GenericParticleFilter if impl == "gpf" else filters.AuxiliaryParticleFilter

        def run(ys, us, n, seed):
            out = cls(nominal, n, np.random.default_rng(seed)).run(ys, us)
            return out["mean"][-1], out["std"][-1], int(np.sum(out["ess"] < 0.5 * n))
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
            return out["mean"][-1], out["std"][-1], int(np.sum(out["ess"] < 0.5 * n))
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
            mean = np.average(pf.X, weights=pf.W, axis=0)
            std = np.sqrt(np.average((pf.X - mean) ** 2, weights=pf.W, axis=0))
            # rs_flags[t]: resampled before step t, i.e. because ESS after step t-1 < ESSrmin N
            return mean, std, int(np.sum(pf.summaries.rs_flags)) + int(pf.wgts.ESS < 0.5 * n)
        return run
    raise SystemExit(f"unknown implementation {impl}; choose from {', '.join(IMPLEMENTATIONS)}")


def maxrss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


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
    before = maxrss_mb()
    seconds = []
    for seed in range(1, args.repeats + 1):
        t0 = time.perf_counter()
        mean, std, resampled = run(ys, us, args.n, seed)
        seconds.append(time.perf_counter() - t0)
    rss = maxrss_mb() - before
    traced = None
    if args.tracemalloc:
        tracemalloc.start()
        run(ys, us, args.n, 1)
        traced = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
    print(json.dumps({"impl": args.impl, "n": args.n, "seconds": seconds, "final_mean": [float(v) for v in mean],
                      "final_std": [float(v) for v in std], "resampled": resampled, "rss_mb": rss,
                      "traced_mb": traced, "numpy": np.__version__}))


if __name__ == "__main__":
    main()
