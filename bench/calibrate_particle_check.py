"""bgc's noise calibration of the RO plant against the particle marginal likelihood (docs/calibrate.md, "Measured").

    PYTHONPATH=. .venv/bin/python bench/calibrate_particle_check.py [--steps 1000] [--seeds 100 ...]
        [--n 20000] [--repeats 8] [--points 9] [--widen 1.5] [--save FILE.json]
    PYTHONPATH=. .venv/bin/python bench/calibrate_particle_check.py --load FILE.json   # the tables again

With the defaults (one run, seed 100): 48 particle filters of 20 000 particles
over 1000 samples, about 10 CPU minutes, and one calibration (about 1 CPU minute).

``bgc calibrate`` maximises the likelihood that the cubature Kalman filter
(CKF) computes by the prediction-error decomposition. On the RO plant, which
is nonlinear in its states, that likelihood is an approximation. This bench
sets it beside an independent one: the particle marginal likelihood of a
bootstrap filter (Gordon, Salmond and Smith 1993) run by N. Chopin's
``particles`` library (``SMC.logLt``: an unbiased estimate of p(y) on the
natural scale, converging to the exact likelihood as N grows; Del Moral 2004,
Andrieu, Doucet and Holenstein 2010), on the same model with the same noise
structure and time indexing (bench/_particles_model.py: prior N(X0,
diag(X0_STD^2)); at sample k, RK4 with u_k, then N(0, diag(PROCESS_STD^2)),
then y_k ~ N(h(x), diag(MEASUREMENT_STD^2)), as bgc.filters.cubature's filter
does). ``particles`` pins numpy < 2, so that part runs in bench/.venvs/particles
(made with pip the first time, bench/_venvs.py) as a subprocess
(bench/_particle_loglik.py).

Method, per run (seeds ``--seeds``):

1. Simulate a healthy RO run of ``--steps`` samples with bgc's truth
   simulator (RK4, 8 times finer than the filters) at the model's noise, and
   calibrate it: ``bgc.open("models/ro.yaml").calibrate(run, "noise")``, the
   four sensors' stds and the process level.
2. Rebuild bgc's likelihood at its estimate (``calibrate._Likelihood``: the
   optimiser's coordinates z are the logs of the stds and of the level;
   ``lik.module(z)`` gives THETA, MEASUREMENT_STD, PROCESS_STD, X0_STD), check
   that it gives the calibration's log-likelihood, and take its Hessian (bgc's
   own central differences) and covariance C.
3. bgc ends estimate i's 95 % interval where the CKF log-likelihood has fallen
   by chi2(0.95, 1) / 2 = 1.92 along the path z(t) = z_hat + t C[:, i] /
   sqrt(C[i, i]) (estimate i moves by t sds, the others follow their best
   values to first order: the profile likelihood's path). Both likelihoods are
   compared along that same path, so that "falls by 1.92 at bgc's ends" means
   the same thing for both. (A slice with the others held at bgc's estimate
   would fall by more than 1.92 at those ends whenever i is correlated with
   the others, and the comparison would test the correlation, not the
   likelihood.) Grid: ``--points`` values of t, evenly spaced on each side of 0
   from ``--widen`` times the low end to ``--widen`` times the high end (the
   interval widened 1.5 times).
4. At each grid point the particle log-likelihood with N = ``--n`` particles
   and seed 1 for every point (common random numbers: systematic resampling
   at every step, so every point draws the same random numbers and the
   profile is smooth in t; _particle_loglik.py), and at the estimate
   ``--repeats`` times with seeds 1, 2, ...: their spread is the Monte Carlo
   std of one estimate.
5. A parabola fitted (least squares) to each particle profile: its maximum is
   the particle argmax, its fall at bgc's ends the particle-likelihood drop,
   its width where it has fallen by 1.92 the particle interval.

Columns:

  estimate          the sensor's noise (absolute std) or the process level (relative)
  bgc [95 %]        bgc's estimate and 95 % interval
  particle argmax   the argmax of the parabola through the particle profile, in the estimate's units
  shift / width     (argmax - estimate) / (high - low), in bgc's coordinates (logs): 0 if they agree;
                    within +-0.25 the argmax lies well inside bgc's interval (its ends are at about +-0.5)
  drop low, high    the parabola's maximum minus its value at bgc's low and high end (1.92 when the
                    CKF's curvature is the particle likelihood's)
  width ratio       the particle interval (the parabola's fall of 1.92) over bgc's
  fit rms           rms residual of the parabola (Monte Carlo noise along the profile, under common
                    random numbers, plus any departure from a quadratic)

``+-``: standard errors from the parabola's least-squares fit (its residual
variance, propagated by the delta method). A guide only: under common random
numbers the residuals along a profile are correlated, and the fit rms also
holds any departure of the profile from a parabola.

And per run: the CKF log-likelihood at the estimate, the particle
log-likelihood there (mean of the repeats), their difference, the Monte
Carlo std of one particle estimate (std of the repeats) and the CPU seconds.
The particle log-likelihood is biased low by about half its variance (the
estimate is unbiased for the likelihood, not its log; Jensen), so a
difference of ~ -var/2 is expected.

Before anything, the hand-typed RO equations (bench/_handwritten_numpy.py,
used by _particles_model.py) are compared with the generated
generated/ro/numpy_model/nominal.py at random states (derivative, outputs
and one RK4 step); the bench stops when they differ.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # before numpy is imported, inherited by the subprocess

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from _venvs import BENCH, ROOT, ensure_venv, progress  # noqa: E402

sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402
from bgc.analysis import calibrate, simulate
from bgc.data import runs  # noqa: E402

import _handwritten_numpy as hand  # noqa: E402

MODEL = ROOT / "models" / "ro.yaml"
#: The fall of the log-likelihood at a 95 % interval's end (chi2(0.95, 1) / 2), as bgc's calibrate.DROP95.
DROP95 = calibrate.DROP95
#: Largest relative difference allowed between the hand-typed and the generated equations.
EQUATIONS_TOL = 1e-9


@dataclass(frozen=True, slots=True)
class Profile:
    """One estimate's profile: bgc's value and interval, the path's grid ``t``
    (in sds of z_i), bgc's ends on it (``t_low``, ``t_high``), the CKF and
    particle log-likelihoods on the grid."""

    seed: int
    name: str
    value: float
    low: float
    high: float
    sd: float
    t: np.ndarray
    t_low: float
    t_high: float
    ckf: np.ndarray
    particle: np.ndarray

    def to_json(self) -> dict:
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in
                ((f, getattr(self, f)) for f in self.__slots__)}

    @classmethod
    def from_json(cls, d: dict) -> "Profile":
        return cls(**{k: (np.array(v, dtype=float) if k in ("t", "ckf", "particle") else v) for k, v in d.items()})


def check_equations(nominal) -> float:
    """The hand-typed equations' largest relative difference from the generated ones; stops the bench above EQUATIONS_TOL."""
    worst = hand.mismatch(nominal, np.random.default_rng(0))
    if not worst <= EQUATIONS_TOL:
        raise SystemExit(f"bench/_handwritten_numpy.py's equations or parameters differ from "
                         f"generated/ro/numpy_model/nominal.py (largest relative difference {worst:.3g}): "
                         "type them in again from generated/ro/equations.txt")
    return worst


def grid(t_low: float, t_high: float, points: int, widen: float) -> np.ndarray:
    """``points`` values of t (odd), evenly spaced on each side of 0 out to ``widen`` times each end."""
    side = (points - 1) // 2
    f = widen * np.arange(1, side + 1) / side
    return np.concatenate([(f * t_low)[::-1], [0.0], f * t_high])


def particle_logliks(python: str, directory: Path, record, nominal, modules, jobs, n: int) -> tuple[np.ndarray, float]:
    """The particle log-likelihood of ``record`` for each job (setting, seed), ``modules`` the settings; CPU s."""
    path = directory / "jobs.npz"
    np.savez(path, ys=record.ys, us=record.us, x0=np.asarray(nominal.X0, dtype=float), dt=float(nominal.DT),
             substeps=int(nominal.SUBSTEPS),
             process_std=np.array([m.PROCESS_STD for m in modules], dtype=float),
             x0_std=np.array([m.X0_STD for m in modules], dtype=float),
             measurement_std=np.array([m.MEASUREMENT_STD for m in modules], dtype=float),
             jobs=np.array(jobs, dtype=np.int64))
    done = subprocess.run([python, str(BENCH / "_particle_loglik.py"), str(path), "--n", str(n)], cwd=BENCH,
                          stdout=subprocess.PIPE, text=True)
    if done.returncode != 0:
        raise SystemExit(f"bench/_particle_loglik.py failed (exit code {done.returncode}); its messages are above")
    out = json.loads(done.stdout.strip().splitlines()[-1])
    return np.array(out["loglik"], dtype=float), float(out["cpu_seconds"])


def versions(python: str) -> str:
    """``particles`` and numpy versions of the venv ``python``."""
    done = subprocess.run([python, "-c", "import numpy, particles; print(particles.__version__, numpy.__version__)"],
                          capture_output=True, text=True)
    found = done.stdout.split()
    return f"particles {found[0]}, numpy {found[1]}" if len(found) == 2 else "versions unknown"


def check_run(session, nominal, python: str, directory: Path, seed: int, args) -> tuple[list[Profile], dict]:
    """Simulate, calibrate and profile one run (see the module docstring); its profiles and summary."""
    numerics = session.compiled.numerics
    progress(f"seed {seed}: simulating {args.steps} samples and calibrating with bgc ...")
    result = simulate.simulate(numerics, simulate.SimulationOptions(steps=args.steps, seed=seed))
    run = runs.parse_run(simulate.to_csv(result), f"seed {seed}")
    c0 = time.process_time()
    c = session.calibrate(run, "noise").calibration
    calibration_seconds = time.process_time() - c0
    bad = [e.name for e in c.estimates if not e.identifiable or e.at_bound]
    if bad:
        raise SystemExit(f"seed {seed}: {', '.join(bad)} not identifiable or at a bound; this check needs all five")
    sensors = [e.subject for e in c.estimates if e.kind == "measurement_noise"]
    lik = calibrate._Likelihood(nominal, numerics, [calibrate.record_of(run, nominal)], sensors, True, [])
    z = np.log([e.value for e in c.estimates])  # the optimiser's coordinates: log stds, log level
    best = lik(z)
    if abs(best - c.loglik) > 1e-6 * max(1.0, abs(c.loglik)):
        raise SystemExit(f"seed {seed}: the rebuilt CKF likelihood {best:.6f} is not the calibration's {c.loglik:.6f}")
    _, H = calibrate._hessian(lambda v: -lik(v), z, calibrate._steps(z), -best)
    cov = np.linalg.inv(H)
    plans = []  # (estimate, sd, t grid, t_low, t_high)
    for i, e in enumerate(c.estimates):
        sd = math.sqrt(cov[i, i])
        t_low, t_high = (math.log(e.low) - z[i]) / sd, (math.log(e.high) - z[i]) / sd
        plans.append((e, sd, grid(t_low, t_high, args.points, args.widen), t_low, t_high))
    # settings: 0 the estimate, then each profile's points other than t = 0 (which is setting 0)
    modules = [lik.module(z)]
    jobs = [(0, r) for r in range(1, args.repeats + 1)]
    where = []  # per profile, per point: the setting index
    ckfs = []
    for i, (e, sd, ts, _, _) in enumerate(plans):
        d = cov[:, i] / sd
        rows, ckf = [], []
        for t in ts:
            if t == 0.0:
                rows.append(0)
                ckf.append(best)
                continue
            modules.append(lik.module(z + t * d))
            jobs.append((len(modules) - 1, 1))
            rows.append(len(modules) - 1)
            ckf.append(lik(z + t * d))
        where.append(rows)
        ckfs.append(np.array(ckf))
    progress(f"seed {seed}: {len(jobs)} particle filters of N = {args.n} over {args.steps} samples ...")
    values, particle_seconds = particle_logliks(python, directory, lik.records[0], nominal, modules, jobs, args.n)
    at = {job: v for job, v in zip(jobs, values)}
    repeats = np.array([at[(0, r)] for r in range(1, args.repeats + 1)])
    profiles = [Profile(seed, e.name, e.value, e.low, e.high, sd, ts, t_low, t_high, ckf,
                        np.array([at[(k, 1)] for k in rows]))
                for (e, sd, ts, t_low, t_high), rows, ckf in zip(plans, where, ckfs)]
    summary = {"seed": seed, "ckf": best, "particle_mean": float(repeats.mean()),
               "mc_std": float(repeats.std(ddof=1)) if len(repeats) > 1 else math.nan,
               "particle_seconds": particle_seconds, "calibration_seconds": calibration_seconds,
               "evaluations": len(jobs), "repeats": args.repeats}
    return profiles, summary


def parabola(p: Profile) -> dict:
    """The parabola through the particle profile: argmax (t and value), shift / width, drops at bgc's ends,
    width ratio, fit rms, and the standard errors (``se_*``) of shift, drops and width ratio from the
    least-squares fit (its residual variance, the delta method; a guide only: under common random
    numbers the residuals along a profile are correlated)."""
    X = np.vander(p.t, 3)
    coef, *_ = np.linalg.lstsq(X, p.particle, rcond=None)
    resid = p.particle - X @ coef
    rms = float(np.sqrt(np.mean(resid ** 2)))
    cov = float(resid @ resid) / max(len(p.t) - 3, 1) * np.linalg.inv(X.T @ X)
    width = p.t_high - p.t_low

    def stats(c: np.ndarray) -> np.ndarray:
        a, b, c0 = c
        if not a < 0:
            return np.full(4, np.nan)
        t_max = -b / (2 * a)
        top = c0 - b * b / (4 * a)
        return np.array([t_max / width, top - np.polyval(c, p.t_low), top - np.polyval(c, p.t_high),
                         2 * math.sqrt(DROP95 / -a) / width])

    value = stats(coef)
    J = np.empty((4, 3))
    for k in range(3):  # the delta method, by central differences in the coefficients
        h = 1e-6 * max(abs(coef[k]), 1e-12)
        e = np.zeros(3)
        e[k] = h
        J[:, k] = (stats(coef + e) - stats(coef - e)) / (2 * h)
    se = np.sqrt(np.maximum(np.einsum("ik,kl,il->i", J, cov, J), 0.0))
    shift, drop_low, drop_high, ratio = value
    return {"argmax": p.value * math.exp(shift * width * p.sd), "shift": shift, "drop_low": drop_low,
            "drop_high": drop_high, "width_ratio": ratio, "rms": rms, "se_shift": se[0], "se_drop_low": se[1],
            "se_drop_high": se[2], "se_width_ratio": se[3]}


def ckf_drops(p: Profile) -> tuple[float, float]:
    """The CKF's own fall at bgc's ends from the same grid's parabola (about 1.92: checks the path is bgc's)."""
    a, b, c0 = np.polyfit(p.t, p.ckf, 2)
    top = np.polyval([a, b, c0], -b / (2 * a))
    return float(top - np.polyval([a, b, c0], p.t_low)), float(top - np.polyval([a, b, c0], p.t_high))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--seeds", type=int, nargs="+", default=[100])
    ap.add_argument("--n", type=int, default=20_000, help="particles per filter")
    ap.add_argument("--repeats", type=int, default=8, help="particle filters at the estimate (seeds 1, 2, ...)")
    ap.add_argument("--points", type=int, default=9, help="grid points per estimate (odd)")
    ap.add_argument("--widen", type=float, default=1.5, help="the grid spans bgc's interval times this")
    ap.add_argument("--save", default=None, help="also write the profiles and summaries to this JSON file")
    ap.add_argument("--load", default=None, help="print the tables of a file --save wrote, computing nothing")
    args = ap.parse_args()
    if args.points < 3 or args.points % 2 == 0:
        ap.error("--points must be odd and at least 3")
    start = time.perf_counter()
    if args.load:
        saved = json.loads(Path(args.load).read_text())
        print_tables(saved["command"], saved["setup"], [Profile.from_json(d) for d in saved["profiles"]],
                     saved["summaries"])
        return 0
    python, why = ensure_venv("particles")
    if python is None:
        raise SystemExit(f"bench/.venvs/particles is not available: {why}")
    session = bgc.open(MODEL)
    nominal = session.package.MODELS["nominal"]
    worst = check_equations(nominal)
    profiles, summaries = [], []
    with tempfile.TemporaryDirectory(prefix="bgc-particle-check-") as tmp:
        for seed in args.seeds:
            run_profiles, summary = check_run(session, nominal, python, Path(tmp), seed, args)
            profiles += run_profiles
            summaries.append(summary)
            progress(f"seed {seed}: done ({time.perf_counter() - start:.0f} s so far)")
    command = ("PYTHONPATH=. .venv/bin/python bench/calibrate_particle_check.py"
               f" --steps {args.steps} --seeds {' '.join(map(str, args.seeds))}"
               f" --n {args.n} --repeats {args.repeats} --points {args.points} --widen {args.widen:g}")
    setup = (f"RO plant (models/ro.yaml), {args.steps} samples per run; the bootstrap filter of `particles` "
             f"({versions(python)}), N = {args.n}, systematic resampling every step, seed 1 at every grid point, "
             f"{args.repeats} seeds at the estimate; {args.points} grid points per estimate along bgc's profile path, "
             f"over its interval widened {args.widen:g}x. The hand-typed equations (bench/_handwritten_numpy.py) "
             f"against generated/ro: largest relative difference {worst:.1g}. "
             f"{time.perf_counter() - start:.0f} s wall-clock, {sum(s['calibration_seconds'] for s in summaries) + sum(s['particle_seconds'] for s in summaries):.0f} CPU s "
             "in bgc calibrate and the particle filters.")
    if args.save:
        Path(args.save).write_text(json.dumps({"command": command, "setup": setup,
                                               "profiles": [p.to_json() for p in profiles],
                                               "summaries": summaries}, indent=1))
    print_tables(command, setup, profiles, summaries)
    return 0


def print_tables(command: str, setup: str, profiles: list[Profile], summaries: list[dict]) -> None:
    """The markdown tables of the module docstring."""
    print(f"```sh\n{command}\n```\n")
    print(setup + "\n")
    print("| run | estimate | bgc [95 %] | particle argmax | shift / width | drop at low, high end | width ratio "
          "| fit rms |")
    print("|---|---|---|---|---|---|---|---|")
    for p in profiles:
        f = parabola(p)
        print(f"| {p.seed} | {p.name} | {p.value:.4g} [{p.low:.4g}, {p.high:.4g}] | {f['argmax']:.4g} | "
              f"{f['shift']:+.3f} +- {f['se_shift']:.3f} | {f['drop_low']:.2f} +- {f['se_drop_low']:.2f}, "
              f"{f['drop_high']:.2f} +- {f['se_drop_high']:.2f} | {f['width_ratio']:.2f} +- {f['se_width_ratio']:.2f} "
              f"| {f['rms']:.2f} |")
    print("\n| run | CKF log-lik at the estimate | particle log-lik (mean) | particle - CKF | Monte Carlo std "
          "| particle filters | CPU s: bgc calibrate, particles |")
    print("|---|---|---|---|---|---|---|")
    for s in summaries:
        print(f"| {s['seed']} | {s['ckf']:.2f} | {s['particle_mean']:.2f} +- {s['mc_std'] / math.sqrt(s['repeats']):.2f} | "
              f"{s['particle_mean'] - s['ckf']:+.2f} | {s['mc_std']:.2f} | {s['evaluations']} | "
              f"{s['calibration_seconds']:.0f}, {s['particle_seconds']:.0f} |")
    ckf = np.array([ckf_drops(p) for p in profiles])
    print(f"\nThe CKF's own drop at bgc's ends, from a parabola on the same grid: {ckf.min():.2f} to {ckf.max():.2f} "
          "(1.92: the path is bgc's). +-: standard errors from the parabola's fit (see the bench's docstring).")


if __name__ == "__main__":
    sys.exit(main())
