"""TRANSCEND's backward propagation against matching the forward signatures.

    .venv/bin/python bench/backward_propagation.py

TRANSCEND (Mosterman and Biswas, 1999) generates fault hypotheses from a
deviating measurement by propagating the deviation backwards on the temporal
causal graph: each node takes the sign it is first reached with (breadth
first, a node is closed once assigned, so loops end), and every parameter met
on the way becomes a hypothesis with the direction the path's signs imply.
bgc instead keeps every fault candidate whose forward signature (compile
time, ``bgc show signatures``) has, at that measurement, the observed sign or
``?`` as its first non-zero symbol.

For every model of the test suite, measurement and sign, this prints the
number of (parameter, direction) candidates each way: forward matching,
backward propagation with first assignment, and backward propagation along
every path (a node may be reached with both signs), and the candidates that
forward matching keeps but first-assignment backward propagation loses. Where
that list is not empty, backward propagation would drop a fault that can
explain the deviation (paths of opposite signs reach the sensor).
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bgc.pipeline import compile_model  # noqa: E402
from bgc.diagnosis.isolate import first_symbol  # noqa: E402

#: the plants of models/ and of the test suite's tests/data/models/
MODELS = sorted([*(ROOT / "models").glob("*.yaml"), *(ROOT / "tests" / "data" / "models").glob("*.yaml")])


def signs(edge_sign, s):
    if edge_sign == 0:
        return ()
    return (1, -1) if edge_sign is None else (edge_sign * s,)


def backward(g, node, sign, first: bool) -> set[tuple[str, int]]:
    """(parameter, direction) pairs that a deviation ``sign`` of ``node`` traces back to."""
    found: set[tuple[str, int]] = set()
    closed: dict[str, set[int]] = {}
    level = {node: {sign}}
    while level:
        for v, ss in level.items():
            closed.setdefault(v, set()).update(ss)
        nxt: dict[str, set[int]] = {}
        for v, ss in level.items():
            for s in ss:
                for p, effect in g.nodes[v].get("effects", ()):
                    found.update((p, d) for d in signs(effect, s))
                for u, _, d in g.in_edges(v, data=True):
                    for su in signs(d["sign"], s):
                        if (u in closed) if first else (su in closed.get(u, set())):
                            continue
                        nxt.setdefault(u, set()).add(su)
        level = nxt
    return found


def main() -> None:
    print("| model | measurement | sign | forward matching | backward, first assignment | backward, every path "
          "| candidates | lost by backward propagation |")
    print("|---|---|---|---|---|---|---|---|")
    for path in MODELS:
        name = path.stem
        fs = compile_model(path).signatures
        g = fs.equations.tcg.graph
        node = {d["measurement"]: n for n, d in g.nodes(data=True) if d.get("measurement")}
        faults = {(s.parameter, s.direction) for s in fs.signatures}
        for j, m in enumerate(fs.measurements):
            for sign, symbol in ((1, "+"), (-1, "-")):
                forward = {(s.parameter, s.direction) for s in fs.signatures
                           if first_symbol(s.symbols[j]) in (symbol, "?")}
                first = backward(g, node[m], sign, True) & faults
                every = backward(g, node[m], sign, False) & faults
                lost = ", ".join(f"{p}{'+' if d > 0 else '-'}" for p, d in sorted(forward - first)) or "-"
                print(f"| {name} | {m} | {symbol} | {len(forward)} | {len(first)} | {len(every)} | {len(faults)} "
                      f"| {lost} |")


if __name__ == "__main__":
    main()
