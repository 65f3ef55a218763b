"""A mode the data do not give, diagnosed, against the same data with the mode given.

    .venv/bin/python bench/hidden_mode.py [--runs 5] [--seed 1]
    .venv/bin/python bench/hidden_mode.py --plant thermostat [--sharp] [--runs 5] [--seed 1]
    .venv/bin/python bench/hidden_mode.py --plant ro [--runs 4] [--seed 1]

The level plant of docs/examples/level.yaml (a tank a pump fills, its
contactor switched by the tank's pressure with a hysteresis band: about 20
switches in a run of 600 samples), its data from solve_ivp on its equations
derived by hand (tests/hybrid_reference.py, ``level_run``: switch times
anywhere within a sample period). For each fault (none; the outlet clogged
by 40 %; the pump's line by 50 %; the tank a quarter smaller; the pressure
sensor biased by 0.03, about 7 of its noise stds) and each of ``--runs``
seeds, the onset drawn uniformly from 8 to 20 s: bgc diagnoses the run file
without its mode column (the mode hidden: read from the measurements, then
read again with the leading hypotheses' own equations) and with it (the
exact reference on the same data: the modes the plant was in). The table
gives per fault and per way the verdicts (isolated right, among candidates,
another fault, unexplained, not detected), the mean size error of those
isolated right, and the seconds per diagnosis, the two ways side by side.

``--plant thermostat``: tests/data/hybrid/thermostat.yaml's room heated by a
radiator whose valve a thermostat opens under 18 and shuts over 21 (about 12
switches in 200 samples), its data from solve_ivp on its equations derived
by hand (tests/hybrid_reference.py, ``thermostat_run``): fault-free, the
walls' R_w -30 %, the radiator's R_ra +50 %, the supply's R_v +50 %, the
room's sensor biased by 0.4 (about 4 of its noise stds) and the valve
stuck shut, each from an onset drawn from 40 to 60 min of a 100-min run;
``--sharp``: the thresholds exact (the model's tolerance taken out, the
plant's thresholds not drawn).

``--plant ro``: the autonomous RO plant of models/ro_hybrid.yaml (its three
valve settings switched by guards on the conductivity and the membrane
pressure and by a time in the secondary setting), its data from bgc's truth
simulator (no hand-derived RO exists to compare with), fault-free runs and
R_pipe clogged by 31 at a drawn onset, each diagnosed both ways.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import bgc  # noqa: E402
from hybrid_reference import (LEVEL_C, LEVEL_R_IN, LEVEL_R_OUT, THERMO_MODEL, THERMO_R_RA, THERMO_R_V,  # noqa: E402
                              THERMO_R_W, THERMO_TOLERANCE, level_csv, level_run, thermostat_csv, thermostat_run,
                              thermostat_sharp)
from stuck_switches import outcome_of  # noqa: E402  (bench/, the script's folder)

LEVEL = ROOT / "docs" / "examples" / "level.yaml"
RO = ROOT / "models" / "ro_hybrid.yaml"
#: The level plant's faults: (name, the value it takes, the fault model, its size).
LEVEL_FAULTS = {
    "none": None,
    "R_out +40 %": ("R_out", 1.4 * LEVEL_R_OUT, "R_out_abrupt", 0.4 * LEVEL_R_OUT),
    "R_in +50 %": ("R_in", 1.5 * LEVEL_R_IN, "R_in_abrupt", 0.5 * LEVEL_R_IN),
    "C_t -25 %": ("C_t", 0.75 * LEVEL_C, "C_t_abrupt", -0.25 * LEVEL_C),
    "p bias +0.03": ("p", 0.03, "p_offset_bias", 0.03),
}
#: The thermostat's faults: (name, the value it takes, the fault model, its size).
THERMOSTAT_FAULTS = {
    "none": None,
    "R_w -30 %": ("R_w", 0.7 * THERMO_R_W, "R_w_abrupt", -0.3 * THERMO_R_W),
    "R_ra +50 %": ("R_ra", 1.5 * THERMO_R_RA, "R_ra_abrupt", 0.5 * THERMO_R_RA),
    "R_v +50 %": ("R_v", 1.5 * THERMO_R_V, "R_v_abrupt", 0.5 * THERMO_R_V),
    "T_room bias +0.4": ("T_room", 0.4, "T_room_offset_bias", 0.4),
    "V stuck shut": ("V", 0.0, "V_stuck_off", None),
}
WAYS = ("hidden", "given")


def outcome(d, right: str | None) -> str:
    """What diagnosis ``d`` made of a run whose fault model is ``right`` (None: no fault)."""
    if right is None:
        return "right" if d.detection is None or d.verdict == "no fault" else "false alarm"
    return outcome_of(d, right)


def diagnose_both(session, hidden: Path, given: Path, right, size, rows: list, label: str) -> None:
    """Diagnose the run both ways; add (label, way, outcome, size error, seconds) to ``rows``."""
    for way, path in zip(WAYS, (hidden, given)):
        started = time.perf_counter()
        d = bgc.diagnose(session, data=path).diagnosis
        seconds = time.perf_counter() - started
        result = outcome(d, right)
        error = abs(d.estimate.value - size) / abs(size) if result == "right" and size else np.nan
        rows.append((label, way, result, error, seconds))
        print(f"  {label}, {way}: {d.verdict} {','.join(d.candidates)} ({seconds:.1f} s)", file=sys.stderr)


def plant_rows(session, faults: dict, runs: int, seed: int, folder: Path, onset_of, files) -> list:
    """The rows of ``runs`` runs per fault of ``faults`` (label: (name, value, fault model, size), or None),
    each run's seed and onset drawn in turn (``onset_of(rng)``), its files hidden and given written by
    ``files(run_seed, fault, onset, hidden path, given path)``, diagnosed both ways."""
    rng = np.random.default_rng(seed)
    rows: list = []
    for label, fault in faults.items():
        for r in range(runs):
            run_seed = int(rng.integers(1 << 30))
            onset = onset_of(rng)
            hidden, given = files(run_seed, None if fault is None else (onset, fault[0], fault[1]),
                                  folder / f"h{r}.csv", folder / f"g{r}.csv")
            diagnose_both(session, hidden, given, None if fault is None else fault[2],
                          None if fault is None else fault[3], rows, label)
    return rows


def level_rows(runs: int, seed: int, folder: Path) -> list:
    def files(run_seed, fault, hidden, given):
        times, modes, y_p, y_q, _ = level_run(run_seed, fault)
        return (level_csv(hidden, times, modes, y_p, y_q, False), level_csv(given, times, modes, y_p, y_q, True))

    return plant_rows(bgc.open(LEVEL), LEVEL_FAULTS, runs, seed, folder,
                      lambda rng: float(np.round(rng.uniform(8.0, 20.0), 2)), files)


def thermostat_rows(runs: int, seed: int, folder: Path, sharp: bool) -> list:
    def files(run_seed, fault, hidden, given):
        run = thermostat_run(run_seed, 200, fault, 0.0 if sharp else THERMO_TOLERANCE)
        return thermostat_csv(hidden, *run, False), thermostat_csv(given, *run, True)

    model = thermostat_sharp(folder) if sharp else THERMO_MODEL  # sharp: the thresholds exact
    return plant_rows(bgc.open(model), THERMOSTAT_FAULTS, runs, seed, folder,
                      lambda rng: float(np.round(rng.uniform(40.0, 60.0) * 2) / 2), files)  # a sample's time


def ro_rows(runs: int, seed: int, folder: Path) -> list:
    session = bgc.open(RO)
    rng = np.random.default_rng(seed)
    rows: list = []
    for label, scenario, right, size in (("none", None, None, None), ("R_pipe +31", "R_pipe:abrupt:31", "R_pipe_abrupt",
                                                                          31.0)):
        for r in range(runs):
            onset = int(rng.integers(100, 200))
            sim = bgc.simulate(session, "none" if scenario is None else f"{scenario}@{onset}", steps=300,
                               seed=int(rng.integers(1 << 30)))
            given = folder / f"ro_g{r}.csv"
            sim.write(given)
            lines = given.read_text().splitlines()
            header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
            cells = [line.split(",") for line in lines[header:]]
            mode = cells[0].index("mode")
            hidden = folder / f"ro_h{r}.csv"
            hidden.write_text("\n".join(lines[:header] + [",".join(c[:mode] + c[mode + 1:]) for c in cells]) + "\n")
            diagnose_both(session, hidden, given, right, size, rows, label)
    return rows


def table(rows: list, labels) -> None:
    print("| fault | way | runs | right | among candidates | another fault | unexplained | not detected | "
          "false alarm | mean size error of those right | seconds per diagnosis |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    seconds = defaultdict(list)
    for label in labels:
        for way in WAYS:
            mine = [r for r in rows if r[0] == label and r[1] == way]
            c = Counter(r[2] for r in mine)
            errors = [r[3] for r in mine if np.isfinite(r[3])]
            seconds[way] += [r[4] for r in mine]
            error = f"{100 * np.mean(errors):.1f} %" if errors else "-"
            print(f"| {label} | {way} | {len(mine)} | {c['right']} | {c['among candidates']} | {c['another fault']} | "
                  f"{c['unexplained']} | {c['not detected']} | {c['false alarm']} | {error} | "
                  f"{np.mean([r[4] for r in mine]):.1f} |")
    hidden, given = np.mean(seconds["hidden"]), np.mean(seconds["given"])
    print(f"\nseconds per diagnosis, mode hidden / mode given, measured side by side: {hidden:.1f} / {given:.1f} "
          f"= {hidden / given:.1f}x")
    for way in WAYS:
        right = sum(r[2] == "right" for r in rows if r[1] == way)
        print(f"{way}: right {right} of {sum(r[1] == way for r in rows)}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--plant", choices=("level", "thermostat", "ro"), default="level")
    p.add_argument("--runs", type=int, default=None, help="runs per fault (level, thermostat: 5, ro: 4)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--sharp", action="store_true", help="the thermostat's thresholds exact")
    a = p.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        if a.plant == "level":
            rows = level_rows(a.runs or 5, a.seed, Path(folder))
            table(rows, LEVEL_FAULTS)
        elif a.plant == "thermostat":
            rows = thermostat_rows(a.runs or 5, a.seed, Path(folder), a.sharp)
            table(rows, THERMOSTAT_FAULTS)
        else:
            rows = ro_rows(a.runs or 4, a.seed, Path(folder))
            table(rows, ("none", "R_pipe +31"))


if __name__ == "__main__":
    main()
