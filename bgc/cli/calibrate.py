"""``bgc calibrate``: noise levels and nominal values from healthy recordings, into a new model file."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ..errors import printable
from .common import add_backend_option, add_columns_option, backend_note, refuse_input_in_output


def add_parser(sub) -> None:
    p = sub.add_parser("calibrate", help="estimate noise levels and nominal values from healthy recordings, and "
                                         "write the calibrated model (a new YAML)")
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--data", nargs="+", required=True, metavar="HEALTHY.csv",
                   help="fault-free recordings of the plant (run files, as bgc simulate writes)")
    p.add_argument("--estimate", default="noise", metavar="WHAT",
                   help="what to estimate, separated by commas: noise (every sensor's noise and the process "
                        "level), measurement_noise, process_noise, initial (each recording's initial state), "
                        "parameter names (default: noise)")
    p.add_argument("-o", "--output", required=True, metavar="CALIBRATED.yaml",
                   help="the calibrated model: a new file (never the model file, nor a file bgc did not write)")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="the calibration report's folder: report.md, report.json, report.html, pictures (default: "
                        "CALIBRATED-report beside the calibrated model)")
    add_columns_option(p)
    p.add_argument("--input-timing", choices=("end", "start"), default=None,
                   help="what a row's u: value is: end, held over the step that ends at the row's time, or start, "
                        "set at the row's time (default: as each file's header says, else end)")
    add_backend_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from .. import api

    from ..api.calibrate import check_calibration_output

    from ..output import artifacts, calibration_report

    out = Path(args.output)
    folder = Path(args.report) if args.report else out.with_name(out.stem + "-report")
    check_calibration_output(out, args.model, args.data)  # before any work
    for item in args.data:
        refuse_input_in_output(item, folder)
    artifacts.check_folder(folder, (*calibration_report.PICTURES, "report.md", "report.json", "report.html",
                                    "manifest.json"),
                           "calibrate")
    start = time.perf_counter()
    session = api.open(args.model, backend=args.backend)
    backend_note(session, args)
    report = session.calibrate(list(args.data), args.estimate, columns=args.columns, input_timing=args.input_timing)
    report.write(out)
    report.write_report(folder)
    cal = report.calibration
    print(f"wrote {printable(str(out))}: {report.name} calibrated on {cal.samples} samples of "
          f"{', '.join(printable(s) for s in cal.sources)} ({time.perf_counter() - start:.1f} s); report in "
          f"{printable(str(folder))}")
    for m in report.modes_read:  # a model with modes, data without a mode column
        print(printable(f"  modes read from {m.source}'s measurements: {len(m.switches)} switch(es), "
                        f"{m.rounds} round(s) of reading and calibrating, {m.moved} sample(s) read otherwise by "
                        "the calibrated model"))
    for e in cal.estimates:
        if not e.identifiable:
            print(printable(f"  {e.name}: not identifiable, kept at {e.start_level:.6g} ({e.why})"))
            continue
        std = f" (std {e.value:.4g} in [{e.low:.4g}, {e.high:.4g}])" if e.kind == "measurement_noise" else ""
        bound = ""
        if e.at_bound:
            bound = ", the data show none" if e.value == 0 else ", at the end of the range searched"
        print(printable(f"  {e.name}: {e.level:.6g} in [{e.level_low:.6g}, {e.level_high:.6g}] (95 %){std}, "
                        f"was {e.start_level:.6g}{bound}"))
    for i in cal.innovations:
        print(printable(f"  innovations of {i.sensor}: mean {i.mean:+.3f}, variance {i.variance:.3f}, Ljung-Box "
                        f"p = {i.p_value:.3g} ({i.lags} lags)"))
    print(printable(f"  {cal.verdict}"))
    return 0
