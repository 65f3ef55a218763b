"""Which faults a model's sensors can detect and tell apart, before the plant
runs: three levels side by side (``bgc analyse``; docs/commands.md).

* **structural**, from the equations' structure (:mod:`.structure`, as the
  Fault Diagnosis Toolbox computes it): a redundancy of the equations that
  holds a fault's equation detects it; one that holds fault i's and not
  fault j's tells i from j;
* **qualitative**, from the TRANSCEND signatures (each sensor's magnitude
  and slope, as ``bgc.diagnosis.isolate`` reads a signature): fault i is
  told from fault j when, whatever direction and kind each takes, once
  every sensor shows its symbols some sensor tells them apart: one of them
  moves it and the other does not, or they move it opposite ways, or its
  slopes differ (a ``?``, a stuck or noisy reading that may show either
  sign or none, tells nothing). bgc's isolation, online, is more cautious:
  a sensor that has not deviated yet rules out nothing (a fault may reach
  it later), and the fault-model filters decide what the symbols leave;
* **quantitative**, from ``bgc distinguish`` (:mod:`.distinguish`): each
  fault model at a change of its scale, at the model's noise over its
  inputs and run length; fault i is told from fault j when, for each of
  i's fault models the data detect, the probability that the data name it
  over every fault model of j is at least the level (0.95).

The faults are the model's fault candidates, one per parameter (a
parameter's kinds and directions together): what happened is told from what
did not when each of its forms is. Each level gives a matrix, ``[i][j]``:
fault i (what happened) is told from fault j; the classes of faults that
cannot be told apart (both ways); and, per pair not told apart, why.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import networkx as nx
import numpy as np

from ..ir import FaultSignatures, Signature, expected_slope, first_symbol
from ..kinds import fault_parameter
from . import structure

#: The levels, in the order they are shown.
LEVELS = ("structural", "qualitative", "quantitative")


@dataclass(frozen=True)
class Level:
    """One level's answer: ``detectable[i]``, ``isolable[i][j]`` (fault i
    told from fault j; the diagonal False), and ``why``: per fault not
    detectable ``(i, i)``, per pair not told apart ``(i, j)``, the reason."""

    name: str
    detectable: tuple[bool, ...]
    isolable: tuple[tuple[bool, ...], ...]
    why: Mapping[tuple[int, int], str]

    def classes(self, faults: Sequence[str]) -> tuple[tuple[str, ...], ...]:
        """The groups of detected faults no two of which can be told apart
        either way (the largest such groups: the maximal cliques of the
        pairs not told apart both ways; a fault may be in more than one),
        each of more than one fault."""
        g = nx.Graph()
        n = len(faults)
        g.add_nodes_from(i for i in range(n) if self.detectable[i])
        g.add_edges_from((i, j) for i in g for j in g
                         if i < j and not self.isolable[i][j] and not self.isolable[j][i])
        groups = [sorted(c) for c in nx.find_cliques(g) if len(c) > 1]
        return tuple(tuple(faults[i] for i in c) for c in sorted(groups))

    def pairs(self) -> set[tuple[int, int]]:
        """The ordered pairs (i, j) where fault i is told from fault j."""
        n = len(self.detectable)
        return {(i, j) for i in range(n) for j in range(n) if self.isolable[i][j]}


def structural(ssm, faults: Sequence[str], sensors: Mapping[str, str] | None = None,
               enters: Mapping[str, frozenset] | None = None) -> tuple[Level, structure.StructuralModel]:
    """The structural level of the state equations ``ssm`` with the fault
    parameters ``faults`` (``sensors``: a sensor fault's parameter -> its
    sensor; ``enters``: a stuck switch's junction -> the equations its stuck
    configurations change, :func:`.structure.of_equations`)."""
    model = structure.of_equations(ssm, {p: p for p in faults}, sensors, enters)
    names, matrix = model.matrix()
    plus = model.overdetermined()
    detectable = tuple(model.faults[p] in plus for p in names)
    why = {}
    for i, p in enumerate(names):
        if not detectable[i]:
            why[i, i] = f"no redundancy of the equations holds {p}'s: its change is taken up by the unknowns"
        for j, q in enumerate(names):
            if i != j and detectable[i] and not matrix[i][j]:
                why[i, j] = f"every redundancy that holds {p}'s equation holds {q}'s as well"
    return Level("structural", detectable, matrix, why), model


def _read(s: Signature) -> tuple[tuple[str, str], ...]:
    """Per sensor, the symbol fault ``s`` shows first and the slope after it."""
    return tuple((first_symbol(x), expected_slope(x)) for x in s.symbols)


def _refutes(a: Signature, b: Signature, measurements: Sequence[str]) -> str | None:
    """How fault ``a``'s symbols, once every sensor shows them, rule ``b``
    out (None: they cannot): a sensor one of them moves and the other does
    not, or moves the other way, or whose slope differs. A ``?`` (a stuck or
    noisy reading: either sign, or none) rules out nothing. The rule read
    one pair at a time; :func:`_alike` applies it to every pair at once."""
    for m, (fa, ka), (fb, kb) in zip(measurements, _read(a), _read(b)):
        if "?" in (fa, fb):
            continue
        if fa != fb:
            return f"{m} moves {fa} under {a.name}, {fb} under {b.name}" if "0" not in (fa, fb) else \
                f"{m} moves under {a.name if fb == '0' else b.name} only"
        if ka in ("+", "-") and kb in ("+", "-") and ka != kb:
            return f"{m}'s slope is {ka} under {a.name}, {kb} under {b.name}"
    return None


def qualitative(signatures: FaultSignatures, faults: Sequence[str]) -> Level:
    """The qualitative level: the signatures of each fault parameter (every
    kind and direction) against each other's. Which pairs of signatures
    :func:`_refutes` cannot tell apart is worked out for every pair at once
    (arrays of the symbols each sensor shows first and the slopes after);
    the reason a pair of faults stays together names the first such pair of
    their signatures, in the models' order."""
    every = signatures.signatures
    by = {p: [k for k, s in enumerate(every) if s.parameter == p] for p in faults}
    ms = signatures.measurements
    alike = _alike(every)
    moving = [any(first_symbol(x) != "0" for x in s.symbols) for s in every]
    moves = {p: [k for k in by[p] if moving[k]] for p in faults}
    detectable = tuple(bool(moves[p]) for p in faults)
    why, matrix, shown = {}, [], {}
    for i, p in enumerate(faults):
        row = []
        if not detectable[i]:
            why[i, i] = "no sensor moves under any of its signatures"
        for j, q in enumerate(faults):
            if i == j or not detectable[i]:
                row.append(False)
                continue
            pair = next(((a, b) for a in moves[p] for b in by[q] if alike[a, b]), None)
            row.append(pair is None)
            if pair is not None:
                a, b = pair
                if a not in shown:
                    shown[a] = _shown(every[a], ms)
                why[i, j] = f"{every[a].name} and {every[b].name} show the same symbols: {shown[a]}"
        matrix.append(tuple(row))
    return Level("qualitative", detectable, tuple(matrix), why)


_CODES = {"0": 0, "+": 1, "-": 2, "?": 3}


def _alike(every: Sequence[Signature]) -> np.ndarray:
    """``[a, b]``: whether :func:`_refutes` finds nothing that tells
    signature a from b (every sensor shows both the same first symbol, or a
    ``?``, and no sensor's slopes differ in sign)."""
    if not every:
        return np.zeros((0, 0), bool)
    read = [_read(s) for s in every]
    first = np.array([[_CODES[f] for f, _ in r] for r in read], dtype=np.int8).reshape(len(every), -1)
    slope = np.array([[_CODES[k] for _, k in r] for r in read], dtype=np.int8).reshape(len(every), -1)
    fa, fb = first[:, None, :], first[None, :, :]
    ka, kb = slope[:, None, :], slope[None, :, :]
    either = (fa == 3) | (fb == 3)
    signed = ((ka == 1) | (ka == 2)) & ((kb == 1) | (kb == 2))
    told = ~either & ((fa != fb) | (signed & (ka != kb)))
    return ~told.any(axis=2)


def _shown(s: Signature, measurements: Sequence[str]) -> str:
    """What signature ``s`` shows: per sensor it moves, magnitude and slope."""
    parts = [f"{m} {first_symbol(x)}" + (f" slope {expected_slope(x)}" if expected_slope(x) in ("+", "-") else "")
             for m, x in zip(measurements, s.symbols) if first_symbol(x) != "0"]
    return ", ".join(parts) or "no sensor moves"


def quantitative(distinctions: Sequence, faults: Sequence[str], level: float) -> Level:
    """The quantitative level from ``bgc distinguish``'s distinctions (one
    per fault model of every candidate, kind and direction)."""
    by = {p: [d for d in distinctions if fault_parameter(d.truth) == p] for p in faults}
    seen = {p: [d for d in by[p] if d.detectability >= level] for p in faults}
    detectable = tuple(bool(seen[p]) for p in faults)
    why, matrix = {}, []
    for i, p in enumerate(faults):
        row = []
        if not detectable[i]:
            best = max(by[p], key=lambda d: d.detectability, default=None)
            why[i, i] = ("no fault model of it" if best is None else
                         f"{best.label} is detected with probability {best.detectability:.3f} at most (< {level:g})")
        for j, q in enumerate(faults):
            if i == j or not detectable[i]:
                row.append(False)
                continue
            close = min(((d, r) for d in seen[p] for r in d.rivals if fault_parameter(r.name) == q),
                        key=lambda dr: dr[1].probability, default=None)
            told = close is None or close[1].probability >= level
            row.append(told)
            if not told:
                d, r = close
                why[i, j] = f"{d.label}'s data name it over {r.name} with probability {r.probability:.3f} (< {level:g})"
        matrix.append(tuple(row))
    return Level("quantitative", detectable, tuple(matrix), why)


def across(levels: Sequence[Level], modes: Sequence[str]) -> Level:
    """One level over the modes a run goes through (``levels[k]``: the level
    in mode ``modes[k]``): a fault is detected when some mode detects it,
    and told from another when some mode tells them apart (its data are
    read in every mode it visits); a pair no mode tells apart gives each
    mode's reason."""
    n = len(levels[0].detectable)
    detectable = tuple(any(lv.detectable[i] for lv in levels) for i in range(n))
    isolable = tuple(tuple(any(lv.isolable[i][j] for lv in levels) for j in range(n)) for i in range(n))
    why = {}
    for i in range(n):
        for j in range(n):
            if (i == j and not detectable[i]) or (i != j and detectable[i] and not isolable[i][j]):
                why[i, j] = "; ".join(f"in {m}: {lv.why[i, j]}" for lv, m in zip(levels, modes) if (i, j) in lv.why)
    return Level(levels[0].name, detectable, isolable, why)
