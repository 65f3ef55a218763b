"""``bgc simulate``: the plant simulated (the truth), with noise and a fault, to a run file."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..errors import BgcError, printable
from .common import add_columns_option, add_prior_option, add_signal_option, parse_noise, seed, signals_of


def add_parser(sub) -> None:
    p = sub.add_parser("simulate", help="simulate the plant (truth) with noise and an injected fault, to CSV")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--steps", type=int, default=None, help="number of samples (default: the model's)")
    p.add_argument("--fault", metavar="NAME:KIND:MAGNITUDE@TIME",
                   help="inject a fault, e.g. R_pipe:incipient:0.5@165 (slope per unit time), R_pipe:abrupt:31@165 "
                        "(bias), a sensor's P_memb:bias:0.3@100 or an actuator's u_pump:gain:-0.2@100; a step "
                        "that comes and goes (intermittent) with its spans: R_pipe:abrupt:31@100-140,200-260,300 "
                        "(present from 100 to 140, from 200 to 260, and from 300 on)")
    p.add_argument("--noise", metavar="process=Q,measurement=R", help="noise levels as fractions of the signal")
    p.add_argument("--seed", type=seed, default=0, help="random seed, an integer >= 0")
    p.add_argument("--inputs", metavar="PROFILE.csv",
                   help="drive the plant with recorded inputs: a run file's u:NAME columns (or a logger's, with "
                        "--columns), each row's value over the step that ends at its time, the first row the first "
                        "step's; the model's signals drive the inputs it lacks")
    add_columns_option(p)
    add_signal_option(p)
    p.add_argument("--modes", metavar="MODE@TIME,...",
                   help="a model with modes: the controlled changes of mode, e.g. closed@12.5,open@30 (the "
                        "autonomous and timed ones happen by themselves)")
    p.add_argument("-o", "--output", metavar="FILE.csv")
    p.add_argument("--plot", metavar="FILE.png", help="also plot measurements and states")
    add_prior_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..api import cache
    from ..output import artifacts
    from ..analysis import simulate as sim

    from ..compiler.load import declares_modes

    if declares_modes(args.model):
        return _hybrid(args)
    if args.modes:
        raise BgcError(f"--modes: {printable(args.model)} has no modes", None, "drop --modes")
    c = cache.open_model(args.model, args.prior_scale).view
    process, measurement = parse_noise(args.noise)
    fault = sim.parse_fault(args.fault, c.numerics) if args.fault else None
    if args.steps is not None:
        sim.check_steps(args.steps, c.numerics, "--steps")
    unexpected = sim.outside_prior(fault, c.numerics, c.modules) if fault else None
    if unexpected:
        print(f"warning: {unexpected}", file=sys.stderr)
    recorded = _input_run(args, c)
    profile = None if recorded is None else sim.input_profile(recorded, tuple(u.name for u in c.model.inputs))
    signals = _signals(args, tuple(u.name for u in c.model.inputs), profile)
    options = sim.SimulationOptions(steps=args.steps, process_noise=process, measurement_noise=measurement,
                                    seed=args.seed, fault=fault, inputs=profile, signals=signals)
    start = time.perf_counter()
    result = sim.simulate(c.numerics, options)
    out = Path(args.output or f"{c.model.name}-run.csv")
    artifacts.write_file(out, sim.to_csv(result))
    print(f"wrote {printable(str(out))}: {len(result.time)} steps of {c.model.name}, fault: "
          f"{fault.describe() if fault else 'none'} ({time.perf_counter() - start:.2f} s)")
    if args.plot:
        from ..output import plots

        artifacts.write_file(Path(args.plot), plots.simulation_figure(
            result, "png", c.labels, sim.noise_free(c.numerics, options).clean_measurements))
        print(f"wrote {printable(args.plot)}")
    return 0


def _input_run(args: argparse.Namespace, view):
    """The run of ``--inputs FILE`` (read through ``--columns``), None
    without it; ``view``: the model's (``.model``), for its columns and
    its run file's default name."""
    from ..api.session import reading_of
    from ..data import runs

    if args.inputs is None:
        if args.columns is not None:
            raise BgcError("--columns applies to --inputs here: a column map reads a logger's file", None,
                           "give --inputs PROFILE.csv, or drop --columns")
        return None
    if Path(args.inputs).resolve() == Path(args.output or f"{view.model.name}-run.csv").resolve():
        raise BgcError(f"--inputs {printable(args.inputs)} is the file -o would write", None,
                       "write the run to another file")
    return runs.read_run(args.inputs, reading_of(view, args.columns))


def _signals(args: argparse.Namespace, names: tuple[str, ...], profile) -> tuple:
    """``--input`` signals, none of them driving an input ``profile`` records."""
    signals = signals_of(args.signals, names)
    both = sorted(set(dict(signals)) & set(profile.values if profile is not None else ()))
    if both:
        raise BgcError(f"--input {both[0]} and --inputs {printable(args.inputs)} both drive u:{both[0]}", None,
                       "give it one of them")
    return signals


def _recorded(args: argparse.Namespace, h) -> tuple:
    """A model with modes: the input profile (None: none) and the controlled
    changes of mode (:func:`bgc.analysis.hybrid.schedule_of`) of ``--inputs
    FILE`` (read through ``--columns``), () without it."""
    from ..analysis import hybrid, simulate as sim

    run = _input_run(args, h)
    if run is None:
        return None, ()
    names = tuple(u.name for u in h.model.inputs)
    profile = sim.input_profile(run, names) if run.inputs or run.modes is None else None
    if run.modes is None:
        return profile, ()
    if args.modes:
        raise BgcError(f"--modes and the mode column of --inputs {printable(args.inputs)} both set the mode", None,
                       "give one of them")
    return profile, hybrid.schedule_of(run, h.model)


def _hybrid(args: argparse.Namespace) -> int:
    """``bgc simulate`` of a model with modes: its automaton over each mode's equations (:mod:`bgc.analysis.hybrid`)."""
    from .. import pipeline
    from ..analysis import hybrid, simulate as sim
    from ..output import artifacts

    h = pipeline.check_model(args.model)
    profile, schedule = _recorded(args, h)
    nums = h.numerics(args.prior_scale)
    process, measurement = parse_noise(args.noise)
    fault = sim.parse_fault(args.fault, nums[0]) if args.fault else None
    if args.steps is not None:
        sim.check_steps(args.steps, nums[0], "--steps")
    unexpected = sim.outside_prior(fault, nums[0]) if fault else None  # (as for a model of one mode)
    if unexpected:
        print(f"warning: {unexpected}", file=sys.stderr)
    signals = _signals(args, tuple(u.name for u in h.model.inputs), profile)
    options = sim.SimulationOptions(steps=args.steps, process_noise=process, measurement_noise=measurement,
                                    seed=args.seed, fault=fault, signals=signals, inputs=profile)
    start = time.perf_counter()
    run = hybrid.simulate(h, nums, options, schedule or hybrid.parse_schedule(args.modes, h.model.modes.names))
    out = Path(args.output or f"{h.model.name}-run.csv")
    artifacts.write_file(out, hybrid.to_csv(run))
    print(f"wrote {printable(str(out))}: {len(run.result.time)} steps of {h.model.name}, {len(run.switches)} "
          f"switch{'es' if len(run.switches) != 1 else ''} of mode, fault: {fault.describe() if fault else 'none'} "
          f"({time.perf_counter() - start:.2f} s)")
    if args.plot:
        from ..output import plots
        from ..output.labels import labels_of

        artifacts.write_file(Path(args.plot), plots.simulation_figure(
            run.result, "png", labels_of(h.model), None, (run.modes, run.mode_names)))
        print(f"wrote {printable(args.plot)}")
    return 0
