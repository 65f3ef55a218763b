"""An independent simulator of the relay circuit (tests/data/hybrid/relay_rl.yaml,
docs/examples/relay.yaml) for the tests: scipy's solve_ivp, with events, on
its equations derived by hand."""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

RELAY_MODES = ("open", "closed", "unpowered")
#: The relay's values (the model file's), and its automaton.
V, R_s, L, C, R_load, R_aux = 8.0, 0.5, 0.2, 2.0, 10.0, 0.5
DT, STEPS, TRIP, BACK = 0.01, 3000, 12.0, 5.0


def derivative(mode: str, x, r_aux: float = R_aux) -> list:
    """d(i, v)/dt in ``mode``, by hand: L di/dt = V - R_s i - v with the
    supply on (i = 0 with it off); C dv/dt = i - v/R_load (- v/R_aux with
    the relay closed)."""
    i, v = x
    di = 0.0 if mode == "unpowered" else (V - R_s * i - v) / L
    dv = (i - v / R_load - (v / r_aux if mode == "closed" else 0.0)) / C
    return [di, dv]


def sampled(end: float, trip: float = TRIP, fault: tuple[float, float] | None = None):
    """The exact run at the sample times DT, 2 DT, ... ``end``: (times,
    states (T, 2), the mode's number at each sample (1 open, 2 closed, 3
    unpowered), the switch times); ``fault`` (time, value): R_aux steps to
    that value then."""
    switches, at = reference(end, trip, fault)
    times = DT * np.arange(1, int(round(end / DT)) + 1)
    states = np.array([at(t) for t in times])
    modes = np.ones(len(times), dtype=int)
    for t, mode in switches:
        modes[times >= t - 1e-12] = RELAY_MODES.index(mode) + 1
    return times, states, modes, [t for t, _ in switches]


def reference(end: float, trip: float = TRIP, fault: tuple[float, float] | None = None):
    """The noise-free relay by solve_ivp: (switch times and modes, a function
    of t giving (i, v)), by hand: L di/dt = V - R_s i - v with the supply on
    (i = 0 with it off); C dv/dt = i - v/R_load (- v/R_aux with the relay
    closed); the relay closes when v rises through 6 and opens when it
    falls through 4; the operator trips the supply at TRIP; it closes again
    BACK later, into the open relay, the coil's current reset to 0;
    ``fault`` (time, value): R_aux takes that value from that time on."""
    at_fault, faulty = fault if fault is not None else (np.inf, R_aux)

    def rhs(mode, after):
        return lambda t, x: derivative(mode, x, faulty if after else R_aux)

    def crossing(level, direction):
        def event(t, x):
            return x[1] - level
        event.terminal, event.direction = True, direction
        return event

    t, x, mode, pieces, switches = 0.0, np.array([0.0, 0.0]), "open", [], []
    while t < end - 1e-12:
        if mode == "unpowered":
            stop, events = min(t + BACK, end), []
        else:
            stop = min(trip, end) if t < trip else end
            events = [crossing(6.0, 1)] if mode == "open" else [crossing(4.0, -1)]
        natural = stop
        if t < at_fault - 1e-12:
            stop = min(stop, at_fault)  # the fault's instant ends a piece: the equations change there
        sol = solve_ivp(rhs(mode, t >= at_fault - 1e-12), (t, stop), x, events=events, dense_output=True,
                        rtol=1e-10, atol=1e-12)
        pieces.append((t, sol.t[-1], mode, sol.sol))
        t, x = sol.t[-1], sol.y[:, -1].copy()
        if sol.status != 1 and stop < natural:
            continue  # the fault struck: the same mode goes on with the new R_aux
        if sol.status == 1:  # a guard fired
            mode = "closed" if mode == "open" else "open"
        elif mode == "unpowered":
            mode, x[0] = "open", 0.0  # the timed transition back, its reset
        elif abs(t - trip) < 1e-12:
            mode, x[0] = "unpowered", 0.0  # the contactor trips: no current through the coil
        else:
            break
        switches.append((t, mode))

    def at(time):  # at a switch's time, the state after it (as a run's row holds it)
        for start, stop, m, dense in reversed(pieces):
            if start <= time <= stop:
                return dense(time)
        raise ValueError(time)
    return switches, at


