"""Independent simulators of the relay circuit (tests/data/hybrid/relay_rl.yaml,
docs/examples/relay.yaml) and of the level plant (docs/examples/level.yaml)
for the tests and benches: scipy's solve_ivp, with events, on their
equations derived by hand."""

from __future__ import annotations

from pathlib import Path

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


#: The level plant's values (the model file's), its level switch's band, its run.
LEVEL_C, LEVEL_R_IN, LEVEL_R_OUT, LEVEL_E, LEVEL_HIGH, LEVEL_LOW = 2.0, 1.0, 1.5, 2.0, 0.8, 0.4
LEVEL_DT, LEVEL_STEPS, LEVEL_NOISE, LEVEL_DISTURBANCE = 0.05, 600, 0.004, 0.01


def level_run(seed: int, fault: tuple[float, str, float] | None = None, steps: int = LEVEL_STEPS):
    """The level plant of docs/examples/level.yaml (a tank a pump fills, its
    contactor switched by the tank's pressure: OFF over 0.8, ON under 0.4)
    by solve_ivp on its equations derived by hand: with the pump running,
    C p' = (E - p)/R_in - p/R_out + w; with it off, C p' = -p/R_out + w (w:
    an inflow disturbance, constant over each sample period); the switch's
    crossings found by solve_ivp's events (anywhere within a sample
    period); the sensors read p and q_out = p/R_out with Gaussian noise of
    std LEVEL_NOISE (the model's declared levels). Returns the times, the
    true mode per sample (1 filling, 2 draining), p and q_out as read, and
    the switch times; ``fault``: (time, name, value): R_in, R_out or C_t
    takes the value from then on, or sensor p reads the value more, or
    (name ``P``, the value unused) the pump's contactor turns ON without a
    command: the pump runs from then on, whatever the mode, until the level
    switch asks for it ON (the mode filling entered), and after that as the
    modes say."""
    rng = np.random.default_rng(seed)
    times = LEVEL_DT * np.arange(1, steps + 1)
    p, mode, t = 0.6, 1, 0.0
    truth, modes, switches = [], [], []
    released = False  # the uncommanded pump's flag, cleared by a mode that asks for the pump ON

    def value(name: str, nominal: float, at: float) -> float:
        return fault[2] if fault and fault[1] == name and at >= fault[0] - 1e-12 else nominal

    for end in times:
        w = LEVEL_DISTURBANCE * rng.standard_normal()
        while t < end - 1e-12:
            stop = fault[0] if fault and t < fault[0] - 1e-12 < end else end
            r_in, r_out, c = value("R_in", LEVEL_R_IN, t), value("R_out", LEVEL_R_OUT, t), value("C_t", LEVEL_C, t)
            forced = bool(fault and fault[1] == "P" and t >= fault[0] - 1e-12 and not released)
            on = mode == 1 or forced

            def f(_, x, r_in=r_in, r_out=r_out, c=c, on=on, w=w):
                return [(((LEVEL_E - x[0]) / r_in if on else 0.0) - x[0] / r_out + w) / c]

            def crossed(_, x, filling=mode == 1):  # the level switch's guards: the mode's, not the pump's
                return x[0] - (LEVEL_HIGH if filling else LEVEL_LOW)

            crossed.terminal, crossed.direction = True, 1 if mode == 1 else -1
            sol = solve_ivp(f, (t, stop), [p], events=crossed, rtol=1e-10, atol=1e-12)
            if sol.status == 1:
                t, p, mode = float(sol.t_events[0][0]), float(sol.y_events[0][0][0]), 2 if mode == 1 else 1
                released = released or (forced and mode == 1)
                switches.append(t)
            else:
                t, p = stop, float(sol.y[0, -1])
        truth.append(p)
        modes.append(mode)
    truth = np.array(truth)
    q = truth / np.array([value("R_out", LEVEL_R_OUT, s) for s in times])
    y_p = truth + LEVEL_NOISE * rng.standard_normal(steps) + np.array([value("p", 0.0, s) for s in times])
    y_q = q + LEVEL_NOISE * rng.standard_normal(steps)
    return times, np.array(modes), y_p, y_q, switches


def level_csv(path: Path, times, modes, y_p, y_q, with_mode: bool) -> Path:
    """A run file of :func:`level_run`'s samples, with the mode column or without."""
    lines = ["time," + ("mode," if with_mode else "") + "u:E,y:p,y:q_out"]
    for t, m, a, b in zip(times, modes, y_p, y_q):
        lines.append(f"{t:.10g}," + (f"{m}," if with_mode else "") + f"{LEVEL_E},{float(a)!r},{float(b)!r}")
    path.write_text("\n".join(lines) + "\n")
    return path


#: The thermostat of tests/data/hybrid/thermostat.yaml: its values (the model file's), its thresholds and their
#: std, its sample period, its sensors' noise (the model's: relative 0.01, 0.005, 0.02 of 30, 19, 40) and the heat
#: disturbances into the radiator and the room (held over each sample period).
THERMO_R_V, THERMO_C_R, THERMO_R_RA, THERMO_C_A, THERMO_R_W, THERMO_T_S = 0.5, 2.0, 1.0, 20.0, 2.0, 50.0
THERMO_LOW, THERMO_HIGH, THERMO_TOLERANCE, THERMO_DT = 18.0, 21.0, 0.15, 0.5
THERMO_NOISE, THERMO_DISTURBANCE = (0.3, 0.095, 0.8), (0.2, 0.3)
THERMO_SENSORS = ("T_rad", "T_room", "q_s")
#: Its model file.
THERMO_MODEL = Path(__file__).resolve().parent / "data" / "hybrid" / "thermostat.yaml"


def thermostat_sharp(folder: Path) -> Path:
    """The thermostat's model with its thresholds exact (the guards'
    tolerance taken out), written into ``folder``."""
    text = THERMO_MODEL.read_text(encoding="utf-8")
    sharp = text.replace(f", tolerance: {THERMO_TOLERANCE:g}", "")
    assert sharp != text and "tolerance" not in sharp.split("transitions:")[1]
    path = Path(folder) / "thermostat.yaml"
    path.write_text(sharp, encoding="utf-8")
    return path


def thermostat_run(seed: int, steps: int = 600, fault: tuple[float, str, float] | None = None,
                   tolerance: float = THERMO_TOLERANCE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The thermostat (a room heated by a radiator whose valve opens when the
    room falls under 18 and shuts over 21) by solve_ivp on its equations
    derived by hand, from T_r = 30, T_a = 19, heating: C_r T_r' = (T_s -
    T_r)/R_v [valve open] - (T_r - T_a)/R_ra + w_r, C_a T_a' = (T_r -
    T_a)/R_ra - T_a/R_w + w_a; each threshold drawn N(0, ``tolerance``^2)
    about its value anew at each visit of the mode; the valve's moves found
    by solve_ivp's events. Returns the times, the mode per sample (1
    heating, 2 idle) and the readings T_rad, T_room, q_s (the supply's heat
    flow, 0 with the valve shut), each with Gaussian noise of
    :data:`THERMO_NOISE`. ``fault``: (time, name, value), the time a
    sample's: R_v, R_ra or R_w takes the value from then on, or sensor
    T_room or T_rad reads the value more, or (name ``V``, the value unused)
    the valve sticks shut."""
    rng = np.random.default_rng(seed)
    x, on, t = np.array([30.0, 19.0]), True, 0.0
    threshold = THERMO_HIGH + rng.normal(0.0, tolerance)
    times, modes, readings = [], [], []

    def value(name: str, nominal: float, at: float) -> float:
        return fault[2] if fault and fault[1] == name and at >= fault[0] - 1e-9 else nominal

    for k in range(1, steps + 1):
        end = k * THERMO_DT
        wr, wa = rng.normal(0.0, THERMO_DISTURBANCE[0]), rng.normal(0.0, THERMO_DISTURBANCE[1])
        start = end - THERMO_DT  # the step's values (a fault's time is a sample's)
        r_v, r_ra, r_w = (value(n, v, start) for n, v in (("R_v", THERMO_R_V), ("R_ra", THERMO_R_RA),
                                                           ("R_w", THERMO_R_W)))
        stuck = bool(fault and fault[1] == "V" and start >= fault[0] - 1e-9)
        while t < end - 1e-12:
            heating = on and not stuck

            def rhs(_, s, heating=heating):
                q = (THERMO_T_S - s[0]) / r_v if heating else 0.0
                return [(q - (s[0] - s[1]) / r_ra + wr) / THERMO_C_R, ((s[0] - s[1]) / r_ra - s[1] / r_w + wa) / THERMO_C_A]

            def crossing(_, s, level=threshold):
                return s[1] - level
            crossing.terminal, crossing.direction = True, (1 if on else -1)
            sol = solve_ivp(rhs, (t, end), x, events=crossing, rtol=1e-10, atol=1e-10)
            x, t = sol.y[:, -1], float(sol.t[-1])
            if sol.status == 1:  # the room reached this visit's threshold: the mode changes, a new threshold
                on = not on
                threshold = (THERMO_HIGH if on else THERMO_LOW) + rng.normal(0.0, tolerance)
            if end - t < 1e-12:
                t = end
        q = (THERMO_T_S - x[0]) / r_v if on and not stuck else 0.0
        times.append(end)
        modes.append(1 if on else 2)
        bias = np.array([value("T_rad", 0.0, end), value("T_room", 0.0, end), 0.0])
        readings.append(np.array([x[0], x[1], q]) + bias + rng.normal(0.0, 1.0, 3) * THERMO_NOISE)
    return np.array(times), np.array(modes, dtype=float), np.array(readings)


def thermostat_csv(path: Path, times, modes, readings, with_mode: bool) -> Path:
    """A run file of :func:`thermostat_run`'s samples, with the mode column or without."""
    rows = ["time," + ("mode," if with_mode else "") + "u:T_s," + ",".join(f"y:{y}" for y in THERMO_SENSORS)]
    rows += [f"{a:.6g}," + (f"{int(m)}," if with_mode else "") + f"{THERMO_T_S:g},{b:.9g},{c:.9g},{d:.9g}"
             for a, m, (b, c, d) in zip(times, modes, readings)]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path
