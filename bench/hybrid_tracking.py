"""Mode tracking with the mode hidden: the autonomous RO (models/ro_hybrid.yaml:
to secondary when the unmeasured conductivity K = e27 rises past 12100, to
purge after 30 s, back to primary when the membrane pressure falls under 20)
followed by the nominal particle filter from its guards alone, the run's
mode column kept for the comparison.

    .venv/bin/python bench/hybrid_tracking.py [--runs 20] [--steps 600] [--particles 50,100,200] [--reference 2000]

Each run k (seed k) is simulated twice by bgc's truth simulator: as the
model says (each guard's threshold drawn per visit from its tolerance:
K's 10, the pressure's 1), and with exact thresholds (a copy of the model
without the tolerances: the plant the guards describe exactly, which the
filter's tolerances do not match). On each, the GPF of the shipped model
at each particle count, a reference with ``--reference`` particles (close
to the exact posterior on the same data), and the GPF of the copy without
tolerances at the largest count (the filter of guards taken exactly, as bgc
had before). A sample is right when the filter's most probable mode (the
weight of the particles in it) is the run's; the table gives, per filter,
the mean over the runs of the share of samples right, the worst run, and
the CPU seconds per run (``time.process_time``).
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

MODEL = ROOT / "models" / "ro_hybrid.yaml"


def exact_copy(folder: Path) -> Path:
    """The model without its guards' tolerances, written into ``folder``."""
    text = re.sub(r",\s*tolerance:\s*[0-9.eE+-]+", "", MODEL.read_text())
    if "tolerance" in text.split("transitions:")[1]:
        raise SystemExit(f"{MODEL.name}: a tolerance this bench cannot strip")
    path = folder / "ro_hybrid.yaml"
    path.write_text(text)
    return path


def main(argv=None) -> int:
    import bgc
    from bgc.analysis.track import track

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--particles", default="50,100,200", help="particle counts, comma-separated")
    parser.add_argument("--reference", type=int, default=2000, help="the reference filter's particles")
    args = parser.parse_args(argv)
    counts = [int(n) for n in args.particles.split(",")]
    with tempfile.TemporaryDirectory() as folder:
        exact = exact_copy(Path(folder))
        shipped, plain = bgc.open(MODEL, backend="numpy"), bgc.open(exact, backend="numpy")
        filters = [(f"tolerances, N = {n}", shipped, n) for n in counts]
        filters += [(f"reference, N = {args.reference}", shipped, args.reference),
                    (f"guards exact, N = {max(counts)}", plain, max(counts))]
        table = {}
        switches = {"as the model says": [], "exact thresholds": []}
        for k in range(args.runs):
            for data, source in (("as the model says", MODEL), ("exact thresholds", exact)):
                sim = bgc.simulate(source, seed=k, steps=args.steps)
                switches[data].append(len(sim.switches))
                for name, session, n in filters:
                    cpu = time.process_time()
                    result = track(sim.run, session.package, "nominal", "gpf", n, seed=k, hidden_mode=True)
                    table.setdefault((data, name), []).append(
                        (result.mode_agreement(sim.run), time.process_time() - cpu))
            print(f"  run {k + 1}/{args.runs}", file=sys.stderr, flush=True)
    print(f"autonomous RO ({MODEL.name}), mode hidden, {args.runs} runs of {args.steps} samples; switches per run "
          + ", ".join(f"{d}: {min(s)} to {max(s)}" for d, s in switches.items()))
    print()
    print("| data | filter (GPF) | samples in the right mode, mean | worst run | runs >= 99.8 % | CPU s per run |")
    print("|---|---|---|---|---|---|")
    for (data, name), rows in table.items():
        share = [r[0] for r in rows]
        print(f"| {data} | {name} | {100 * statistics.mean(share):.2f} % | {100 * min(share):.2f} % | "
              f"{sum(s >= 0.998 for s in share)} of {len(share)} | {statistics.median(r[1] for r in rows):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
