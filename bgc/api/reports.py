"""What the API returns: a diagnosis's, a calibration's and a distinguishability prediction's report."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np


from .. import arguments
from ..ir import NoiseLevels
from ..analysis import distinguish as distinction
from ..output.labels import Labels
from ..data import runs
from ..analysis import simulate
from ..diagnosis.diagnose import Diagnosis
from ..diagnosis.options import DiagnosisOptions
from .calibrate import check_calibration_output


@dataclass(frozen=True, slots=True)
class DiagnosisReport:
    """A diagnosis and what it was made from: the model file, the run (read or
    simulated), the injected fault of a simulated ``scenario`` (None for data
    from a file or a fault-free scenario), the relative noise levels the
    filters assumed (None: the model's), and the options."""

    model: str
    source: str
    run: runs.Run
    scenario: str | None
    injected: simulate.FaultInjection | None
    noise: tuple[float | None, float | None]
    noise_levels: NoiseLevels
    options: DiagnosisOptions
    diagnosis: Diagnosis
    #: What each variable is and its unit, from the model (:mod:`bgc.output.labels`).
    labels: Labels = Labels()
    #: A monitor's stream (:func:`bgc.monitor`, ``bgc monitor``): the rows read in all and the first
    #: one's time; the run is the record the last diagnoser kept of them. None: the run is all the data.
    stream: tuple | None = None

    def __repr__(self) -> str:  # the run and the diagnosis hold arrays: the verdict is what a reader wants
        d = self.diagnosis
        return (f"<bgc.DiagnosisReport of {self.model}: {d.verdict}"
                + (f": {', '.join(d.candidates)}" if d.candidates else "") + ">")

    @property
    def fault_log(self) -> tuple:
        """A monitor's fault log (``episodes``: :func:`bgc.monitor`,
        ``bgc monitor --episodes``): its closed episodes and repairs, in
        order (:class:`~bgc.events.EpisodeClosed`, :class:`~bgc.events.Repaired`);
        empty for a diagnosis of one fault."""
        from .. import events as ev

        return tuple(e for e in self.diagnosis.events if isinstance(e, (ev.EpisodeClosed, ev.Repaired)))

    @property
    def intermittent(self) -> dict[str, dict]:
        """The faults of the log that went away without a repair, by
        parameter: ``spans`` (the (onset, end) it was present over, the end
        None while it is), ``values`` (the parameter's value estimated at
        each appearance) and their ``mean``; a repair of the parameter
        starts its story again (a fault of it after the repair is a new one).
        A diagnosis that names a fault coming and going as one fault node
        (:mod:`bgc.diagnosis.intermittent`) gives it too: its one value the
        parameter's while present (a sensor's or actuator's: the magnitude),
        ``magnitude`` with its ``interval``, the fault ``model``, and
        ``appeared`` / ``went``, per span, the interval of its times."""
        from .. import events as ev

        out: dict[str, dict] = {}
        d = getattr(self, "diagnosis", None)  # a monitor's fault log alone has none
        for h in () if d is None else d.hypotheses:
            i = h.intermittent
            if i is None or h.name not in d.candidates:
                continue
            t = d.time_of
            value = h.estimate.parameter_value if h.estimate.target == "parameter" else i.value
            out[h.parameter] = {
                "spans": [(t(s.on), None if s.off is None else t(s.off)) for s in i.spans],
                "values": [value], "mean": value, "model": h.name, "magnitude": i.value,
                "interval": (i.low, i.high),
                "appeared": [(t(s.on_low), t(s.on_high)) for s in i.spans],
                "went": [None if s.off is None else (t(s.off_low), t(s.off_high)) for s in i.spans]}
        for p in dict.fromkeys(e.parameter for e in self.fault_log if getattr(e, "action", None) == "ended"):
            last = max((i for i, e in enumerate(self.fault_log) if isinstance(e, ev.Repaired) and p in e.parameters),
                       default=-1)
            mine = [e for e in self.fault_log[last + 1:] if getattr(e, "parameter", None) == p
                    and e.action in ("accommodated", "ended")]
            if not any(e.action == "ended" for e in mine):
                continue
            each: dict[int, float] = {}  # per appearance, its value last estimated (a further change moves it)
            for e in mine:
                if e.action == "accommodated":
                    each[e.appearance] = e.value
            values = [each[k] for k in sorted(each)]  # none: named gone by a checkpoint's fault node at once
            out[p] = {"spans": mine[-1].present, "values": values,
                      "mean": sum(values) / len(values) if values else None}
        return out

    def write(self, folder: str | Path) -> Path:
        """Write the report folder ``bgc diagnose -o`` writes into ``folder``
        (report.md, report.json, report.html, the plots, the run when it was
        simulated, manifest.json): a new or empty folder, or one a diagnosis
        report was written to before and nobody changed since. Returns the
        folder.

        Raises
        ------
        ArgumentTypeError
            ``folder`` is not a path.
        OutputError
            ``folder`` is a file, or holds files bgc did not write (or that
            changed since), or another command's report.
        """
        arguments.path("bgc.DiagnosisReport.write", "folder", folder)
        from ..output import artifacts, report

        out = Path(folder)
        artifacts.write_folder(out, report.report_files(self))
        return out

    def to_dict(self) -> dict:
        """The report as plain data: what ``report.json`` holds (times in the
        model's time unit; docs/diagnosis.md, "report.json")."""
        from ..output import report

        return report.report_data(self)

    def table(self, what: str = "hypotheses"):
        """A part of the diagnosis as a :class:`~bgc.api.tables.Table`:
        ``hypotheses`` (one row per fault model tried: its onset, posterior,
        estimate with interval and ``estimate_method``, when and why it was
        dropped; times in the model's unit), ``series`` (per step: ``time``,
        each measurement ``y:NAME``, the nominal observer's prediction
        ``yhat:NAME`` and normalised residual ``z:NAME``) or ``events``
        (what happened, in time order, with its sentence)."""
        arguments.choice("bgc.DiagnosisReport.table", "what", what, ("hypotheses", "series", "events"))
        from .tables import Table

        d = self.diagnosis
        if what == "hypotheses":
            rows = [_hypothesis_row(d, h) for h in d.hypotheses]
            return Table.of(rows, HYPOTHESIS_COLUMNS)
        if what == "events":
            from ..output import events

            rows = [events.record(e, d.time_of, clock=d.clock) for e in d.events]
            return Table.of([{"time": r["time"], "event": r["event"], "sentence": r["text"]}
                             for r in rows], ("time", "event", "sentence"))
        columns = {"time": d.time}
        by_time = {float(t): k for k, t in enumerate(self.run.time)}  # a step without a sample: NaN
        at = np.array([by_time.get(float(t), -1) for t in d.time])
        for y in d.outputs:
            measured = self.run.measurements.get(y)
            columns[f"y:{y}"] = np.where(at >= 0, measured[at] if measured is not None else np.nan, np.nan)
        columns.update({f"yhat:{y}": d.nominal_y_mean[:, j] for j, y in enumerate(d.outputs)})
        columns.update({f"z:{y}": d.nominal_z[:, j] for j, y in enumerate(d.outputs)})
        names = tuple(columns)
        return Table(names, tuple(zip(*(np.asarray(columns[n], dtype=float).tolist() for n in names))))

    def to_frame(self, what: str = "hypotheses"):
        """:meth:`table` as a pandas DataFrame (``pip install 'bgc[data]'``)."""
        return self.table(what).to_frame()

    def figures(self) -> dict:
        """The report's plots as live :class:`matplotlib.figure.Figure`
        objects, by the file name :meth:`write` gives each:
        ``measurements.png`` and ``residuals.png``, and ``hypotheses.png``
        and ``estimate.png`` when a fault model was tried. Plain figures,
        not pyplot's: a notebook shows one when it is the cell's value
        (``%matplotlib inline``), ``fig.savefig(...)`` saves it."""
        from ..output import plots

        return plots.diagnosis_plots(self)

    def _repr_html_(self) -> str:
        """A notebook's view: the verdict in words, the detection, the
        estimate with its interval and its picture (:func:`bgc.output.summary.diagnosis_html`)."""
        from ..output import summary

        return summary.diagnosis_html(self)


@dataclass(frozen=True, slots=True)
class CalibrationReport:
    """A calibration (:meth:`Session.calibrate`): the model file, the
    model's name, the sensors whose noise, whether the process level and
    which parameters were estimated, the :class:`~bgc.analysis.calibrate.Calibration`
    (estimates, intervals, innovations) and ``text``, the calibrated model
    file (the user's text with the estimates in place, comments kept)."""

    model: str
    name: str
    sensors: tuple[str, ...]
    process: bool
    parameters: tuple[str, ...]
    calibration: calibration.Calibration
    text: str
    units: Mapping[str, str | None] = field(default_factory=dict)
    #: per recording without a mode column (a model with modes), the modes read from its measurements
    #: (:class:`~bgc.analysis.calibrate.ModesRead`)
    modes_read: tuple = ()

    def _repr_html_(self) -> str:
        """A notebook's view: whether the model fits the data, the estimates
        with their intervals and their picture (:func:`bgc.output.summary.calibration_html`)."""
        from ..output import summary

        return summary.calibration_html(self)

    def write_report(self, folder: str | Path) -> Path:
        """Write the calibration report into ``folder`` (report.md,
        report.html, report.json, estimates.png, residuals.png, autocorrelation.png;
        docs/calibrate.md, "The report"): a new or empty folder, or one a
        calibration report was written to before and nobody changed since.

        Raises
        ------
        OutputError
            ``folder`` is a file, or holds files bgc did not write.
        """
        arguments.path("bgc.CalibrationReport.write_report", "folder", folder)
        from ..output import artifacts, calibration_report

        out = Path(folder)
        artifacts.write_folder(out, calibration_report.report_files(self))
        return out

    def write(self, path: str | Path) -> Path:
        """Write the calibrated model to ``path`` (a new file, or one bgc
        wrote and nobody changed since: never the model file, a data file
        or another file bgc did not write).

        Raises
        ------
        OutputError
            ``path`` is the model file or a data file, or exists and bgc did
            not write it (or it changed since).
        """
        arguments.path("bgc.CalibrationReport.write", "path", path)
        check_calibration_output(path, self.model, self.calibration.sources)
        from ..output import artifacts

        return artifacts.write_file(Path(path), self.text)


@dataclass(frozen=True, slots=True)
class DistinguishabilityReport:
    """What the data of a model's scenarios are predicted to tell apart
    (:mod:`bgc.analysis.distinguish`): one :class:`Distinction` per scenario,
    over ``steps`` samples at the relative noise levels ``noise`` (None: the
    model's); ``scenario`` when one was asked for, else every fault
    candidate, kind and direction at a relative ``change`` of its parameter
    (a drift reaches it at the end of the run) from the fraction ``at`` of
    the run."""

    model: str
    source: str
    steps: int
    dt: float
    noise: tuple[float | None, float | None]
    scenario: str | None
    change: float | None
    at: float | None
    distinctions: tuple[distinction.Distinction, ...]
    #: Why the model's diagnoser would not expect the scenario's fault (outside its prior), or None.
    warning: str | None = None
    #: How often bgc's own detector alarmed on the scenario in simulated runs
    #: (:class:`bgc.api.detection.DetectorRate`; None: not measured)
    detector: object | None = None
    #: The inputs driven otherwise than the model says: (name, :class:`~bgc.ir.Signal`) pairs
    signals: tuple = ()
    #: A model with modes: the controlled changes asked for (``MODE@TIME,...``); "" : the modes its
    #: guards and timed transitions reach; None: a model of one mode
    modes: str | None = None
    #: An intermittent fault that goes away inside the run: ``steps`` are those before it first does
    #: (its first appearance is told apart, as a step)
    first_appearance: bool = False
    #: The model's time unit (None: not named)
    time_unit: str | None = None


#: The columns of :meth:`DiagnosisReport.table` ``("hypotheses")``.
HYPOTHESIS_COLUMNS = ("model", "parameter", "kind", "target", "onset", "posterior", "candidate", "estimate",
                      "low", "high", "std", "level", "magnitude", "estimate_method", "parameter_value", "truth",
                      "dropped", "reason")


def _hypothesis_row(d: Diagnosis, h) -> dict:
    """One hypothesis of ``d`` as a row of plain values (times in the model's unit)."""
    e = h.estimate
    return {"model": h.name, "parameter": h.parameter, "kind": h.kind, "target": e.target,
            "onset": d.time_of(h.onset_step), "posterior": float(h.posterior), "candidate": h.name in d.candidates,
            "estimate": float(e.value), "low": float(e.low), "high": float(e.high), "std": float(e.std),
            "level": float(e.level), "magnitude": e.magnitude, "estimate_method": e.method,
            "parameter_value": float(e.parameter_value), "truth": e.truth,
            "dropped": d.time_of(h.dropped_step), "reason": h.reason or None}
