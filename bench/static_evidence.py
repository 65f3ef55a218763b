"""How far apart do the data put two fault hypotheses? Their static evidences
(docs/diagnosis.md section 6) on every detected run of one fault in a sweep.

    .venv/bin/python bench/static_evidence.py [--runs out/sweep/runs.csv] [--fault R_rp:incipient]
                                              [--against R_pipe_incipient]

Re-runs ``bgc.diagnose`` on every run of the sweep (``bgc experiment
experiments/sweep.yaml -o out/sweep``) whose injected fault is ``--fault`` and
which was detected (the same scenario, seed, filter, particles and noise: the
same diagnosis), and prints the log Bayes factor of the true hypothesis against
``--against``: the log of the ratio of their static evidences, p(y | hypothesis),
with the magnitude integrated over its prior and the onset over its window.
Under equal priors, a positive factor is a right call; its size says how sure
any diagnoser can be (1 nat is odds of 2.7 to 1). The priors the model states
multiply these odds (``faults: ... prior`` in the model file).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402
from bgc.diagnosis.options import DiagnosisOptions


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", default=str(ROOT / "out" / "sweep" / "runs.csv"))
    ap.add_argument("--fault", default="R_rp:incipient", help="PARAMETER:KIND of the injected fault")
    ap.add_argument("--against", default="R_pipe_incipient", help="the other hypothesis (a fault model's name)")
    args = ap.parse_args()
    path = Path(args.runs)
    if not path.is_file():
        sys.exit(f"{path}: no such file; run: bgc experiment experiments/sweep.yaml -o out/sweep")
    parameter, kind = args.fault.split(":")
    truth = f"{parameter}_{kind}"
    with path.open(encoding="utf-8") as f:
        rows = [r for r in csv.DictReader(line for line in f if not line.startswith("#"))
                if r["fault"] == parameter and r["kind"] == kind and r["detected"] == "true"]
    print(f"log Bayes factor {truth} / {args.against} on the {len(rows)} detected runs of {args.fault} in {path}\n")
    print("| scenario | filter | noise | verdict | candidates | log Bayes factor |")
    print("|---|---|---|---|---|---|")
    factors = []
    for r in rows:
        noise = {k: float(r[f"{k}_noise"]) if r[f"{k}_noise"] else None for k in ("process", "measurement")}
        model = Path(r["model"]) if Path(r["model"]).is_absolute() else ROOT / r["model"]
        rep = bgc.diagnose(model, scenario=r["scenario"], seed=int(r["seed"]), process_noise=noise["process"],
                           measurement_noise=noise["measurement"], generated=ROOT / "generated",
                           options=DiagnosisOptions(method=r["filter"], particles=int(r["particles"]),
                                                    seed=int(r["seed"]), workers=1))
        d = rep.diagnosis
        evidence = {h.name: h.static_log_evidence for h in d.hypotheses if h.static_log_evidence is not None}
        factor = evidence.get(truth, -math.inf) - evidence.get(args.against, -math.inf)
        factors.append(factor)
        print(f"| {r['scenario']} | {r['filter']} | {r['noise']} | {d.verdict} | {', '.join(d.candidates)} | "
              f"{factor:.2f} |", flush=True)
    finite = [f for f in factors if math.isfinite(f)]
    if finite:
        print(f"\nfavour {truth}: {sum(f > 0 for f in finite)} of {len(finite)}; largest |log Bayes factor| "
              f"{max(abs(f) for f in finite):.2f} (odds {math.exp(max(abs(f) for f in finite)):.1f} to 1); "
              f"mean {sum(finite) / len(finite):.2f}")


if __name__ == "__main__":
    main()
