"""Particle estimates of the RO plant's log-likelihood, by N. Chopin's `particles`, at given noise levels.

Started by bench/calibrate_particle_check.py with the python of
bench/.venvs/particles (``particles`` pins numpy < 2):

    _particle_loglik.py JOBS.npz --n N

JOBS.npz holds one record (``ys`` (T, n_y), ``us`` (T, n_u)), the model's
``x0``, ``dt``, ``substeps``, K noise settings (``process_std`` (K, n_x),
``x0_std`` (K, n_x), ``measurement_std`` (K, n_y)) and ``jobs`` (J, 2), rows
(setting, seed). For each job: ``np.random.seed(seed)``, then the bootstrap
filter of bench/_particles_model.py's RO model with N particles over the
record, and its log-likelihood estimate ``SMC.logLt`` (the log of the
product over t of the mean unnormalised weight: the particle marginal
likelihood, an unbiased estimate of p(y_0 .. y_T-1) on the natural scale).

Resampling is systematic at *every* step (``ESSrmin=1``), not adaptive: the
same seed then makes the same sequence of draws whatever the noise levels
(adaptive resampling draws a uniform only at some steps, and the streams of
two settings part at the first step where they differ), so that settings run
with one seed share their random numbers (common random numbers) and their
log-likelihoods differ smoothly.

Prints one JSON line: ``loglik`` (J,) in job order, and the CPU seconds.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import particles  # noqa: E402
from particles import state_space_models as ssms  # noqa: E402

from _particles_model import RO  # noqa: E402


def loglik(ys, us, x0, x0_std, process_std, measurement_std, dt, substeps, n, seed) -> float:
    """One particle estimate of log p(ys) at these noise levels, with N = ``n`` and ``seed``."""
    np.random.seed(seed)
    ssm = RO(us=us, x0=x0, x0_std=x0_std, process_std=process_std, measurement_std=measurement_std, dt=dt,
             substeps=substeps)
    pf = particles.SMC(fk=ssms.Bootstrap(ssm=ssm, data=list(ys)), N=n, resampling="systematic", ESSrmin=1.0,
                       collect=[])
    pf.run()
    return float(pf.logLt)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("jobs")
    ap.add_argument("--n", type=int, required=True)
    args = ap.parse_args()
    with np.load(args.jobs) as d:
        data = {k: d[k] for k in d.files}
    out = []
    start = time.process_time()
    for j, (k, seed) in enumerate(data["jobs"]):
        out.append(loglik(data["ys"], data["us"], data["x0"], data["x0_std"][k], data["process_std"][k],
                          data["measurement_std"][k], float(data["dt"]), int(data["substeps"]), args.n, int(seed)))
        print(f"    particle job {j + 1}/{len(data['jobs'])}: log-likelihood {out[-1]:.2f} "
              f"({time.process_time() - start:.0f} CPU s so far)", file=sys.stderr, flush=True)
    print(json.dumps({"loglik": out, "cpu_seconds": time.process_time() - start, "numpy": np.__version__,
                      "particles": particles.__version__}))


if __name__ == "__main__":
    main()
