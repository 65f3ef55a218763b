"""Compile time of RC ladders: n sections, one capacitor (one state) per section.

Run: .venv/bin/python bench/compile_scaling.py [--max 320] [--bgt]

Prints seconds per n for bgc's stages (load+validate+SCAP, TCG, equations, DBNs)
and the fitted growth exponent of the total. With --bgt and BondGraphTools
installed (pip install '.[bench]'), the same ladders are built in
BondGraphTools and its constitutive relations timed side by side in the same run,
with the ratio printed.

Targets (issue 3): under 1 s at n = 80, under 10 s at n = 320; about linear growth.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bgc.compiler import causality, dbn, equations, load, tcg, validate  # noqa: E402


def ladder_yaml(n: int) -> str:
    lines = ["name: ladder", "parameters:"]
    for i in range(1, n + 1):
        lines.append(f"  R{i}: 1.0")
        lines.append(f"  C{i}: 1.0")
    lines += ["  RL: 1.0", "inputs: {V: 1.0}", "elements:", "  V: {kind: Se}"]
    for i in range(1, n + 1):
        lines += [f"  s{i}: {{kind: '1'}}", f"  R{i}: {{kind: R}}", f"  p{i}: {{kind: '0'}}", f"  C{i}: {{kind: C}}"]
    lines += ["  RL: {kind: R}", "bonds:"]
    b = 1
    prev = "V"
    for i in range(1, n + 1):
        for tail, head in ((prev, f"s{i}"), (f"s{i}", f"R{i}"), (f"s{i}", f"p{i}"), (f"p{i}", f"C{i}")):
            lines.append(f"  {b}: [{tail}, {head}]")
            b += 1
        prev = f"p{i}"
    lines.append(f"  {b}: [p{n}, RL]")
    lines.append(f"measurements: {{e{b}: {{noise: 0.02}}}}")
    return "\n".join(lines) + "\n"


def time_bgc(n: int) -> dict[str, float]:
    text = ladder_yaml(n)
    t0 = time.perf_counter()
    cbg = causality.assign(validate.validate(load.loads(text, f"ladder{n}.yaml")))
    t1 = time.perf_counter()
    graph = tcg.build(cbg)
    t2 = time.perf_counter()
    ssm = equations.derive(graph)
    t3 = time.perf_counter()
    dbn.build(ssm)
    t4 = time.perf_counter()
    assert len(ssm.states) == n
    return {"check": t1 - t0, "tcg": t2 - t1, "equations": t3 - t2, "dbn": t4 - t3, "total": t4 - t0}


def time_bgt(n: int) -> float | None:
    """Seconds for BondGraphTools to build the same ladder and derive its
    constitutive relations (its equations), or None when it is not installed."""
    try:
        import BondGraphTools as bgt
    except ImportError:
        return None
    t0 = time.perf_counter()
    model = bgt.new(name="ladder")
    prev = bgt.new("Se", name="V")
    bgt.add(model, prev)
    for _ in range(n):
        s, r, p, c = bgt.new("1"), bgt.new("R", value=1.0), bgt.new("0"), bgt.new("C", value=1.0)
        bgt.add(model, s, r, p, c)
        bgt.connect(prev, s)
        bgt.connect(s, r)
        bgt.connect(s, p)
        bgt.connect(p, c)
        prev = p
    rl = bgt.new("R", value=1.0)
    bgt.add(model, rl)
    bgt.connect(prev, rl)
    _ = model.constitutive_relations
    assert len(model.state_vars) == n
    return time.perf_counter() - t0


def fit_exponent(ns: list[int], ts: list[float]) -> float:
    xs = [math.log(n) for n in ns]
    ys = [math.log(max(t, 1e-9)) for t in ts]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max", type=int, default=320)
    ap.add_argument("--bgt", action="store_true",
                    help="also time BondGraphTools (pip install '.[bench]'; slow: minutes at n >= 40)")
    ap.add_argument("--bgt-max", type=int, default=40)
    args = ap.parse_args()
    ns = [n for n in (5, 10, 20, 40, 80, 160, 320, 640) if n <= args.max]
    print("RC ladder compile time, bgc (seconds; median of 3 runs below n = 160, 1 run above)")
    print(f"{'n':>5} {'check':>8} {'tcg':>8} {'equations':>10} {'dbn':>8} {'total':>8}" + ("  BondGraphTools   ratio" if args.bgt else ""))
    totals = []
    for n in ns:
        runs = [time_bgc(n) for _ in range(3 if n < 160 else 1)]
        r = sorted(runs, key=lambda d: d["total"])[len(runs) // 2]
        totals.append(r["total"])
        line = f"{n:>5} {r['check']:>8.3f} {r['tcg']:>8.3f} {r['equations']:>10.3f} {r['dbn']:>8.3f} {r['total']:>8.3f}"
        if args.bgt and n <= args.bgt_max:
            t = time_bgt(n)
            line += "  not installed" if t is None else f"  {t:>14.2f}   {t / r['total']:>6.0f}x"
        print(line, flush=True)
    big = [(n, t) for n, t in zip(ns, totals) if n >= 20]
    if len(big) >= 2:
        k = fit_exponent([n for n, _ in big], [t for _, t in big])
        print(f"fitted growth exponent (n >= 20): total ~ n^{k:.2f}")
    targets = {80: 1.0, 320: 10.0}
    for n, limit in targets.items():
        if n in ns:
            t = totals[ns.index(n)]
            print(f"target n = {n}: {t:.3f} s (limit {limit:g} s): {'met' if t < limit else 'MISSED'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
