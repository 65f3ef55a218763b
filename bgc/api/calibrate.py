"""The checks of a calibration's output file and of the calibrated model's text."""

from __future__ import annotations

import hashlib
from pathlib import Path


from ..errors import (
    CalibrationError, OutputError, printable,
)
from ..analysis import calibrate as calibration


def check_calibration_output(path: str | Path, model: str | Path, data=()) -> None:
    """Refuse, before any work, a calibrated model's path that is the model
    file, one of the ``data`` files, a folder, or an existing file bgc did
    not write (or that changed since): what :meth:`CalibrationReport.write`
    would refuse.

    Raises
    ------
    OutputError
        The path cannot take the calibrated model.
    """
    from ..output import artifacts

    out = Path(path)
    where = printable(str(out))
    for other, what in [(model, "the model file")] + [(d, "a data file") for d in data]:
        try:
            same = out.exists() and Path(other).exists() and out.samefile(other)
        except (OSError, TypeError):
            same = False
        if same:
            raise OutputError(f"{where} is {what}: a calibration never replaces it", None,
                              "write the calibrated model to a new file, e.g. -o calibrated.yaml")
    artifacts.check_writable(out, "the calibrated model")


def _model_text(path: str, c) -> str:
    """The model file's text, as it was compiled (its hash checked; ``c``: a
    :class:`bgc.pipeline.Compiled` or its view)."""
    try:
        text = Path(path).read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{printable(path)}: cannot read the model file again ({exc})", None,
                               "check the path") from None
    if hashlib.sha256(text.encode("utf-8")).hexdigest() != c.model.source_sha256:
        raise CalibrationError(f"{printable(path)} changed since it was compiled", None,
                               "open the model again (bgc.open) and calibrate")
    return text


def _check_calibrated(text: str, result: calibration.Calibration, c) -> None:
    """The calibrated text reads back, by bgc's own reader and validator
    (the compiler's first stages: sympy is imported here), with every
    estimate as written (else a bug: InternalError); ``c``: the model's
    compilation or its view."""
    from ..compiler import load, validate
    from ..errors import BgcError, InternalError
    from ..output.calibrated import number

    try:
        model = validate.validate(load.loads(text, c.model.source))
    except BgcError as exc:
        raise InternalError(f"the calibrated model does not read back: {exc.line()}") from None
    params = {p.name: p.value for p in model.parameters}
    sensors = {m.name: m.noise for m in model.measurements}
    for e in result.estimates:
        if not e.identifiable or e.kind == "initial":  # a recording's start: reported, not written
            continue
        got = {"measurement_noise": lambda: sensors[e.subject], "process_noise": lambda: model.settings.process_noise,
               "parameter": lambda: params[e.subject]}[e.kind]()
        want = float(number(e.level if e.kind != "parameter" else e.value))
        if got != want:
            raise InternalError(f"the calibrated model reads {e.name} as {got!r}, not {want!r}")
    allowed = {m.name: m.residual_variance_sd for m in model.measurements}
    for s, v in result.spread:
        if allowed.get(s) != float(number(v)):
            raise InternalError(f"the calibrated model reads {s}'s residual_variance_sd as {allowed.get(s)!r}, "
                                f"not {float(number(v))!r}")


def read_modes(model, record):
    """``record`` (a :class:`bgc.analysis.calibrate.Record` whose mode input
    is NaN: the data have no mode column) with each sample's mode as
    ``model`` (a generated model with modes, at its values) reads it from
    the measurements: the diagnosis's bank of cubature Kalman filters over
    the modes' histories (:class:`bgc.diagnosis.hidden.ModeDecoder`), each
    sample's likeliest mode once the data settle it."""
    import dataclasses

    import numpy as np

    from ..data.sampler import Sample
    from ..diagnosis.hidden import ModeDecoder

    decoder = ModeDecoder(model)
    ts = record.ts if record.ts is not None else (np.arange(len(record.ys)) + 1) * float(model.DT)
    decided = []
    for k in range(len(record.ys)):
        decided += decoder.push(Sample(k, float(ts[k]), record.us[k].copy(), record.ys[k].copy()))
    decided += decoder.flush()
    us = record.us.copy()
    column = model.MODE_INPUT
    for sample in decided:
        us[sample.k, column] = sample.u[column]
    return dataclasses.replace(record, us=us)
