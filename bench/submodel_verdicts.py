"""Each submodel of a chain of tanks diagnosed on its own, beside the whole plant (issue 49, point 4).

Run: .venv/bin/python bench/submodel_verdicts.py [--tanks 8] [--seeds 3] [--particles 300]

The chain of ``bench/chain_scale.py`` is simulated by ``bgc simulate``
(fault-free, a pipe's resistance, a tank's capacitance, a sensor's bias,
each from t = 50 s) and diagnosed whole (``bgc.diagnose``), and each of its
submodels (``bgc compile --decompose``) is diagnosed by the same function on
its part of the run: the plant's inputs it reads, the sensors it reads as
inputs (each held over a sample at the mean of the sample's two readings),
its own sensors. Per run: the whole diagnosis's verdict and seconds, the
submodels that did not end in "no fault", the faults that touch every one of
them (what a single fault must explain), and the seconds of all the
submodels' diagnoses.

This measures each submodel's own diagnosis; the one diagnosis made of the
submodels' evidence (``bgc diagnose --decompose``) is measured by
``bench/decomposed_diagnosis.py``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import bgc  # noqa: E402
from bgc import pipeline  # noqa: E402
from bgc.data import runs  # noqa: E402
from chain_scale import chain_yaml  # noqa: E402


def part_of(run: runs.Run, s) -> runs.Run:
    """The run as submodel ``s`` reads it."""
    inputs = {i: run.inputs[i] for i in s.inputs}
    for sensor, name in s.read_as:
        y = run.measurements[sensor]
        inputs[name] = np.concatenate([y[:1], 0.5 * (y[1:] + y[:-1])])
    return runs.Run(run.time, inputs, {o: run.measurements[o] for o in s.outputs}, {}, {}, ())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tanks", type=int, default=8)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--particles", type=int, default=300)
    args = ap.parse_args()
    if args.tanks < 4:
        ap.error("--tanks: at least 4 (the scenarios strike the tanks around the middle one)")
    n = args.tanks
    mid = n // 2
    scenarios = ["none", f"R{mid - 1}:abrupt:0.5@50", f"C{mid}:abrupt:-0.4@50", f"p{mid + 1}:bias:0.5@50"]
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(tmp) / f"chain{n}.yaml"
        model.write_text(chain_yaml(n))
        d = pipeline.decompose_model(model)
        for s in d.decomposition.submodels:
            (Path(tmp) / f"{s.name}.yaml").write_text(s.text)
        subs = d.decomposition.submodels
        print(f"chain of {n} tanks: {len(subs)} submodels of at most "
              f"{max(len(p.equations.states) for p in d.parts)} state(s); {args.particles} particles")
        print(f"{'scenario':<22} {'seed':>4}  {'whole':<28} {'s':>6}  {'submodels not at no fault':<40} "
              f"{'faults touching them all':<26} {'s':>6}")
        for scenario in scenarios:
            for seed in range(args.seeds):
                sim = bgc.simulate(str(model), scenario, seed=seed)
                t0 = time.perf_counter()
                whole = bgc.diagnose(str(model), sim, particles=args.particles, seed=seed)
                tw = time.perf_counter() - t0
                t0 = time.perf_counter()
                alarmed, names = [], set()
                for s in subs:
                    rep = bgc.diagnose(str(Path(tmp) / f"{s.name}.yaml"), part_of(sim.run, s),
                                       particles=args.particles, seed=seed)
                    if rep.diagnosis.verdict != "no fault":
                        alarmed.append(f"{s.outputs[0]}:{rep.diagnosis.verdict}")
                        names.add(s.name)
                ts = time.perf_counter() - t0
                subjects = sorted({f for s in subs for f in s.faults})
                common = [f for f in subjects if names <= set(d.decomposition.touching(f))] if names else []
                print(f"{scenario:<22} {seed:>4}  {whole.diagnosis.verdict + ': ' + ', '.join(whole.diagnosis.candidates):<28.28} "
                      f"{tw:>6.1f}  {' '.join(alarmed) or '-':<40.40} {', '.join(common) or '-':<26.26} {ts:>6.1f}",
                      flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
