"""How close `bgc calibrate`'s estimates come to the truth, and how often
their 95 % intervals cover it (docs/calibrate.md, "Measured").

    .venv/bin/python bench/calibrate_accuracy.py MODEL [--steps 1000] [--seeds 20] [--estimate noise]
        [--fit-model OTHER.yaml]

Fault-free runs of MODEL simulated by the truth simulator (RK4, 8 times finer
than the filters) at the model's noise levels, seeds 100, 101, ...; each is
calibrated with ``bgc.open(FIT).calibrate(run, estimate)``, FIT the model
itself or ``--fit-model`` (the same plant with other values, e.g. a parameter
off: the truth is then MODEL's). Prints each run, then per estimate the mean
and rms relative error of the model file's value (a sensor's relative noise,
the process level, a parameter's value), the largest, and how many 95 %
intervals cover the truth; and the seconds per calibration.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import bgc
from bgc.runtime import runs, simulate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--estimate", default="noise")
    parser.add_argument("--fit-model", default=None, help="the model calibrated (default: MODEL)")
    args = parser.parse_args()
    truth = bgc.open(args.model)
    fit = bgc.open(args.fit_model) if args.fit_model else truth
    settings = truth.compiled.model.settings
    levels = {m.name: m.noise for m in truth.compiled.model.measurements}
    values = {p.name: p.value for p in truth.compiled.model.parameters}
    errors: dict[str, list[float]] = {}
    covers: dict[str, list[bool]] = {}
    seconds = []
    for seed in range(100, 100 + args.seeds):
        result = simulate.simulate(truth.compiled.numerics, simulate.SimulationOptions(steps=args.steps, seed=seed))
        run = runs.parse_run(simulate.to_csv(result), f"seed {seed}")
        start = time.perf_counter()
        c = fit.calibrate(run, args.estimate).calibration
        seconds.append(time.perf_counter() - start)
        for e in c.estimates:
            true = {"parameter": lambda: values[e.subject], "process_noise": lambda: settings.process_noise,
                    "measurement_noise": lambda: levels[e.subject]}[e.kind]()
            errors.setdefault(e.name, []).append(e.level / true - 1)
            covers.setdefault(e.name, []).append(bool(e.level_low < true < e.level_high))
        print(f"seed {seed}: " + ", ".join(f"{e.name} {e.level:.4g}" + ("" if e.identifiable else " (held)")
                                           for e in c.estimates) + f" ({seconds[-1]:.1f} s)", flush=True)
    print(f"\n{args.model}, {args.steps} samples, --estimate {args.estimate}"
          + (f", fitted model {args.fit_model}" if args.fit_model else "") + f", {args.seeds} seeds")
    print("| estimate | mean error | rms error | largest | 95 % interval covers |\n|---|---|---|---|---|")
    for name, err in errors.items():
        e = np.array(err)
        print(f"| {name} | {100 * e.mean():+.2f} % | {100 * np.sqrt((e ** 2).mean()):.2f} % | "
              f"{100 * np.abs(e).max():.1f} % | {sum(covers[name])}/{len(e)} |")
    print(f"\nseconds per calibration: mean {np.mean(seconds):.1f}, {np.min(seconds):.1f} to {np.max(seconds):.1f}")


if __name__ == "__main__":
    main()
