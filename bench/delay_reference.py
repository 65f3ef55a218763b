"""How soon a drift can be detected at all: bgc's detector beside exact
references on the same scenario (issue 48's delay target).

For each scenario (a fault that moves the residuals' mean), at a false-alarm
probability of 1 % over the run, the median delay from the first sample that
sees the fault to the alarm of:

- **bound**: no detector can do better (Neyman and Pearson on the data up to
  each sample: the likelihood ratio that knows the fault, its onset and its
  size; :meth:`bgc.analysis.distinguish.Distinction.ideal_delay`), computed;
- **GLR, fault known**: the generalised likelihood ratio of the true fault's
  linearised response with its onset and size unknown (the maximum over
  onsets and sizes of the whitened residuals' projection on the response),
  by Monte Carlo on the model's whitened innovations;
- **GLR, fault set known**: the same, maximised over every fault model that
  moves a mean (the detector a user could build with the fault list: Willsky
  and Jones 1976), by Monte Carlo;
- **mean**, **bank without matched**, **bank (all)**: bgc's detector
  (``--detect mean``, ``--detect mean,drift,variance,frozen,pooled``,
  ``--detect all``) on ``--runs`` runs of bgc's own simulator: its median
  delay over every run, a run not detected counted as never (as the bound's
  median is), and how many it detected.

The Monte Carlo references draw ``--paths`` fault-free and as many faulty
sequences of whitened innovations (N(0, I), plus the fault's whitened
deviation: the linearised model's exact law); each threshold is its
fault-free draws' 99 % quantile of the statistic's largest value over the
run, and a delay counts a run not alarmed by the run's end as never (the
median is "never" when half are). The sizes are unconstrained (both signs),
the onsets those of ``bgc distinguish``'s families (every sample for runs
up to 400 samples).

Scenarios: ``MODEL SCENARIO`` pairs on the command line, or by default the
first drifts of ``experiments/sweep_bank.yaml``'s draws at the model's
noise (``--per-model`` of each model).

    .venv/bin/python bench/delay_reference.py --per-model 3 --runs 30
    .venv/bin/python bench/delay_reference.py models/two_tank.yaml R12:incipient:0.005@60
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bgc.analysis import distinguish  # noqa: E402
from bgc.api import cache  # noqa: E402
from bgc.api import distinguish as api_distinguish  # noqa: E402
from bgc.api.session import scenario_of  # noqa: E402
from bgc.diagnosis.detect import TESTS  # noqa: E402
from bgc.model import package as packages  # noqa: E402
from bgc.model.protocol import onset_sample  # noqa: E402

FALSE_ALARM = distinguish.FALSE_ALARM
#: The bank before the matched test joined it.
BEFORE = tuple(t for t in TESTS if t != "matched")
CHUNK = 50


def families(model: str, steps: int | None):
    """The model's compiled view and its prediction families at its own noise."""
    opened = cache.open_model(model)
    c = opened.view
    T = steps or c.model.settings.steps
    package = packages.load_package(opened.folder, c.model.name, str(model), None)
    return c, api_distinguish._families(package, T)


def glr_max(fam, names: list[str], E: np.ndarray) -> np.ndarray:
    """The GLR statistic (P, T): at each sample k the largest, over the
    fault models ``names`` and their onsets up to k, of (G' e)^2 / G' G over
    the data up to k (G a whitened unit response, e the innovations ``E``
    (P, T, n_y))."""
    P, T, n_y = E.shape
    best = np.zeros((P, T))
    for name in names:
        G = fam.response(name).reshape(T, n_y, -1)
        B = np.cumsum((G * G).sum(axis=1), axis=0)  # (T, onsets)
        live = B > 1e-12 * max(float(B.max()), 1e-300)
        inv = np.where(live, 1.0 / np.where(live, B, 1.0), 0.0)
        for a in range(0, P, CHUNK):
            A = np.cumsum(np.einsum("ptj,tjo->pto", E[a:a + CHUNK], G, optimize=True), axis=1)
            best[a:a + CHUNK] = np.maximum(best[a:a + CHUNK], (A * A * inv[None]).max(axis=2))
    return best


def glr_delay(fam, names: list[str], w: np.ndarray, onset: int, paths: int, rng) -> float | None:
    """The median delay (samples) of the GLR over ``names`` at 1 % over the
    run, by Monte Carlo; None: never in half of the runs."""
    T, n_y = w.shape
    null = glr_max(fam, names, rng.standard_normal((paths, T, n_y))).max(axis=1)
    threshold = float(np.quantile(null, 1.0 - FALSE_ALARM))
    stat = glr_max(fam, names, rng.standard_normal((paths, T, n_y)) + w[None])
    above = stat[:, onset:] > threshold
    first = np.where(above.any(axis=1), above.argmax(axis=1), np.inf)
    median = float(np.median(first))
    return None if math.isinf(median) else median


def bgc_delay(model: str, scenario: str, runs: int, tests: tuple[str, ...]):
    r = api_distinguish.distinguishability(model, scenario, detector_runs=runs, detectors=tests)
    return r.detector


def scenarios_from_sweep(per_model: int) -> list[tuple[str, str]]:
    from bgc.experiment.campaign_file import load_campaign

    out, seen = [], {}
    for spec in load_campaign(ROOT / "experiments" / "sweep_bank.yaml").specs:
        if spec.kind not in ("incipient", "drift") or spec.noise != "model" or spec.detectors != ("mean",) \
                or spec.filter != "gpf":
            continue
        model = str(Path(spec.model).resolve())
        if seen.get(model, 0) < per_model and (model, spec.scenario) not in out:
            out.append((model, spec.scenario))
            seen[model] = seen.get(model, 0) + 1
    return out


def cell(samples: float | None, dt: float) -> str:
    return "never" if samples is None else f"{samples * dt:.3g}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("pairs", nargs="*", help="MODEL SCENARIO ...")
    parser.add_argument("--per-model", type=int, default=3)
    parser.add_argument("--runs", type=int, default=30, help="bgc's detector's simulated runs per scenario")
    parser.add_argument("--paths", type=int, default=1000, help="Monte Carlo draws per reference and law")
    parser.add_argument("--seed", type=int, default=0)
    a = parser.parse_args(argv)
    pairs = list(zip(a.pairs[::2], a.pairs[1::2])) if a.pairs else scenarios_from_sweep(a.per_model)
    rng = np.random.default_rng(a.seed)
    print(f"| scenario | bound | GLR, fault known | GLR, fault set known | mean: median (detected of {a.runs}) "
          "| bank without matched | bank (all) | mean / bound | without matched / bound | all / bound |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    ratios = {"bank": [], "before": [], "mean": [], "glr": [], "set": []}
    for model, scenario in pairs:
        started = time.time()
        c, fam = families(model, None)
        inj = scenario_of("bench", scenario, c.numerics)
        T = fam.y.shape[0]
        dt = c.model.settings.dt
        onset = onset_sample(dt * np.arange(1, T + 1), inj.time)
        name = f"{inj.parameter}_{inj.kind}"
        d = distinguish.distinguish(fam, name, inj.magnitude, onset, {})
        w = fam.whitening.apply(distinguish.deviations(fam, name, [inj.magnitude], [onset]))[:, :, 0]
        bound = d.ideal_delay(FALSE_ALARM)
        movers = [n for n in fam.names if distinguish.noisy_row(fam.package.MODELS[n]) is None]
        known = glr_delay(fam, [name], w, onset, a.paths, rng)
        fault_set = glr_delay(fam, movers, w, onset, a.paths, rng)
        mean, before, bank = (bgc_delay(model, scenario, a.runs, t) for t in (("mean",), BEFORE, TESTS))
        label = f"{Path(model).stem} {scenario}"

        def det(rate):
            value = rate.median_over_runs
            return f"{'never' if math.isinf(value) else f'{value:.3g}'} ({rate.detected})"

        def ratio(rate, key):
            value = rate.median_over_runs
            if bound is None or math.isinf(value) or bound == 0:
                return "–"
            ratios[key].append(value / (bound * dt))
            return f"{value / (bound * dt):.2f}"

        print(f"| {label} | {cell(bound, dt)} | {cell(known, dt)} | {cell(fault_set, dt)} | {det(mean)} | "
              f"{det(before)} | {det(bank)} | {ratio(mean, 'mean')} | {ratio(before, 'before')} | "
              f"{ratio(bank, 'bank')} |", flush=True)
        if bound:
            for key, value in (("glr", known), ("set", fault_set)):
                if value is not None:
                    ratios[key].append(value / bound)
        print(f"<!-- {label}: {time.time() - started:.0f} s -->", file=sys.stderr)
    print()
    for key, text in (("glr", "GLR, fault known"), ("set", "GLR, fault set known"), ("mean", "mean test"),
                      ("before", "bank without matched"), ("bank", "bank (all)")):
        if ratios[key]:
            print(f"median of {text} / bound over {len(ratios[key])} scenarios: "
                  f"{statistics.median(ratios[key]):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
