"""What declaring every sensor kind costs a diagnosis of RO, side by side in one run.

    .venv/bin/python bench/sensor_kinds_cost.py [--seeds 2] [--particles 1000]

Issue 48, point 3: the shipped RO model declares a bias, a drift, a stuck
reading and a burst of noise on each of its four sensors (28 fault models);
until 2026-12-04 it declared the bias and the drift only (20). The variant
here is models/ro.yaml with each sensor's kinds cut back to ``[bias,
drift]``, written to a temporary folder; nothing else differs. Each run is
simulated from the shipped model and diagnosed by both, GPF with
``--particles``, ``workers=1`` (one process), the CPU seconds of the process
(time.process_time) per diagnosis; the target is a ratio of at most 1.5.
The scenarios: fault-free, a plant step, a plant drift, and each sensor kind
on one sensor. Prints one row per run (both verdicts, both times, the
ratio), then the median and the largest ratio.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import re  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bgc  # noqa: E402
from bgc.diagnosis.options import DiagnosisOptions  # noqa: E402

SCENARIOS = ("none", "R_pipe:abrupt:24@165", "R_memb:incipient:0.05@165", "F_back:bias:0.331@150",
             "F_back:drift:0.002207@150", "P_memb:stuck:0@150", "F_loop:noise:4@150")


def bias_and_drift(text: str) -> str:
    """models/ro.yaml's text with each sensor's kinds ``[bias, drift, stuck, noise]`` cut back to ``[bias, drift]``."""
    out, n = re.subn(r"^(  \w+: \{kinds: \[bias, drift), stuck, noise\]", r"\1]", text, flags=re.M)
    if n != 4:
        raise SystemExit(f"expected the four sensors' kinds [bias, drift, stuck, noise] in models/ro.yaml, found {n}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--particles", type=int, default=1000)
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        variant = Path(folder) / "ro.yaml"
        variant.write_text(bias_and_drift((ROOT / "models" / "ro.yaml").read_text()))
        sessions = {"bias and drift": bgc.open(variant), "as shipped": bgc.open(ROOT / "models" / "ro.yaml")}
        counts = {k: len(s.package.MODELS) - 1 for k, s in sessions.items()}
        print(f"RO, GPF {a.particles} particles, one process; fault models: "
              + ", ".join(f"{k} {n}" for k, n in counts.items()))
        print("| scenario | seed | bias and drift | s | as shipped (every kind) | s | ratio |")
        print("|---|---|---|---|---|---|---|")
        ratios = []
        for scenario in SCENARIOS:
            for seed in range(1, a.seeds + 1):
                run = bgc.simulate(sessions["as shipped"], scenario=scenario, seed=seed)
                row = []
                for session in sessions.values():
                    start = time.process_time()
                    d = bgc.diagnose(session, data=run, options=DiagnosisOptions(
                        filter="gpf", particles=a.particles, seed=seed, workers=1)).diagnosis
                    row.append((d.verdict + (": " + ", ".join(d.candidates[:2]) if d.candidates else ""),
                                time.process_time() - start))
                ratios.append(row[1][1] / row[0][1])
                print(f"| {scenario} | {seed} | {row[0][0]} | {row[0][1]:.1f} | {row[1][0]} | {row[1][1]:.1f} | "
                      f"{ratios[-1]:.2f} |", flush=True)
        print(f"\nCPU time, as shipped over bias and drift: median {statistics.median(ratios):.2f}, "
              f"largest {max(ratios):.2f} (target: at most 1.5)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
