"""An independent simulator of a chain of measured tanks (the plant of
``bench/chain_scale.py``, started at its steady state), for the tests and
benches of the decomposed diagnosis: scipy's solve_ivp on its equations
derived by hand, faults the model lists and one it does not (a leak).

Tank i (1..n) of capacity C_i holds pressure p_i; pipe i of resistance R_i
carries q_i = (p_i - p_(i+1)) / R_i to the next tank (the last one's to
the open air, p_(n+1) = 0); the inflow f_in enters tank 1:

    C_i dp_i/dt = q_(i-1) - q_i,    q_0 = f_in.

At the steady state every pipe carries f_in, so p_i = f_in (R_i + ... + R_n).
A pressure sensor on each tank reads p_i plus Gaussian noise.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

DT, STEPS, F_IN = 0.5, 200, 1.0


def values(n: int) -> tuple[list[float], list[float]]:
    """The capacities and resistances of tank and pipe 1..n (as chain_scale's model file writes them)."""
    return ([1.0 + 0.1 * (i % 3) for i in range(1, n + 1)], [1.0 + 0.2 * (i % 2) for i in range(1, n + 1)])


def steady(n: int, f_in: float = F_IN) -> list[float]:
    """p_i = f_in (R_i + ... + R_n): each pipe carries the inflow."""
    _, R = values(n)
    return [f_in * sum(R[i:]) for i in range(n)]


def chain_yaml(n: int, description: str, initial: list[float] | None = None, noise: float = 0.01,
               simulation: str = f"dt: {DT:g}, steps: {STEPS}") -> str:
    """The model file of a chain of ``n`` tanks (``bench/chain_scale.py``'s
    too): every pipe's resistance and tank's capacity and every sensor's
    bias faults; the tanks' ``initial`` pressures (None: empty), the
    sensors' ``noise`` and the ``simulation`` section's text."""
    C, R = values(n)
    lines = [f"name: chain{n}", f"description: {description}", "domain: hydraulic", "parameters:"]
    for i in range(1, n + 1):
        lines += [f"  C{i}: {C[i - 1]:g}", f"  R{i}: {R[i - 1]:g}"]
    lines += [f"inputs: {{f_in: {F_IN!r}}}", "elements:", "  Sf_in: {kind: Sf, value: f_in}"]
    for i in range(1, n + 1):
        start = "" if initial is None else f", initial: {initial[i - 1]:.12g}"
        lines += [f"  tank{i}: {{kind: '0'}}", f"  C{i}: {{kind: C{start}}}", f"  pipe{i}: {{kind: '1'}}",
                  f"  R{i}: {{kind: R}}"]
    lines += ["bonds:", "  1: [Sf_in, tank1]"]
    b, sensors = 2, []
    for i in range(1, n + 1):
        sensors.append(f"  p{i}: {{expr: e{b}, noise: {noise:g}}}")
        lines += [f"  {b}: [tank{i}, C{i}]", f"  {b + 1}: [tank{i}, pipe{i}]", f"  {b + 2}: [pipe{i}, R{i}]"]
        b += 3
        if i < n:
            lines.append(f"  {b}: [pipe{i}, tank{i + 1}]")
            b += 1
    lines += ["measurements:", *sensors, "faults:"]
    for i in range(1, n + 1):
        lines += [f"  R{i}: [abrupt]", f"  C{i}: [abrupt]", f"  p{i}: [bias]"]
    lines += [f"simulation: {{{simulation}}}"]
    return "\n".join(lines) + "\n"


def model_yaml(n: int, noise: float = 0.01, process: float = 0.003) -> str:
    """The model file of the chain started at its steady state (:func:`chain_yaml`);
    sensor noise ``noise``, process noise ``process`` (fractions of the
    readings and states: the tanks' pressures grow with the chain, and so
    does their noise)."""
    return chain_yaml(n, f"a chain of {n} tanks at their steady state, a pressure sensor on each", steady(n), noise,
                      f"dt: {DT:g}, steps: {STEPS}, process_noise: {process:g}")


def derivative(p, C, R, leak: tuple[int, float] | None = None) -> np.ndarray:
    """dp/dt by hand; ``leak``: (tank, k), an outflow k sqrt(p) from that tank (a fault no model lists)."""
    n = len(p)
    q = np.empty(n + 1)
    q[0] = F_IN
    q[1:] = (np.asarray(p) - np.append(p[1:], 0.0)) / np.asarray(R)
    dp = (q[:-1] - q[1:]) / np.asarray(C)
    if leak is not None:
        i, k = leak
        dp[i - 1] -= k * np.sqrt(max(p[i - 1], 0.0)) / C[i - 1]
    return dp


def run(n: int, fault: str = "none", onset: float = 50.0, seed: int = 0, noise: float = 0.007):
    """(time, readings (steps x n)) of the chain from its steady state
    over ``STEPS`` samples of ``DT`` (the first at DT), with ``fault``:
    ``none``, ``R<i>:<delta>`` (pipe i's resistance + delta from
    ``onset``), ``C<i>:<delta>``, ``p<i>:<bias>`` (sensor i reads bias
    more from ``onset``) or ``leak<i>:<k>`` (tank i leaks k sqrt(p_i));
    each sensor's noise std ``noise`` times its steady reading."""
    C, R = values(n)
    p0 = np.array(steady(n))
    t = DT * np.arange(1, STEPS + 1)
    before = t < onset - 1e-9
    C2, R2, leak, bias = list(C), list(R), None, None
    if fault != "none":
        what, size = fault.split(":")
        size = float(size)
        i = int(what.lstrip("RCpleak"))
        if what.startswith("R"):
            R2[i - 1] += size
        elif what.startswith("C"):
            C2[i - 1] += size
        elif what.startswith("p"):
            bias = (i, size)
        else:
            leak = (i, size)
    first = solve_ivp(lambda _, p: derivative(p, C, R), (0.0, onset), p0, rtol=1e-10, atol=1e-12,
                      dense_output=True)
    second = solve_ivp(lambda _, p: derivative(p, C2, R2, leak), (onset, t[-1]), first.y[:, -1], rtol=1e-10,
                       atol=1e-12, dense_output=True)
    p = np.where(before[:, None], first.sol(np.minimum(t, onset)).T, second.sol(np.maximum(t, onset)).T)
    rng = np.random.default_rng(seed)
    y = p + rng.standard_normal(p.shape) * noise * p0
    if bias is not None:
        y[~before, bias[0] - 1] += bias[1]
    return t, y


def as_run(t, y, inputs: float = F_IN):
    """A :class:`bgc.data.runs.Run` of the readings (the inflow recorded as the model's input)."""
    from bgc.data.runs import Run

    return Run(np.asarray(t, dtype=float), {"f_in": np.full(len(t), inputs)},
               {f"p{i + 1}": y[:, i] for i in range(y.shape[1])}, {}, {}, (), "chain_reference")
