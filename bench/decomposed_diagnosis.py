"""The diagnosis on the submodels beside the whole plant's, on chains of 8 to 32 tanks (issue 49, point 4).

Run: .venv/bin/python bench/decomposed_diagnosis.py [--tanks 8 16 32] [--seeds 20] [--whole-seeds 20]

The chain of ``bench/chain_scale.py``, started at its steady state, is
simulated by an independent simulator (``tests/chain_reference.py``: scipy's
solve_ivp on its equations derived by hand; sensors 0.7 times as noisy as
the model says, no process noise) under five scenarios, each from t = 50:

* ``none``: fault-free;
* ``R2``: pipe 2's resistance 0.5 higher (a listed fault near the inflow);
* ``bias``: the middle tank's sensor reading 4 % of its steady value high;
* ``C2``: tank 2's capacity 0.5 higher (at steady state nothing shows it:
  no fault is the right verdict, and both must agree it is unseen);
* ``leak``: the middle tank leaking a quarter of the inflow (a fault the
  model does not list: "unexplained" is the right verdict).

Each run is diagnosed whole (``bgc.diagnose(..., filter="ckf")``: the same
method, every fault model over the whole plant; its hypotheses' jobs on
two worker processes) and on the submodels (``decompose=True``, one
process), with the model's compilation and split done once beforehand (not
timed). Per size and scenario: the runs each got right, the runs whose
verdict and first candidate agree, and the median seconds of each, with
their ratio. ``--whole-seeds``: the whole plant is diagnosed on the first
so many seeds only (at 32 tanks one of its diagnoses takes minutes); the
agreement counts those.

``--parts-detector``: each run diagnosed on the submodels twice more, side by
side in this process (``bgc.diagnosis.decomposed.diagnose``, no report):
with the detector on the whole plant's nominal filter (the default) and on
the submodels' own residuals (the plan without its whole plant's package,
as before that filter was added); prints each one's verdicts right, the
step of its alarm, and its median seconds.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import bgc  # noqa: E402
import chain_reference as chain  # noqa: E402
from bgc.api.decomposed import open_plan  # noqa: E402
from bgc.diagnosis import decomposed  # noqa: E402

SCENARIOS = ("none", "R2", "bias", "C2", "leak")
#: The leak's outflow at the steady state, a fraction of the inflow.
LEAK = 0.25


def fault_of(name: str, n: int) -> tuple[str, str]:
    """(the simulator's fault, the right verdict's first word and candidate) of scenario ``name`` on ``n`` tanks."""
    mid = n // 2
    p = chain.steady(n)[mid - 1]
    return {"none": ("none", "no fault:"),
            "R2": ("R2:0.5", "isolated:R2_abrupt"),
            "bias": (f"p{mid}:{0.04 * p:.6g}", f"isolated:p{mid}_offset_bias"),
            "C2": ("C2:0.5", "no fault:"),
            "leak": (f"leak{mid}:{LEAK * chain.F_IN / math.sqrt(p):.6g}", "unexplained:")}[name]


def said(d) -> str:
    return f"{d.verdict}:{d.candidates[0] if d.candidates and d.verdict != 'unexplained' else ''}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tanks", type=int, nargs="+", default=[8, 16, 32])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--whole-seeds", type=int, default=None, help="seeds the whole plant is diagnosed on (default all)")
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    ap.add_argument("--parts-detector", action="store_true",
                    help="also diagnose with the detector on the submodels' own residuals, side by side")
    args = ap.parse_args()
    whole_seeds = args.seeds if args.whole_seeds is None else min(args.whole_seeds, args.seeds)
    print(f"command: .venv/bin/python bench/decomposed_diagnosis.py --tanks {' '.join(map(str, args.tanks))} "
          f"--seeds {args.seeds} --whole-seeds {whole_seeds} --scenarios {' '.join(args.scenarios)}")
    summary = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.tanks:
            model = Path(tmp) / f"chain{n}.yaml"
            model.write_text(chain.model_yaml(n))
            t0 = time.perf_counter()
            bgc.open(str(model))
            compiled = time.perf_counter() - t0
            t0 = time.perf_counter()
            plan = open_plan(str(model))
            print(f"\nchain of {n} tanks: compiled whole in {compiled:.1f} s, split into {len(plan.parts)} "
                  f"submodels in {time.perf_counter() - t0:.1f} s (not timed below)", flush=True)
            for name in args.scenarios:
                fault, right = fault_of(name, n)
                row = {"n": n, "scenario": name, "fault": fault, "right_split": 0, "right_whole": 0, "agree": 0,
                       "split_s": [], "whole_s": [], "runs": args.seeds, "whole_runs": whole_seeds}
                for seed in range(args.seeds):
                    t, y = chain.run(n, fault, seed=seed)
                    run = chain.as_run(t, y)
                    t0 = time.perf_counter()
                    split = bgc.diagnose(str(model), run, decompose=True).diagnosis
                    row["split_s"].append(time.perf_counter() - t0)
                    row["right_split"] += said(split) == right
                    line = f"  {name:<5} seed {seed:>2}  split {said(split):<26} {row['split_s'][-1]:6.2f} s"
                    if seed < whole_seeds:
                        t0 = time.perf_counter()
                        whole = bgc.diagnose(str(model), run, filter="ckf", seed=seed).diagnosis
                        row["whole_s"].append(time.perf_counter() - t0)
                        row["right_whole"] += said(whole) == right
                        row["agree"] += said(whole) == said(split)
                        line += f"  whole {said(whole):<26} {row['whole_s'][-1]:7.2f} s"
                    if args.parts_detector:
                        for label, used in (("whole filter", plan), ("parts", replace(plan, whole=None))):
                            t0 = time.perf_counter()
                            d = decomposed.diagnose(run, used)
                            seconds = time.perf_counter() - t0
                            row.setdefault(label, []).append((said(d) == right, d.detection, seconds))
                            line += (f"\n      detector on the {label:<12} {said(d):<26} alarm "
                                     f"{'-' if d.detection is None else d.detection.step:>4} {seconds:6.2f} s")
                    print(line, flush=True)
                summary.append(row)
    print("\n| tanks | scenario | fault | right, submodels | right, whole | same verdict | median s, submodels "
          "| median s, whole | ratio |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in summary:
        ms = statistics.median(r["split_s"])
        mw = statistics.median(r["whole_s"]) if r["whole_s"] else math.nan
        print(f"| {r['n']} | {r['scenario']} | {r['fault']} | {r['right_split']}/{r['runs']} | "
              f"{r['right_whole']}/{r['whole_runs']} | {r['agree']}/{r['whole_runs']} | {ms:.2f} | {mw:.2f} | "
              f"{mw / ms:.1f}x |")
    if args.parts_detector:
        print("\n| tanks | scenario | detector on | right | alarms | median s |")
        print("|---|---|---|---|---|---|")
        for r in summary:
            for label in ("whole filter", "parts"):
                done = r[label]
                print(f"| {r['n']} | {r['scenario']} | {label} | {sum(ok for ok, _, _ in done)}/{len(done)} | "
                      f"{sum(d is not None for _, d, _ in done)}/{len(done)} | "
                      f"{statistics.median(s for _, _, s in done):.2f} |")
    sizes = sorted({r["n"] for r in summary})
    if len(sizes) > 1:
        for label, key in (("submodels", "split_s"), ("whole", "whole_s")):
            medians = [[statistics.median(r[key]) for r in summary if r["n"] == n and r[key]] for n in sizes]
            if not all(medians):  # (the whole plant not diagnosed at some size: --whole-seeds 0)
                continue
            per = [statistics.mean(m) for m in medians]
            slope = (math.log(per[-1]) - math.log(per[0])) / (math.log(sizes[-1]) - math.log(sizes[0]))
            print(f"mean over scenarios of the median seconds, {label}: "
                  + ", ".join(f"{n}: {v:.2f}" for n, v in zip(sizes, per)) + f" (grows as n^{slope:.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
