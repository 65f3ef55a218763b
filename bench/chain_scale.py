"""Compile time of a chain of tanks, whole and split into submodels (issue 49, point 4).

Run: .venv/bin/python bench/chain_scale.py [--sizes 8,16,32,64] [--analyse]

A chain of n tanks, an inflow into the first, a pipe from each tank to the
next and an outlet from the last, a pressure sensor on every tank; faults:
every pipe's resistance and tank's capacitance (abrupt) and every sensor
(bias). The file is written by :func:`chain_yaml`.

Per n, side by side in one run: the seconds of the whole compilation (every
fault model generated over the whole plant: ``bgc compile``, no pictures)
and of the compilation split into submodels (``bgc compile --decompose``:
the whole plant's numbers, the split, and each submodel's own fault models),
their ratio, the submodels and the most states one holds, and the fault
models generated. With ``--analyse``, also ``bgc analyse --no-quantitative``
(the structural and qualitative levels) on the whole plant.

Targets (issue 49): the compilation of the 32-tank chain under 10 s, and
growing at most linearly with the plant; ``bgc analyse`` of the 64-tank
chain under 10 s.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import chain_reference  # noqa: E402
from bgc import pipeline  # noqa: E402


def chain_yaml(n: int) -> str:
    """The model file of a chain of ``n`` tanks (module docstring), empty at
    the start; the capacities and resistances vary a little from tank to
    tank (tests/chain_reference.py writes it)."""
    return chain_reference.chain_yaml(n, f"a chain of {n} tanks, a pressure sensor on each")


def whole(text: str, name: str) -> tuple[float, int]:
    t0 = time.perf_counter()
    c = pipeline.compile_model(name, text=text)
    pipeline.generated_files(c)
    return time.perf_counter() - t0, 1 + len(c.dbn.faulty)


def split(text: str, name: str) -> tuple[float, int, int, int]:
    t0 = time.perf_counter()
    d = pipeline.decompose_model(name, text=text)
    pipeline.decomposed_files(d)
    seconds = time.perf_counter() - t0
    return (seconds, len(d.parts), max(len(p.equations.states) for p in d.parts),
            sum(1 + len(p.dbn.faulty) for p in d.parts))


def analysed(text: str, name: str) -> float:
    import tempfile

    from bgc.api.analyse import analyse

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / name
        path.write_text(text)
        t0 = time.perf_counter()
        analyse(str(path), quantitative=False)
        return time.perf_counter() - t0


def slope(ns: list[int], ts: list[float]) -> float:
    """The fitted exponent k of t ~ n^k."""
    xs, ys = [math.log(n) for n in ns], [math.log(max(t, 1e-9)) for t in ts]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="8,16,32,64", help="the chains' numbers of tanks (default 8,16,32,64)")
    ap.add_argument("--analyse", action="store_true", help="also time bgc analyse --no-quantitative (minutes)")
    args = ap.parse_args()
    ns = [int(v) for v in args.sizes.split(",")]
    print("Compile time of a chain of n tanks (seconds, one run each, in this process)")
    head = f"{'n':>4} {'whole':>8} {'models':>7} {'split':>8} {'models':>7} {'parts':>6} {'states':>7} {'ratio':>7}"
    print(head + (f" {'analyse':>8}" if args.analyse else ""))
    w, s = [], []
    for n in ns:
        text = chain_yaml(n)
        tw, mw = whole(text, f"chain{n}.yaml")
        ts, parts, states, ms = split(text, f"chain{n}.yaml")
        w.append(tw)
        s.append(ts)
        line = f"{n:>4} {tw:>8.2f} {mw:>7} {ts:>8.2f} {ms:>7} {parts:>6} {states:>7} {tw / ts:>6.1f}x"
        if args.analyse:
            line += f" {analysed(text, f'chain{n}.yaml'):>8.2f}"
        print(line, flush=True)
    if len(ns) >= 2:
        print(f"fitted growth: whole ~ n^{slope(ns, w):.2f}, split ~ n^{slope(ns, s):.2f}")
    if 32 in ns:
        t = s[ns.index(32)]
        print(f"target: the 32-tank chain split in {t:.2f} s (limit 10 s): {'met' if t < 10 else 'MISSED'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
