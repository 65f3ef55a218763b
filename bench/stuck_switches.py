"""Stuck switches diagnosed on data from another simulator: the relay of
docs/examples/relay.yaml (its contactor S and relay K switched by an
operator: the data's mode column), solved by scipy's solve_ivp on its
equations derived by hand, piece by piece between the plant's switches.

    .venv/bin/python bench/stuck_switches.py [--runs 60] [--steps 600] [--seed 1] [--late]
    .venv/bin/python bench/stuck_switches.py --plant ro [--runs 30] [--steps 600]
    .venv/bin/python bench/stuck_switches.py --plant supply [--runs 60] [--steps 600]

Each run draws an operator's schedule (a change of mode every 0.6 to 1.5 s
among open, closed and unpowered: the supply on with the relay open or
closed, or off), a fault (K stuck ON, K stuck OFF, S stuck OFF, a step of
R_aux or R_load, or none, in turn), its onset (uniform over the first
two-thirds of the run; with ``--late``, over its last 12 %: the fault then
acts over a few dozen samples at most, which puts many runs near the edge of
what the data can tell), and the measurement noise (the model's 0.01, or
twice it). The plant runs in the configuration the fault makes (a stuck
switch from its onset, whatever the mode says). bgc diagnoses each run with
the model as written (GPF, 500 particles).

A stuck switch is *separable* in a run when the plant's noise-free
response differs from what the mode column says (the same run with no
fault) by more than 3 measurement-noise stds on some sensor for at least 10
samples: otherwise no diagnosis could tell it (a switch stuck in the
position the operator never moves it from changes nothing). The exact
reference is that noise-free difference itself. It is *predicted separable*
when ``bgc distinguish`` of the run's scenario, through the run's modes at
the model's noise, predicts no rival in its ambiguity group and an ideal
detector held at 1 % false alarms per run that sees it with probability
0.95 or more (the issue's target: isolated in 95 % of those runs). The
tables give, per fault kind, by each of the two: the runs, those separable,
and of those how many were isolated as the right fault, named among
ambiguous candidates, called another fault, unexplained, or not detected;
and for the runs with no fault or a parametric one, how often a stuck
switch was named.

``--plant ro``: the RO plant of models/ro_hybrid_valve.yaml (its valve set
by an operator through its cycle, primary, secondary, purge, primary, a
change every 20 to 60 s), one of its six stuck valves per run in turn, the data from bgc's
truth simulator (RK4 on 8 substeps of each mode's equations: not the
filters' code, but bgc's equations; no hand-derived RO to compare with),
the model's noise; separable as above, from the simulator's noise-free
runs with and without the fault.

``--plant supply``: the supply of docs/examples/switched_rc.yaml (its
contactor S closed and opened by an operator, a change every 1 to 6 s), one
fault per run in turn: S stuck ON or OFF, S turned ON or OFF without a
command (from its onset until the operator next asks for S in that state),
a step of R_load, or none; the data from solve_ivp on the supply's
equations derived by hand (docs/examples/switched_rc.yaml), at the model's
noise (twice it is a plant noisier than its model, which the diagnosis
calls a mismatch: not this bench's question). The steps of R_load isolated
are set against the simulator's: each run's line says the test that alarmed
and the size's estimate and interval, and a last line the size's error, the
interval's coverage and the onset's error over them. A stuck switch and one that moved by itself are the same
plant until the operator's next command of the switch: where none comes
after the onset, ``bgc distinguish`` puts the other in the ambiguity group,
and the run is not predicted separable.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

MODEL = ROOT / "docs" / "examples" / "relay.yaml"
R_S, L, C, R_LOAD, R_AUX, V = 0.5, 0.2, 2.0, 10.0, 0.5, 8.0
DT = 0.01
#: The modes' switches ON (S the contactor, K the relay), by mode number.
ON = {1: {"S"}, 2: {"S", "K"}, 3: set()}
FAULTS = ("K:stuck_on", "K:stuck_off", "S:stuck_off", "R_aux:abrupt", "R_load:abrupt", "none")


def schedule(rng, end: float) -> list[tuple[float, int]]:
    """An operator's changes of mode: (time, mode number), from open at 0."""
    out, t, mode = [(0.0, 1)], 0.0, 1
    while True:
        t += rng.uniform(0.6, 1.5)
        if t >= end:
            return out
        mode = int(rng.choice([m for m in (1, 2, 3) if m != mode]))
        out.append((t, mode))


def plant(on: set, r_aux: float, r_load: float):
    """The relay's equations in the configuration ``on`` (i = f3, v = e6):
    S ON: L di/dt = V - R_s i - v; S OFF: i = 0 (the coil's current cut);
    C dv/dt = i - v / R_load (- v / R_aux with K ON)."""
    def f(t, x):
        i, v = x
        di = (V - R_S * i - v) / L if "S" in on else 0.0
        return [di, ((i if "S" in on else 0.0) - v / r_load - (v / r_aux if "K" in on else 0.0)) / C]
    return f


def truth(times, modes: list[tuple[float, int]], fault: str, onset: float, size: float) -> np.ndarray:
    """The plant's states at ``times``, solved piece by piece between the
    changes of its configuration (the operator's and the fault's)."""
    name, kind = fault.split(":") if fault != "none" else ("", "")
    cuts = sorted({t for t, _ in modes} | ({onset} if fault != "none" else set()) | {times[-1] + DT})
    out = np.empty((len(times), 2))
    x = [0.0, 0.0]
    for start, end in zip(cuts[:-1], cuts[1:]):
        mode = [m for t, m in modes if t <= start + 1e-12][-1]
        on = set(ON[mode])
        r_aux, r_load = R_AUX, R_LOAD
        if start >= onset - 1e-12:
            if kind == "stuck_on":
                on.add(name)
            elif kind == "stuck_off":
                on.discard(name)
            elif name == "R_aux":
                r_aux += size
            elif name == "R_load":
                r_load += size
        if "S" not in on:
            x[0] = 0.0
        inside = (times >= start - 1e-9) & (times < end - 1e-9)
        sol = solve_ivp(plant(on, r_aux, r_load), (start, end), x, dense_output=True, rtol=1e-9, atol=1e-11)
        out[inside] = sol.sol(times[inside]).T
        if "S" not in on:
            out[inside, 0] = 0.0
        x = list(sol.sol(end))
    return out


def outcome_of(d, fault: str) -> str:
    """What diagnosis ``d`` made of a run with ``fault`` (``NAME:KIND``)."""
    right = fault.replace(":", "_")
    if d.detection is None or d.verdict == "no fault":
        return "not detected"
    if d.verdict == "isolated":
        return "right" if d.candidates == (right,) else "another fault"
    if d.verdict == "ambiguous":
        return "among candidates" if right in d.candidates else "another fault"
    return d.verdict


def predicted(session, column, times, fault: str, onset: float, modes: str | None = None) -> bool:
    """Whether ``bgc distinguish`` predicts stuck switch ``fault`` from
    ``onset`` separable (module docstring) over the run's mode column
    ``column`` (the mode's number per sample) at the model's noise: through
    the API where the model lets the run's changes be its controlled ones
    (``modes``: the schedule's text), else by the prediction's own functions
    on that column (the relay's guard-driven changes an operator forces)."""
    import bgc
    from bgc.analysis import distinguish as distinction
    from bgc.model import linear
    from bgc.model.protocol import onset_sample

    if modes is not None:
        (d,) = bgc.distinguishability(session, f"{fault}@{onset:g}", steps=len(times), modes=modes).distinctions
    else:
        package = session.package
        families = distinction.prepare(package, linear.scenario_inputs(package, len(times), (), column))
        from bgc.api.distinguish import _stuck_candidates

        priors = {f.parameter: f.prior for f in session.view.model.faults} | \
            {s.junction: s.prior for s in _stuck_candidates(session.view)}
        d = distinction.distinguish(families, fault.replace(":", "_"), 1.0, onset_sample(times, onset), priors)
    return d.power(0.01) >= 0.95 and not d.group


def table(rows: list, faults, what: str, which: int = 1, title: str = "separable") -> None:
    """Print, per fault of ``faults``, its runs (``rows``: fault, separable,
    outcome, ..., predicted separable), those separable (``which``: the
    row's entry that says it) and their outcomes, and the share of the
    separable ones isolated right (``what``: how the faults are called)."""
    print(f"| fault | runs | {title} | isolated right | among candidates | another fault | unexplained | "
          "not detected |")
    print("|---|---|---|---|---|---|---|---|")
    for fault in faults:
        mine = [r for r in rows if r[0] == fault]
        c = Counter(r[2] for r in mine if r[which])
        print(f"| {fault} | {len(mine)} | {sum(bool(r[which]) for r in mine)} | {c['right']} | "
              f"{c['among candidates']} | {c['another fault']} | {c['unexplained']} | {c['not detected']} |")
    sep = [r for r in rows if r[0] in faults and r[which]]
    right = sum(r[2] == "right" for r in sep)
    print(f"\n{what} isolated right where {title}: {right} of {len(sep)} ({100 * right / max(len(sep), 1):.1f} %)")


def mode_at(modes: list[tuple[float, int]], t: float) -> int:
    """The mode number an operator's changes ``modes`` ((time, mode) pairs, from time 0) have at ``t``."""
    return [m for at, m in modes if at <= t + 1e-9][-1]


def run_text(times, modes, ys, sensors=("i_L", "v_C"), voltage: float = V) -> str:
    """A run file of readings ``ys`` (of ``sensors``) under the supply ``voltage``, its mode column the operator's."""
    lines = ["time,mode,u:V," + ",".join(f"y:{y}" for y in sensors)]
    for t, row in zip(times, ys):
        lines.append(f"{t:.10g},{mode_at(modes, t)},{voltage}," + ",".join(repr(float(v)) for v in row))
    return "\n".join(lines) + "\n"


def summary(rows: list, faults, others, what: str, which: int, seconds: float, runs: int, other_line) -> None:
    """Print the tables of the switch faults ``faults`` (separable by the
    noise-free criterion, then by the prediction: the row's entry ``which``),
    a line per other fault of ``others`` (``other_line(fault, its rows)``), and the CPU."""
    print()
    table(rows, faults, what)
    print()
    table(rows, faults, what, which, "predicted separable")
    for fault in others:
        print(other_line(fault, [r for r in rows if r[0] == fault]))
    print(f"CPU {seconds:.0f} s ({seconds / max(runs, 1):.1f} s per run)")


def main(argv=None) -> int:
    import warnings

    import bgc
    from bgc.data import runs

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=60)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--plant", choices=("relay", "ro", "supply"), default="relay")
    parser.add_argument("--late", action="store_true",
                        help="the relay's onsets over the run's last 12 %% only: a fault seen over a few dozen "
                             "samples at most, many runs near the edge of what the data can tell")
    args = parser.parse_args(argv)
    if args.plant == "ro":
        return ro(args)
    if args.plant == "supply":
        return supply(args)
    session = bgc.open(MODEL, backend="numpy")
    times = DT * np.arange(1, args.steps + 1)
    end = float(times[-1])
    rows = []
    started = time.process_time()
    for k in range(args.runs):
        rng = np.random.default_rng([args.seed, k])
        fault = FAULTS[k % len(FAULTS)]
        modes = schedule(rng, end)
        onset = float(rng.uniform(0.88 * end, end - DT)) if args.late else float(rng.uniform(0.1, 2 * end / 3))
        size = float(rng.uniform(0.3, 0.8)) * (R_AUX if fault.startswith("R_aux") else R_LOAD)
        noise = 0.01 * (1 + k % 2)
        x = truth(times, modes, fault, onset, size)
        nominal = truth(times, modes, "none", onset, 0.0)
        separable = int((np.abs(x - nominal) > 3 * noise).any(axis=1).sum()) >= 10
        ys = x + noise * rng.standard_normal(x.shape)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = bgc.diagnose(session, runs.parse_run(run_text(times, modes, ys), f"run{k}.csv"), particles=500,
                             seed=k).diagnosis
        outcome = outcome_of(d, fault)
        stuck_named = any("stuck" in c for c in d.candidates)
        column = [mode_at(modes, t) for t in times]
        told = predicted(session, column, times, fault, onset) if "stuck" in fault else False
        rows.append((fault, separable, outcome, stuck_named, noise, told))
        print(f"run {k:3d} {fault:14s} onset {onset:5.2f} noise {noise:.2f} separable {separable!s:5s} "
              f"predicted {told!s:5s} -> {d.verdict}: {', '.join(d.candidates) or '-'}", flush=True)
    def other_line(fault, mine):
        c = Counter(r[2] for r in mine)
        return (f"{fault}: {len(mine)} runs; {c['right']} isolated right, a stuck switch named in "
                f"{sum(r[3] for r in mine)}; outcomes {dict(c)}")

    summary(rows, FAULTS[:3], FAULTS[3:], "stuck switches", 5, time.process_time() - started, args.runs, other_line)
    return 0


RO = ROOT / "models" / "ro_hybrid_valve.yaml"
RO_FAULTS = ("J_brine:stuck_on", "J_brine:stuck_off", "J_back:stuck_on", "J_back:stuck_off", "J_aes:stuck_on",
             "J_aes:stuck_off")


def ro(args) -> int:
    """The RO's stuck valves (module docstring)."""
    import bgc

    session = bgc.open(RO, backend="numpy")
    dt = session.view.model.settings.dt
    end = args.steps * dt
    names = ("primary", "secondary", "purge")
    rows = []
    started = time.process_time()
    for k in range(args.runs):
        rng = np.random.default_rng([args.seed, 100, k])
        fault = RO_FAULTS[k % len(RO_FAULTS)]
        t, mode, changes = 0.0, 0, []
        while True:
            t += float(rng.uniform(20.0, 60.0))
            if t >= end - dt:
                break
            mode = (mode + 1) % 3  # the model's controlled transitions: primary, secondary, purge, primary
            changes.append(f"{names[mode]}@{round(t / dt) * dt:g}")
        modes = ",".join(changes)
        onset = round(float(rng.uniform(0.05, 2 / 3)) * end / dt) * dt
        scenario = f"{fault}@{onset:g}"
        quiet = dict(steps=args.steps, modes=modes, process_noise=0.0, measurement_noise=1e-12)  # noise-free, to rounding
        clean = bgc.simulate(RO, scenario, seed=k, **quiet)
        healthy = bgc.simulate(RO, "none", seed=k, **quiet)
        std = np.asarray(session.view.numerics.noise.measurement, dtype=float)
        sensors = [m.name for m in session.view.model.measurements]
        y = np.column_stack([clean.measurements[n] for n in sensors])
        y0 = np.column_stack([healthy.measurements[n] for n in sensors])
        separable = int((np.abs(y - y0) > 3 * std).any(axis=1).sum()) >= 10
        sim = bgc.simulate(RO, scenario, seed=k, steps=args.steps, modes=modes)
        d = bgc.diagnose(session, sim, particles=500, seed=k).diagnosis
        told = predicted(session, None, sim.time, fault, onset, modes)
        rows.append((fault, separable, outcome_of(d, fault), told))
        print(f"run {k:3d} {fault:17s} onset {onset:6.1f} modes {modes[:60]:60s} separable {separable!s:5s} "
              f"predicted {told!s:5s} -> {d.verdict}: {', '.join(d.candidates) or '-'}", flush=True)
    summary(rows, RO_FAULTS, (), "stuck valves", 3, time.process_time() - started, args.runs, None)
    return 0


SUPPLY = ROOT / "docs" / "examples" / "switched_rc.yaml"
SUPPLY_FAULTS = ("S:stuck_on", "S:stuck_off", "S:uncommanded_on", "S:uncommanded_off", "R_load:abrupt", "none")
#: The supply's values (docs/examples/switched_rc.yaml) and its sensors' noise stds (0.02 of v_C's 8 V and
#: i_s's 10 A: the model's MEASUREMENT_STD).
SUPPLY_V, SUPPLY_R_S, SUPPLY_C, SUPPLY_R_LOAD, SUPPLY_DT = 10.0, 1.0, 1.0, 4.0, 0.05
SUPPLY_STD = np.array([0.16, 0.2])


def switch_state(fault: str, onset: float, modes: list[tuple[float, int]], t: float) -> bool:
    """Whether the supply's contactor S is ON at time ``t`` (mode 1, closed,
    asks it ON; mode 2, open, OFF): as commanded, stuck from the onset, or
    moved by itself at the onset until the first command (at or after it)
    that asks for it in that state, by hand."""
    commanded = mode_at(modes, t) == 1
    name, _, kind = fault.partition(":")
    if name != "S" or t < onset - 1e-12:
        return commanded
    state = kind.endswith("_on")
    if kind.startswith("stuck"):
        return state
    asks = [onset] + [at for at, _ in modes if onset < at <= t + 1e-12]  # the commands since the onset
    released = any((mode_at(modes, a) == 1) == state for a in asks)
    return commanded if released else state


def supply_run(times, modes, fault: str, onset: float, size: float) -> np.ndarray:
    """The supply's noise-free readings (v_C, i_s) at ``times``, solved piece
    by piece between the changes of its configuration by solve_ivp."""
    cuts = sorted({t for t, _ in modes} | {onset, times[-1] + SUPPLY_DT})
    out = np.empty((len(times), 2))
    v = 0.0
    for start, end in zip(cuts[:-1], cuts[1:]):
        on = switch_state(fault, onset, modes, start)
        r_load = SUPPLY_R_LOAD + (size if fault == "R_load:abrupt" and start >= onset - 1e-12 else 0.0)

        def f(_, x, on=on, r_load=r_load):
            return [((SUPPLY_V - x[0]) / SUPPLY_R_S if on else 0.0) / SUPPLY_C - x[0] / (r_load * SUPPLY_C)]

        inside = (times >= start - 1e-9) & (times < end - 1e-9)
        sol = solve_ivp(f, (start, end), [v], dense_output=True, rtol=1e-10, atol=1e-12)
        out[inside, 0] = sol.sol(times[inside])[0]
        out[inside, 1] = np.where(on, (SUPPLY_V - out[inside, 0]) / SUPPLY_R_S, 0.0)
        v = float(sol.sol(end)[0])
    return out


def supply(args) -> int:
    """The supply's switch faults (module docstring)."""
    import warnings

    import bgc
    from bgc.data import runs

    session = bgc.open(SUPPLY, backend="numpy")
    times = SUPPLY_DT * np.arange(1, args.steps + 1)
    end = float(times[-1])
    names = {1: "closed", 2: "open"}
    rows, steps = [], []
    started = time.process_time()
    for k in range(args.runs):
        rng = np.random.default_rng([args.seed, 200, k])
        fault = SUPPLY_FAULTS[k % len(SUPPLY_FAULTS)]
        modes, t, mode = [(0.0, 1)], 0.0, 1
        while True:
            t = round((t + float(rng.uniform(1.0, 6.0))) / SUPPLY_DT) * SUPPLY_DT
            if t >= end:
                break
            mode = 3 - mode
            modes.append((t, mode))
        text = ",".join(f"{names[m]}@{at:g}" for at, m in modes[1:])
        onset = round(float(rng.uniform(0.05, 2 / 3)) * end / SUPPLY_DT) * SUPPLY_DT
        size = float(rng.uniform(0.3, 0.8)) * SUPPLY_R_LOAD
        scale = 1
        y = supply_run(times, modes, fault, onset, size)
        separable = int((np.abs(y - supply_run(times, modes, "none", onset, 0.0)) > 3 * scale * SUPPLY_STD)
                        .any(axis=1).sum()) >= 10
        ys = y + scale * SUPPLY_STD * rng.standard_normal(y.shape)
        text_run = run_text(times, modes, ys, ("v_C", "i_s"), SUPPLY_V)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = bgc.diagnose(session, runs.parse_run(text_run, f"run{k}.csv"), seed=k).diagnosis
        told = predicted(session, None, times, fault, onset, text) if fault.startswith("S:") else False
        rows.append((fault, separable, outcome_of(d, fault), told))
        sized = ""
        if fault == "R_load:abrupt" and rows[-1][2] == "right":  # the step's size and onset against the truth
            e = d.best.estimate
            steps.append((e.value / size - 1.0, e.low <= size <= e.high, d.onset - onset))
            sized = (f" (the {d.detection.test} test; size {e.value:.3f} [{e.low:.3f}, {e.high:.3f}] against "
                     f"{size:.3f}, onset {d.onset:.2f})")
        print(f"run {k:3d} {fault:18s} onset {onset:5.2f} separable {separable!s:5s} "
              f"predicted {told!s:5s} -> {d.verdict}: {', '.join(d.candidates) or '-'}{sized}", flush=True)
    summary(rows, SUPPLY_FAULTS[:4], SUPPLY_FAULTS[4:], "switch faults", 3, time.process_time() - started,
            args.runs, lambda fault, mine: f"{fault}: {len(mine)} runs; outcomes {dict(Counter(r[2] for r in mine))}")
    if steps:
        errors, covers, onsets = zip(*steps)
        print(f"R_load's steps isolated: size error {100 * min(errors):+.1f} to {100 * max(errors):+.1f} % (mean "
              f"|error| {100 * float(np.mean(np.abs(errors))):.1f} %), the 95 % interval holding the truth in "
              f"{sum(covers)} of {len(covers)}, onset error {min(onsets):+.2f} to {max(onsets):+.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
