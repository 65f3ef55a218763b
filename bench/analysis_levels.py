"""``bgc analyse`` on every shipped, test and example plant (issue 49): per
plant (per mode for a model with modes), its faults, how many each level
detects and how many ordered pairs each tells apart, and whether the
structural level equals the Fault Diagnosis Toolbox's (the reference,
``faultdiagnosistoolbox``, the test extra's) on the same structural model.

    .venv/bin/python bench/analysis_levels.py            # structural and qualitative
    .venv/bin/python bench/analysis_levels.py --quantitative

The quantitative level (``bgc distinguish`` of every fault model at the
model's noise) takes a few seconds per plant more.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))


def fdt_agrees(level, model) -> bool:
    """Whether the toolbox's detectability and isolability equal ``level``'s on ``model``."""
    from test_analyse import fdt_model

    tool = fdt_model(model)
    detected, _ = tool.DetectabilityAnalysis()
    im = tool.IsolabilityAnalysis()
    faults = list(model.faults)
    n = len(faults)
    return set(detected) == {f for f, d in zip(faults, level.detectable) if d} and \
        all(level.isolable[i][j] == (i != j and not im[i][j]) for i in range(n) for j in range(n))


def main() -> int:
    from bgc.analysis import isolability
    from bgc.api.analyse import analyse
    from bgc.compiler import load
    from bgc.pipeline import compile_model

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quantitative", action="store_true", help="also the quantitative level")
    args = p.parse_args()
    plants = sorted(q for q in [*(ROOT / "models").glob("*.yaml"), *(ROOT / "tests/data/models").glob("*.yaml"),
                                *(ROOT / "docs/examples").glob("*.yaml")]
                    if "faults:" in q.read_text(encoding="utf-8") and q.stem not in ("broken_two_tank", "campaign",
                                                                                       "tank_logger"))
    levels = ("structural", "qualitative") + (("quantitative",) if args.quantitative else ())
    head = " | ".join(f"{x[:5]}. detected / pairs" for x in levels)
    print(f"| plant | mode | faults | {head} | FDT equal | seconds |")
    print("|---|---|---|" + "---|" * len(levels) + "---|---|")
    for path in plants:
        t = time.perf_counter()
        try:
            r = analyse(path, quantitative=args.quantitative)
        except Exception as exc:  # a plant bgc cannot analyse: said in the table
            print(f"| {path.relative_to(ROOT)} | | | {type(exc).__name__}: {str(exc).splitlines()[0]} |")
            continue
        seconds = time.perf_counter() - t
        n = len(r.faults)
        if load.declares_modes(path):
            from bgc.api.analyse import _stuck_configs, _stuck_equations

            c = compile_model(path)
            sensors = {f.parameter: f.subject for f in c.model.faults if f.target == "sensor"}
            enters = _stuck_equations(c, _stuck_configs(c, c.model.modes.stuck))  # a stuck switch in what it changes
            for m in c.modes:
                s, model = isolability.structural(m.equations, r.faults, sensors, enters[m.name])
                q = r.by_mode[m.name][1]
                print(f"| {path.relative_to(ROOT)} | {m.name} | {n} | {sum(s.detectable)} / {len(s.pairs())} | "
                      f"{sum(q.detectable)} / {len(q.pairs())} |" + (" |" if args.quantitative else "")
                      + f" {'yes' if fdt_agrees(s, model) else 'NO'} | |")
        cells = " | ".join(f"{sum(r.get(x).detectable)} / {len(r.get(x).pairs())}" for x in levels)
        agree = "" if r.by_mode else ("yes" if fdt_agrees(r.get("structural"), r.structure) else "NO")
        print(f"| {path.relative_to(ROOT)} | {'across' if r.by_mode else ''} | {n} | {cells} | {agree} | "
              f"{seconds:.1f} |")
    print("\n(pairs: ordered pairs (i, j), i told from j, of the n (n - 1) there are)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
